//! Which loop candidates to believe, and the map they make.
//!
//! The default method, [`RobustMethod::Em`], is one model of every loop
//! decision ([`model`]): a candidate is a true loop with a prior
//! probability from its inlier count (the gate's mixture, tempered by the
//! rate at which verification is fooled), and its innovation — its error
//! against the map made without it and the candidates of its cluster — is
//! evidence for or against it, under distributions of true and wrong loops
//! that EM learns from the data. EM's schedule ([`schedule`]) anneals a
//! consensus map cheaply (Lee, Fraundorfer & Pollefeys, IROS 2013, with a
//! narrowing kernel and one linearised step per E-step), then decides every
//! candidate by its innovation until the accepted set repeats; when the
//! resulting map still fails the χ² test, the clusters of accepted loops
//! that explain the failure are taken out ([`search`]).
//!
//! The other methods are the robust kernels of pgo's peers ([`kernels`]):
//! Huber, Cauchy, DCS and GNC-TLS, weighting the candidates that passed the
//! gate by a fixed function of their residual.

mod clusters;
mod doubt;
mod innovation;
mod kernels;
mod model;
mod schedule;
mod search;
mod starts;

pub use doubt::{DOUBT_MOVE, Doubt, HeldBack, Outlying};
pub use model::{LoopModel, Scale};
pub use schedule::{Proposal, Swing};
pub use search::{MAX_REMOVALS, Search, Suspect, Test};
pub use starts::{Start, StartEnd};

use crate::geometry::Pose;
use crate::solve::init::ChordalInit;
use crate::solve::{Session, SolveError};
use innovation::Innovations;
use serde::Serialize;

/// A robust method for loop candidates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum RobustMethod {
    /// Plain least squares.
    None,
    /// The loop model, decided by EM ([`model`], [`schedule`]).
    #[default]
    Em,
    /// Huber kernel.
    Huber,
    /// Cauchy kernel.
    Cauchy,
    /// Dynamic covariance scaling.
    Dcs,
    /// Graduated non-convexity, truncated least squares.
    Gnc,
}

impl RobustMethod {
    /// Its name on the command line and in the JSON report.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Em => "em",
            Self::Huber => "huber",
            Self::Cauchy => "cauchy",
            Self::Dcs => "dcs",
            Self::Gnc => "gnc",
        }
    }
}

/// The default kernel width of each method for edges of dimension `dim`,
/// on the whitened-residual-norm scale:
///
/// * EM: `√χ²_dim(1 − 10⁻⁶)` (5.54 in 2D, 6.19 in 3D), the end of its
///   annealing: a calibrated true loop falls beyond it once in a million;
/// * GNC: `√χ²_dim(0.99)`, the inlier threshold of GTSAM's `GncOptimizer`;
/// * Huber and Cauchy: `√χ²_dim(0.95)`, the width the peers use;
/// * DCS: `c = 1`, i.e. `Φ = c² = 1`, Agarwal et al.'s default.
pub fn default_c(method: RobustMethod, dim: usize) -> f64 {
    let quantile = |alpha: f64| {
        crate::stats::chi2_critical(dim.max(1) as u64, alpha)
            .map(f64::sqrt)
            .unwrap_or(3.0)
    };
    match method {
        RobustMethod::Em => quantile(1e-6),
        RobustMethod::Gnc | RobustMethod::None => quantile(0.01),
        RobustMethod::Huber | RobustMethod::Cauchy => quantile(0.05),
        RobustMethod::Dcs => 1.0,
    }
}

/// The fewest loop candidates EM learns its model from: a mean and a
/// spread for the true loops and for one wrong population, and the two
/// rates, need a few candidates each ([`model`]'s smallest start is 4).
/// With fewer, EM weighs them with its kernel (Cauchy at its width `c`).
pub const MIN_CANDIDATES: usize = 8;

