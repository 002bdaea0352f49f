//! The job again on a graph that grew since its last solution
//! ([`crate::PoseGraph::update`]): the last map and decisions are the
//! start, new poses are composed along trusted edges, and only as much is
//! solved as the additions need.
//!
//! 1. Nothing added: the last solution stands.
//! 2. Only new poses, each hung on the map by one trusted edge (odometry
//!    to a new keyframe): composing them gives the optimum exactly, since
//!    each new edge can be met with zero error and leaves the rest of the
//!    map's optimality conditions untouched.
//! 3. Otherwise the gate is learned again from every count (a 1-D EM over
//!    the distinct counts, and what a batch job would find), and EM
//!    decides every candidate by its innovation starting from the last
//!    accepted set and the last map ([`robust::resume`]): the decisions
//!    the new evidence does not touch come back as they were after one
//!    solve and one evaluation; the χ² search acts on a failed test as in
//!    the batch job. Where the new trusted edges only hang new poses on
//!    the map, EM starts with the new candidates the last loop model
//!    accepts against it ([`robust::Proposal`]), which saves the round
//!    that would find them. Where the last decisions are no start the
//!    batch job's decisions can be reached from (a kernel method, fewer
//!    candidates than EM's model needs, no last loop model, no accepted
//!    loop: [`untrusted_start`]) the whole job runs instead, and so it
//!    does where EM's decisions from the last ones swung or rejected a
//!    loop the last update accepted: the new evidence overturned the
//!    consensus the last decisions stood for. An exact update whose map
//!    fails its test, whose decisions did not settle, whose model calls
//!    wrong a population the information calls consistent, that accepts
//!    a loop the information calls an outlier (once per such loop: the
//!    loops the last whole job's two starts kept are remembered) or that
//!    holds loops back by their counts runs the whole job too: the batch
//!    job would seek EM's second start there, or its annealing may accept
//!    what the warm decisions held back. So does one that leaves a
//!    candidate's posterior near ½: there EM can have two fixed points,
//!    and which one a solve ends at depends on where it started.

use super::{Error, Settings, candidates, finish};
use crate::geometry::Pose;
use crate::graph::{Graph, VertexId};
use crate::io::g2o::G2oPose;
use crate::report::{
    DecisionChange, IncrementalReport, InitializationReport, LoopReport, OptimizerReport, Report,
    UpdateSolve,
};
use crate::robust::{self, RobustMethod, Test};
use crate::solve::init::{ChordalInit, Initialization, grow_tree};
use crate::solve::{Observer, Optimizer, Ordering, Session, SolveSettings, Spare};
use crate::stats::Chi2Test;
use std::time::Instant;

/// An update's solves stop once an iteration lowers the objective by less
/// than this share of it, as a batch job's do. The stop says how far the
/// *last* step went, not how far the map still is from the optimum: from
/// an iteration that lowered the objective by `τ·χ²` the poses were about
/// `√(τ·χ²/H)` from the optimum (`H` the information along the step), and
/// Gauss–Newton's quadratic convergence leaves them about the square of
/// that after it. The randomized replays of `tests/update_equals_optimize.rs`
/// (every update compared with a batch job, issue 47) measured, with the
/// decisions equal: 10⁻⁴ (with a model tolerance of 10⁻⁸) left poses up to
/// 1.3·10⁻⁵ of the map's size and rotations 3·10⁻⁵ rad from the batch's;
/// 10⁻⁶ positions within 1.4·10⁻⁷ of the size but rotations 3·10⁻⁶ rad
/// apart; 10⁻⁸ every pose within 10⁻⁶ on CI's replays, but on the wider
/// ones with aliases placed anywhere (`wider_aliased_replays`) rotations
/// 1.0–1.2·10⁻⁶ rad apart on 6 of 96 (a check that then read SE(2)'s `y`
/// with `θ`); 10⁻⁹ none, at 11 %
/// more factorisations than 10⁻⁸ (manhattanOlson3500 every 10 poses,
/// `examples/replay`: 1125 against 1013). A capped update
/// ([`update_solver`]) keeps the looser [`CAPPED_TOLERANCE`]: it promises
/// a latency, not the batch map, and an update with nothing added
/// finishes it.
pub const UPDATE_TOLERANCE: f64 = 1e-9;

/// A capped update's ([`crate::Options`]' `update_iterations`) relative
/// tolerance and model tolerance
/// ([`crate::solve::SolveSettings::model_tolerance`]): it stops after a step
/// whose decrease the Gauss–Newton model foresaw to within this share of
/// the objective (manhattanOlson3500 replayed every pose with one
/// iteration per update: 1411 solves instead of 2013).
pub const CAPPED_TOLERANCE: f64 = 1e-4;

