//! The schedule of EM: when to reweight, when to solve, when to decide.
//!
//! 1. **Annealing** ([`anneal`]): from the map of the trusted edges, the
//!    candidates that passed the gate are weighted by the IROS 2013 E-step,
//!    `w = c_t² / (c_t² + r²)`, with a kernel width `c_t` that starts at the
//!    median residual and narrows by [`ANNEAL_STEP`] per E-step to `c` (as
//!    GNC's μ schedule does), each E-step followed by *one* linearised step
//!    of the map from where it is. It ends at the E-step after the first
//!    [`SETTLE_STEPS`] at the final width `c`: a map close to the
//!    consensus of the loops, found at the cost of a few steps instead of a
//!    solve per E-step, and its set of candidates of weight ≥ ½ (the held
//!    set) to decide from.
//! 2. **Decisions by innovation** ([`decide`]): the candidates of weight ≥ ½
//!    are accepted and the map is solved with them (at full weight, the
//!    others left out); every candidate — accepted, rejected, or dropped by
//!    the gate — is judged by its innovation against that map without its
//!    cluster ([`super::innovation`]), under the loop model fitted to all of
//!    them ([`super::model`]); the accepted set is replaced by those whose
//!    posterior is ≥ ½, and the map solved again, until the set repeats. The
//!    map returned is the least-squares map of the accepted loops.

use super::clusters;
use super::innovation::{Evaluation, Innovations, beside_unchecked, through_wide_chains};
use super::kernels::{GNC_MU_STEP, cauchy_weight};
use super::model::{Evidence, LoopModel, Scale};
use super::{Candidate, Layers};
use crate::geometry::Pose;
use crate::graph::Graph;
use crate::linear::Parallelism;
use crate::solve::init::ChordalInit;
use crate::solve::{Crawl, Session, SolveError};
use std::time::Instant;

/// The kernel width's square is divided by this every E-step until it
/// reaches `c²`: the factor by which GNC's μ grows per round.
pub const ANNEAL_STEP: f64 = GNC_MU_STEP;

/// E-steps at the final width before the one the annealing ends at
/// ([`Annealing::e_step`]). The first weighs a map solved at the wider
/// width before it (or the trusted edges' map); the second, the first map
/// solved at the final width, which still sheds the loops the wider width
/// let in — on the 10⁵-pose sphere of the scale benchmark the held set
/// went 6224 → 6138 (469 joined, 555 left) → 7556 over those steps; the
/// last weighs the map solved without them.
pub const SETTLE_STEPS: usize = 2;

/// Most E-steps of the annealing: from a width of 10⁶ times `c` (a wrong
/// loop across the map at the start) down to `c` takes
/// `log(10¹²)/log(1.4) ≈ 82` steps, and [`SETTLE_STEPS`] + 1 more end it;
/// the cap cuts short only a start wider than 10⁸·`c`.
pub const MAX_ANNEAL_STEPS: usize = 120;

/// The relative decrease of a damped LM step at which a decision's solve
/// stops before the accepted set has settled (the settled set is then
/// solved again to the job's own tolerance and judged once more). A set
/// that has not settled is a guess the next evaluation revises, and its
/// map only has to be good enough to judge the candidates by:
/// * on long trajectories LM crawls along bending modes of the map (on a
///   3·10⁵-pose sphere the first decision's solve took 80 damped
///   iterations, each lowering the objective by ~3·10⁻⁶ of it). Those
///   modes are where the map is least certain, so the innovations, whose
///   covariance holds that uncertainty, barely move with them;
/// * a set that gained loops far from where the map before put them
///   walks a long valley: on the 10⁶-pose sphere of the scale benchmark
///   the second decision took 36 damped iterations of 0.02–2.5 % each,
///   and the next evaluation dropped much of what it had fitted.
///
/// Damped steps that gain less than 1 % of the objective are that walk.
/// At 10⁶ poses this took the LM iterations from 51 to 16 with the same
/// decisions and map; 10⁻³ took 28. Gauss–Newton steps are left to
/// converge where they converge quadratically; for those that converge
/// linearly see [`DECIDING_LINEAR_TOLERANCE`].
pub const DECIDING_TOLERANCE: f64 = 1e-2;

/// The relative decrease of a Gauss–Newton step converging linearly (at
/// least half the decrease of the step before it) at which a decision's
/// solve stops before the accepted set has settled. A set that holds
/// aliases keeps large residuals, and there Gauss–Newton converges
/// linearly: on torus3D with 300 aliases (the places sweep's seed 2,
/// information calibrated) each step gained 0.88–0.93 of the one before,
/// and six solves of such sets ran to their cap of 100 iterations (two
/// more to 95 and 79). What such a run
/// leaves is its step's gain times `ρ/(1 − ρ)` for a ratio `ρ` of
/// successive gains, up to 13 times it there: 10⁻⁴ leaves at most about
/// 0.1 % of the objective, a tenth of what [`DECIDING_TOLERANCE`] lets a
/// damped crawl leave. 10⁻² and 10⁻³ let the decisions on MIT with 30
/// scattered aliases (seed 24, information as published) end at another
/// set, the map 19.8 % off instead of 2.8 %; asking `ρ` ≥ 0.8 as well
/// kept that map at 10⁻³ but left the torus job over 4 minutes, as
/// before.
pub const DECIDING_LINEAR_TOLERANCE: f64 = 1e-4;