/// The layers of EM on top of its model, each of which can be switched off
/// for an ablation (`pgo optimize --expert no-LAYER,…`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Layers {
    /// Anneal a consensus map before deciding ([`schedule`]); off: decide
    /// from the initial map with every candidate that passed the gate.
    pub annealing: bool,
    /// Decide every candidate by its innovation ([`schedule::decide`]);
    /// off: the annealed weights decide (≥ ½ accepted).
    pub decisions: bool,
    /// Judge a candidate against the map without its whole cluster
    /// ([`clusters`]); off: without itself only.
    pub clusters: bool,
    /// Judge a cluster's member also against the map with the members
    /// that agree better with the rest of it, keeping the larger
    /// innovation ([`innovation`]); off: without the cluster only.
    pub agreement: bool,
    /// Learn the rate at which verification is fooled ([`model`]); off: a
    /// count's posterior is the prior.
    pub aliasing: bool,
    /// Let the wrong loops form several populations ([`model`]); off: one.
    pub populations: bool,
    /// Act on a failed χ² test ([`search`]).
    pub search: bool,
    /// Solve each accepted set from its chordal relaxation when that fits
    /// it better than the map before ([`schedule::decide`]; with the
    /// chordal guess only).
    pub relaxation: bool,
    /// Let the decisions accept a candidate the gate dropped when its
    /// innovation convinces the model (`rescued_loops` in the report); off:
    /// a dropped candidate stays out (reason `gated`).
    pub rescue: bool,
    /// Start EM a second time from a plain Cauchy kernel on the caller's
    /// poses and keep the better end ([`starts`]); off: the annealed start
    /// only.
    pub starts: bool,
    /// Reject a candidate whose innovation lies beyond the true loops'
    /// reach, whatever its posterior ([`schedule::verdict`], reason
    /// `outlying`); off: the posterior alone decides.
    pub reach: bool,
    /// Try the end kept without the loops its outlying check names, or
    /// else without each cluster its doubt check names, and keep the
    /// better end ([`starts::recheck`]); off: they are only named
    /// (`outlying`, `doubtful`, exit status 5).
    pub recheck: bool,
    /// Try the end kept without its keystone — the accepted cluster whose
    /// removal would move the map most, by more than
    /// [`doubt::KEYSTONE_MOVE`] of its size — and keep the end without it
    /// where that is better and accepts as many candidates
    /// ([`starts::recheck`]); off: not sought.
    pub keystone: bool,
}

impl Default for Layers {
    fn default() -> Self {
        Self {
            annealing: true,
            decisions: true,
            clusters: true,
            agreement: true,
            aliasing: true,
            populations: true,
            search: true,
            relaxation: true,
            rescue: true,
            starts: true,
            reach: true,
            recheck: true,
            keystone: true,
        }
    }
}

impl Layers {
    /// The layer names, as `--expert` takes them (with `no-`).
    pub const NAMES: [&'static str; 13] = [
        "annealing",
        "decisions",
        "clusters",
        "agreement",
        "aliasing",
        "populations",
        "search",
        "relaxation",
        "rescue",
        "starts",
        "reach",
        "recheck",
        "keystone",
    ];

    /// Parses `no-LAYER[,no-LAYER…]` (empty: every layer on).
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut layers = Self::default();
        for item in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let slot = match item {
                "no-annealing" => &mut layers.annealing,
                "no-decisions" => &mut layers.decisions,
                "no-clusters" => &mut layers.clusters,
                "no-agreement" => &mut layers.agreement,
                "no-aliasing" => &mut layers.aliasing,
                "no-populations" => &mut layers.populations,
                "no-search" => &mut layers.search,
                "no-relaxation" => &mut layers.relaxation,
                "no-rescue" => &mut layers.rescue,
                "no-starts" => &mut layers.starts,
                "no-reach" => &mut layers.reach,
                "no-recheck" => &mut layers.recheck,
                "no-keystone" => &mut layers.keystone,
                _ => {
                    return Err(format!(
                        "unknown layer '{item}': expected no-LAYER with LAYER one of {}",
                        Self::NAMES.join(", ")
                    ));
                }
            };
            *slot = false;
        }
        Ok(layers)
    }
}

/// A loop candidate as the robust back end sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Its edge in the graph.
    pub edge: usize,
    /// The gate's posterior of the true-loop count component (`None`: no
    /// count, or counts not used).
    pub count_posterior: Option<f64>,
    /// Whether it passed the gate: only those shape the first maps.
    pub kept: bool,
}

/// Why a candidate ended where it did.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reason {
    /// The loop model's posterior is ≥ ½.
    Consistent,
    /// The loop model's posterior is < ½.
    Inconsistent,
    /// Nothing else checks it; its prior decided.
    Unchecked,
    /// Taken out because the map failed the χ² test without it.
    ExplainsChi2,
    /// Its posterior is ≥ ½, but its innovation lies beyond the reach of
    /// the map's true loops (the loop model's fitted density puts the
    /// largest of them there with a chance below
    /// [`schedule::REACH_LEVEL`], and its `ν²` exceeds its information's
    /// mean); or the outlying check named it in an end it was accepted in,
    /// and the end without it was kept ([`starts::recheck`]).
    Outlying,
    /// The decisions did not settle on it: the last evaluation's posterior
    /// and the set the map was solved with disagree (it was accepted on
    /// some maps of a cycle of sets and rejected on others, and the set
    /// kept is the cycle's best-fitting one).
    Unsettled,
    /// Weighted by a kernel (weight ≥ ½ or not).
    Kernel,
    /// Dropped by the gate, and the method weighs only the kept ones (a
    /// kernel, or EM with the layer `rescue` off).
    Dropped,
    /// Kept with weight 1 (no robust method).
    Trusted,
}