/// How far a pose may have moved (the largest component of its
/// tangent-space move: metres, radians) since its block of the factor was
/// last formed for a capped update to keep that block's panels
/// ([`crate::solve::SolveSettings::keep_factor`]). An edge's Jacobians turn
/// with its ends' rotations and scale with the relative translation, so
/// such a move changes them by about this share of an edge of a metre
/// (odometry's scale in the replayed maps): the kept factor is that of a
/// matrix off by about 1 %, whose step LM's gain ratio still judges.
/// iSAM2's relinearisation threshold is 0.1 by default. On
/// manhattanOlson3500 replayed every pose, the panels formed again hold
/// 32 %, 41 % and 49 % of whole factorisations' flops at 0.1, 10⁻² and 10⁻³
/// (29 % with no pose moving; `examples/refactor_share … --capped`).
pub const KEEP_FACTOR_MOVE: f64 = 1e-2;

/// What a graph keeps between updates: the last solution's poses (of its
/// first `poses.len()` vertices), how many edges it had, whether each
/// candidate edge was accepted, the last report (returned again when
/// nothing was added), the elimination order and what the last optimiser
/// spares the next ([`Spare`]). Its memory is that of the poses, one byte
/// per edge, four bytes per pose (the order), the linear system's layout
/// for the next one to grow from (16 bytes per edge, 8 per pose and per
/// pair of poses an edge joins, 4 per block row of the factor's
/// supernodes), the report (about 100 bytes per loop candidate), the
/// factor's values (8 bytes each) and the prepared poses and measurements
/// (SE(2): 64 bytes per pose and 40 per edge; SE(3): 184 and 128).
#[derive(Clone, Debug)]
pub(crate) struct Warm<P: Pose<D>, const D: usize> {
    poses: Vec<P>,
    edges: usize,
    /// Per edge: `Some(accepted)` for a loop candidate, `None` for a
    /// trusted edge.
    accepted: Vec<Option<bool>>,
    report: Report,
    /// The elimination order of the last solve, for the next.
    ordering: Ordering,
    /// Whether the last solve converged (to an update's tolerances: poses
    /// hung on its map by odometry are composed, not solved).
    converged: bool,
    /// Whether it converged to a job's strict tolerances, not a capped
    /// update's looser ones ([`update_solver`]): an update with nothing
    /// added then has nothing to do.
    settled: bool,
    /// The last optimiser's allocation and preparations, for the next
    /// update's.
    spare: Spare<P, D>,
    /// The accepted loops beyond the information as stated
    /// ([`beyond_stated`]) that the last whole job's two starts kept: an
    /// update that accepts only these does not run the whole job again.
    examined: Vec<(VertexId, VertexId)>,
}

impl<P: Pose<D>, const D: usize> Warm<P, D> {
    /// The state after a job on `graph` that made `report`.
    pub(crate) fn after(graph: &Graph<P, D>, report: &Report, ordering: Ordering) -> Self {
        let mut accepted = vec![None; graph.edges.len()];
        let candidates = (0..graph.edges.len()).filter(|&k| graph.edges[k].is_candidate());
        for (k, l) in candidates.zip(&report.loops) {
            accepted[k] = Some(l.accepted);
        }
        Self {
            poses: graph.poses.clone(),
            edges: graph.edges.len(),
            accepted,
            report: report.clone(),
            ordering,
            converged: report.optimizer.converged,
            settled: report.optimizer.converged,
            spare: Spare::default(),
            examined: if report.robust.starts.len() > 1 {
                beyond_stated(report)
            } else {
                Vec::new()
            },
        }
    }
}