/// Most decisions (solves of an accepted set): each one that changes the
/// set takes out the loops the previous map did not support; a set that
/// has not settled after this many is cycling.
pub const MAX_DECISIONS: usize = 10;

/// The state of an annealing: the candidates it weighs (those that passed
/// the gate), the kernel width's square over `c²`, and how many E-steps
/// were at the final width.
struct Annealing {
    kept: Vec<usize>,
    c: f64,
    factor: Option<f64>,
    at_width: usize,
}

impl Annealing {
    fn new(candidates: &[Candidate], c: f64) -> Self {
        Self {
            kept: candidates
                .iter()
                .filter(|c| c.kept)
                .map(|c| c.edge)
                .collect(),
            c,
            factor: None,
            at_width: 0,
        }
    }

    /// One E-step at the graph's map: the IROS 2013 (Cauchy) weights of the
    /// kept candidates at the next width — first the one that puts the
    /// median residual at `c`, then `ANNEAL_STEP` times narrower, never
    /// below `c`. True once the width is `c` and [`SETTLE_STEPS`] E-steps
    /// passed at it.
    ///
    /// Further E-steps at the final width would pull the loops consistent
    /// with the held ones in, a few per E-step (region growing along the
    /// map), while loops at the edge of the kernel (`r² ≈ c²`) flicker in
    /// and out. The decisions do that growing better: they judge every
    /// candidate exactly by its innovation and take a region's loops in at
    /// once. On the 10⁶-pose sphere of the scale benchmark, E-steps 4–29
    /// at the final width grew the held set from 58 333 to 79 029 loops,
    /// one chordal relaxation each; the first decision from 58 333 accepts
    /// 89 999 of the 90 000 true loops.
    fn e_step<P: Pose<D>, const D: usize>(
        &mut self,
        graph: &Graph<P, D>,
        weights: &mut [f64],
    ) -> bool {
        let r2: Vec<f64> = (self.kept.iter())
            .map(|&k| graph.edge_chi2(&graph.edges[k]))
            .collect();
        let factor = match self.factor {
            None => median(&r2) / (self.c * self.c),
            Some(f) => f / ANNEAL_STEP,
        }
        .max(1.0);
        self.factor = Some(factor);
        let width = self.c * factor.sqrt();
        for (&k, &r) in self.kept.iter().zip(&r2) {
            weights[k] = cauchy_weight(r, width);
        }
        if factor > 1.0 {
            return false;
        }
        self.at_width += 1;
        self.at_width > SETTLE_STEPS
    }
}

/// What an annealing did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Annealed {
    /// E-steps taken.
    pub steps: usize,
    /// Chordal relaxations solved (on the chordal relaxation: one per
    /// E-step).
    pub relaxations: usize,
    /// Whether the session's budget cut it short.
    pub cut_short: bool,
}

/// The annealing (step 1 of the module doc): leaves the weights of the
/// candidates that passed the gate in `weights` (one per edge; the others
/// stay 0) and the map in the session's graph.
pub fn anneal<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    candidates: &[Candidate],
    c: f64,
) -> Result<Annealed, SolveError> {
    let mut annealing = Annealing::new(candidates, c);
    let mut out = Annealed::default();
    if annealing.kept.is_empty() {
        return Ok(out);
    }
    while out.steps < MAX_ANNEAL_STEPS {
        out.steps += 1;
        if annealing.e_step(session.graph, weights) {
            break;
        }
        session.run(weights, 1)?;
        if session.exhausted() {
            out.cut_short = true;
            break;
        }
    }
    Ok(out)
}

/// The annealing on the chordal relaxation: each E-step is followed by a
/// chordal solve (rotations, then translations; two linear solves) with the
/// candidates at their weights, from scratch — a convex stand-in for the
/// map that is cheap to solve and that no earlier map biases. Where the
/// edges it weighs leave part of the map apart from the gauge (a session
/// joined only by candidates the gate dropped), no relaxation places that
/// part, and the annealing runs on the map itself ([`anneal`]), which
/// holds the part where the initial guess put it.
pub fn anneal_chordal<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    candidates: &[Candidate],
    c: f64,
) -> Result<Annealed, SolveError> {
    if leaves_part_apart(session.graph, weights) {
        return anneal(session, weights, candidates, c);
    }
    let mut annealing = Annealing::new(candidates, c);
    let mut out = Annealed::default();
    if annealing.kept.is_empty() {
        return Ok(out);
    }
    // The weights change every step, the edges of positive weight do not:
    // the linear problems' structure is built once.
    let mut reuse = P::Reuse::from(session.optimizer.parallelism().clone());
    let mut done = false;
    while !done && out.steps < MAX_ANNEAL_STEPS {
        if session.exhausted() {
            out.cut_short = true;
            return Ok(out);
        }
        let start = Instant::now();
        P::chordal_reusing(session.graph, Some(weights), &mut reuse)?;
        session.relaxed_since(start);
        out.relaxations += 1;
        out.steps += 1;
        done = annealing.e_step(session.graph, weights);
    }
    Ok(out)
}