/// The fate of every candidate and how it was reached.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// Whether the final map was solved with each candidate (weight ≥ ½).
    pub accepted: Vec<bool>,
    /// Each candidate's weight in the final solve.
    pub weights: Vec<f64>,
    /// EM: each candidate's posterior at the last evaluation.
    pub posteriors: Vec<Option<f64>>,
    /// EM: each candidate's squared innovation at the last evaluation.
    pub innovations: Vec<Option<f64>>,
    /// Why each candidate ended where it did.
    pub reasons: Vec<Reason>,
    /// EM: the loop model at the last evaluation.
    pub model: Option<LoopModel>,
    /// E-steps of the annealing, or reweighting rounds of a kernel.
    pub rounds: usize,
    /// EM with the chordal guess: chordal relaxations solved.
    pub relaxations: usize,
    /// EM: accepted sets solved.
    pub decisions: usize,
    /// EM with the chordal guess: accepted sets solved from their
    /// relaxation.
    pub relaxed_starts: usize,
    /// EM: the clusters of candidates.
    pub clusters: usize,
    /// EM: what the χ² search did.
    pub search: Option<Search>,
    /// Whether the iteration or time budget cut the method short.
    pub cut_short: bool,
    /// EM from an update's start ([`resume`]): whether its decisions swung
    /// ([`schedule::Swing`]) and it gave up, the map and decisions left
    /// unfinished: the caller runs the whole job instead.
    pub swung: bool,
    /// EM: where each of its starts ended ([`starts`]; empty with one
    /// start).
    pub starts: Vec<StartEnd>,
    /// EM: whether the decisions did not settle at the last map they
    /// judged (a candidate its model accepts and the set rejects, or the
    /// reverse): what EM's second start and an update's whole job follow.
    /// A set kept from a cycle is reported as judged at its own map, where
    /// its candidates can be `unsettled` though this is false — unless
    /// that map disputes as many candidates as it confirms ([`disputed`]).
    pub unsettled: bool,
    /// EM: the accepted clusters of a passing map that the map cannot
    /// vouch for ([`doubt`]).
    pub doubtful: Vec<Doubt>,
    /// EM: the rejected candidates of a passing map that their counts
    /// alone kept out and that would move it ([`doubt`]).
    pub held_back: Vec<HeldBack>,
    /// EM: the accepted candidates of a passing map whose innovations lie
    /// beyond the true loops' and that move it ([`doubt`]).
    pub outlying: Vec<Outlying>,
    /// EM: the keystone of a passing map with no outlying candidates
    /// ([`doubt::keystone`]), for [`starts::recheck`] to try without.
    keystone: Option<Vec<usize>>,
    /// EM: the clusters of accepted loops the outlying check flags whose
    /// removal moves the map too little to name them, but enough for
    /// [`starts::recheck`] to try without ([`doubt::RECHECK_MOVE`]).
    below_warning: Vec<Vec<usize>>,
    /// EM: the sizes of the clusters' moves at the map kept, from the
    /// decisions' evaluation of it, with the set it judged
    /// ([`doubt::Moves`]).
    moves: Option<(Vec<bool>, doubt::Moves)>,
    /// EM: the common offsets of the clusters at the map kept, from the
    /// decisions' evaluation of it, with the set it judged.
    offsets: Option<(Vec<bool>, Vec<doubt::Offset>)>,
}

impl Outcome {
    /// Nothing decided yet about `n` candidates.
    fn new(n: usize) -> Self {
        Self {
            accepted: vec![false; n],
            weights: vec![0.0; n],
            posteriors: vec![None; n],
            innovations: vec![None; n],
            reasons: vec![Reason::Dropped; n],
            model: None,
            rounds: 0,
            relaxations: 0,
            decisions: 0,
            relaxed_starts: 0,
            clusters: 0,
            search: None,
            cut_short: false,
            swung: false,
            starts: Vec::new(),
            unsettled: false,
            doubtful: Vec::new(),
            held_back: Vec::new(),
            outlying: Vec::new(),
            keystone: None,
            below_warning: Vec::new(),
            moves: None,
            offsets: None,
        }
    }
}

/// What the robust solve is asked to do: the candidates, the method that
/// weighs them and its kernel width, EM's layers, and the χ² test EM's
/// search acts on.
pub struct Job<'a, P: Pose<D>, const D: usize> {
    /// Every loop candidate.
    pub candidates: &'a [Candidate],
    /// How they are weighed.
    pub method: RobustMethod,
    /// The kernel width on the whitened residual norm.
    pub c: f64,
    /// EM's layers.
    pub layers: &'a Layers,
    /// The χ² test of a map and its weights.
    pub test: &'a Test<'a, P, D>,
    /// Whether the map starts from the chordal relaxation (EM anneals on
    /// it and solves each accepted set from it when that fits better).
    pub chordal: bool,
    /// The caller's own poses (a g2o file's vertices), from which EM's
    /// second start runs a plain kernel ([`starts`]); `None`: one start.
    pub given: Option<&'a [P]>,
}