/// Solves `graph` again from the state `warm` of its last solution (see
/// the module doc), leaving the map in `graph` and filling `report`.
/// Returns the state to keep, or `Err(reason)` when the last decisions
/// are no start the batch job's decisions can be reached from
/// ([`untrusted_start`]), or EM's decisions swung
/// ([`robust::Outcome::swung`]) or rejected a loop the last update
/// accepted ([`REVERSED`]): the caller then runs the whole job.
pub(crate) fn update_graph<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    warm: &mut Warm<P, D>,
    config: &Settings<'_>,
    report: &mut Report,
    observer: &mut dyn Observer,
) -> Result<Result<Warm<P, D>, &'static str>, Error> {
    let start = Instant::now();
    let added = place(graph, warm);
    candidates::mark(graph, config.options.gate.candidates);
    let new_candidates = (warm.edges..graph.edges.len())
        .filter(|&k| graph.edges[k].is_candidate())
        .count();
    let mut step = IncrementalReport {
        solve: UpdateSolve::Warm,
        reason: String::new(),
        new_poses: graph.num_vertices() - warm.poses.len(),
        new_edges: graph.edges.len() - warm.edges,
        new_candidates,
        changed: Vec::new(),
    };
    // Nothing added: the last map stands if it settled, else its solve
    // goes on (a capped update's, to a batch job's tolerance).
    let closing = step.new_edges == 0 && step.new_poses == 0;
    if closing && warm.settled {
        *report = warm.report.clone();
        step.solve = UpdateSolve::None;
        step.reason = "nothing added".into();
        report.incremental = Some(step);
        let mut next = warm.clone();
        next.spare = std::mem::take(&mut warm.spare);
        return Ok(Ok(next));
    }
    if !closing && new_candidates == 0 && added.all_by_tree && warm.converged {
        extended(graph, warm, config, report, start);
        step.solve = UpdateSolve::Extended;
        step.reason = "only poses hung on the map by one trusted edge each".into();
        report.incremental = Some(step);
        let mut next = Warm::after(graph, report, warm.ordering.clone());
        next.settled = warm.settled;
        next.spare = std::mem::take(&mut warm.spare);
        next.examined = warm.examined.clone();
        return Ok(Ok(next));
    }
    let spare = std::mem::take(&mut warm.spare);
    let Resolved {
        full,
        previous,
        ordering,
        spare,
        strict,
    } = match resolve(
        graph,
        (warm, added.trusted_by_tree, closing, spare),
        config,
        report,
        observer,
        start,
    )? {
        Ok(resolved) => resolved,
        Err(reason) => return Ok(Err(reason)),
    };
    step.solve = if full {
        UpdateSolve::Full
    } else {
        UpdateSolve::Warm
    };
    step.reason = solve_reason(full, closing, config.options.robust.method, report);
    step.changed = changes(graph, &previous, report);
    if !full && step.changed.iter().any(|c| !c.accepted) {
        return Ok(Err(REVERSED));
    }
    report.incremental = Some(step);
    let mut next = Warm::after(graph, report, ordering);
    next.settled &= strict;
    next.spare = spare;
    next.examined = warm.examined.clone();
    Ok(Ok(next))
}

/// Why an update that solved did so as it did: from the last decisions
/// (`full` false) or every candidate weighed again, after `closing` (nothing
/// added) or new edges.
fn solve_reason(full: bool, closing: bool, robust: RobustMethod, report: &Report) -> String {
    match (full, robust) {
        _ if closing => "nothing added: the last map's solve continued".into(),
        (false, _) if report.loops.is_empty() => "new edges: solved from the last map".into(),
        (false, _) => "new edges: EM's decisions from the last ones".into(),
        (true, RobustMethod::Em) => format!(
            "fewer than {} candidates: every one weighed again by the kernel",
            robust::MIN_CANDIDATES
        ),
        (true, m) => format!("every candidate weighed again by {}", m.name()),
    }
}

/// The earlier decisions (`previous`, by edge) that `report`'s differ from.
fn changes<P: G2oPose<D>, const D: usize>(
    graph: &Graph<P, D>,
    previous: &[Option<bool>],
    report: &Report,
) -> Vec<DecisionChange> {
    let candidate_edges = (0..graph.edges.len()).filter(|&k| graph.edges[k].is_candidate());
    (candidate_edges.zip(&report.loops))
        .filter(|&(k, l)| {
            previous
                .get(k)
                .copied()
                .flatten()
                .is_some_and(|a| a != l.accepted)
        })
        .map(|(k, l)| DecisionChange {
            index: k,
            from: l.from,
            to: l.to,
            accepted: l.accepted,
            reason: l.reason,
        })
        .collect()
}

/// The account of an update that ran the whole job on `graph` (its
/// outcome in `report`) for `reason` (the last decisions, in `warm`, were
/// no start to resume from, or EM's decisions from them swung): what was
/// added since and which earlier decisions the job changed.
pub(crate) fn after_fallback<P: G2oPose<D>, const D: usize>(
    graph: &Graph<P, D>,
    warm: &Warm<P, D>,
    report: &Report,
    reason: &str,
) -> IncrementalReport {
    IncrementalReport {
        solve: UpdateSolve::Batch,
        reason: reason.into(),
        new_poses: graph.num_vertices() - warm.poses.len(),
        new_edges: graph.edges.len() - warm.edges,
        new_candidates: (warm.edges..graph.edges.len())
            .filter(|&k| graph.edges[k].is_candidate())
            .count(),
        changed: changes(graph, &warm.accepted, report),
    }
}

/// How the new poses were placed.
struct Placed {
    /// Whether every new edge is trusted and placed a new pose (so that
    /// the map stays optimal without a solve).
    all_by_tree: bool,
    /// Whether every new trusted edge placed a new pose (so that the map
    /// is the optimum of the last accepted set, the new candidates left
    /// out).
    trusted_by_tree: bool,
}