/// What the decisions found.
#[derive(Clone, Debug)]
pub struct Decided {
    /// Whether the map was solved with each candidate.
    pub accepted: Vec<bool>,
    /// The loop model at the last evaluation.
    pub model: Option<LoopModel>,
    /// The innovations at the last evaluation.
    pub innovations: Innovations,
    /// The innovations and loop model at the map of the set kept, when
    /// that set was kept from a cycle and so last judged on another set's
    /// map: what the report says of each candidate.
    pub at_own_map: Option<(Innovations, Option<LoopModel>)>,
    /// The cluster of each candidate.
    pub clusters: Vec<Vec<usize>>,
    /// Whether a cluster's members are also judged against the map with
    /// those that agree better ([`Layers::agreement`]).
    pub within: bool,
    /// Accepted sets solved.
    pub decisions: usize,
    /// Chordal relaxations of accepted sets solved ([`relaxed_start`]).
    pub relaxations: usize,
    /// Accepted sets solved from their relaxation (it fitted them better
    /// than the map before).
    pub relaxed_starts: usize,
    /// Whether the budget cut them short.
    pub cut_short: bool,
    /// Whether they gave up swinging ([`Swing::GiveUp`]).
    pub swung: bool,
    /// Whether a candidate the gate dropped may be accepted
    /// ([`Layers::rescue`]).
    pub rescue: bool,
}

/// What [`decide`] does when its set swings: a round flips back decisions
/// the round before flipped (a wrong group in: the map bends, whole
/// regions look inconsistent and go out; without them everything fits and
/// comes back in). Once is common and settles at the next round (a
/// candidate near the threshold, or a 2-cycle [`decide`] ends). From the
/// annealing's start the set settles within [`MAX_DECISIONS`]; from an
/// update's start, the last update's set, a second swing is the sign that
/// the new evidence overturned the old decisions, which the annealing of
/// the whole job sorts out in fewer evaluations (a replay of sphere2500
/// with 100 aliased candidates swung for 8 and 10 rounds at two updates).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Swing {
    /// Go on until the set repeats.
    Continue,
    /// Stop at the second swing, [`Decided::swung`] set.
    GiveUp,
}

impl Decided {
    /// Adds the work of `other` (its decisions, relaxations and relaxed
    /// starts) to these decisions' counts.
    pub fn count_work_of(&mut self, other: &Decided) {
        self.decisions += other.decisions;
        self.relaxations += other.relaxations;
        self.relaxed_starts += other.relaxed_starts;
    }

    /// These decisions with no work counted: the same decisions taken
    /// again from a record of them ([`super::search::Restarts`]).
    pub fn without_work(mut self) -> Self {
        (self.decisions, self.relaxations, self.relaxed_starts) = (0, 0, 0);
        self
    }

    /// Nothing decided yet: the candidates `edges` of weight ≥ ½ accepted,
    /// and their clusters (each its own with the layer off).
    fn start<P: Pose<D>, const D: usize>(
        graph: &Graph<P, D>,
        edges: &[usize],
        weights: &[f64],
        layers: &Layers,
    ) -> Self {
        Self {
            accepted: edges.iter().map(|&k| held(weights[k])).collect(),
            model: None,
            innovations: Innovations::default(),
            at_own_map: None,
            clusters: if layers.clusters {
                clusters::of_edges(graph, edges)
            } else {
                (0..edges.len()).map(|k| vec![k]).collect()
            },
            within: layers.agreement,
            decisions: 0,
            relaxations: 0,
            relaxed_starts: 0,
            cut_short: false,
            swung: false,
            rescue: layers.rescue,
        }
    }

    /// Solves the map with the accepted set in `weights` (1 accepted, 0
    /// not), one decision more: `again`, the set settled on a map solved to
    /// [`DECIDING_TOLERANCE`], to the job's own tolerance from that map;
    /// otherwise from the better fitting of the map before and the set's
    /// chordal relaxation (if `how` says so) to [`DECIDING_TOLERANCE`].
    /// Returns whether the map met the job's tolerance.
    fn solve<P: ChordalInit<D>, const D: usize>(
        &mut self,
        session: &mut Session<'_, P, D>,
        weights: &[f64],
        how: &Deciding<'_>,
        again: bool,
    ) -> Result<bool, SolveError> {
        self.decisions += 1;
        if again {
            session.converge(weights)?;
            return Ok(true);
        }
        if how.relax && how.layers.relaxation {
            self.relaxations += 1;
            self.relaxed_starts += usize::from(relaxed_start(session, weights)?);
        }
        let crawl = Crawl {
            damped: DECIDING_TOLERANCE,
            linear: DECIDING_LINEAR_TOLERANCE,
        };
        session.converge_unless_crawling(weights, crawl)
    }

    /// Whatever ended the decisions: the set kept is the one in `weights`
    /// (after [`MAX_DECISIONS`], the one the map was solved with, not the
    /// last one judged), its map solved to the job's tolerance unless it
    /// `converged` there, and judged at its own map if that is not the one
    /// of the set `judged` last.
    fn end<P: ChordalInit<D>, const D: usize>(
        &mut self,
        session: &mut Session<'_, P, D>,
        weights: &[f64],
        (candidates, edges): (&[Candidate], &[usize]),
        how: &Deciding<'_>,
        (converged, judged): (bool, &[bool]),
        solved: &mut SetSolved<'_, P, D>,
    ) -> Result<(), SolveError> {
        for (a, &k) in self.accepted.iter_mut().zip(edges) {
            *a = weights[k] == 1.0;
        }
        if !converged && !self.cut_short && !self.swung {
            session.converge(weights)?;
            solved(session.graph, weights, &self.accepted);
        }
        if self.accepted != judged && !self.cut_short && !self.swung && how.layers.decisions {
            self.judge_at_own_map(session, weights, (candidates, edges), how)?;
        }
        Ok(())
    }

