//! Acting on a failed χ² test. The decisions leave the map of the loops
//! the model judged consistent; when that map still fails the χ² test of
//! the file's information, either the noise of the file is larger than its
//! information says (every loop a little off, none more than the others)
//! or some accepted loops are wrong in a way their innovations did not
//! show. For a cluster of accepted loops, removing it lowers `D²` by its
//! joint statistic `e_Aᵀ·S⁻¹·e_A` ([`super::innovation`]), which for true
//! loops under the file's information is χ²(m·D), `m` loops of dimension
//! `D`. A cluster *explains* the failure when the map without it would
//! pass and its drop stands out as an outlier on its own: above the
//! critical value of χ²(m·D) at `α/K`, the χ² test's level shared among
//! the `K` clusters tested (Baarda's data snooping, with Bonferroni's
//! correction for testing them all). Without the second condition a true
//! loop explains a map that fails by chance, as one in `1/α` correct maps
//! does: in a simulated 10⁴-pose sphere without wrong loops, the map
//! failed at p = 0.04 and removing its one loop with a drop of 22.6 (on 6
//! dimensions, one of 900 clusters: p = 0.001 alone, 0.9 among them) made
//! it pass. The search takes the cluster that explains the failure with
//! the largest drop — or only its member that explains it alone, if one
//! does ([`alone`]) — out, solves again (until LM crawls, as for a
//! decision: [`REMOVAL_CRAWL`]; to the job's tolerance once the map
//! passes), and repeats while the test fails
//! and a cluster explains it, and, once it passes, while a cluster stands
//! out that did not before: loops consistent with one taken out, which
//! only its removal shows. When no cluster explains the failure alone but
//! a few that stand out would together ([`jointly`]: two aliases each
//! bending the map), they are taken out one at a time, most outstanding
//! first, and kept only if the map ends up passing ([`Before`]). What is
//! left of a failure is reported as the suspects.
//!
//! When no cluster explains it, the decisions may have started from a map
//! the wrong loops had already bent (most candidates wrong, their counts no
//! help): every innovation is then measured against a wrong map.
//! [`restart`] decides once more from the map of the trusted edges alone,
//! which no candidate shaped — with the scale learned, then with the true
//! loops' innovations centred where the file's information puts them
//! ([`super::Scale::File`], as the χ² test takes it: when wrong loops are
//! the majority, a learned scale fits them instead). Of every set the
//! decisions solved on the way — the first decisions' and the restarts' —
//! those whose maps passed the test are kept ([`Passing`]), and the job
//! ends at the one of least truncated least squares `J`
//! ([`Passing::best`]) if that is lower than the failing end's own `J`: a
//! failed test is resolved when a set considered resolves it, and among
//! those by how much each leaves out for its fit, since a map of a few
//! loops passes with ease; but a correct map fails by chance once in
//! `1/α`, and leaving true loops out to pass costs more than it saves. A
//! set that fails explains nothing: with information the file states too
//! tight (every loop a little off), fewer loops always fail by less, and
//! keeping the end that fails least would throw away true loops to shrink
//! `D²`.

use super::innovation::Evaluation;
use super::schedule::{self, Decided, Deciding, left_out, objective, relaxed_start};
use super::{Candidate, Layers};
use crate::geometry::Pose;
use crate::graph::Graph;
use crate::solve::init::ChordalInit;
use crate::solve::{Crawl, Session, SolveError};
use crate::stats::{Chi2Test, chi2_critical};
use serde::Serialize;
use std::time::Instant;

/// Most clusters removed: each removal is a solve and an evaluation, and a
/// failure that needs more is not explained by a few wrong loops.
pub const MAX_REMOVALS: usize = 8;

/// Suspects reported when the test still fails.
pub const SUSPECTS: usize = 10;