/// Solves for the map with the candidates weighed by the job's method,
/// leaving the map in the session's graph and the weights in `weights`
/// (one per edge: the trusted edges stay 1).
pub fn solve<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
) -> Result<Outcome, SolveError> {
    let (candidates, method, c) = (job.candidates, job.method, job.c);
    let n = candidates.len();
    for cand in candidates {
        weights[cand.edge] = if cand.kept { 1.0 } else { 0.0 };
    }
    let mut out = Outcome::new(n);
    let kept: Vec<usize> = candidates
        .iter()
        .filter(|c| c.kept)
        .map(|c| c.edge)
        .collect();
    // Too few candidates to learn EM's model from: EM's kernel with every
    // prior ½, the Cauchy kernel at EM's width.
    let few = method == RobustMethod::Em && n < MIN_CANDIDATES;
    match method {
        RobustMethod::Em if n >= MIN_CANDIDATES => {
            out = starts::em(session, weights, job)?;
            doubts(session, weights, job, &mut out);
            out = starts::recheck(session, weights, job, out)?;
        }
        RobustMethod::None => {
            session.converge(weights)?;
            out.cut_short = session.exhausted();
        }
        RobustMethod::Em => {
            (out.rounds, out.cut_short) = kernels::reweight(
                session,
                weights,
                &kept,
                (RobustMethod::Cauchy, c),
                kernels::Until::Settled,
            )?;
            // As EM does: the final map is solved with the accepted ones.
            for &k in &kept {
                weights[k] = if weights[k] >= 0.5 { 1.0 } else { 0.0 };
            }
            if !out.cut_short {
                session.converge(weights)?;
                out.cut_short = session.exhausted();
            }
        }
        kernel => {
            (out.rounds, out.cut_short) = kernels::reweight(
                session,
                weights,
                &kept,
                (kernel, c),
                kernels::Until::Settled,
            )?;
        }
    }
    for (k, cand) in candidates.iter().enumerate() {
        out.weights[k] = weights[cand.edge];
        out.accepted[k] = weights[cand.edge] >= 0.5;
        if (method != RobustMethod::Em || few) && cand.kept {
            out.reasons[k] = if method == RobustMethod::None {
                Reason::Trusted
            } else {
                Reason::Kernel
            };
        }
    }
    Ok(out)
}

/// EM from the map in the session's graph (the job's initial guess):
/// annealing, decisions by innovation, and the χ² search; the outcome's
/// weights are not yet filled in.
fn annealed_start<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    (job, restarts): (&Job<'_, P, D>, &mut search::Restarts<P>),
) -> Result<Outcome, SolveError> {
    let mut out = Outcome::new(job.candidates.len());
    if session.exhausted() {
        // No budget at all: the initial guess stands (a run of no
        // iteration records it).
        session.run(weights, 0)?;
        out.cut_short = true;
        return Ok(out);
    }
    let annealed = match (job.layers.annealing, job.chordal) {
        (false, _) => schedule::Annealed::default(),
        (true, true) => schedule::anneal_chordal(session, weights, job.candidates, job.c)?,
        (true, false) => schedule::anneal(session, weights, job.candidates, job.c)?,
    };
    out.rounds = annealed.steps;
    out.relaxations = annealed.relaxations;
    if annealed.cut_short {
        // The annealed map so far stands (a run of no iteration records it).
        session.run(weights, 0)?;
        out.cut_short = true;
        return Ok(out);
    }
    settle(
        session,
        weights,
        (job, restarts),
        (job.chordal, Swing::Continue),
        &mut out,
    )?;
    Ok(out)
}

/// Re-decides every candidate from an earlier solution: the decisions by
/// innovation and the χ² search of EM, started from the accepted set in
/// `weights` (1 accepted, 0 not) and the map in the session's graph —
/// instead of the annealing, whose work the earlier decisions did. With a
/// method other than EM, or too few candidates for EM's model, every
/// candidate is weighed again by [`solve`] from the map as it is. With a
/// `proposal`, EM first accepts the new candidates the last model accepts
/// against the map as it is ([`schedule::propose`]). EM gives up when its
/// decisions swing ([`schedule::Swing`], [`Outcome::swung`]).
/// Returns the outcome and whether it was that full re-weighing.
pub fn resume<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
    proposal: Option<&Proposal<'_>>,
) -> Result<(Outcome, bool), SolveError> {
    let candidates = job.candidates;
    if job.method != RobustMethod::Em || candidates.len() < MIN_CANDIDATES {
        let job = Job {
            chordal: false,
            ..*job
        };
        let out = solve(session, weights, &job)?;
        return Ok((out, job.method != RobustMethod::None));
    }
    let mut out = Outcome::new(candidates.len());
    if session.exhausted() {
        session.run(weights, 0)?;
        out.cut_short = true;
    } else {
        if let Some(proposal) = proposal {
            schedule::propose(session, weights, candidates, proposal, job.layers)?;
        }
        let restarts = &mut search::Restarts::default();
        settle(
            session,
            weights,
            (job, restarts),
            (false, Swing::GiveUp),
            &mut out,
        )?;
        if out.swung {
            return Ok((out, false));
        }
        doubts(session, weights, job, &mut out);
        out = starts::recheck(session, weights, job, out)?;
    }
    for (k, cand) in candidates.iter().enumerate() {
        out.weights[k] = weights[cand.edge];
        out.accepted[k] = weights[cand.edge] >= 0.5;
    }
    Ok((out, false))
}