    /// The set kept, from a cycle, judged at its own map (it was last
    /// judged on another set's): the report's innovations, posteriors and
    /// reasons are those ([`Decided::at_own_map`]); what the job does next
    /// still follows the decisions' last judgement.
    fn judge_at_own_map<P: Pose<D>, const D: usize>(
        &mut self,
        session: &mut Session<'_, P, D>,
        weights: &[f64],
        judging: (&[Candidate], &[usize]),
        how: &Deciding<'_>,
    ) -> Result<(), SolveError> {
        let kept = self.accepted.clone();
        let (innovations, model) = (self.innovations.clone(), self.model.clone());
        self.evaluate(session, weights, judging, how)?;
        let own = std::mem::replace(&mut self.innovations, innovations);
        self.at_own_map = Some((own, std::mem::replace(&mut self.model, model)));
        self.accepted = kept;
        Ok(())
    }

    /// Ends the decisions at `set` instead (one flag per candidate, with
    /// their `edges`): solved as a decision is, to the job's tolerance, and
    /// judged at its own map.
    pub fn adopt<P: ChordalInit<D>, const D: usize>(
        &mut self,
        session: &mut Session<'_, P, D>,
        weights: &mut [f64],
        (candidates, edges): (&[Candidate], &[usize]),
        set: &[bool],
        how: &Deciding<'_>,
    ) -> Result<(), SolveError> {
        for (&k, &a) in edges.iter().zip(set) {
            weights[k] = if a { 1.0 } else { 0.0 };
        }
        self.accepted = set.to_vec();
        if !self.solve(session, weights, how, false)? {
            session.converge(weights)?;
        }
        self.cut_short |= session.exhausted();
        if !self.cut_short {
            self.evaluate(session, weights, (candidates, edges), how)?;
            self.at_own_map = None;
        }
        Ok(())
    }

    /// The innovations of the candidates (with their `edges`) at the map in
    /// the session's graph, the set in `weights` and these decisions'
    /// clusters: exact where the formulas hold, through a wide chain where
    /// they cancel, unchecked beside an unchecked cluster; and the
    /// parallelism they ran with.
    pub(super) fn innovations_at_map<P: Pose<D>, const D: usize>(
        &self,
        session: &mut Session<'_, P, D>,
        weights: &[f64],
        edges: &[usize],
    ) -> Result<(Innovations, Parallelism), SolveError> {
        let mut eval = Evaluation::new(session.optimizer, session.graph, weights)?
            .judging_within_clusters(self.within);
        // Exact innovations: a lower bound (a lone candidate outside the map)
        // is not the evidence the model describes, and a wrong loop's bound
        // can sit among the true loops' innovations.
        let mut innov = eval.innovations(edges, &self.accepted, &self.clusters, true);
        let parallelism = eval.parallelism().clone();
        drop(eval);
        let clusters = (edges, self.accepted.as_slice(), self.clusters.as_slice());
        through_wide_chains(session, weights, clusters, &mut innov)?;
        beside_unchecked(session.graph, weights, clusters, &mut innov);
        Ok((innov, parallelism))
    }

    /// One evaluation of the map in the session's graph (the least-squares
    /// map of the set in `weights`): the innovations of the `candidates`
    /// (with their `edges`) and the loop model, kept in these decisions;
    /// returns the set they accept.
    fn evaluate<P: Pose<D>, const D: usize>(
        &mut self,
        session: &mut Session<'_, P, D>,
        weights: &[f64],
        (candidates, edges): (&[Candidate], &[usize]),
        how: &Deciding<'_>,
    ) -> Result<Vec<bool>, SolveError> {
        let start = Instant::now();
        let (innov, parallelism) = self.innovations_at_map(session, weights, edges)?;
        let fit = Instant::now();
        let (model, next) = judge(
            candidates,
            &innov,
            &self.accepted,
            (D, how.scale),
            how.layers,
            &parallelism,
        );
        session.modelled(fit.elapsed());
        session.evaluated_since(start);
        self.innovations = innov;
        self.model = Some(model);
        Ok(next)
    }
}

/// How [`decide`] decides.
#[derive(Clone, Copy)]
pub struct Deciding<'a> {
    /// Where the true loops' innovations are centred.
    pub scale: Scale,
    /// EM's layers.
    pub layers: &'a Layers,
    /// Whether each accepted set is solved from the better fitting of the
    /// map before and its chordal relaxation ([`relaxed_start`]; a job on
    /// the chordal guess).
    pub relax: bool,
    /// Whether to stop at the second swing ([`Swing`]).
    pub swing: Swing,
}

/// What [`decide`] shows of each set it solves: the map in the graph, the
/// weights it was solved with, and the set (one flag per candidate).
pub type SetSolved<'s, P, const D: usize> = dyn FnMut(&Graph<P, D>, &[f64], &[bool]) + 's;