/// A cluster of accepted loops and what removing it would do.
#[derive(Clone, Debug, Serialize)]
pub struct Suspect {
    /// The candidates of the cluster the map was solved with (indices
    /// among the loop candidates).
    pub loops: Vec<usize>,
    /// By how much `D²` drops without them.
    pub d2_drop: f64,
    /// Whether they explain the failure: the map without them passes the
    /// test (or would, without the clusters removed after them as well),
    /// and their drop stands out among the clusters tested.
    pub explains: bool,
}

/// What the search did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Search {
    /// Whether the decisions were made again from the trusted edges' map,
    /// and that end was kept.
    pub restarted: bool,
    /// The clusters removed, in order.
    pub removed: Vec<Suspect>,
    /// The accepted clusters with the largest drops at the end, when the
    /// test still fails.
    pub suspects: Vec<Suspect>,
}

/// The test of the map in the session's graph with `weights`.
pub type Test<'t, P, const D: usize> = dyn Fn(&Graph<P, D>, &[f64]) -> Option<Chi2Test> + 't;

/// The sets the decisions solved whose maps passed the χ² test, from
/// every start of the decisions: where a failed test that no cluster
/// explains ends (module doc, [`Passing::best`]).
#[derive(Clone, Default)]
pub struct Passing {
    sets: Vec<PassingSet>,
}

/// A set whose map passed, and what ranks it.
#[derive(Clone)]
struct PassingSet {
    /// One flag per candidate.
    accepted: Vec<bool>,
    /// `Σ eᵀΩe` over the edges its map was solved with.
    fit: f64,
    /// The candidates it leaves out.
    left_out: usize,
    /// Its test's residual degrees of freedom and `D²/K`.
    dof: i64,
    scale: f64,
}

impl Passing {
    /// Records the set `accepted` of the `candidates` if its map (in
    /// `graph`, solved with `weights`) passes `test`; of a set solved
    /// twice, the better fitting map counts.
    pub fn record<P: Pose<D>, const D: usize>(
        &mut self,
        (graph, weights): (&Graph<P, D>, &[f64]),
        candidates: &[Candidate],
        accepted: &[bool],
        test: &Test<'_, P, D>,
    ) {
        let Some(t) = test(graph, weights).filter(|t| t.passed && t.dof_residual > 0) else {
            return;
        };
        let set = PassingSet {
            accepted: accepted.to_vec(),
            fit: objective(graph, weights, candidates, 0.0),
            left_out: left_out(weights, candidates),
            dof: t.dof_residual,
            scale: t.d2 / t.dof_residual as f64,
        };
        self.keep(set);
    }

    /// Keeps `set`: of a set solved twice, the better fitting map counts.
    fn keep(&mut self, set: PassingSet) {
        match self.sets.iter_mut().find(|s| s.accepted == set.accepted) {
            Some(s) if set.fit < s.fit => *s = set,
            Some(_) => {}
            None => self.sets.push(set),
        }
    }

    /// Keeps every set of `other`, in its order, as [`Passing::record`]
    /// would have.
    pub fn merge(&mut self, other: &Passing) {
        for set in &other.sets {
            self.keep(set.clone());
        }
    }

    /// What [`super::schedule::decide`] is to show each set it solves to:
    /// [`Passing::record`] of the `candidates` under `test`.
    pub fn recording<'r, P: Pose<D>, const D: usize>(
        &'r mut self,
        candidates: &'r [Candidate],
        test: &'r Test<'_, P, D>,
    ) -> impl FnMut(&Graph<P, D>, &[f64], &[bool]) + 'r {
        move |g, w, set| self.record((g, w), candidates, set, test)
    }

    /// The passing set of least truncated least squares `J` (the objective
    /// EM's starts are ranked by, [`super::starts`]) with kernel width `c`:
    /// `Σ eᵀΩe + s²·c²` per candidate left out, `s²` the `D²/K` of the
    /// passing map with the most residual degrees of freedom (the closest
    /// estimate of the file's information scale among maps consistent with
    /// it). Every map here passes: what tells them apart is how much each
    /// leaves out, and a map of a few loops passes with ease (the restart
    /// from the trusted edges' map can end at one: sphere2500 with 300
    /// aliases placed anywhere, docs/method.md §7). Returns the set, its
    /// `J`, and the price `s²·c²` of a candidate left out, by which another
    /// map's `J` compares with it.
    pub fn best(&self, c: f64) -> Option<(&[bool], f64, f64)> {
        let price = self.sets.iter().max_by_key(|s| s.dof)?.scale * c * c;
        let j = |s: &PassingSet| s.fit + price * s.left_out as f64;
        let best = self.sets.iter().min_by(|a, b| j(a).total_cmp(&j(b)))?;
        Some((&best.accepted, j(best), price))
    }
}