/// Puts the last solution's poses back and composes every new pose along
/// trusted edges from them (a pose no trusted edge reaches keeps the
/// caller's).
fn place<P: G2oPose<D>, const D: usize>(graph: &mut Graph<P, D>, warm: &Warm<P, D>) -> Placed {
    let old = warm.poses.len();
    graph.poses[..old].clone_from_slice(&warm.poses);
    // Old edges join old poses only: the new trusted edges reach every
    // new pose that any trusted edge reaches.
    let trusted: Vec<usize> = (warm.edges..graph.edges.len())
        .filter(|&k| !graph.edges[k].is_candidate())
        .collect();
    let mut known: Vec<bool> = (0..graph.num_vertices()).map(|k| k < old).collect();
    grow_tree(graph, &mut known, &trusted);
    let new_edges = &graph.edges[warm.edges..];
    let trusted_by_tree = known.iter().all(|&k| k) && trusted.len() == graph.num_vertices() - old;
    Placed {
        all_by_tree: trusted_by_tree && new_edges.len() == trusted.len(),
        trusted_by_tree,
    }
}

/// The report of an extension: the last decisions, and the last χ² and
/// χ² test with the new edges' own χ² (composition meets them to rounding)
/// and constraints added; the degrees of freedom of the residual do not
/// change, as each new edge brings one new pose.
fn extended<P: G2oPose<D>, const D: usize>(
    graph: &Graph<P, D>,
    warm: &Warm<P, D>,
    config: &Settings<'_>,
    report: &mut Report,
    start: Instant,
) {
    let new_edges = &graph.edges[warm.edges..];
    let added: f64 = new_edges.iter().map(|e| graph.edge_chi2(e)).sum();
    let chi2 = warm.report.optimizer.final_chi2 + added;
    report.gate = warm.report.gate.clone();
    report.robust = warm.report.robust.clone();
    report.loops = warm.report.loops.clone();
    report.input_chi2 = chi2;
    report.initialization = InitializationReport {
        method: Initialization::Previous,
        chi2,
        time_s: start.elapsed().as_secs_f64(),
        vertices_without_line: 0,
    };
    report.optimizer = OptimizerReport {
        solver: warm.report.optimizer.solver,
        initial_chi2: chi2,
        final_chi2: chi2,
        initial_objective: chi2,
        final_objective: chi2,
        converged: true,
        ..OptimizerReport::default()
    };
    let test = match &warm.report.chi2_test {
        Some(t) => Chi2Test::new(
            t.d2 + added,
            t.dof_constraints + new_edges.len() as u64,
            t.dof_residual,
            config.options.test.dof,
            config.options.test.alpha,
        ),
        None => {
            let weights: Vec<f64> = (0..graph.edges.len())
                .map(|k| match warm.accepted.get(k).copied().flatten() {
                    Some(false) => 0.0,
                    _ => 1.0,
                })
                .collect();
            finish::chi2_test(graph, &weights, config)
        }
    };
    match test {
        Ok(t) => report.chi2_test = Some(t),
        Err(e) => report.warnings.push(format!("no χ² test: {e}")),
    }
}

/// The weights to start the robust solve from — the last accepted set,
/// and what joins new parts to it — and each edge's earlier decision
/// (`None` for a trusted or new edge).
fn start_weights<P: G2oPose<D>, const D: usize>(
    graph: &Graph<P, D>,
    warm: &Warm<P, D>,
    candidates: &[robust::Candidate],
    method: RobustMethod,
) -> (Vec<f64>, Vec<Option<bool>>) {
    let mut previous = warm.accepted.clone();
    previous.resize(graph.edges.len(), None);
    let mut weights = candidates::initial_weights(graph, candidates, method == RobustMethod::None);
    for c in candidates {
        if previous[c.edge] == Some(true) {
            weights[c.edge] = 1.0;
        }
    }
    (weights, previous)
}

/// The most iterations of each of an update's solves: the options', but
/// an update whose candidates EM decides converges, as EM judges each loop
/// by its innovation at the optimum of the others (capped, its decisions
/// swung and the replays fell back to whole jobs: the aliased manhattan
/// replay every 100 poses took 6 whole jobs instead of 1, and 2.5 times
/// as long).
fn update_iterations(config: &Settings<'_>, method: RobustMethod) -> Option<usize> {
    match config.options.solver.update_iterations {
        Some(k) if method == RobustMethod::None => Some(k.min(config.solver.max_iterations)),
        _ => None,
    }
}

