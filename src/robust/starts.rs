//! EM's starts, and the choice among where they end.
//!
//! EM's decisions by innovation are local moves: from the set they start
//! with they reach a set that no single candidate's innovation would change,
//! and the χ² search then takes out what explains a failed test. Which such
//! set they reach depends on the map they start from. The annealed start
//! ([`super::annealed_start`]) builds its first map on the chordal
//! relaxation of the trusted edges and the candidates at their annealing
//! weights; a stretch of the map that aliases claim to be another place can
//! pull that relaxation, and the decisions then start inside the wrong
//! basin. So EM has a second start that shares nothing with the first: a
//! plain robust kernel — Cauchy at the peers' width, `√χ²_D(0.95)` — solved
//! by iteratively reweighted LM from the caller's own poses (a g2o file's
//! vertices), as GTSAM's LM with a Cauchy loss does, until the set it
//! leaves at weight ≥ ½ is the same two rounds in a row
//! ([`kernels::Until::HeldSetRepeats`]); EM decides from that set. And a
//! third, which seeks the objective that ranks the ends (below) directly:
//! its truncated least squares — graduated non-convexity's TLS kernel
//! ([`kernels`], GTSAM's μ schedule) with the truncation at `J`'s price
//! per candidate left out, `s²·c²` with `s²` the annealed end's misfit
//! scale where that is below the file's, else 1 — from the caller's poses
//! until its weights are 0 or 1; EM decides from the set it holds. Neither
//! kernel start finds every end the other does: the Cauchy kernel weighs
//! every candidate down from the first map on, GNC begins convex with
//! every weight near 1 and hardens. The truncated start is sought only
//! where the annealed end fails the χ² test or its decisions did not
//! settle, and the kernel start's end, if it has one, leaves the same
//! question: where the second start was sought for the model's
//! disagreements with the stated information alone (below), GNC's
//! schedule of 20–40 solves would be spent for nothing — unless that
//! disagreement is a population called wrong that the stated information
//! calls consistent (true loops the annealed end may have left out) and
//! the kernel start reached no end (its weights did not stand within its
//! share of iterations): then nothing answered it.
//!
//! Where the best of those ends has a model that calls wrong a population
//! the information as stated calls consistent, and no other start reached
//! its accepted set, the loops it left out at innovations within EM's
//! kernel are put back: the map is solved from that end's with them, and
//! EM decides from there ([`readmitted`]). A young map that a group of
//! aliases bent can keep true loops out at innovations the file's noise
//! allows; the kernel starts, from the caller's poses, need not reach the
//! set that holds them, and where that end passes with decisions that
//! settled, nothing else asks again. Two starts that share nothing and
//! reach one set answer the question; the start is not sought then.
//!
//! Where the best of those ends still fails the χ² test or its decisions
//! did not settle, EM decides once more from that end's map, with every
//! candidate judged against the map without its cluster only — without
//! the agreement layer ([`super::innovation`]), by which the members of a
//! cluster that agree with each other speak against one that does not —
//! and then with every layer from where that ends, within the annealed
//! start's share of iterations. A group of aliases at a revisited place
//! that outnumbers the true loop beside it agrees with itself, and where
//! the map leans its way the true loop is the member that disagrees;
//! judged against the map without the cluster, the true loop fits and the
//! group does not ([`without_agreement`]).
//!
//! The second start is sought only when the annealed end's map fails the
//! χ² test (or there is no test), or its decisions did not settle (some
//! candidate is [`super::Reason::Unsettled`]: the model at the map kept
//! accepts it and the set kept rejects it, or the reverse; for a set kept
//! from a cycle, when its own map disputes as many candidates as it
//! confirms, [`Outcome::unsettled`]), or its loop model calls a
//! population of candidates wrong that the information as the file states
//! it calls consistent ([`super::model::LoopModel::wrong_within_kernel`]:
//! a run of true loops the decisions left out can look so), or accepts a
//! candidate that information calls an outlier
//! ([`super::model::LoopModel::accepts_beyond_stated`]: aliases that bent
//! the map widen the true loops' fitted spread until it reaches them). A
//! map that passes, at decisions that settled, with neither, is
//! consistent with the information of its edges, the test the method's
//! answer rests on, and a fixed point of the decisions; it stands. A map
//! that passes but leaves out loops its own model accepts is neither: the
//! test cannot see loops left out (a map fits what it keeps), and on torus3D with 300 aliases placed anywhere
//! such an end kept 306 of 4,049 true loops and was 31.7 % off. Run always,
//! the second start doubled the solver's factorisations on a graph of 10⁶
//! poses for nothing (docs/method.md §5, "When the test fails or the
//! decisions did not settle").
//!
//! Each start ends at an accepted set `S` and its least-squares map `X_S`.
//! The job keeps
//!
//! 1. an end whose map passes the χ² test over one whose map fails it: a
//!    failed test is resolved when any start resolves it;
//! 2. among ends alike in that, the one of the lower objective
//!
//!    ```text
//!    J(S) = Σ_{trusted ∪ S} eᵀΩe(X_S) + s²·c² · |candidates ∉ S|,
//!    ```
//!
//!    the truncated least squares of the loop model: `c` EM's kernel
//!    width, at which a true loop is left out once in a million, on the
//!    scale `s²` of the file's information that the best-fitting end
//!    shows — the least `D²/K` (the χ² test's misfit per residual degree of
//!    freedom) among the ends, one scale for all (a file whose information
//!    is 100 times too loose has residuals 100 times too small, and would
//!    otherwise pay for leaving a loop out a hundredfold). For a linear problem,
//!    adding a candidate to `S` raises the least-squares minimum by exactly
//!    its squared innovation `ν²`, and taking one out lowers it by its
//!    deleted residual's: EM's decisions move by the same innovations, so
//!    an end they cannot improve one candidate at a time is a local minimum
//!    of `J`, and `J` ranks the local minima the starts found.
//!
//! Ties keep the earlier start's end; two ends of one accepted set are one
//! end.
//!
//! The end kept meets one more end where its outlying check
//! ([`super::doubt`]) names accepted loops — beyond the true loops' own
//! scale, and moving the map — in a map that passes with settled decisions,
//! the end every start above stands on: EM's decisions again from the map
//! solved without them, holding them out as the χ² search holds out what it
//! takes ([`recheck`]). An alias the map bent to fit leaves a map that
//! falls back without it, and the two ends are ranked by `J` as the starts'
//! are; the update does the same at its end ([`super::resume`]). So does a
//! loop the check flags whose removal moves the map too little to name it,
//! but more than the map may be off ([`super::doubt::RECHECK_MOVE`]), held
//! out with the loops already rejected as outlying. Where the check names
//! and tries nothing, the end meets the end without each cluster its
//! doubt check names ([`super::doubt::doubtful`]: accepted loops that err
//! by one offset beyond their own noise, whose removal would move the
//! map), and the end without its keystone ([`super::doubt::keystone`]):
//! the accepted cluster the map rests on most, which a group of aliases
//! that bent a map with few loops can be (a doubtful cluster that is the
//! keystone is tried as the keystone). An end without a doubtful cluster
//! replaces the kept one only where it ranks first and nothing questions
//! it: it must resolve the doubt, not trade it for another (a ring whose
//! true loops all close it at one place bends cheaply to a group of
//! aliases, and both clusters err by a common offset; without the group
//! the true loops fit). The end without the keystone replaces the kept
//! one only where it ranks first, accepts as many candidates, and nothing
//! questions it (it passes, settled, and names no doubtful cluster, loop
//! held back or outlying loop): taken out as a
//! whole, a cluster of true loops at a tension lowers the fit by more than
//! their price, and a group of aliases that agree with each other fits as a
//! place seen twice would. EM's decisions from the map without the keystone
//! start where the keystone bent it, and the true loops it pushed out need
//! not come back from there; so, where nothing questions the end kept, the
//! annealed start runs again too, on the chordal relaxation without the
//! keystone ([`annealed_without`]), and the better of the two ends that
//! meets those conditions is the one that competes.