/// The doubtful clusters, the candidates held back by their counts and
/// the outlying accepted candidates ([`doubt`]) of EM's end in the session
/// (the accepted set in `weights`, the evaluation of it in `out`), when its
/// map passes the χ² test, its decisions settled and the budget did not
/// cut it short; they are written into `out`. Where a candidate is
/// `unsettled` the map already warns that its decisions are unconfirmed,
/// and the loops it holds wrongly bend the true clusters around them,
/// whose offsets then stand out by the dozen (sphere2500 seed 6 of the
/// places sweep, published: 44 clusters of 1,351 loops, 11 of them the
/// aliases). They advise: a factorisation that fails here (the map was
/// just solved with the same edges) finds none.
fn doubts<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
    job: &Job<'_, P, D>,
    out: &mut Outcome,
) {
    out.keystone = None;
    out.below_warning = Vec::new();
    let test = (job.test)(session.graph, weights);
    let settled = !out.unsettled && !out.reasons.contains(&Reason::Unsettled);
    let finished = !out.cut_short && !session.exhausted();
    let Some(t) = test.filter(|t| t.passed && settled && finished) else {
        return;
    };
    let accepted: Vec<bool> = (job.candidates.iter())
        .map(|c| weights[c.edge] >= 0.5)
        .collect();
    let known = (out.offsets.as_ref())
        .filter(|(set, _)| *set == accepted)
        .map(|(_, offsets)| offsets.as_slice());
    let ends = (job.candidates, accepted.as_slice());
    let advise = |what: &str, e: SolveError| log::debug!("no {what} sought: {e}");
    out.doubtful = doubt::doubtful(session, weights, ends, (job.layers, t.alpha), known)
        .unwrap_or_else(|e| {
            advise("doubtful clusters", e);
            Vec::new()
        });
    let Some(model) = out.model.as_ref() else {
        return;
    };
    // Rejected by the posterior although the innovation alone speaks for a
    // true loop: the count decided.
    let held: Vec<bool> = (0..job.candidates.len())
        .map(|k| {
            let speaks = (out.innovations[k])
                .is_some_and(|nu2| nu2 > 0.0 && model.speaks_for_a_true_loop(nu2.ln()));
            out.reasons[k] == Reason::Inconsistent && speaks
        })
        .collect();
    out.held_back = doubt::held_back(session, weights, (job.candidates, &held), job.layers)
        .unwrap_or_else(|e| {
            advise("candidates held back", e);
            Vec::new()
        });
    let tests = (job.layers, t.alpha, out.doubtful.as_slice());
    (out.outlying, out.below_warning) =
        doubt::outlying(session, weights, ends, (&out.innovations, model), tests).unwrap_or_else(
            |e| {
                advise("outlying candidates", e);
                (Vec::new(), Vec::new())
            },
        );
    if out.outlying.is_empty() && job.layers.keystone {
        let known = (out.moves.as_ref())
            .filter(|(set, _)| *set == accepted)
            .map(|(_, moves)| moves);
        out.keystone =
            doubt::keystone(session, weights, ends, job.layers, known).unwrap_or_else(|e| {
                advise("keystone", e);
                None
            });
    }
}