/// The search of the module doc, from the decisions `decided`; updates
/// them (and `weights`, and the map) for every cluster it removes. `None`
/// when the budget cut the decisions short or the layer is off.
pub fn explain<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    candidates: &[Candidate],
    decided: &mut Decided,
    layers: &Layers,
    test: &Test<'_, P, D>,
) -> Result<Option<Search>, SolveError> {
    if decided.cut_short || !layers.search {
        return Ok(None);
    }
    let mut search = Search::default();
    let edges: Vec<usize> = candidates.iter().map(|c| c.edge).collect();
    // The loops of every cluster that stood out at an earlier ranking.
    let mut stood_out = vec![false; candidates.len()];
    // The state before removals that explain the failure only together.
    let mut before: Option<Before<P>> = None;
    // Whether the map was last solved only until it crawled.
    let mut crawled = false;
    loop {
        let Some(t) = test(session.graph, weights) else {
            return finished(session, weights, crawled, search);
        };
        if t.passed && crawled {
            // A map that passes where LM crawled passes at its optimum too:
            // the test and the ranking are taken there.
            crawled = false;
            session.converge(weights)?;
            if session.exhausted() {
                return Ok(Some(search));
            }
            judge_again(session, weights, decided, &edges)?;
            continue;
        }
        if t.passed && search.removed.is_empty() {
            return Ok(Some(search));
        }
        if t.passed {
            before = None;
        }
        let ranked = rank(decided, &t, D);
        let tested = ranked.len();
        let left = MAX_REMOVALS.saturating_sub(search.removed.len());
        let (found, together) = choose(&ranked, &t, (D, left), &mut stood_out);
        let Some(cluster) = found.filter(|_| search.removed.len() < MAX_REMOVALS) else {
            if !t.passed {
                match before.take() {
                    Some(b) => {
                        // The map restored may be one solved until it crawled.
                        b.restore(session, weights, decided, &mut search);
                        crawled = true;
                    }
                    None => search.suspects = ranked.into_iter().take(SUSPECTS).collect(),
                }
            }
            return finished(session, weights, crawled, search);
        };
        if together && before.is_none() {
            before = Some(Before::take(session, weights, decided, (&search, &ranked)));
        }
        let member = alone(
            session,
            weights,
            (&edges, decided),
            (&t, tested),
            &cluster,
            together,
        )?;
        let cluster = member.unwrap_or(cluster);
        for &k in &cluster.loops {
            decided.accepted[k] = false;
            weights[edges[k]] = 0.0;
        }
        search.removed.push(cluster);
        crawled = !session.converge_unless_crawling(weights, REMOVAL_CRAWL)?;
        if session.exhausted() {
            if let Some(b) = before.take() {
                b.restore(session, weights, decided, &mut search);
            }
            return Ok(Some(search));
        }
        judge_again(session, weights, decided, &edges)?;
    }
}