use super::schedule::{misfit_scale, objective};
use super::search::Restarts;
use super::{
    Candidate, Job, Outcome, Reason, RobustMethod, Swing, annealed_start, kernels, settle,
};
use crate::geometry::Pose;
use crate::graph::Graph;
use crate::solve::init::ChordalInit;
use crate::solve::{Session, SolveError};
use serde::Serialize;

/// Which start an end came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Start {
    /// The annealing on the job's initial guess.
    Annealed,
    /// A plain Cauchy kernel from the caller's own poses.
    Kernel,
    /// Graduated non-convexity's truncated least squares at `J`'s price
    /// per candidate left out, from the caller's own poses.
    Truncated,
    /// EM's decisions from the map of the best end so far solved with the
    /// candidates it rejects that the information as stated calls
    /// consistent, where its model calls such a population wrong.
    Readmitted,
    /// EM's decisions without the agreement layer, then with every layer,
    /// from the map of the best end so far where that leaves the decisions
    /// open.
    WithoutAgreement,
    /// EM's decisions from the end kept, with the loops it named
    /// `outlying` ([`super::doubt`]) taken out.
    WithoutOutlying,
    /// EM's decisions from the end kept, with one of the clusters it named
    /// `doubtful` ([`super::doubt`]) taken out.
    WithoutDoubtful,
    /// EM's decisions from the end kept, with its keystone
    /// ([`super::doubt::keystone`]) taken out.
    WithoutKeystone,
    /// The annealed start again, on the chordal relaxation, with the end
    /// kept's keystone taken out.
    AnnealedWithoutKeystone,
}