/// The options of an update's solves: its iteration bound
/// ([`update_iterations`]), and an update's tolerance
/// ([`UPDATE_TOLERANCE`]; capped, [`CAPPED_TOLERANCE`]) or, `closing`
/// (nothing added: a capped update's convergence carried on), a batch
/// job's.
///
/// A capped update's solve also stops, converged to an update's
/// tolerance, after a step whose decrease the Gauss–Newton model foresaw
/// to within [`CAPPED_TOLERANCE`] of the objective: the model then holds
/// but for about that much, so the next step would take out about that
/// much — less than the relative decrease an update's convergence asks
/// for. The poses hung on its map by odometry are then composed, not
/// solved again (manhattanOlson3500 replayed every pose with one iteration
/// per update: 1411 solves instead of 2013, the map before the closing
/// update 9·10⁻⁷ above the batch χ²). It is not *settled*: an update with
/// nothing added finishes it to a batch job's tolerance. Returns whether
/// the solve is held to the strict tolerances (`false`: capped).
fn update_solver<P: Pose<D>, const D: usize>(
    config: &Settings<'_>,
    method: RobustMethod,
    closing: bool,
    graph: &Graph<P, D>,
) -> (SolveSettings, bool) {
    let cap = update_iterations(config, method);
    let max_iterations = cap.unwrap_or(config.solver.max_iterations);
    let end_step = Some(finish::end_step(graph));
    if closing {
        let solver = SolveSettings {
            max_iterations,
            reuse_factor: true,
            end_step,
            ..config.solver.clone()
        };
        return (solver, true);
    }
    let solver = SolveSettings {
        relative_tolerance: match cap {
            Some(_) => CAPPED_TOLERANCE,
            None => UPDATE_TOLERANCE,
        },
        model_tolerance: cap.map(|_| CAPPED_TOLERANCE),
        keep_factor: cap.map(|_| KEEP_FACTOR_MOVE),
        reuse_factor: true,
        end_step: end_step.filter(|_| cap.is_none()),
        max_iterations,
        ..config.solver.clone()
    };
    (solver, cap.is_none())
}

/// The report's start of an update: the χ² of the placed map — the old
/// poses are the last map's ([`place`]), so their edges' χ² is the last
/// report's and only the new edges are evaluated.
fn report_start<P: G2oPose<D>, const D: usize>(
    graph: &Graph<P, D>,
    warm: &Warm<P, D>,
    report: &mut Report,
    start: Instant,
) {
    let added: f64 = (graph.edges[warm.edges..].iter())
        .map(|e| graph.edge_chi2(e))
        .sum();
    report.input_chi2 = warm.report.optimizer.final_chi2 + added;
    report.initialization = InitializationReport {
        method: Initialization::Previous,
        chi2: report.input_chi2,
        time_s: start.elapsed().as_secs_f64(),
        vertices_without_line: 0,
    };
}

/// What [`resolve`] returns.
struct Resolved<P: Pose<D>, const D: usize> {
    /// Whether every candidate was weighed again.
    full: bool,
    /// Each edge's earlier decision.
    previous: Vec<Option<bool>>,
    /// The elimination order used.
    ordering: Ordering,
    /// What the optimiser spares the next update's.
    spare: Spare<P, D>,
    /// Whether the solve was held to the strict tolerances
    /// ([`update_solver`]).
    strict: bool,
}