/// EM from an accepted set: decisions by innovation until the set repeats
/// (or, as `swing` says, swings), the χ² search, and each candidate's
/// posterior and reason. `chordal`: whether each accepted set may be
/// solved from its chordal relaxation.
fn settle<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    (job, restarts): (&Job<'_, P, D>, &mut search::Restarts<P>),
    (chordal, swing): (bool, Swing),
    out: &mut Outcome,
) -> Result<(), SolveError> {
    let (candidates, layers, test) = (job.candidates, job.layers, job.test);
    let how = schedule::Deciding {
        scale: Scale::Learned,
        layers,
        relax: chordal,
        swing,
    };
    let mut passing = search::Passing::default();
    let (mut decided, mut search) = decide_and_explain(
        session,
        (weights, candidates),
        &how,
        test,
        &mut passing.recording(candidates, test),
    )?;
    if decided.swung {
        out.swung = true;
        out.decisions = decided.decisions;
        return Ok(());
    }
    // A failed test no cluster explains: decide again from the trusted
    // edges' map, with the scale learned and with the file's; then end at
    // the passing set of least `J` of all the decisions solved.
    let unexplained = search.as_ref().is_some_and(|s| !s.suspects.is_empty())
        && search::verdict(session, weights, test) == Some(false);
    for scale in [Scale::Learned, Scale::File] {
        if !unexplained || search::verdict(session, weights, test) != Some(false) {
            break;
        }
        let restarted = search::restart(
            session,
            weights,
            candidates,
            &mut decided,
            test,
            |session, weights| {
                let how = schedule::Deciding { scale, ..how };
                restarts.decide(session, weights, (candidates, &how), &mut passing, test)
            },
        )?;
        if restarted {
            search = search::explain(session, weights, candidates, &mut decided, layers, test)?;
            if let Some(s) = &mut search {
                s.restarted = true;
            }
        }
    }
    if unexplained && !decided.cut_short && !session.exhausted() {
        let ending = (&mut decided, &mut search);
        end_passing(session, weights, (job, &how), ending, &passing)?;
    }
    record(out, decided, search, (candidates, &how));
    Ok(())
}

/// Ends the decisions of a failed test no cluster explained at the passing
/// set of least `J` they solved ([`search::Passing::best`]), if that is
/// not the set they end at, its `J` is lower than their end's (a map that
/// fails by chance, as one correct map in `1/α` does, keeps its loops and
/// its suspects), and its map passes when solved again.
fn end_passing<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    (job, how): (&Job<'_, P, D>, &schedule::Deciding<'_>),
    (decided, search): (&mut schedule::Decided, &mut Option<Search>),
    passing: &search::Passing,
) -> Result<(), SolveError> {
    let Some((best, j, price)) = passing.best(job.c) else {
        return Ok(());
    };
    let passes = search::verdict(session, weights, job.test) == Some(true);
    let end = schedule::objective(session.graph, weights, job.candidates, price);
    if best == decided.accepted.as_slice() || (!passes && end <= j) {
        return Ok(());
    }
    let saved = (
        session.graph.poses.clone(),
        weights.to_vec(),
        decided.clone(),
    );
    let edges: Vec<usize> = job.candidates.iter().map(|c| c.edge).collect();
    decided.adopt(session, weights, (job.candidates, &edges), best, how)?;
    if search::verdict(session, weights, job.test) != Some(true) {
        // Solved again, its map fails after all: the decisions' end stands.
        session.graph.poses = saved.0;
        weights.copy_from_slice(&saved.1);
        *decided = saved.2;
        return Ok(());
    }
    if let Some(s) = search {
        s.suspects.clear();
        s.removed.retain(|r| r.loops.iter().all(|&k| !best[k]));
        s.restarted = false;
    }
    Ok(())
}

/// The decisions by innovation and the χ² search, again while the search
/// takes clusters out: a wrong loop that bent the map can leave true loops
/// inconsistent with it, which the map without it shows. The clusters
/// taken out stay out (their prior of a true loop is 0) and the decisions
/// start from the set the search left; the searches' removals add up to at
/// most [`MAX_REMOVALS`].
fn decide_and_explain<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    (weights, candidates): (&mut [f64], &[Candidate]),
    how: &schedule::Deciding<'_>,
    test: &Test<'_, P, D>,
    solved: &mut schedule::SetSolved<'_, P, D>,
) -> Result<(schedule::Decided, Option<Search>), SolveError> {
    let layers = how.layers;
    let mut judged = candidates.to_vec();
    let mut removed: Vec<Suspect> = Vec::new();
    let mut before: Option<schedule::Decided> = None;
    loop {
        let mut decided = schedule::decide(session, weights, &judged, how, solved)?;
        if let Some(b) = &before {
            decided.count_work_of(b);
        }
        if decided.swung {
            return Ok((decided, None));
        }
        let Some(mut search) =
            search::explain(session, weights, &judged, &mut decided, layers, test)?
        else {
            // Cut short: what earlier rounds took out stays reported.
            let search = (!removed.is_empty()).then(|| Search {
                removed,
                ..Search::default()
            });
            return Ok((decided, search));
        };
        let again = !search.removed.is_empty()
            && removed.len() + search.removed.len() < MAX_REMOVALS
            && !decided.cut_short
            && !session.exhausted();
        for k in search.removed.iter().flat_map(|r| r.loops.iter().copied()) {
            judged[k].count_posterior = Some(0.0);
        }
        removed.append(&mut search.removed);
        if !again {
            search.removed = removed;
            let taking = (weights, candidates, judged.as_slice());
            take_back(
                session,
                taking,
                (how, test, solved),
                (&mut decided, &mut search),
            )?;
            return Ok((decided, Some(search)));
        }
        before = Some(decided);
    }
}