/// Where one start ended, as the report shows it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StartEnd {
    /// The start.
    pub start: Start,
    /// Candidates accepted at its end.
    pub accepted: usize,
    /// Its objective `J` (module doc); `None` for a start that did not
    /// settle.
    pub objective: Option<f64>,
    /// Whether its map passed the χ² test (`None`: no test).
    pub passed: Option<bool>,
    /// Whether the job kept it.
    pub chosen: bool,
    /// LM iterations the start took (the kernel start: at most as many as
    /// the annealed start).
    pub iterations: usize,
    /// Whether it reached an end: the kernel start's set of weight ≥ ½
    /// stood, and the start without the agreement layer settled, within
    /// the annealed start's iterations (else it has no end to compare).
    /// The truncated start always reaches one: GNC's rounds bound it, and
    /// an end the budget cut short competes with none.
    pub settled: bool,
    /// Its fit at a price of 0 and of 1 per candidate left out, to rank
    /// it again on another scale ([`End::rank`]).
    #[serde(skip)]
    fit: Option<(f64, f64)>,
}

impl StartEnd {
    /// Its objective `J` at the scale `s2` with kernel width `c` (module
    /// doc), where it has an end.
    fn rank(&mut self, s2: f64, c: f64) {
        if let Some((fit, with_one)) = self.fit {
            self.objective = Some(fit + s2 * c * c * (with_one - fit));
        }
    }

    /// A start that reached no end.
    fn unsettled(start: Start) -> Self {
        Self {
            start,
            accepted: 0,
            objective: None,
            passed: None,
            chosen: false,
            iterations: 0,
            settled: false,
            fit: None,
        }
    }
}

/// Where a start ended: its map, weights and outcome, and how it ranks.
struct End<P> {
    poses: Vec<P>,
    weights: Vec<f64>,
    out: Outcome,
    summary: StartEnd,
    /// Its map's misfit scale ([`misfit_scale`]).
    scale: Option<f64>,
}

impl<P: Clone> End<P> {
    /// The end in the session's graph and `weights`, from `start`.
    fn take<const D: usize>(
        graph: &Graph<P, D>,
        weights: &[f64],
        job: &Job<'_, P, D>,
        (start, out): (Start, Outcome),
    ) -> Self
    where
        P: Pose<D>,
    {
        let (summary, _) = summary(graph, weights, job, start);
        Self::keep(graph, weights, job, (summary, out))
    }

    /// The end of `summary` in the session's graph and `weights`.
    fn keep<const D: usize>(
        graph: &Graph<P, D>,
        weights: &[f64],
        job: &Job<'_, P, D>,
        (summary, out): (StartEnd, Outcome),
    ) -> Self
    where
        P: Pose<D>,
    {
        let fit = (
            objective(graph, weights, job.candidates, 0.0),
            objective(graph, weights, job.candidates, 1.0),
        );
        Self {
            poses: graph.poses.clone(),
            weights: weights.to_vec(),
            out,
            summary: StartEnd {
                fit: Some(fit),
                ..summary
            },
            scale: misfit_scale(graph, weights),
        }
    }

    /// Its objective `J` at the scale `s2` with kernel width `c` (module
    /// doc).
    fn rank(&mut self, s2: f64, c: f64) {
        self.summary.rank(s2, c);
    }

    /// Puts this end's map and weights back in the session's graph and
    /// `weights`. An end solved before another start ran (`solved_before`)
    /// gets one more run from its map (an iteration or two), which makes
    /// the report's last run its own.
    fn restore<const D: usize>(
        &self,
        session: &mut Session<'_, P, D>,
        weights: &mut [f64],
        solved_before: bool,
    ) -> Result<(), SolveError>
    where
        P: Pose<D>,
    {
        session.graph.poses.copy_from_slice(&self.poses);
        weights.copy_from_slice(&self.weights);
        if solved_before && !session.exhausted() {
            session.converge(weights)?;
        }
        Ok(())
    }

    /// Whether its map fails the χ² test (or has none) or its decisions
    /// did not settle.
    fn leaves_open(&self) -> bool {
        self.summary.passed != Some(true) || self.out.unsettled
    }

    /// Whether this end is to be kept over `other` (module doc). Two ends
    /// of one accepted set are one end, their maps apart by the solver's
    /// tolerance: neither is better.
    fn better_than(&self, other: &Self) -> bool {
        if held(&self.weights) == held(&other.weights) {
            return false;
        }
        match (self.summary.passed, other.summary.passed) {
            (Some(true), Some(false)) => true,
            (Some(false), Some(true)) => false,
            _ => {
                self.summary.objective.unwrap_or(f64::INFINITY)
                    < other.summary.objective.unwrap_or(f64::INFINITY)
            }
        }
    }
}

/// Where the session's map and `weights` ended from `start`, with its χ²
/// verdict (the iterations still to be set), and the test's α (`None`: no
/// test).
fn summary<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    weights: &[f64],
    job: &Job<'_, P, D>,
    start: Start,
) -> (StartEnd, Option<f64>) {
    let test = (job.test)(graph, weights);
    let end = StartEnd {
        start,
        accepted: (job.candidates.iter())
            .filter(|c| weights[c.edge] >= 0.5)
            .count(),
        objective: None,
        passed: test.as_ref().map(|t| t.passed),
        chosen: false,
        iterations: 0,
        settled: true,
        fit: None,
    };
    (end, test.map(|t| t.alpha))
}