/// The decisions by innovation (step 2 of the module doc), starting from
/// the candidates of weight ≥ ½ in `weights`; leaves the final weights (1
/// accepted, 0 not) in `weights` and the least-squares map of the accepted
/// set in the session's graph. Each set solved, with its map, is shown to
/// `solved`.
pub fn decide<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    candidates: &[Candidate],
    how: &Deciding<'_>,
    solved: &mut SetSolved<'_, P, D>,
) -> Result<Decided, SolveError> {
    let (layers, swing) = (how.layers, how.swing);
    let edges: Vec<usize> = candidates.iter().map(|c| c.edge).collect();
    let mut out = Decided::start(session.graph, &edges, weights, layers);
    // The sets solved, each with its map's fit ([`excess`]).
    let mut seen: Vec<(Vec<bool>, f64)> = Vec::new();
    let mut swings = Swings::new(edges.len());
    // Whether the map in the graph met the job's own tolerance, and whether
    // the set repeats on a map that did not (it is then solved again).
    let (mut converged, mut again) = (false, false);
    // The best set of the cycles half steps left ([`half_step`]), with its
    // fit.
    let mut before_half: Option<(Vec<bool>, f64)> = None;
    // How many candidates the cycle last halved moved ([`half_step_out`]).
    let mut halved = usize::MAX;
    // The set whose map the last evaluation judged.
    let mut judged = out.accepted.clone();
    while out.decisions < MAX_DECISIONS {
        for (&k, &a) in edges.iter().zip(&out.accepted) {
            weights[k] = if a { 1.0 } else { 0.0 };
        }
        converged = out.solve(session, weights, how, std::mem::take(&mut again))?;
        if session.exhausted() {
            out.cut_short = true;
            break;
        }
        solved(session.graph, weights, &out.accepted);
        judged.clone_from(&out.accepted);
        let next = out.evaluate(session, weights, (candidates, &edges), how)?;
        if session.exhausted() {
            // No budget left to solve another set: the set kept is the one
            // the map was solved with.
            out.cut_short = true;
            break;
        }
        if !layers.decisions {
            // The innovations are reported; the annealed set stands.
            break;
        }
        if next == out.accepted && !converged {
            // Settled on a map solved to the looser tolerance: solve it to
            // the job's and judge again.
            again = true;
            continue;
        }
        if swings.record(&out.accepted, &next) >= 2 && swing == Swing::GiveUp {
            out.swung = true;
            break;
        }
        let fit = excess(session.graph, weights, &out.accepted);
        seen.push((std::mem::replace(&mut out.accepted, next), fit));
        if let Some(first) = seen.iter().position(|(s, _)| *s == out.accepted) {
            // Settled (a cycle of one set), or cycling.
            let cycle = &seen[first..];
            if let Some(half) = half_step_out(cycle, &out, (&mut before_half, &mut halved)) {
                out.accepted = half;
                continue;
            }
            let sets = competing(cycle, before_half.take(), &seen[0]);
            if keep_best(&sets, &edges, weights) {
                converged = false;
            }
            break;
        }
    }
    if let Some((set, _)) = before_half.filter(|_| out.decisions >= MAX_DECISIONS) {
        // The decisions after the half step neither settled nor cycled.
        converged &= !keep_best(&[(set, 0.0)], &edges, weights);
    }
    out.end(
        session,
        weights,
        (candidates, &edges),
        how,
        (converged, &judged),
        solved,
    )?;
    Ok(out)
}

/// The sets to keep the best of at the end of `cycle`: a settled set (a
/// cycle of one) stands; a cycle's sets compete with the best one before
/// the half step, if any (`before`), and with the set the decisions
/// started from (`start`): decisions that did not settle end on no map
/// that fits worse than the one they began with. On MIT with 30 aliases
/// in groups of 10 placed anywhere (seed 23 of the MIT sweep in
/// docs/benchmarks.md, information calibrated) the gate kept 7 true
/// loops; their map's model, which could not tell two alias groups from
/// the true loops, accepted 40 candidates, whose map rejected all but 6,
/// and the decisions swung between 6 and 40. The cycle's better fitting
/// set, the 6, left the map 18.9 % off; the 7 it started from fit better
/// and leave it 5.4 % off, where LM + Cauchy and GNC behind the gate end.
fn competing(
    cycle: &[(Vec<bool>, f64)],
    before: Option<(Vec<bool>, f64)>,
    start: &(Vec<bool>, f64),
) -> Vec<(Vec<bool>, f64)> {
    let mut sets = cycle.to_vec();
    if sets.len() > 1 {
        sets.extend(before);
        if !sets.iter().any(|(s, _)| *s == start.0) {
            sets.push(start.clone());
        }
    }
    sets
}

/// The set of a half step out of `cycle` (the sets since the first one
/// judged again, each with its fit; the last one's map judged, in `out`,
/// the set `out.accepted`), if a [`half_step`] leads out of it and the
/// cycle moves fewer candidates than the last one halved (`halved`, the
/// decisions' first cycle any): the steps halve until one candidate moves
/// at a time, or a cycle moves as many as one before, so they end.
/// `before_half` keeps the best-fitting set of the cycles halved.
///
/// One halving is not always enough. On a young sphere
/// (`tests/update_equals_optimize.rs`, seed 60, aliases placed anywhere in
/// groups of 5, the first 325 poses) the model at a map of 43 loops
/// accepted 8 candidates of one place, 3 true loops and 5 aliases, whose
/// map rejected all 8; the half step added the 4 of least `ν²`, one of
/// them an alias, whose map rejected those 4 again. Halved again (of the
/// 4 to take out, the alias and a true loop, the 2 of largest `ν²`), the
/// map of the other two accepts the third true loop, and the set settles
/// without the aliases.
fn half_step_out(
    cycle: &[(Vec<bool>, f64)],
    out: &Decided,
    (before_half, halved): (&mut Option<(Vec<bool>, f64)>, &mut usize),
) -> Option<Vec<bool>> {
    if cycle.len() < 2 {
        return None;
    }
    let last = &cycle[cycle.len() - 1].0;
    let moves = (last.iter().zip(&out.accepted))
        .filter(|(a, b)| a != b)
        .count();
    if moves >= *halved {
        return None;
    }
    let half = half_step(last, &out.accepted, &out.innovations)?;
    *halved = moves;
    let best = cycle.iter().min_by(|a, b| a.1.total_cmp(&b.1)).cloned();
    *before_half = (before_half.take().into_iter())
        .chain(best)
        .min_by(|a, b| a.1.total_cmp(&b.1));
    Some(half)
}