/// When a removal's map is solved no further: once LM crawls, as a
/// decision's map is ([`schedule::DECIDING_TOLERANCE`],
/// [`schedule::DECIDING_LINEAR_TOLERANCE`]). A set the search is still
/// taking loops out of fails its test, and the map of a set that holds
/// wrong loops crawls: on sphere2500 with 300 aliases placed anywhere
/// (the places sweep's seed 6, information as published) seven of eight
/// removals' solves ran to the 100 iterations of the job's limit, the
/// objective falling by 0.1 % per iteration at 18 times the test's
/// critical value — 780 of the job's 2,002 iterations. The map that passes
/// is solved to the job's tolerance before it is tested again
/// ([`explain`]).
const REMOVAL_CRAWL: Crawl = Crawl {
    damped: schedule::DECIDING_TOLERANCE,
    linear: schedule::DECIDING_LINEAR_TOLERANCE,
};

/// The search's end: the map solved to the job's tolerance where the last
/// solve stopped at a crawl (`crawled`).
pub(super) fn finished<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
    crawled: bool,
    search: Search,
) -> Result<Option<Search>, SolveError> {
    if crawled && !session.exhausted() {
        session.converge(weights)?;
    }
    Ok(Some(search))
}

/// The innovations of every candidate at the map in the session (the set
/// in `weights`), into `decided`: as the decisions' evaluation takes them.
fn judge_again<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
    decided: &mut Decided,
    edges: &[usize],
) -> Result<(), SolveError> {
    let start = Instant::now();
    decided.innovations = decided.innovations_at_map(session, weights, edges)?.0;
    session.evaluated_since(start);
    Ok(())
}

/// The cluster of `ranked` to take out next, if any, and whether it
/// explains the failure of `t` only together with others ([`jointly`],
/// within the `left` removals left; edges of dimension `dimension`);
/// marks in `stood_out` the loops of every cluster that stands out now.
/// Once the test passes, a cluster is taken out only if it stands out now
/// and did not before: loops consistent with one taken out, which only its
/// removal shows (a true loop of a heavy tail stood out from the start, and
/// a map that passes keeps it).
fn choose(
    ranked: &[Suspect],
    t: &Chi2Test,
    (dimension, left): (usize, usize),
    stood_out: &mut [bool],
) -> (Option<Suspect>, bool) {
    let found = (ranked.iter())
        .filter(|s| !t.passed || !s.loops.iter().any(|&k| stood_out[k]))
        .find(|s| s.explains)
        .cloned();
    let outstanding: Vec<bool> = (ranked.iter())
        .map(|s| stands_out(t, s.d2_drop, (s.loops.len(), dimension), ranked.len()))
        .collect();
    // None alone: the first of the clusters that do together.
    let together = found.is_none() && !t.passed;
    let found = found.or_else(|| {
        together
            .then(|| jointly((ranked, &outstanding), t, (dimension, left)))
            .flatten()
    });
    for (s, _) in ranked.iter().zip(&outstanding).filter(|(_, o)| **o) {
        s.loops.iter().for_each(|&k| stood_out[k] = true);
    }
    (found, together)
}

/// The member of the explaining cluster `cluster` that explains the
/// failure of `t` alone, with the largest drop, if any: one wrong loop
/// among the true loops of a place (an alias a few poses off joins their
/// cluster) is taken out without them. Each member is tested as a cluster
/// of one against the map with the rest of the cluster; the level is
/// shared among the `tested` clusters and these members. With `together`
/// (the cluster explains the failure only with others, [`jointly`]) a
/// member need only stand out.
fn alone<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &[f64],
    (edges, decided): (&[usize], &Decided),
    (t, tested): (&Chi2Test, usize),
    cluster: &Suspect,
    together: bool,
) -> Result<Option<Suspect>, SolveError> {
    if cluster.loops.len() < 2 {
        return Ok(None);
    }
    let start = Instant::now();
    let singles: Vec<Vec<usize>> = cluster.loops.iter().map(|&k| vec![k]).collect();
    let joint =
        Evaluation::for_clusters(session.optimizer, session.graph, weights, (edges, &singles))?
            .innovations(edges, &decided.accepted, &singles, true)
            .joint;
    session.evaluated_since(start);
    let tests = tested + singles.len();
    Ok((cluster.loops.iter().zip(joint))
        .filter_map(|(&k, drop)| {
            let drop = drop?;
            let enough = if together {
                stands_out(t, drop, (1, D), tests)
            } else {
                explains(t, drop, (1, D), tests)
            };
            enough.then_some(Suspect {
                loops: vec![k],
                d2_drop: drop,
                explains: true,
            })
        })
        .max_by(|a, b| a.d2_drop.total_cmp(&b.d2_drop)))
}