/// EM: the annealed start, then — when its map fails the χ² test, its
/// decisions did not settle or its model disagrees with the information as
/// stated (module doc), the caller gave poses and budget is left —
/// the kernel start and the truncated start from the caller's poses, and
/// the start with the loops left out readmitted and the one without the
/// agreement layer from the best end's map; the best end (module doc) left
/// in the session's graph and `weights`.
pub fn em<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
) -> Result<Outcome, SolveError> {
    let before = session.iterations();
    let mut restarts = Restarts::default();
    let annealed = annealed_start(session, weights, (job, &mut restarts))?;
    let share = session.iterations() - before;
    let Some(given) = job
        .given
        .filter(|_| job.layers.starts && !annealed.cut_short && !session.exhausted())
    else {
        return Ok(annealed);
    };
    let (mut ended, alpha) = summary(session.graph, weights, job, Start::Annealed);
    ended.iterations = share;
    if ended.passed == Some(true) && settled(job, weights, &annealed, alpha) {
        // A map that passes the χ² test, at decisions that settled, is not
        // second-guessed (module doc).
        ended.chosen = true;
        let mut out = annealed;
        out.starts = vec![ended];
        return Ok(out);
    }
    let first = End::keep(session.graph, weights, job, (ended, annealed));
    // Whether the ends so far leave the decisions open (the truncated
    // start's question).
    let mut open = first.leaves_open();
    let truncated = (RobustMethod::Gnc, truncation_width(first.scale, job.c));
    let mut ends = vec![first];
    let mut unsettled = Vec::new();
    // The kernel start gets the annealed start's share of iterations; the
    // truncated start runs GNC's schedule, whose rounds bound it.
    for (start, kernel, cap) in [
        (Start::Kernel, peers_cauchy::<D>(), share),
        (Start::Truncated, truncated, usize::MAX),
    ] {
        if session.exhausted() || start == Start::Truncated && !open {
            break;
        }
        session.graph.poses.copy_from_slice(given);
        let before = session.iterations();
        let out = kernel_start(session, weights, (job, &mut restarts), (cap, kernel))?;
        let used = session.iterations() - before;
        match reached(session.graph, weights, job, (start, out, used)) {
            Ok(end) => {
                open &= end.leaves_open();
                ends.push(end);
            }
            Err(none) => {
                // A kernel start that reached no end answered nothing: where
                // the annealed end's model calls wrong a population the
                // stated information calls consistent (true loops it may
                // have left out: a map fits what it keeps), that stays open.
                open |= (ends[0].out.model.as_ref()).is_some_and(|m| m.wrong_within_kernel());
                unsettled.push(none);
            }
        }
    }
    readmitted(session, weights, job, &mut ends)?;
    let apart = without_agreement(session, weights, (job, share), &mut ends)?;
    unsettled.extend(apart);
    keep_best(session, weights, job, ends, unsettled)
}

/// The best of `ends` (the annealed end first; an end cut short by the
/// budget competes with none) back in the session's graph and `weights`,
/// with the work of all and every start's summary, `unsettled` those of
/// the starts that left no end.
fn keep_best<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
    mut ends: Vec<End<P>>,
    unsettled: Vec<StartEnd>,
) -> Result<Outcome, SolveError> {
    let best = best_of(&mut ends, job.c);
    // The start run last: the last end's, unless a later one left none.
    let last = (unsettled.iter().map(|u| u.start))
        .chain(ends.iter().map(|e| e.summary.start))
        .max();
    let mut kept = ends.remove(best);
    kept.restore(session, weights, last != Some(kept.summary.start))?;
    kept.summary.chosen = true;
    let mut out = kept.out;
    let mut starts = vec![kept.summary];
    for other in ends {
        add_work(&mut out, &other.out);
        starts.push(other.summary);
    }
    starts.extend(unsettled);
    starts.sort_by_key(|e| e.start);
    out.starts = starts;
    Ok(out)
}

/// The index of the best of `ends` (module doc), each ranked on their
/// least misfit scale with kernel width `c`: the first end unless a later
/// one not cut short by the budget is better.
fn best_of<P: Clone>(ends: &mut [End<P>], c: f64) -> usize {
    // `misfit_scale` is finite and positive where it is `Some`.
    let s2 = (ends.iter().filter_map(|e| e.scale))
        .reduce(f64::min)
        .unwrap_or(1.0);
    for end in ends.iter_mut() {
        end.rank(s2, c);
    }
    let mut best = 0;
    for k in 1..ends.len() {
        if !ends[k].out.cut_short && ends[k].better_than(&ends[best]) {
            best = k;
        }
    }
    best
}