/// Half the way from the set `last` to the set `next` its map's model
/// accepts, on a cycle: of the candidates it would add, the half with the
/// smallest `ν²` at that map (`innov`); of those it would remove, the half
/// with the largest; unchecked ones all the way. `None` where that is the
/// whole way (one candidate to move), or where the two sets dispute as
/// many candidates as they share: a swing of most of the accepted loops
/// is no local conflict a half step could settle, and halving it only
/// cycles on (sphere2500 with 300 aliases placed anywhere, every count
/// true-like, its information as published: the decisions swung between
/// 3 and 2,697 accepted loops, and the half steps went on swinging until
/// a solve ran out of iterations).
///
/// A cycle of sets is the model's judgement of each candidate against a
/// map that lacks the others moving with it. A group of aliases and the
/// true loops near it can each fit a map holding neither, and together
/// bend it until every one of them looks wrong: the decisions then swing
/// between the set without them and the set with all of them, and the
/// best-fitting of the two leaves the true loops out (a simulated sphere
/// of 380 poses: 9 true loops and 3 aliases added and removed together,
/// the true loops rejected with posteriors 0.52–0.88 at the map kept).
/// Added by increasing `ν²`, the true loops go in first, and the map with
/// them judges the aliases.
fn half_step(last: &[bool], next: &[bool], innov: &Innovations) -> Option<Vec<bool>> {
    let nu2 = |k: usize| innov.nu2.get(k).copied().flatten();
    let mut add: Vec<(f64, usize)> = Vec::new();
    let mut remove: Vec<(f64, usize)> = Vec::new();
    let mut half = last.to_vec();
    for (k, (&a, &b)) in last.iter().zip(next).enumerate() {
        match (a != b, nu2(k)) {
            (false, _) => {}
            (true, None) => half[k] = b,
            (true, Some(v)) if b => add.push((v, k)),
            (true, Some(v)) => remove.push((-v, k)),
        }
    }
    if add.len() + remove.len() < 2 || swings_most(last, next) {
        return None;
    }
    for (moves, to) in [(&mut add, true), (&mut remove, false)] {
        moves.sort_by(|a, b| a.0.total_cmp(&b.0));
        for &(_, k) in moves.iter().take(moves.len().div_ceil(2)) {
            half[k] = to;
        }
    }
    (half != next).then_some(half)
}

/// Whether the sets `last` and `next` dispute at least as many candidates
/// as they share: a swing of most of the accepted loops, no local conflict.
pub(super) fn swings_most(last: &[bool], next: &[bool]) -> bool {
    let shared = last.iter().zip(next).filter(|&(&a, &b)| a && b).count();
    let disputed = last.iter().zip(next).filter(|&(a, b)| a != b).count();
    disputed >= shared
}

/// Of the sets of a cycle (each map of which judges the next set), each
/// with its map's [`excess`], puts the one whose map fits its measurements
/// best, as the χ² test measures it, in `weights` (for candidates
/// `edges`); returns whether that changed them.
fn keep_best(cycle: &[(Vec<bool>, f64)], edges: &[usize], weights: &mut [f64]) -> bool {
    let Some((set, _)) = cycle.iter().min_by(|a, b| a.1.total_cmp(&b.1)) else {
        return false;
    };
    let changed = edges
        .iter()
        .zip(set)
        .any(|(&e, &a)| a != (weights[e] == 1.0));
    for (&e, &a) in edges.iter().zip(set) {
        weights[e] = if a { 1.0 } else { 0.0 };
    }
    changed
}

/// How much more `Σ eᵀΩe` the least-squares map of the accepted set in
/// `weights` (`accepted` of the candidates) has than its measurements'
/// information expects: each accepted loop adds `D` degrees of freedom to
/// the χ² test, so between sets that differ in a few loops this ranks
/// their maps as the test does.
fn excess<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    weights: &[f64],
    accepted: &[bool],
) -> f64 {
    let loops = accepted.iter().filter(|&&a| a).count();
    graph.chi2_where(|k| weights[k] > 0.0) - (loops * D) as f64
}

/// The loop model's objective of the map in `graph` with `weights`: `Σ
/// eᵀΩe` over the edges it was solved with, plus `price` for each
/// candidate left out (those the gate dropped too: the model may rescue
/// them, and a set that does must not pay for it) — the truncated least squares whose one-candidate
/// moves are the decisions by innovation (adding a candidate raises the
/// least-squares minimum by its `ν²`, to first order). The price is `s²·c²`:
/// EM's kernel width `c`, at which a true loop is left out once in a
/// million, on the scale `s²` of the file's information that a map shows
/// ([`misfit_scale`]: information 100 times too loose leaves residuals 100
/// times too small, and leaving a loop out would otherwise cost a
/// hundredfold).
pub(super) fn objective<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    weights: &[f64],
    candidates: &[Candidate],
    price: f64,
) -> f64 {
    graph.chi2_where(|k| weights[k] > 0.0) + price * left_out(weights, candidates) as f64
}