/// When no cluster explains the failure of `t` alone: the clusters of
/// `ranked` that stand out among them (`outstanding`), by how far (the Wilson–Hilferty
/// normal score of the drop on its degrees of freedom), and the first of
/// them if the map would pass without it and the next ones (the drops
/// added up). Taken out one at a time, each removal followed by a solve
/// and a ranking, they are kept only if the map ends up passing
/// ([`Before`]). `None` also when more than `left` clusters (the removals
/// left of [`MAX_REMOVALS`]) would be needed: each removal is a solve, and
/// a failure that needs more is not a few wrong loops'.
fn jointly(
    (ranked, outstanding): (&[Suspect], &[bool]),
    t: &Chi2Test,
    (dimension, left): (usize, usize),
) -> Option<Suspect> {
    let mut out: Vec<(f64, &Suspect)> = (ranked.iter().zip(outstanding))
        .filter(|(_, o)| **o)
        .map(|(s, _)| (normal_score(s.d2_drop, s.loops.len() * dimension), s))
        .collect();
    out.sort_by(|a, b| b.0.total_cmp(&a.0));
    let (mut drop, mut loops) = (0.0, 0);
    for (_, s) in out.iter().take(left) {
        drop += s.d2_drop;
        loops += s.loops.len();
        if passes_without(t, drop, loops, dimension) {
            let first = out.first()?.1;
            return Some(Suspect {
                explains: true,
                ..first.clone()
            });
        }
    }
    None
}

/// The Wilson–Hilferty normal score of `x` under χ²(`dof`): how many
/// standard deviations `(x/dof)^⅓` lies above its mean.
fn normal_score(x: f64, dof: usize) -> f64 {
    let k = dof.max(1) as f64;
    let v = 2.0 / (9.0 * k);
    ((x.max(0.0) / k).cbrt() - (1.0 - v)) / v.sqrt()
}

/// The map, its weights and decisions, and the search's findings before a
/// removal that explains the failure only together with later ones.
pub(super) struct Before<P> {
    poses: Vec<P>,
    weights: Vec<f64>,
    decided: Decided,
    removed: usize,
    suspects: Vec<Suspect>,
}

impl<P> Before<P> {
    pub(super) fn take<const D: usize>(
        session: &Session<'_, P, D>,
        weights: &[f64],
        decided: &Decided,
        (search, ranked): (&Search, &[Suspect]),
    ) -> Self
    where
        P: Pose<D>,
    {
        Self {
            poses: session.graph.poses.clone(),
            weights: weights.to_vec(),
            decided: decided.clone(),
            removed: search.removed.len(),
            suspects: ranked.iter().take(SUSPECTS).cloned().collect(),
        }
    }

    /// Undoes the removals since: the test still fails, with the suspects
    /// of the map before them.
    pub(super) fn restore<const D: usize>(
        self,
        session: &mut Session<'_, P, D>,
        weights: &mut [f64],
        decided: &mut Decided,
        search: &mut Search,
    ) where
        P: Pose<D>,
    {
        session.graph.poses = self.poses;
        weights.copy_from_slice(&self.weights);
        *decided = self.decided;
        search.removed.truncate(self.removed);
        search.suspects = self.suspects;
    }
}