/// The end kept (`kept`, in the session's graph and `weights`) tried
/// without the loops its outlying check named: EM's decisions again from
/// the map solved without them ([`without`]), whose end competes with the
/// kept one as the starts' ends do (module doc), again while the end that
/// wins names some. A loop the check names lies beyond the true loops' own
/// scale and moves the map, as an alias does that bent the map into
/// another basin (docs/method.md §7); without it the map can fall back,
/// and the aliases that fitted the bent map no longer fit. Leaving out a
/// true loop within the true loops' reach lowers the fit by less than
/// `J`'s price for it, and the end with it stays. Where the check names
/// none, the same without each cluster named doubtful and without the
/// end's keystone, once per end kept, and, where nothing questions the end
/// kept, the annealed start again without the keystone
/// ([`trials_without`]); an end without a doubtful cluster that nothing
/// questions, and an end without the keystone that also accepts as many
/// candidates and is questioned by nothing, win where they rank first
/// (module doc). Returns the outcome of the end kept, its doubts found.
pub fn recheck<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
    mut kept: Outcome,
) -> Result<Outcome, SolveError> {
    let mut tried: Vec<Vec<bool>> = Vec::new();
    while let Some(trial) = to_recheck(job, &kept).filter(|_| !session.exhausted()) {
        let mut starts = std::mem::take(&mut kept.starts);
        let start = (starts.iter().find(|s| s.chosen)).map_or(Start::Annealed, |s| s.start);
        let (summary, _) = summary(session.graph, weights, job, start);
        let mut before = End::keep(session.graph, weights, job, (summary, kept));
        tried.push(held(&before.weights));
        let questioned = !unquestioned(&before);
        let mut trials = trials_without(session, weights, job, (&trial, questioned))?;
        let s2 = (before.scale.into_iter())
            .chain(trials.iter().filter_map(|t| t.scale))
            .reduce(f64::min)
            .unwrap_or(1.0);
        before.rank(s2, job.c);
        trials.iter_mut().for_each(|t| t.rank(s2, job.c));
        // Every end listed is ranked on the scale the ends are compared
        // by, the end kept at the objective it was compared by.
        starts.iter_mut().for_each(|s| s.rank(s2, job.c));
        match starts.iter_mut().find(|s| s.chosen) {
            Some(s) => {
                s.objective = before.summary.objective;
                s.fit = before.summary.fit;
            }
            None => starts.push(StartEnd {
                chosen: true,
                ..before.summary.clone()
            }),
        }
        // The end without a keystone answers whether it kept other loops
        // out: it must put back as many as it takes out, and nothing may
        // question it; the end without a doubtful cluster must resolve the
        // doubt: nothing may question it (module doc).
        let answers = |t: &End<P>| {
            !t.out.cut_short
                && !tried.contains(&held(&t.weights))
                && match t.summary.start {
                    Start::WithoutKeystone | Start::AnnealedWithoutKeystone => {
                        t.summary.accepted >= before.summary.accepted && unquestioned(t)
                    }
                    Start::WithoutDoubtful => unquestioned(t),
                    _ => true,
                }
        };
        let win = (0..trials.len())
            .filter(|&k| answers(&trials[k]) && trials[k].better_than(&before))
            .reduce(|a, b| {
                if trials[b].better_than(&trials[a]) {
                    b
                } else {
                    a
                }
            });
        tried.extend(trials.iter().map(|t| held(&t.weights)));
        let listed = starts.len();
        starts.extend(trials.iter().map(|t| t.summary.clone()));
        let ran_last = trials.len() - 1;
        let Some(w) = win else {
            before.restore(session, weights, true)?;
            kept = before.out;
            trials.iter().for_each(|t| add_work(&mut kept, &t.out));
            kept.starts = starts;
            break;
        };
        starts.iter_mut().for_each(|s| s.chosen = false);
        starts[listed + w].chosen = true;
        let after = trials.remove(w);
        after.restore(session, weights, w != ran_last)?;
        kept = after.out;
        add_work(&mut kept, &before.out);
        trials.iter().for_each(|t| add_work(&mut kept, &t.out));
        kept.starts = starts;
        super::doubts(session, weights, job, &mut kept);
    }
    Ok(kept)
}