/// Gives back the clusters the χ² search took out that the map it ended
/// at no longer speaks against. The search takes out the cluster of the
/// largest drop first, and a true loop whose drop was large only because
/// aliases bent the map is taken out before them: on a young sphere
/// (`tests/update_equals_optimize.rs`, seed 55) a true loop at `ν²` 8.4
/// on 6 dimensions left with a drop of 999, and the aliases after it; at
/// the map without them the model accepts it by its own innovation and
/// count (posterior 0.9986). Where the map passes, a cluster is freed
/// when the model at that map accepts every member by its own count's
/// prior ([`schedule::verdict`]), none beyond the true loops' reach, and
/// its members' `ν²` added up would not stand out among the clusters
/// ([`search::stands_out`]: the search would take it out again, as it
/// would a true loop of a heavy tail at `ν²` 104–186 on 3 dimensions that
/// the model accepts). The decisions run once more with the freed
/// clusters at their own priors, and their end is kept if its map passes
/// with nothing taken out again; else the search's end stands. `judged`:
/// the candidates as the last decisions judged them, the removed ones at
/// a prior of 0.
fn take_back<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    (weights, candidates, judged): (&mut [f64], &[Candidate], &[Candidate]),
    (how, test, solved): (
        &schedule::Deciding<'_>,
        &Test<'_, P, D>,
        &mut schedule::SetSolved<'_, P, D>,
    ),
    (decided, search): (&mut schedule::Decided, &mut Search),
) -> Result<(), SolveError> {
    let back = freed(session, weights, (candidates, how, test), (decided, search));
    if back.is_empty() {
        return Ok(());
    }
    let saved = (session.graph.poses.clone(), weights.to_vec());
    let mut judging = judged.to_vec();
    for &k in &back {
        judging[k].count_posterior = candidates[k].count_posterior;
    }
    let mut again = schedule::decide(session, weights, &judging, how, solved)?;
    let explained = match again.swung {
        true => None,
        false => search::explain(session, weights, &judging, &mut again, how.layers, test)?,
    };
    let stands = explained.is_some_and(|s| s.removed.is_empty())
        && search::verdict(session, weights, test) == Some(true);
    if stands {
        again.count_work_of(decided);
        *decided = again;
        search
            .removed
            .retain(|r| r.loops.iter().all(|k| !back.contains(k)));
    } else {
        session.graph.poses = saved.0;
        weights.copy_from_slice(&saved.1);
        decided.count_work_of(&again);
    }
    Ok(())
}

/// The loops of the clusters [`take_back`] frees: none unless the map of
/// `weights` passes its test and the decisions ran to their end.
fn freed<P: Pose<D>, const D: usize>(
    session: &Session<'_, P, D>,
    weights: &[f64],
    (candidates, how, test): (&[Candidate], &schedule::Deciding<'_>, &Test<'_, P, D>),
    (decided, search): (&schedule::Decided, &Search),
) -> Vec<usize> {
    if search.removed.is_empty() || decided.cut_short || session.exhausted() {
        return Vec::new();
    }
    let (Some(model), Some(t)) = (&decided.model, test(session.graph, weights)) else {
        return Vec::new();
    };
    if !t.passed {
        return Vec::new();
    }
    let (accepts, beyond) = schedule::verdict(model, &decided.innovations, candidates, how.layers);
    // The clusters the search would rank, and the one given back.
    let tested = 1
        + (decided.clusters.iter())
            .filter(|c| c.iter().any(|&k| decided.accepted[k]))
            .count();
    let quiet = |loops: &[usize]| {
        let nu2: Option<f64> = loops.iter().map(|&k| decided.innovations.nu2[k]).sum();
        nu2.is_some_and(|v| !search::stands_out(&t, v, (loops.len(), D), tested))
    };
    (search.removed.iter())
        .filter(|r| r.loops.iter().all(|&k| accepts[k] && !beyond[k]) && quiet(&r.loops))
        .flat_map(|r| r.loops.iter().copied())
        .collect()
}