/// The gate, and the robust solve from the last decisions (and, where the
/// placed map is the last accepted set's optimum, `optimal`, the new
/// candidates the last loop model accepts against it); `closing`: nothing
/// was added, and the last solve, cut short, is finished to a batch job's
/// tolerance; `spare`: what the last update's optimiser spared this one.
/// Returns [`Resolved`], or `Err(reason)` when the last decisions are no
/// start to resume from ([`untrusted_start`]) or EM's decisions swung.
fn resolve<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    (warm, optimal, closing, spare): (&Warm<P, D>, bool, bool, Spare<P, D>),
    config: &Settings<'_>,
    report: &mut Report,
    observer: &mut dyn Observer,
    start: Instant,
) -> Result<Result<Resolved<P, D>, &'static str>, Error> {
    let solve_error = Error::from;
    let gating = Instant::now();
    let candidates = candidates::gate(graph, config, report);
    report.time.gate_s = gating.elapsed().as_secs_f64();
    let method = if candidates.iter().any(|c| c.kept) {
        config.options.robust.method
    } else {
        RobustMethod::None
    };
    if let Some(reason) = untrusted_start(warm, method, candidates.len()) {
        return Ok(Err(reason));
    }
    if gated_out(warm, &candidates) {
        return Ok(Err(GATED_OUT));
    }
    let (mut weights, previous) = start_weights(graph, warm, &candidates, method);
    let (solver, strict) = update_solver(config, method, closing, graph);
    let evaluated = method != RobustMethod::None;
    let ordering = Some(warm.ordering.clone().for_innovations(evaluated));
    let mut optimizer = Optimizer::with_ordering(graph, Some(&weights), solver.clone(), ordering)
        .map_err(solve_error)?;
    optimizer.reuse_spare(spare);
    report_start(graph, warm, report, start);
    let proposal = (warm.report.robust.model.as_ref())
        .filter(|_| optimal)
        .map(|model| robust::Proposal {
            model,
            new: (0..candidates.len())
                .filter(|&k| candidates[k].edge >= warm.edges)
                .collect(),
        });
    let (mut full, mut swung) = (false, false);
    let weigh =
        |session: &mut Session<'_, P, D>, weights: &mut [f64], c: f64, test: &Test<'_, P, D>| {
            let job = robust::Job {
                candidates: &candidates,
                method,
                c,
                layers: &config.options.expert.layers,
                test,
                chordal: false,
                given: None,
            };
            let (outcome, all) = robust::resume(session, weights, &job, proposal.as_ref())?;
            full = all;
            swung = outcome.swung;
            Ok(outcome)
        };
    let run = finish::Run {
        config,
        solver,
        candidates: &candidates,
        method,
    };
    run.solve_and_test(graph, &mut optimizer, &mut weights, weigh, report, observer)?;
    if swung {
        return Ok(Err(SWUNG));
    }
    let ordering = optimizer.ordering().cloned().unwrap_or_default();
    let spare = optimizer.take_spare();
    Ok(Ok(Resolved {
        full,
        previous,
        ordering,
        spare,
        strict,
    }))
}

/// The reason of an update whose EM decisions swung from the last ones.
const SWUNG: &str = "EM's decisions from the last ones swung: the whole job";

/// The reason of an update whose EM decisions, from the last ones,
/// rejected a loop the last update accepted. The last decisions are a
/// start the batch job's decisions are reached from because they are the
/// consensus its annealing would find; evidence that takes an accepted
/// loop out has overturned that consensus, and EM from it can end at
/// another fixed point than the annealing's (a sphere with aliased groups,
/// `tests/update_equals_optimize.rs`: two true loops rejected, χ² 1.3 %
/// above the batch job's, poses 4 % of the map's size apart).
const REVERSED: &str = "EM's decisions rejected a loop the last update accepted: the whole job";

/// The reason of an update whose map failed the χ² test: the whole job
/// tries EM's second start, as `optimize()` does (docs/method.md §5).
const FAILED: &str = "the update's map failed the χ² test: the whole job, with its second start";

/// The reason of an update whose EM decisions did not settle (a loop
/// `unsettled`): the whole job tries EM's second start, as `optimize()`
/// does (docs/method.md §5).
const UNSETTLED: &str =
    "the update's decisions did not settle: the whole job, with its second start";

/// The reason of an update whose loop model calls a population of
/// candidates wrong that the file's information calls consistent: the
/// whole job tries EM's second start, as `optimize()` does
/// (docs/method.md §5).
const WITHIN_KERNEL: &str = "the update's model calls wrong a population the information calls consistent: \
     the whole job, with its second start";

/// The reason of an update whose model accepts a candidate that the file's
/// information calls an outlier: the whole job tries EM's second start, as
/// `optimize()` does (docs/method.md §5).
const BEYOND_STATED: &str = "the update accepts a loop the information calls an outlier: \
     the whole job, with its second start";

/// The accepted loops of `report` beyond the reach of the information as
/// stated ([`crate::robust::LoopModel::stated_bound`]), by their ends.
fn beyond_stated(report: &Report) -> Vec<(VertexId, VertexId)> {
    let (Some(model), Some(test)) = (report.robust.model.as_ref(), report.chi2_test.as_ref())
    else {
        return Vec::new();
    };
    let accepted: Vec<(&LoopReport, f64)> = (report.loops.iter())
        .filter(|l| l.accepted)
        .filter_map(|l| l.innovation.filter(|&v| v > 0.0).map(|v| (l, v)))
        .collect();
    let Some(bound) = model.stated_bound(accepted.len(), test.alpha) else {
        return Vec::new();
    };
    (accepted.into_iter())
        .filter(|&(_, nu2)| nu2 > bound)
        .map(|(l, _)| (l.from, l.to))
        .collect()
}

/// The reason of an update whose map holds loops back by their counts
/// (true-looking innovations, counts that call them wrong): EM from the
/// last decisions can hold there a run of true loops that the batch job's
/// annealing accepts (docs/method.md §7b).
const HELD_BACK: &str = "the update's map holds loops back by their counts: the whole job";