/// The ends that meet the end kept in [`recheck`]: EM's decisions from its
/// map without each set of candidates the `trial` names ([`without`]);
/// where one is its keystone and nothing questions the end kept (not
/// `questioned`), also the annealed start again without it
/// ([`annealed_without`]). The ends without a keystone or a doubtful
/// cluster get their own checks at their maps (they win only where nothing
/// questions them). An end its checks question warns as it is: the
/// annealed start without its keystone could end at a lower `J` with more
/// aliases than it held, questioned by nothing (MIT with groups of 5 at
/// revisited places, seed 40, calibrated: five aliases named doubtful,
/// exit 5, would become ten, exit 0).
fn trials_without<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
    (trial, questioned): (&[(Start, Vec<usize>)], bool),
) -> Result<Vec<End<P>>, SolveError> {
    let mut trials = Vec::with_capacity(trial.len() + 1);
    for (which, named) in trial {
        if !trials.is_empty() && session.exhausted() {
            break;
        }
        let mut end = without(session, weights, job, (*which, named))?;
        if *which == Start::WithoutOutlying {
            trials.push(end);
            continue;
        }
        super::doubts(session, weights, job, &mut end.out);
        trials.push(end);
        if *which == Start::WithoutKeystone && !questioned && !session.exhausted() {
            let mut fresh = annealed_without(session, weights, job, named)?;
            super::doubts(session, weights, job, &mut fresh.out);
            trials.push(fresh);
        }
    }
    Ok(trials)
}

/// Whether an end passes its χ² test with decisions that settled, and its
/// checks name no doubtful cluster, no loop held back and no outlying one
/// ([`super::doubt`]): a map nothing questions.
fn unquestioned<P: Clone>(end: &End<P>) -> bool {
    let out = &end.out;
    !end.leaves_open()
        && !out.reasons.contains(&Reason::Unsettled)
        && out.doubtful.is_empty()
        && out.held_back.is_empty()
        && out.outlying.is_empty()
}

/// What the end kept is tried without, if anything, each set of
/// candidates as the start it makes: the loops its outlying check named,
/// else those it flagged below the warning
/// ([`super::doubt::RECHECK_MOVE`]), else each cluster it named doubtful
/// and its keystone (module doc), each where its layer is on.
fn to_recheck<P: Pose<D>, const D: usize>(
    job: &Job<'_, P, D>,
    kept: &Outcome,
) -> Option<Vec<(Start, Vec<usize>)>> {
    if job.layers.recheck && !kept.outlying.is_empty() {
        let named = kept.outlying.iter().flat_map(|o| o.loops.clone()).collect();
        return Some(vec![(Start::WithoutOutlying, named)]);
    }
    // Flagged loops too close to the map's error to name: tried without,
    // the loops already rejected as outlying held out with them (else the
    // trial would weigh again what an earlier one took out).
    if job.layers.recheck && !kept.below_warning.is_empty() {
        let rejected = (0..kept.reasons.len()).filter(|&k| kept.reasons[k] == Reason::Outlying);
        let named = kept.below_warning.iter().flatten().copied().chain(rejected);
        return Some(vec![(Start::WithoutOutlying, named.collect())]);
    }
    let keystone = kept.keystone.clone().filter(|_| job.layers.keystone);
    // A doubtful cluster that is also the keystone is tried as the
    // keystone, by the stricter rule.
    let mut trial: Vec<_> = (kept.doubtful.iter())
        .filter(|d| job.layers.recheck && keystone.as_ref() != Some(&d.loops))
        .map(|d| (Start::WithoutDoubtful, d.loops.clone()))
        .collect();
    trial.extend(keystone.map(|k| (Start::WithoutKeystone, k)));
    (!trial.is_empty()).then_some(trial)
}

/// The end of EM's decisions from the map in the session's graph solved
/// without the candidates `named`, which they hold out as the χ² search
/// holds out what it takes (a prior of 0), as the start `which`; those
/// named by the outlying check that end rejected are `outlying`.
fn without<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
    (which, named): (Start, &[usize]),
) -> Result<End<P>, SolveError> {
    let iterations = session.iterations();
    let judged = held_out(job.candidates, weights, named);
    session.converge(weights)?;
    let holding = Job {
        candidates: &judged,
        ..*job
    };
    let mut out = Outcome::new(job.candidates.len());
    let restarts = &mut Restarts::default();
    let how = (job.chordal, Swing::Continue);
    settle(session, weights, (&holding, restarts), how, &mut out)?;
    for &k in named.iter().filter(|_| which == Start::WithoutOutlying) {
        if weights[job.candidates[k].edge] < 0.5 {
            out.reasons[k] = Reason::Outlying;
        }
    }
    let mut end = End::take(session.graph, weights, job, (which, out));
    end.summary.iterations = session.iterations() - iterations;
    Ok(end)
}

/// `candidates` with those `named` held out, as the χ² search holds out
/// what it takes: each at weight 0 in `weights` and a prior of 0.
fn held_out(candidates: &[Candidate], weights: &mut [f64], named: &[usize]) -> Vec<Candidate> {
    let mut judged = candidates.to_vec();
    for &k in named {
        weights[candidates[k].edge] = 0.0;
        judged[k].count_posterior = Some(0.0);
    }
    judged
}