/// How many of the `candidates` `weights` leave out (weight below ½).
pub(super) fn left_out(weights: &[f64], candidates: &[Candidate]) -> usize {
    (candidates.iter())
        .filter(|c| weights[c.edge] < 0.5)
        .count()
}

/// The misfit per residual degree of freedom of the map in `graph` with
/// `weights`, `Σ eᵀΩe / (Σ edge dimensions − free pose parameters)` — the
/// χ² test's `D²/K`: the scale of the file's information that the map
/// shows (1 where it is calibrated). `None` without residual degrees of
/// freedom.
pub(super) fn misfit_scale<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    weights: &[f64],
) -> Option<f64> {
    let used = weights.iter().filter(|&&w| w > 0.0).count();
    let free = graph.num_vertices() - graph.gauge().len();
    let dof = used.saturating_sub(free) * D;
    let scale = graph.chi2_where(|k| weights[k] > 0.0) / dof as f64;
    (dof > 0 && scale.is_finite() && scale > 0.0).then_some(scale)
}

/// The swings of [`decide`]'s sets ([`Swing`]).
struct Swings {
    /// The candidates the last round flipped.
    flipped: Vec<bool>,
    /// Rounds that flipped back some the round before had flipped.
    count: usize,
}

impl Swings {
    fn new(n: usize) -> Self {
        Self {
            flipped: vec![false; n],
            count: 0,
        }
    }

    /// Records the round from `accepted` to `next`; the swings so far.
    fn record(&mut self, accepted: &[bool], next: &[bool]) -> usize {
        let flips: Vec<bool> = next.iter().zip(accepted).map(|(n, a)| n != a).collect();
        let back = flips
            .iter()
            .zip(&self.flipped)
            .any(|(&now, &then)| now && then);
        self.count += usize::from(back);
        self.flipped = flips;
        self.count
    }
}

/// What an update knows before it solves ([`propose`]).
pub struct Proposal<'a> {
    /// The loop model of the last update's last evaluation.
    pub model: &'a LoopModel,
    /// The candidates added since (indices into the candidates).
    pub new: Vec<usize>,
}

/// Accepts (weight 1 in `weights`) the new candidates of `proposal` that
/// the last loop model accepts by their innovation against the map in the
/// session's graph, which must be the least-squares map of the accepted
/// set in `weights` (as after an update whose new trusted edges only hang
/// new poses on the last map). Returns how many it accepted.
///
/// A guess for [`decide`] to start from: when a new loop is consistent,
/// decisions started without it solve and judge every candidate twice,
/// once to find it and once to confirm the set with it; started with it,
/// once. The decisions judge every candidate again whatever the guess, so
/// a wrong one costs a round and changes nothing else.
pub fn propose<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    candidates: &[Candidate],
    proposal: &Proposal<'_>,
    layers: &Layers,
) -> Result<usize, SolveError> {
    if proposal.new.is_empty() {
        return Ok(0);
    }
    let start = Instant::now();
    let edges: Vec<usize> = candidates.iter().map(|c| c.edge).collect();
    let decided = Decided::start(session.graph, &edges, weights, layers);
    let mut new = vec![false; candidates.len()];
    for &k in &proposal.new {
        new[k] = true;
    }
    let touched: Vec<Vec<usize>> = (decided.clusters.iter())
        .filter(|cluster| cluster.iter().any(|&k| new[k]))
        .cloned()
        .collect();
    let mut eval = Evaluation::for_clusters(
        session.optimizer,
        session.graph,
        weights,
        (&edges, &touched),
    )?
    .judging_within_clusters(decided.within);
    let mut innov = eval.innovations(&edges, &decided.accepted, &touched, false);
    let accepts = |innov: &Innovations, k: usize| match innov.evidence(candidates, k) {
        Some(e) => proposal.model.posterior(&e) >= 0.5,
        None => proposal.model.prior(candidates[k].count_posterior) >= 0.5,
    };
    // Lower bounds the model would accept, made exact.
    let open: Vec<usize> = (proposal.new.iter().copied())
        .filter(|&k| !innov.exact[k] && accepts(&innov, k))
        .collect();
    eval.refine(&edges, &open, &mut innov);
    let joined: Vec<usize> = (proposal.new.iter().copied())
        .filter(|&k| accepts(&innov, k))
        .collect();
    for &k in &joined {
        weights[edges[k]] = 1.0;
    }
    session.evaluated_since(start);
    Ok(joined.len())
}

/// Whether the edges of non-zero `weights` leave part of the map apart from
/// the gauge (a session joined only by candidates they leave out): no
/// chordal relaxation of them places that part.
fn leaves_part_apart<P: Pose<D>, const D: usize>(graph: &Graph<P, D>, weights: &[f64]) -> bool {
    !graph.unconstrained_vertices(Some(weights)).is_empty()
}