/// The reason of an update with a candidate on a knife edge
/// ([`on_knife_edge`]).
const KNIFE_EDGE: &str = "a candidate's posterior lies near ½: the whole job";

/// Posterior odds of a true loop within this factor (as a natural
/// logarithm) of even — posteriors from 0.27 to 0.73 — put a candidate on
/// a knife edge: its own decision moves the true loops' fit, and with it
/// its posterior, enough that accepted and rejected can both be fixed
/// points of EM, and which one a solve ends at depends on where it started
/// (the warm decisions or the batch job's annealing). Of the 192 wider
/// replays of `tests/update_equals_optimize.rs`, five differed from the
/// batch job at such a candidate: at three its posteriors at the two
/// fixed points were 0.08–0.31 nat apart in log-odds (0.44 and 0.52 the
/// widest), at one both were 0.52 (the true loops' reach decided), at one
/// the update's was 0.56 (its model of nothing). One nat is three times
/// the widest gap.
const KNIFE_EDGE_LN_ODDS: f64 = 1.0;

/// Whether a candidate of `report` has a posterior on a knife edge
/// ([`KNIFE_EDGE_LN_ODDS`]).
fn on_knife_edge(report: &Report) -> bool {
    (report.loops.iter())
        .filter_map(|l| l.posterior)
        .any(|p| (p / (1.0 - p)).ln().abs() < KNIFE_EDGE_LN_ODDS)
}

/// Why the last decisions, in `warm`, are no start from which the robust
/// solve `method` of `candidates` candidates reaches the batch job's
/// decisions and map (`None`: they are). The batch job weighs the
/// candidates from the trusted edges' map (annealing, a second start from
/// the caller's poses); an update resumes from the last map and decisions,
/// which reaches the same end only where that end is the one fixed point
/// the last decisions lead to:
///
/// * a robust kernel (or EM's kernel, with fewer than
///   [`robust::MIN_CANDIDATES`]) weighs every candidate again from the
///   map it starts from, and the pose graph's objective is not convex: from
///   the last map it ends in another minimum than from the batch job's
///   start (issue 47: χ² 2 % apart with Huber on aliased loops);
/// * EM without a last loop model (the last candidates were too few, or
///   weighed by a kernel) has no decisions of its own to resume from: the
///   kernel's are another method's;
/// * EM whose last decisions accepted no candidate learned no true-loop
///   population: its model rejects the new loops for want of one, a fixed
///   point the batch job's annealing does not start from (issue 47: 0 of 18
///   true loops accepted, the batch job 18 of 18).
fn untrusted_start<P: Pose<D>, const D: usize>(
    warm: &Warm<P, D>,
    method: RobustMethod,
    candidates: usize,
) -> Option<&'static str> {
    match method {
        RobustMethod::None => None,
        RobustMethod::Em if candidates < robust::MIN_CANDIDATES => Some(
            "fewer candidates than EM learns from: its kernel weighs them all again, the whole job",
        ),
        RobustMethod::Em => match &warm.report.robust.model {
            None => Some("no last loop model to resume EM from: the whole job"),
            Some(_) if !warm.report.loops.iter().any(|l| l.accepted) => {
                Some("the last decisions accepted no loop: the whole job")
            }
            Some(_) => None,
        },
        _ => Some("a kernel weighs every candidate again: the whole job"),
    }
}

/// The reason of an update whose gate finds two components in the counts
/// where the last update's found none (and kept every candidate), and
/// drops a loop the last update accepted: every prior changes at once,
/// and the batch job decides such a loop from its count's low prior,
/// while EM's decisions from the last ones start with it accepted and
/// the loop model fitted from that start can hold it (a grid's first 160
/// poses in `wider_aliased_replays`: four true loops kept at a posterior
/// near 1 that the batch job's model put at 10⁻⁵–0.1). Where the
/// threshold only shifts, the warm decisions were the batch job's on
/// every replay measured (docs/method.md §7b).
const GATED_OUT: &str = "the gate drops a loop the last update accepted: the whole job";

/// Whether this update's gate, where the last one found no two components,
/// drops a candidate the last update accepted ([`GATED_OUT`]). Candidates
/// keep their order as the graph grows: the last report's loops are the
/// first of `candidates`.
fn gated_out<P: Pose<D>, const D: usize>(
    warm: &Warm<P, D>,
    candidates: &[robust::Candidate],
) -> bool {
    warm.report.gate.threshold.is_none()
        && (candidates.iter().zip(&warm.report.loops)).any(|(c, l)| l.kept && l.accepted && !c.kept)
}