/// EM's annealed start again, on the chordal relaxation, with the
/// candidates `named` held out as [`without`] holds them out. The
/// relaxation reads no pose, so an update's end meets the same trial as
/// the batch job's.
fn annealed_without<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
    named: &[usize],
) -> Result<End<P>, SolveError> {
    let iterations = session.iterations();
    // The annealed start's first weights: every candidate the gate kept.
    for c in job.candidates {
        weights[c.edge] = if c.kept { 1.0 } else { 0.0 };
    }
    let judged = held_out(job.candidates, weights, named);
    let holding = Job {
        candidates: &judged,
        chordal: true,
        ..*job
    };
    let out = annealed_start(session, weights, (&holding, &mut Restarts::default()))?;
    let mut end = End::take(
        session.graph,
        weights,
        job,
        (Start::AnnealedWithoutKeystone, out),
    );
    end.summary.iterations = session.iterations() - iterations;
    Ok(end)
}

/// The start without the agreement layer, where the best of `ends` leaves
/// the decisions open (its map fails the χ² test, or its decisions did not
/// settle): EM's decisions from that end's map with every candidate judged
/// against the map without its cluster only, then with every layer from
/// where they end, within `share` iterations (the annealed start's). A
/// cluster's members that agree with each other speak against one that
/// does not ([`super::innovation`]); where a group of aliases outnumbers
/// the true loop beside it in the map an end leans to, that is the true
/// loop, and the decisions settle without it (module doc). Its end joins
/// `ends`; returns the start's summary where the share ran out first.
fn without_agreement<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    (job, share): (&Job<'_, P, D>, usize),
    ends: &mut Vec<End<P>>,
) -> Result<Option<StartEnd>, SolveError> {
    let best = best_of(ends, job.c);
    if !job.layers.agreement || session.exhausted() || !ends[best].leaves_open() {
        return Ok(None);
    }
    ends[best].restore(session, weights, false)?;
    let layers = super::Layers {
        agreement: false,
        ..*job.layers
    };
    let apart = Job {
        layers: &layers,
        ..*job
    };
    let before = session.iterations();
    let (out, capped) = session.capped(share, |session| {
        let first = decided_from_map(session, weights, &apart, job.chordal)?;
        let mut out = if first.cut_short {
            Outcome::new(job.candidates.len())
        } else {
            decided_from_map(session, weights, job, job.chordal)?
        };
        add_work(&mut out, &first);
        Ok::<_, SolveError>(out)
    });
    let (out, used) = (out?, session.iterations() - before);
    let out = (!out.cut_short || !capped || session.exhausted()).then_some(out);
    match reached(
        session.graph,
        weights,
        job,
        (Start::WithoutAgreement, out, used),
    ) {
        Ok(end) => {
            ends.push(end);
            Ok(None)
        }
        Err(none) => Ok(Some(none)),
    }
}

/// The start with the loops the best of `ends` left out readmitted, where
/// its model calls wrong a population that the information as stated
/// calls consistent and no other end holds its set: every candidate the
/// gate kept that the end rejects at an innovation within EM's kernel
/// ([`super::model::LoopModel::within_kernel`]) is put back, the map is
/// solved from that end's, and EM decides from there (module doc). Its
/// end joins `ends`. EM decides from the map itself, without chordal
/// relaxations of the sets it tries: a relaxation rebuilds a map from its
/// set alone, and the one the readmitted loops made would be lost.
fn readmitted<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
    ends: &mut Vec<End<P>>,
) -> Result<(), SolveError> {
    let best = best_of(ends, job.c);
    let end = &ends[best];
    let Some(model) = (end.out.model.as_ref()).filter(|m| m.wrong_within_kernel()) else {
        return Ok(());
    };
    // Another start that reached the same set answered the question.
    let set = held(&end.weights);
    let confirmed = (ends.iter().enumerate()).any(|(k, e)| k != best && held(&e.weights) == set);
    if confirmed {
        return Ok(());
    }
    let within = |v: &Option<f64>| v.is_some_and(|v| v > 0.0 && model.within_kernel(v.ln()));
    let left_out: Vec<usize> = (job.candidates.iter().zip(&end.out.innovations))
        .filter(|(c, v)| c.kept && end.weights[c.edge] < 0.5 && within(v))
        .map(|(c, _)| c.edge)
        .collect();
    if left_out.is_empty() || session.exhausted() {
        return Ok(());
    }
    end.restore(session, weights, false)?;
    for &edge in &left_out {
        weights[edge] = 1.0;
    }
    let before = session.iterations();
    session.converge(weights)?;
    let out = decided_from_map(session, weights, job, false)?;
    let mut end = End::take(session.graph, weights, job, (Start::Readmitted, out));
    end.summary.iterations = session.iterations() - before;
    ends.push(end);
    Ok(())
}

/// EM's decisions with the layers of `job` from the map in the session's
/// graph and `weights`, each set they try solved from its chordal
/// relaxation where `relax` (else from the map before it).
fn decided_from_map<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    job: &Job<'_, P, D>,
    relax: bool,
) -> Result<Outcome, SolveError> {
    let mut out = Outcome::new(job.candidates.len());
    let how = (relax, Swing::Continue);
    settle(
        session,
        weights,
        (job, &mut Restarts::default()),
        how,
        &mut out,
    )?;
    Ok(out)
}