/// Starts the solve of an accepted set (`weights` 1 or 0) from its chordal
/// relaxation when that fits it better (lower `Σ eᵀΩe` over its edges) than
/// the map before; returns whether it did, else leaves the map as it was.
/// A set whose edges leave part of the map apart from the gauge (the
/// sessions of a multi-session map joined only by loops it rejects) has no
/// relaxation that places that part: the map before stays, and the solve
/// holds the part where it is ([`crate::solve`]).
///
/// The map before is the last decision's (or the annealing's last
/// relaxation, at the Cauchy weights), and neither start is better
/// everywhere:
/// * a set that gained or lost many loops leaves the map before far from
///   its optimum. On the 10⁵-pose sphere of the scale benchmark the
///   annealed map, bent by the wrong loops it still held at small weights,
///   made LM crawl for 28 iterations where the relaxation of the accepted
///   set took 4.
/// * On loose information a warm start can settle in a local minimum a
///   fresh start avoids: intel with 1000 random wrong candidates and its
///   published information ended at `Σ eᵀΩe` 2.5 times the accepted set's
///   optimum, 3.4 % of the map off; LM from the relaxation reached the
///   optimum in 4 iterations.
/// * Where the map before fits better, LM from it ends lower than the
///   relaxation: no map fits a problem better than its minimum.
pub(super) fn relaxed_start<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
) -> Result<bool, SolveError> {
    if leaves_part_apart(session.graph, weights) {
        return Ok(false);
    }
    let fit = |g: &Graph<P, D>| g.chi2_where(|k| weights[k] > 0.0);
    let before = session.graph.poses.clone();
    let at = fit(session.graph);
    let start = Instant::now();
    let mut reuse = P::Reuse::from(session.optimizer.parallelism().clone());
    P::chordal_reusing(session.graph, Some(weights), &mut reuse)?;
    let better = fit(session.graph) < at;
    if !better {
        session.graph.poses = before;
    }
    session.relaxed_since(start);
    Ok(better)
}

/// Fits the loop model to every candidate's evidence and returns it with
/// the set it accepts ([`verdict`]).
fn judge(
    candidates: &[Candidate],
    innov: &Innovations,
    accepted: &[bool],
    (dimension, scale): (usize, Scale),
    layers: &Layers,
    parallelism: &Parallelism,
) -> (LoopModel, Vec<bool>) {
    // Exact zeros (a loop the map fits perfectly) have no logarithm: they
    // are consistent whatever the model, and say nothing about its spread.
    let (fitted, start): (Vec<Evidence>, Vec<bool>) = (0..candidates.len())
        .zip(accepted)
        .filter_map(|(k, &a)| {
            (innov.evidence(candidates, k))
                .filter(|e| e.innovation > 0.0 && e.innovation.is_finite())
                .map(|e| (e, a))
        })
        .unzip();
    let model = LoopModel::fit(&fitted, &start, (dimension, scale), layers, parallelism);
    let (next, _) = verdict(&model, innov, candidates, layers);
    (model, next)
}

/// The level at which the decisions bound the true loops' reach
/// ([`verdict`]): the chance that they reject the largest true loop of a
/// map whose accepted loops are all true (Bonferroni over them). The χ²
/// test's default level; a level of its own, so that `--alpha` changes
/// the verdict and not the decisions.
pub const REACH_LEVEL: f64 = 0.05;

/// The set the loop `model` accepts at one evaluation (the innovations
/// `innov`), and the candidates it leaves out beyond the true loops'
/// reach. A candidate is accepted when its posterior is ≥ ½ (for one that
/// nothing else checks, its prior; one the gate dropped only with the
/// layer `rescue`), unless (with the layer `reach`) its innovation lies
/// where no true loop of the map reaches: among the `K` so accepted with
/// an innovation, its upper tail under the true loops' fitted density
/// below [`REACH_LEVEL`] over `K` ([`LoopModel::beyond_reach`]), and its
/// `ν²` above `D`, the mean of `χ²_D` under the information as the file
/// states it. The posterior weighs the true loops' density against the
/// wrong loops' where both are far in their tails — an innovation
/// between a wide true population and a narrow wrong one goes to the
/// wider — and there the tail says what
/// the ratio cannot: such a loop is no likelier true than wrong, and one
/// wrong loop bends the map where one true loop less costs it little. A
/// loop that errs by no more than its information's own expectation is
/// never rejected by its tail: that would rest only on the map's true
/// loops being far tighter than their information, as rounding makes
/// those of a noise-free file (docs/method.md §4).
pub(super) fn verdict(
    model: &LoopModel,
    innov: &Innovations,
    candidates: &[Candidate],
    layers: &Layers,
) -> (Vec<bool>, Vec<bool>) {
    let mut accepted: Vec<bool> = (0..candidates.len())
        .map(|k| {
            let c = &candidates[k];
            (c.kept || layers.rescue)
                && match innov.evidence(candidates, k) {
                    Some(e) => model.posterior(&e) >= 0.5,
                    None => model.prior(c.count_posterior) >= 0.5,
                }
        })
        .collect();
    let mut beyond = vec![false; candidates.len()];
    if !layers.reach {
        return (accepted, beyond);
    }
    let tested: Vec<(usize, f64)> = (0..candidates.len())
        .filter(|&k| accepted[k])
        .filter_map(|k| innov.nu2.get(k).copied().flatten().map(|v| (k, v)))
        .collect();
    let expected = model.dimension() as f64;
    for (k, _) in model.beyond_reach(&tested, REACH_LEVEL) {
        if innov.nu2[k].is_some_and(|v| v > expected) {
            (accepted[k], beyond[k]) = (false, true);
        }
    }
    (accepted, beyond)
}

/// Whether a candidate of annealing weight `w` is held: the decisions start
/// from the candidates of weight ≥ ½.
fn held(w: f64) -> bool {
    w >= 0.5
}

/// The median of a slice (0 when empty).
fn median(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    let mut v = x.to_vec();
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

#[cfg(test)]
mod tests;