/// Fills `out` with what the decisions `decided` and the χ² search
/// `search` found: the counts, and each candidate's innovation, posterior
/// and reason.
fn record(
    out: &mut Outcome,
    decided: schedule::Decided,
    search: Option<Search>,
    (candidates, how): (&[Candidate], &schedule::Deciding<'_>),
) {
    out.decisions = decided.decisions;
    out.relaxations += decided.relaxations;
    out.relaxed_starts = decided.relaxed_starts;
    out.clusters = decided.clusters.len();
    out.cut_short = decided.cut_short;
    let removed: Vec<usize> = search
        .iter()
        .flat_map(|s| s.removed.iter().flat_map(|r| r.loops.iter().copied()))
        .collect();
    let last = (&decided.innovations, &decided.model);
    // The report's judgement, at the map kept.
    let (innovations, model) = match &decided.at_own_map {
        Some((i, m)) => (i, m),
        None => last,
    };
    let judging = (&decided, candidates, removed.as_slice(), how);
    (out.reasons, out.posteriors) = reasons((innovations, model), judging);
    for k in 0..candidates.len() {
        out.innovations[k] = innovations.nu2.get(k).copied().flatten();
    }
    // Whether the decisions did not settle at the last map they judged
    // (the report's reasons when that map is the one kept), or the set
    // kept from a cycle is disputed at its own map.
    out.unsettled = match decided.at_own_map {
        None => out.reasons.contains(&Reason::Unsettled),
        Some(_) => {
            reasons(last, judging).0.contains(&Reason::Unsettled)
                || disputed(&out.reasons, &decided.accepted)
        }
    };
    out.offsets = doubt::offsets(innovations, &decided.clusters, &decided.accepted)
        .map(|offsets| (decided.accepted.clone(), offsets));
    out.moves = doubt::moves(innovations, &decided.clusters, &decided.accepted)
        .map(|moves| (decided.accepted.clone(), moves));
    out.model = model.clone();
    out.search = search;
}

/// Whether the model at the map of a set kept from a cycle (`accepted`)
/// disputes at least as many candidates (`reasons`, [`Reason::Unsettled`])
/// as it confirms of the set: the half step's test of a swing that is no
/// local conflict ([`schedule::swings_most`]). Such a set is no fixed point
/// of the decisions near it, and is treated as one that did not settle
/// (EM's second start, an update's whole job; docs/method.md §5, "A
/// cycle").
fn disputed(reasons: &[Reason], accepted: &[bool]) -> bool {
    // The set the model at that map accepts.
    let judged: Vec<bool> = (accepted.iter().zip(reasons))
        .map(|(&a, &r)| a != (r == Reason::Unsettled))
        .collect();
    judged != accepted && schedule::swings_most(accepted, &judged)
}

/// What [`reasons`] judges against: the decisions, the candidates, the
/// loops the χ² search took out, and how the decisions judge.
type Judging<'a> = (
    &'a schedule::Decided,
    &'a [Candidate],
    &'a [usize],
    &'a schedule::Deciding<'a>,
);

/// Each candidate's reason and posterior under the loop `model` with
/// `innovations`, against the set `decided` accepted (`removed`: the loops
/// the χ² search took out), as the decisions `how` judge
/// ([`schedule::verdict`]).
fn reasons(
    (innovations, model): (&Innovations, &Option<LoopModel>),
    (decided, candidates, removed, how): Judging<'_>,
) -> (Vec<Reason>, Vec<Option<f64>>) {
    let n = candidates.len();
    let (judged, beyond) = match model {
        Some(m) => schedule::verdict(m, innovations, candidates, how.layers),
        None => (vec![false; n], vec![false; n]),
    };
    (0..n)
        .map(|k| {
            let e = innovations.evidence(candidates, k);
            let posterior = model.as_ref().map(|m| match &e {
                Some(e) => m.posterior(e),
                None => m.prior(candidates[k].count_posterior),
            });
            let reason = if removed.contains(&k) {
                Reason::ExplainsChi2
            } else if !candidates[k].kept && !decided.rescue {
                Reason::Dropped
            } else if e.is_none() {
                Reason::Unchecked
            } else if judged[k] != decided.accepted[k] {
                Reason::Unsettled
            } else if judged[k] {
                Reason::Consistent
            } else if beyond[k] {
                Reason::Outlying
            } else {
                Reason::Inconsistent
            };
            (reason, posterior)
        })
        .unzip()
}

#[cfg(test)]
mod tests {
    use super::{Reason, disputed};

    /// A kept set its map disputes as much as it confirms is disputed; a
    /// local conflict, or a set nothing disputes, is not.
    #[test]
    fn a_set_its_map_disputes_as_much_as_it_confirms_is_disputed() {
        use Reason::{Consistent as C, Inconsistent as I, Unsettled as U};
        // 3 confirmed, 4 disputed (the torus3D end in miniature).
        let reasons = [C, C, C, U, U, U, U, I];
        let accepted = [true, true, true, false, false, false, false, false];
        assert!(disputed(&reasons, &accepted));
        // 4 confirmed, 3 disputed: a local conflict.
        let reasons = [C, C, C, C, U, U, U, I];
        let accepted = [true, true, true, true, false, false, true, false];
        assert!(!disputed(&reasons, &accepted));
        // Nothing disputed, nothing accepted.
        assert!(!disputed(&[I, I], &[false, false]));
        // An accepted but disputed candidate is not confirmed.
        assert!(disputed(&[U, C], &[true, true]));
    }
}