/// The accepted clusters by the drop of `D²` without them, largest first,
/// each marked with whether it explains the failure of the test `t`.
fn rank(decided: &Decided, t: &Chi2Test, dimension: usize) -> Vec<Suspect> {
    let mut out: Vec<Suspect> = decided
        .clusters
        .iter()
        .zip(&decided.innovations.joint)
        .filter_map(|(members, joint)| {
            let loops: Vec<usize> = members
                .iter()
                .copied()
                .filter(|&k| decided.accepted[k])
                .collect();
            let drop = (*joint)?;
            (!loops.is_empty()).then_some(Suspect {
                explains: false,
                loops,
                d2_drop: drop,
            })
        })
        .collect();
    let tested = out.len();
    for s in &mut out {
        s.explains = explains(t, s.d2_drop, (s.loops.len(), dimension), tested);
    }
    out.sort_by(|a, b| b.d2_drop.total_cmp(&a.d2_drop));
    out
}

/// Whether `loops` accepted loops of dimension `dimension` whose removal
/// lowers `D²` by `drop` explain the failure of the test `t`, as one of
/// `tested` clusters: the test passes without them, and the drop exceeds
/// the critical value of χ²(loops·dimension) at `t.alpha / tested`.
fn explains(t: &Chi2Test, drop: f64, (loops, dimension): (usize, usize), tested: usize) -> bool {
    stands_out(t, drop, (loops, dimension), tested) && passes_without(t, drop, loops, dimension)
}

/// Whether a drop of `D²` by `drop` without `loops` accepted loops of
/// dimension `dimension` is an outlier as one of `tested` clusters: above
/// the critical value of χ²(loops·dimension) at `t.alpha / tested`.
pub(super) fn stands_out(
    t: &Chi2Test,
    drop: f64,
    (loops, dimension): (usize, usize),
    tested: usize,
) -> bool {
    let alpha = t.alpha / tested.max(1) as f64;
    chi2_critical((loops * dimension) as u64, alpha).is_ok_and(|c| drop > c)
}

/// Whether the test `t` would pass without `loops` accepted loops (edges of
/// dimension `dimension`) whose removal lowers `D²` by `drop`.
fn passes_without(t: &Chi2Test, drop: f64, loops: usize, dimension: usize) -> bool {
    let d2 = (t.d2 - drop).max(0.0);
    Chi2Test::new(
        d2,
        t.dof_constraints.saturating_sub(loops as u64),
        t.dof_residual - (loops * dimension) as i64,
        t.dof_convention,
        t.alpha,
    )
    .is_ok_and(|t| t.passed)
}

/// The verdict of the χ² test of the session's map with `weights`:
/// `Some(passed)`, or `None` when the map has no test (no redundancy, such
/// as a tree of trusted edges without loops).
pub fn verdict<P: Pose<D>, const D: usize>(
    session: &Session<'_, P, D>,
    weights: &[f64],
    test: &Test<'_, P, D>,
) -> Option<bool> {
    test(session.graph, weights).map(|t| t.passed)
}