/// Where `start` ended after `used` iterations, in `graph` and `weights`
/// (`out`; `None` where it reached no end): an end to rank, or the summary
/// of a start that reached none.
fn reached<P: Pose<D>, const D: usize>(
    graph: &Graph<P, D>,
    weights: &[f64],
    job: &Job<'_, P, D>,
    (start, out, used): (Start, Option<Outcome>, usize),
) -> Result<End<P>, StartEnd> {
    let Some(out) = out else {
        return Err(StartEnd {
            iterations: used,
            ..StartEnd::unsettled(start)
        });
    };
    let mut end = End::take(graph, weights, job, (start, out));
    end.summary.iterations = used;
    Ok(end)
}

/// Which edges the `weights` hold (weight ≥ ½).
fn held(weights: &[f64]) -> Vec<bool> {
    weights.iter().map(|&w| w >= 0.5).collect()
}

/// Adds the work of an end not kept (`other`) to the outcome kept.
fn add_work(out: &mut Outcome, other: &Outcome) {
    out.rounds += other.rounds;
    out.relaxations += other.relaxations;
    out.decisions += other.decisions;
    out.relaxed_starts += other.relaxed_starts;
    out.cut_short |= other.cut_short;
}

/// Whether the decisions that ended at `out` (the candidates `weights`
/// accepts) settled, with no population called wrong that the file calls
/// consistent and no loop accepted that it calls an outlier at the χ²
/// test's `alpha` (module doc).
fn settled<P: Pose<D>, const D: usize>(
    job: &Job<'_, P, D>,
    weights: &[f64],
    out: &Outcome,
    alpha: Option<f64>,
) -> bool {
    !out.unsettled
        && !(out.model.as_ref()).is_some_and(|m| {
            m.wrong_within_kernel()
                || alpha.is_some_and(|a| {
                    m.accepts_beyond_stated(&accepted_innovations(job, weights, out), a)
                })
        })
}

/// The squared innovations of the candidates `weights` accepts, as `out`
/// judged them.
fn accepted_innovations<P: Pose<D>, const D: usize>(
    job: &Job<'_, P, D>,
    weights: &[f64],
    out: &Outcome,
) -> Vec<f64> {
    (job.candidates.iter().zip(&out.innovations))
        .filter(|(c, _)| weights[c.edge] >= 0.5)
        .filter_map(|(_, nu2)| nu2.filter(|&v| v > 0.0))
        .collect()
}

/// The Cauchy kernel at the peers' width, `√χ²_D(0.95)`.
fn peers_cauchy<const D: usize>() -> (RobustMethod, f64) {
    let method = RobustMethod::Cauchy;
    (method, super::default_c(method, D))
}

/// The width of the truncated start's truncation: a candidate whose
/// `eᵀΩe` exceeds `s²·c²` costs `J` more in the map than out of it
/// (module doc), `c` EM's kernel width and `s²` the misfit scale of the
/// annealed end's map where that shows the file's information looser than
/// its noise, else the file's own (1). Wrong loops a map holds only raise
/// its misfit (hundreds of times the file's scale on a young grid with
/// aliases in groups), and a truncation that wide holds them all.
fn truncation_width(scale: Option<f64>, c: f64) -> f64 {
    scale.unwrap_or(1.0).min(1.0).sqrt() * c
}

/// A start from the map in the session's graph: `kernel` (a method and
/// its width) over the kept candidates within `cap` LM iterations, then
/// EM's decisions from the candidates it holds. `None` where the kernel
/// did not settle within `cap`.
fn kernel_start<P: ChordalInit<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    (job, restarts): (&Job<'_, P, D>, &mut Restarts<P>),
    (cap, kernel): (usize, (RobustMethod, f64)),
) -> Result<Option<Outcome>, SolveError> {
    let mut out = Outcome::new(job.candidates.len());
    let kept: Vec<usize> = (job.candidates.iter())
        .filter(|c| c.kept)
        .map(|c: &Candidate| c.edge)
        .collect();
    for c in job.candidates {
        weights[c.edge] = if c.kept { 1.0 } else { 0.0 };
    }
    // GNC's weights are fractions until its truncation hardens: only its
    // settled weights say which candidates it holds.
    let until = match kernel.0 {
        RobustMethod::Gnc => kernels::Until::Settled,
        _ => kernels::Until::HeldSetRepeats,
    };
    let (reweighted, capped) =
        session.capped(cap, |s| kernels::reweight(s, weights, &kept, kernel, until));
    (out.rounds, out.cut_short) = reweighted?;
    if out.cut_short && capped && !session.exhausted() {
        // Its share of iterations spent before the weights settled (not
        // the job's budget).
        return Ok(None);
    }
    if out.cut_short {
        return Ok(Some(out));
    }
    settle(
        session,
        weights,
        (job, restarts),
        (job.chordal, Swing::Continue),
        &mut out,
    )?;
    Ok(Some(out))
}