/// What an update ran: the graph as solved, its report, the state the next
/// update starts from, and the initial guess when the whole job ran.
pub(crate) struct Updated<P: Pose<D>, const D: usize> {
    /// The graph with the update's map.
    pub graph: Graph<P, D>,
    /// Its report.
    pub report: Report,
    /// The state of the next update.
    pub warm: Warm<P, D>,
    /// The initial guess, when the whole job ran.
    pub initial: Option<Vec<P>>,
}

/// Why the whole job runs instead of the update that reported `r` (its
/// warm state having `examined` the loops beyond the stated information
/// it lists), if it does: an exact update (not capped: that promises a
/// latency, not the batch map) whose map the batch job could end
/// elsewhere. The batch job would seek EM's second start (the map fails
/// the test, the decisions did not settle, or the model disagrees with
/// the information as stated where no whole job has looked), or the warm
/// decisions hold loops back that its annealing may accept.
fn whole_job_instead(
    r: &Report,
    examined: &[(VertexId, VertexId)],
    config: &Settings<'_>,
) -> Option<&'static str> {
    let exact = config.options.robust.method == RobustMethod::Em
        && config.options.solver.update_iterations.is_none();
    if !exact {
        None
    } else if r.chi2_test.as_ref().is_some_and(|t| !t.passed) {
        Some(FAILED)
    } else if r.robust.unsettled {
        Some(UNSETTLED)
    } else if (r.robust.model.as_ref()).is_some_and(|m| m.wrong_within_kernel()) {
        Some(WITHIN_KERNEL)
    } else if (beyond_stated(r).iter()).any(|l| !examined.contains(l)) {
        Some(BEYOND_STATED)
    } else if !r.robust.held_back.is_empty() {
        Some(HELD_BACK)
    } else if on_knife_edge(r) {
        Some(KNIFE_EDGE)
    } else {
        None
    }
}

/// An update of the caller's `graph` (with the vertices no line defined,
/// `missing`) from `last`, the last update's state — or, `Err(reason)`,
/// none to resume from: the whole job, its report saying why. The whole
/// job also runs when EM's decisions swung from the last ones (the new
/// evidence overturned them, docs/method.md §7b). `report`: the report
/// before the job.
pub(crate) fn update<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    graph: &Graph<P, D>,
    missing: &[usize],
    last: Result<&mut Warm<P, D>, &'static str>,
    config: &Settings<'_>,
    report: Report,
    observer: &mut dyn Observer,
) -> Result<Updated<P, D>, Error> {
    // The whole job on a copy of the caller's graph, `why` saying why from
    // the graph it solved and its report.
    type Why<'a, P, const D: usize> = &'a dyn Fn(&Graph<P, D>, &Report) -> IncrementalReport;
    // The next update keeps the last update's elimination order where it
    // still holds (`ordering`), as it would have without the whole job: a
    // fresh fill-reducing order of the map is not always as good (the
    // aliased manhattan replay every 10 poses: factorisations 2.3 ms
    // against 3.8 ms at 1,600 poses after a whole job at 1,450).
    let whole = |mut report: Report,
                 observer: &mut dyn Observer,
                 (why, ordering): (Why<'_, P, D>, Ordering)| {
        let mut solved = graph.clone();
        let initial = super::run(&mut solved, missing, config, &mut report, observer)?;
        report.incremental = Some(why(&solved, &report));
        let warm = Warm::after(&solved, &report, ordering);
        Ok(Updated {
            graph: solved,
            report,
            warm,
            initial: Some(initial),
        })
    };
    match last {
        Ok(warm) => {
            let (mut solved, mut updated) = (graph.clone(), report.clone());
            match update_graph(&mut solved, warm, config, &mut updated, observer)? {
                Ok(next) => match whole_job_instead(&updated, &next.examined, config) {
                    Some(reason) => {
                        let why = |g: &Graph<P, D>, r: &Report| after_fallback(g, warm, r, reason);
                        whole(report, observer, (&why, warm.ordering.clone()))
                    }
                    None => Ok(Updated {
                        graph: solved,
                        report: updated,
                        warm: next,
                        initial: None,
                    }),
                },
                // No start to resume from, or EM's decisions swung: the
                // whole job instead.
                Err(reason) => {
                    let why = |g: &Graph<P, D>, r: &Report| after_fallback(g, warm, r, reason);
                    whole(report, observer, (&why, warm.ordering.clone()))
                }
            }
        }
        Err(reason) => {
            let why = |g: &Graph<P, D>, _: &Report| IncrementalReport {
                solve: UpdateSolve::Batch,
                reason: reason.into(),
                new_poses: g.num_vertices(),
                new_edges: g.edges.len(),
                new_candidates: g.num_candidates(),
                changed: Vec::new(),
            };
            whole(report, observer, (&why, Ordering::default()))
        }
    }
}