/// The restart of the module doc: `decide` run again from no candidate
/// accepted; keeps its end (the map, `weights` and the decisions) if that
/// has a χ² test and passes it, and says whether it did. Either way
/// `decided` counts the decisions and relaxations of both.
pub fn restart<P: Pose<D>, const D: usize>(
    session: &mut Session<'_, P, D>,
    weights: &mut [f64],
    candidates: &[Candidate],
    decided: &mut Decided,
    test: &Test<'_, P, D>,
    decide: impl FnOnce(&mut Session<'_, P, D>, &mut [f64]) -> Result<Decided, SolveError>,
) -> Result<bool, SolveError> {
    let saved = (session.graph.poses.clone(), weights.to_vec());
    for c in candidates {
        weights[c.edge] = 0.0;
    }
    let mut again = decide(session, weights)?;
    // Only a passing map explains the failure; one without a test does not.
    // Whichever end is kept counts the work of both.
    if !again.cut_short && verdict(session, weights, test) == Some(true) {
        again.count_work_of(decided);
        *decided = again;
        return Ok(true);
    }
    decided.count_work_of(&again);
    session.graph.poses = saved.0;
    weights.copy_from_slice(&saved.1);
    Ok(false)
}

/// The restarts' decisions ([`restart`]) of one job, kept so that EM's
/// second start, when its test fails unexplained as well, does not make
/// them again. A restart decides from no candidate accepted, on the
/// trusted edges' chordal relaxation where that fits them better than the
/// map of the start it follows ([`super::schedule::relaxed_start`]): it
/// then begins at the same poses whichever start it follows, and its
/// decisions, map and passing sets are the same bits. A record is taken
/// only for a restart that begins exactly where the recorded one began —
/// the same scale, poses and weights — and that the budget did not cut
/// short (docs/method.md §7).
pub struct Restarts<P> {
    done: Vec<Restarted<P>>,
}

impl<P> Default for Restarts<P> {
    fn default() -> Self {
        Self { done: Vec::new() }
    }
}

/// One restart's beginning and end.
struct Restarted<P> {
    scale: super::Scale,
    /// The poses and weights it began from.
    from: (Vec<P>, Vec<f64>),
    /// The map and weights it ended at, its decisions, and the passing
    /// sets it solved.
    to: (Vec<P>, Vec<f64>),
    decided: Decided,
    passing: Passing,
}

impl<P> Restarts<P> {
    /// [`super::schedule::decide`] of `candidates` as `how` says, from the
    /// map in the session's graph and `weights` (the restart's: no
    /// candidate accepted), each passing set it solves recorded in
    /// `passing` — or, where a restart of this job began at the same
    /// scale, poses and weights, its record: its end, its passing sets and
    /// its decisions, with no work counted. A start on the chordal
    /// relaxation (`how.relax`) first takes the relaxation where it fits
    /// the trusted edges better than the map before.
    pub fn decide<const D: usize>(
        &mut self,
        session: &mut Session<'_, P, D>,
        weights: &mut [f64],
        (candidates, how): (&[Candidate], &Deciding<'_>),
        passing: &mut Passing,
        test: &Test<'_, P, D>,
    ) -> Result<Decided, SolveError>
    where
        P: ChordalInit<D>,
    {
        let relaxed = how.relax && how.layers.relaxation;
        if relaxed {
            relaxed_start(session, weights)?;
        }
        // Only a restart on the relaxation begins where another began.
        let from = relaxed.then(|| (session.graph.poses.clone(), weights.to_vec()));
        let known = (from.as_ref())
            .and_then(|from| (self.done.iter()).find(|r| r.scale == how.scale && r.from == *from));
        if let Some(r) = known {
            session.graph.poses.clone_from(&r.to.0);
            weights.copy_from_slice(&r.to.1);
            passing.merge(&r.passing);
            return Ok(r.decided.clone().without_work());
        }
        let mut solved = Passing::default();
        let decided = schedule::decide(
            session,
            weights,
            candidates,
            how,
            &mut solved.recording(candidates, test),
        )?;
        passing.merge(&solved);
        if let Some(from) = from.filter(|_| !decided.cut_short && !session.exhausted()) {
            self.done.push(Restarted {
                scale: how.scale,
                from,
                to: (session.graph.poses.clone(), weights.to_vec()),
                decided: decided.clone(),
                passing: solved,
            });
        }
        Ok(decided)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::DofConvention;

    /// The simulated 10⁴-pose sphere of the module doc: 5400 residual
    /// degrees of freedom, `D²` 5585 (p = 0.04), 900 clusters of 6-D loops.
    fn failed_by_chance() -> Chi2Test {
        let t = Chi2Test::new(5585.3, 10_899, 5400, DofConvention::Residual, 0.05).unwrap();
        assert!(!t.passed);
        t
    }

    fn passing(accepted: usize, of: usize, fit: f64, dof: i64) -> PassingSet {
        PassingSet {
            accepted: (0..of).map(|k| k < accepted).collect(),
            fit,
            left_out: of - accepted,
            dof,
            scale: fit / dof as f64,
        }
    }

    #[test]
    fn of_the_passing_sets_the_one_that_leaves_out_least_for_its_fit_ends_a_failure() {
        // sphere2500 with 300 aliases placed anywhere (docs/method.md §7):
        // the restart's end of one loop passes with D² 0.3 on 6 degrees of
        // freedom; the annealed set of 2,380 passes with 1,432 on 14,280.
        let c = 6.19;
        let mut sets = Passing::default();
        sets.sets.push(passing(1, 2750, 0.3, 6));
        sets.sets.push(passing(2380, 2750, 1432.0, 14_280));
        // J: 0.3 + 0.1·c²·2749 ≈ 10 560 against 1432 + 0.1·c²·370 ≈ 2854.
        let accepted = |p: &Passing| p.best(c).map(|b| b.0.iter().filter(|&&a| a).count());
        assert_eq!(accepted(&sets), Some(2380));
        // The price of a loop left out is on the scale of the map with the
        // most degrees of freedom (0.1), not the one loop's 0.05.
        let (_, j, price) = sets.best(c).unwrap();
        assert!((price - 1432.0 / 14_280.0 * c * c).abs() < 1e-9, "{price}");
        assert!((j - 1432.0 - 370.0 * price).abs() < 1e-6, "{j}");
        // A set that fits much worse for a few loops more loses.
        sets.sets.push(passing(2390, 2750, 9000.0, 14_340));
        assert_eq!(accepted(&sets), Some(2380));
        assert!(Passing::default().best(c).is_none());
    }

    #[test]
    fn a_drop_that_passes_the_map_explains_it_only_if_it_stands_out_among_the_clusters() {
        let t = failed_by_chance();
        // One loop of 900 lowering D² by 22.6: the map would pass, but
        // χ²₆ exceeds 22.6 once in a thousand, so among 900 clusters that
        // is no outlier.
        assert!(passes_without(&t, 22.6, 1, 6));
        assert!(!explains(&t, 22.6, (1, 6), 900));
        // The same drop as the only cluster tested stands out (χ²₆ at 0.05
        // is 12.6).
        assert!(explains(&t, 22.6, (1, 6), 1));
        // A wrong loop's drop stands out among any number of clusters.
        assert!(explains(&t, 200.0, (1, 6), 900));
        // A cluster of five loops is held to χ²₃₀: 60 stands out alone,
        // not among 900.
        assert!(explains(&t, 60.0, (5, 6), 1));
        assert!(!explains(&t, 60.0, (5, 6), 900));
        // A drop that leaves the map failing explains nothing, however it
        // stands out.
        assert!(!passes_without(&t, 5.0, 1, 6));
        assert!(!explains(&t, 5.0, (1, 6), 1));
    }

    /// Three clusters that stand out, none alone enough: `D²` 5735 exceeds
    /// the critical value (about 5571) by 164, so two drops of 80 leave the
    /// map failing and three make it pass.
    fn three_that_explain_together() -> (Chi2Test, Vec<Suspect>) {
        let t = Chi2Test::new(5585.3 + 150.0, 10_899, 5400, DofConvention::Residual, 0.05).unwrap();
        let ranked: Vec<Suspect> = (0..3)
            .map(|k| Suspect {
                loops: vec![k],
                d2_drop: 80.0,
                explains: false,
            })
            .collect();
        (t, ranked)
    }

    #[test]
    fn clusters_that_explain_a_failure_together_are_taken_out_only_within_the_removals_left() {
        let (t, ranked) = three_that_explain_together();
        let outstanding: Vec<bool> = (ranked.iter())
            .map(|s| stands_out(&t, s.d2_drop, (1, 6), ranked.len()))
            .collect();
        assert_eq!(outstanding, [true; 3]);
        assert!(!passes_without(&t, 160.0, 2, 6));
        assert!(passes_without(&t, 240.0, 3, 6));
        let first = jointly((&ranked, &outstanding), &t, (6, 3));
        assert_eq!(first.map(|s| s.loops), Some(vec![0]));
        // Two removals left cannot make the map pass: none is started.
        assert!(jointly((&ranked, &outstanding), &t, (6, 2)).is_none());
    }
}
