//! `update()` is `optimize()` after every call (issue 47): simulated maps
//! replayed as a mapping front end makes them — each pose, then the edges
//! whose later end it is — with an update every random 1–50 poses, now and
//! then a `fix()`, a `forget()`, other options or a cancelled update
//! between them; after **every** update that was not cancelled, the
//! update's solution is compared with `optimize()` of the same graph:
//!
//! * the same accepted set, the same χ² verdict, the same doubtful
//!   clusters, the same loops held back by their counts and the same
//!   outlying accepted loops;
//! * χ² within 10⁻⁶ of the batch's, relatively;
//! * every position within 10⁻⁶ of the map's size (the diagonal of the
//!   batch map's bounding box) and every rotation within 10⁻⁶ rad.
//!
//! 2D (grid) and 3D (sphere, torus) worlds, wrong loops placed at random,
//! in consistent groups and as aliases, deterministic seeds. Every
//! mismatch of every case is printed before the test fails.

use pgo::{Cancel, GraphPose, Options, PoseGraph, Solution};

mod common;
use common::{add_pose_and_edges, edges_due, poses_apart};
use pgo_sim::{
    AnySimulation, InlierModel, OutlierPolicy, Simulation, SimulationOptions, World, simulate,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// The relative χ² and the share of the map's size by which an update may
/// differ from a batch job (README, docs/method.md §7b).
const TOLERANCE: f64 = 1e-6;

/// One replay.
#[derive(Clone, Copy, Debug)]
struct Case {
    world: World,
    policy: OutlierPolicy,
    seed: u64,
    poses: usize,
    loops: usize,
    wrong: usize,
    /// `--robust` of every update (`None`: the default, EM).
    robust: Option<&'static str>,
}

/// How an update differed from the batch job.
#[derive(Debug)]
struct Mismatch {
    case: Case,
    poses: usize,
    solve: String,
    what: String,
}

fn accepted<P>(s: &Solution<P>) -> Vec<usize> {
    (s.loops().iter().filter(|d| d.accepted))
        .map(|d| d.index)
        .collect()
}

/// What differs between the update's solution `u` and the batch's `b`
/// (empty: nothing beyond the tolerances).
fn compare<P: GraphPose<D>, const D: usize>(u: &Solution<P>, b: &Solution<P>) -> Vec<String> {
    let mut out = Vec::new();
    let (au, ab) = (accepted(u), accepted(b));
    if au != ab {
        let only_u: Vec<_> = au.iter().filter(|k| !ab.contains(k)).collect();
        let only_b: Vec<_> = ab.iter().filter(|k| !au.contains(k)).collect();
        out.push(format!(
            "accepted {}/{} vs batch {}/{} (only update: {only_u:?}, only batch: {only_b:?})",
            au.len(),
            u.loops().len(),
            ab.len(),
            b.loops().len()
        ));
    }
    if u.passed() != b.passed() {
        out.push(format!(
            "verdict {:?} vs batch {:?}",
            u.passed(),
            b.passed()
        ));
    }
    // The loops of each doubtful cluster, of each cluster held back, and
    // of each outlying cluster.
    let named = |s: &Solution<P>| -> [Vec<Vec<usize>>; 3] {
        let robust = &s.report().robust;
        [
            robust.doubtful.iter().map(|d| d.loops.clone()).collect(),
            robust.held_back.iter().map(|h| h.loops.clone()).collect(),
            robust.outlying.iter().map(|o| o.loops.clone()).collect(),
        ]
    };
    let kinds = ["doubtful clusters", "loops held back", "outlying loops"];
    for ((kind, nu), nb) in kinds.iter().zip(named(u)).zip(named(b)) {
        if nu != nb {
            out.push(format!("{kind} {nu:?} vs batch {nb:?}"));
        }
    }
    let (cu, cb) = (u.chi2(), b.chi2());
    let rel = (cu - cb).abs() / cb.abs().max(f64::MIN_POSITIVE);
    if rel > TOLERANCE && (cu - cb).abs() > 1e-12 {
        out.push(format!(
            "χ² {cu:.9e} vs batch {cb:.9e} (relative {rel:.2e})"
        ));
    }
    let (dp, size, dr) = poses_apart(u, b);
    let size = size.max(1.0);
    if dp > TOLERANCE * size || dr > TOLERANCE {
        out.push(format!(
            "poses {dp:.2e} apart ({:.2e} of the map's size {size:.1}), rotations {dr:.2e}",
            dp / size
        ));
    }
    out
}

/// Replays `sim` (see the module doc), returning how many updates were
/// compared and every mismatch.
fn replay<P: GraphPose<D>, const D: usize>(
    case: Case,
    sim: &Simulation<P, D>,
    mismatches: &mut Vec<Mismatch>,
) -> usize {
    let mut rng = StdRng::seed_from_u64(case.seed ^ 0x5eed);
    let noisy = &sim.noisy;
    let n = noisy.len();
    let mut options = Options::default();
    if let Some(m) = case.robust {
        options.set("robust", m).unwrap();
    }
    let mut other = options.clone();
    other.set("alpha", "0.01").unwrap();
    let mut g = PoseGraph::<P, D>::new();
    let mut next = rng.random_range(1..=50usize);
    let mut compared = 0;
    for (k, due) in edges_due(noisy).iter().enumerate() {
        add_pose_and_edges(&mut g, noisy, k, due);
        next -= 1;
        if next > 0 && k + 1 < n {
            continue;
        }
        next = rng.random_range(1..=50usize);
        match rng.random_range(0..40u32) {
            0 => g.fix(rng.random_range(0..=k as u64)).unwrap(),
            1 => g.forget(),
            2 => std::mem::swap(&mut options, &mut other),
            3 => {
                // A cancelled update keeps the earlier state.
                let cancel = Cancel::new();
                cancel.cancel();
                let s = g.update_with(&options, &mut cancel.clone()).unwrap();
                assert!(s.cancelled());
            }
            _ => {}
        }
        let u = g.update(&options).unwrap();
        let b = g.optimize(&options).unwrap();
        compared += 1;
        let solve = u
            .incremental()
            .map_or(String::new(), |i| format!("{:?} ({})", i.solve, i.reason));
        for what in compare(&u, &b) {
            mismatches.push(Mismatch {
                case,
                poses: k + 1,
                solve: solve.clone(),
                what,
            });
        }
    }
    compared
}

fn run(case: Case, mismatches: &mut Vec<Mismatch>) -> usize {
    let options = SimulationOptions {
        world: case.world,
        poses: case.poses,
        loops: case.loops,
        outliers: case.wrong,
        outlier_policy: case.policy,
        group_size: 5,
        inliers: Some(InlierModel::default()),
        seed: case.seed,
        ..Default::default()
    };
    match simulate(&options).unwrap() {
        AnySimulation::Planar(sim) => replay(case, &sim, mismatches),
        AnySimulation::Spatial(sim) => replay(case, &sim, mismatches),
    }
}

/// Runs `cases`, prints every mismatch and fails if there is one.
fn check(cases: &[Case]) {
    let (mut mismatches, mut compared) = (Vec::new(), 0);
    for &case in cases {
        compared += run(case, &mut mismatches);
    }
    for m in &mismatches {
        eprintln!(
            "{:?} {:?} seed {} robust {:?}: at {} poses, {}: {}",
            m.case.world, m.case.policy, m.case.seed, m.case.robust, m.poses, m.solve, m.what
        );
    }
    eprintln!(
        "{compared} updates compared, {} mismatches",
        mismatches.len()
    );
    assert!(mismatches.is_empty());
}

fn cases(world: World, poses: usize, seeds: &[u64], robust: Option<&'static str>) -> Vec<Case> {
    let policies = [
        OutlierPolicy::Random,
        OutlierPolicy::Grouped,
        OutlierPolicy::Aliased,
    ];
    let mut out = Vec::new();
    for &seed in seeds {
        for policy in policies {
            out.push(Case {
                world,
                policy,
                seed,
                poses,
                loops: poses / 8,
                wrong: poses / 25,
                robust,
            });
        }
    }
    out
}

#[test]
fn every_update_of_a_planar_replay_is_the_batch_job() {
    check(&cases(World::Grid2d, 400, &[1, 2], None));
}

#[test]
fn every_update_of_a_spatial_replay_is_the_batch_job() {
    let mut all = cases(World::Sphere3d, 300, &[3], None);
    all.extend(cases(World::Torus3d, 300, &[4], None));
    check(&all);
}

#[test]
fn every_update_with_a_kernel_is_the_batch_job() {
    let mut all = cases(World::Grid2d, 300, &[5], Some("huber"));
    all.extend(cases(World::Sphere3d, 200, &[6], Some("huber")));
    check(&all);
}

/// Issue 47's worst case: `pgo simulate --world grid2d --poses 2000
/// --loops 200 --wrong 50 --inliers --seed 2`, updated at 126 and 210
/// poses (the second update rejected all 18 true loops, the batch job
/// accepted them); and `sphere3d` seed 6 at 147 poses.
#[test]
fn the_issue_47_replays_are_the_batch_job() {
    fn at<P: GraphPose<D>, const D: usize>(sim: &Simulation<P, D>, stops: &[usize]) -> Vec<String> {
        let noisy = &sim.noisy;
        let mut g = PoseGraph::<P, D>::new();
        let mut out = Vec::new();
        let mut from = 0;
        for &stop in stops {
            for k in from..stop {
                g.add_pose(k as u64, *noisy.pose(k as u64).unwrap())
                    .unwrap();
            }
            for e in noisy.edges() {
                let hi = e.from.max(e.to) as usize;
                if (from..stop).contains(&hi) {
                    if e.loop_candidate {
                        g.add_loop_candidate(e.from, e.to, e.measurement, e.information, e.inliers)
                            .unwrap();
                    } else {
                        g.add_edge(e.from, e.to, e.measurement, e.information)
                            .unwrap();
                    }
                }
            }
            let options = Options::default();
            let u = g.update(&options).unwrap();
            let b = g.optimize(&options).unwrap();
            for what in compare(&u, &b) {
                out.push(format!("at {stop} poses: {what}"));
            }
            from = stop;
        }
        out
    }
    let sim = |world, seed| SimulationOptions {
        world,
        poses: 2000,
        loops: 200,
        outliers: 50,
        inliers: Some(InlierModel::default()),
        seed,
        ..Default::default()
    };
    let mut found = Vec::new();
    match simulate(&sim(World::Grid2d, 2)).unwrap() {
        AnySimulation::Planar(s) => found.extend(at(&s, &[126, 210])),
        AnySimulation::Spatial(_) => unreachable!(),
    }
    match simulate(&sim(World::Sphere3d, 6)).unwrap() {
        AnySimulation::Spatial(s) => found.extend(at(&s, &[60, 147])),
        AnySimulation::Planar(_) => unreachable!(),
    }
    for f in &found {
        eprintln!("{f}");
    }
    assert!(found.is_empty());
}

/// A simulated map (`world`, 400 poses, 60 true loops) with 40 aliases
/// placed anywhere, in groups of `group` a 5–30 poses off, every group's
/// counts like a true loop's (`pgo corrupt --wrong-mode aliased
/// --alias-place anywhere --alias-offset 5,30 --true-like-counts 1.0
/// --true-like-by-group`), its `wrong` the aliases.
fn aliased_anywhere(world: World, seed: u64, group: usize) -> AnySimulation {
    use pgo_sim::{AliasOffsets, AliasPlace, CorruptionOptions, corrupt};
    let sim = simulate(&SimulationOptions {
        world,
        poses: 400,
        loops: 60,
        inliers: Some(InlierModel::default()),
        seed,
        ..Default::default()
    })
    .unwrap();
    let aliases = CorruptionOptions {
        outliers: 40,
        policy: OutlierPolicy::Aliased,
        group_size: group,
        alias_offsets: AliasOffsets { min: 5, max: 30 },
        alias_place: AliasPlace::Anywhere,
        inliers: Some(InlierModel::default()),
        true_like_share: 1.0,
        true_like_by_group: true,
        ..CorruptionOptions::default()
    };
    let mut rng = StdRng::seed_from_u64(seed);
    match sim {
        AnySimulation::Planar(mut s) => {
            let c = corrupt(&s.noisy, &aliases, &mut rng).unwrap();
            (s.noisy, s.wrong) = (c.graph, c.wrong);
            AnySimulation::Planar(s)
        }
        AnySimulation::Spatial(mut s) => {
            let c = corrupt(&s.noisy, &aliases, &mut rng).unwrap();
            (s.noisy, s.wrong) = (c.graph, c.wrong);
            AnySimulation::Spatial(s)
        }
    }
}

/// One update of [`every_poses`]: after how many poses, why it ran the
/// whole job (`None`: it did not), how many of how many candidates it
/// accepted, how it differed from the batch job, and the true loops each
/// rejected and wrong ones each accepted (update, then batch).
#[derive(Debug)]
struct Step {
    poses: usize,
    whole_job: Option<String>,
    accepted: (usize, usize),
    mismatches: Vec<String>,
    errors: [(usize, usize); 2],
}

/// The true loops `s` rejects and the wrong ones it accepts, `wrong[k]`
/// whether its `k`-th candidate is wrong.
fn errors<P>(s: &Solution<P>, wrong: &[bool]) -> (usize, usize) {
    let (mut rejected, mut accepted) = (0, 0);
    for (d, &w) in s.loops().iter().zip(wrong) {
        rejected += usize::from(!w && !d.accepted);
        accepted += usize::from(w && d.accepted);
    }
    (rejected, accepted)
}

/// [`aliased_anywhere`] on the sphere.
fn aliased_sphere(seed: u64, group: usize) -> Simulation<pgo::Se3, 6> {
    match aliased_anywhere(World::Sphere3d, seed, group) {
        AnySimulation::Spatial(sim) => sim,
        AnySimulation::Planar(_) => unreachable!("a sphere is spatial"),
    }
}

/// Replays the first `upto` poses of `sim`'s graph as a front end does, an
/// update every `every` poses, each compared with `optimize()` of the same
/// graph.
fn every_poses<P: GraphPose<D>, const D: usize>(
    sim: &Simulation<P, D>,
    every: usize,
    upto: usize,
) -> Vec<Step> {
    let options = Options::default();
    let mut g = PoseGraph::<P, D>::new();
    // Whether each candidate added so far is wrong.
    let (mut steps, mut wrong) = (Vec::new(), Vec::new());
    for (k, due) in edges_due(&sim.noisy).iter().enumerate().take(upto) {
        let candidates = add_pose_and_edges(&mut g, &sim.noisy, k, due);
        wrong.extend(candidates.iter().map(|&i| sim.wrong[i]));
        if (k + 1) % every != 0 {
            continue;
        }
        let u = g.update(&options).unwrap();
        let b = g.optimize(&options).unwrap();
        let inc = u.incremental().unwrap();
        steps.push(Step {
            poses: k + 1,
            whole_job: (inc.solve == pgo::UpdateSolve::Batch).then(|| inc.reason.clone()),
            accepted: (accepted(&u).len(), u.loops().len()),
            mismatches: compare(&u, &b),
            errors: [errors(&u, &wrong), errors(&b, &wrong)],
        });
    }
    steps
}

/// The steps of `steps` that differ from the batch job.
fn mismatched(steps: &[Step]) -> Vec<&Step> {
    steps.iter().filter(|s| !s.mismatches.is_empty()).collect()
}

/// After how many poses the steps of `steps` ran the whole job for a
/// reason that says `why`.
fn whole_jobs(steps: &[Step], why: &str) -> Vec<usize> {
    (steps.iter())
        .filter(|s| s.whole_job.as_ref().is_some_and(|r| r.contains(why)))
        .map(|s| s.poses)
        .collect()
}

/// A young map whose first loops are all true and whose gate splits their
/// counts (most near the largest count, which a feature count saturates
/// at): no loop model can be fitted, and the model of nothing decides by
/// the innovations alone. A sphere's first 220 poses, updated every 20:
/// every candidate accepted (at 160 poses the gate keeps 7 of 25, and the
/// loop model once accepted 4), every update the batch job.
#[test]
fn a_young_map_keeps_the_true_loops_its_gate_drops() {
    let sim = aliased_sphere(8, 10);
    let steps = every_poses(&sim, 20, 220);
    assert!(mismatched(&steps).is_empty(), "{steps:#?}");
    // Every alias of this map is beyond its 288th pose.
    let young: Vec<_> = (steps.iter())
        .filter(|s| s.poses >= 80 && s.accepted.0 < s.accepted.1)
        .collect();
    assert!(young.is_empty(), "{young:#?}");
}

/// An update whose decisions reject a loop the last update accepted runs
/// the whole job: the new evidence overturned the consensus the last
/// decisions stood for, and the warm decisions from it can end at another
/// fixed point than the batch job's annealing. A sphere with aliases in
/// groups of 5, updated every 20 poses: at 220 poses the decisions from
/// the last ones rejected two true loops that the update at 200 accepted
/// (χ² 1.3 % above the batch job's, poses 4 % of the map's size apart).
#[test]
fn an_update_that_rejects_an_accepted_loop_runs_the_whole_job() {
    let sim = aliased_sphere(3, 5);
    let steps = every_poses(&sim, 20, 220);
    assert!(mismatched(&steps).is_empty(), "{steps:#?}");
    assert!(
        !whole_jobs(&steps, "rejected a loop").is_empty(),
        "{steps:#?}"
    );
}

/// An update whose decisions swing — a round flips back decisions the
/// round before flipped, twice — runs the whole job (docs/method.md §7b).
/// A grid with aliases in groups of 10, updated every 20 poses: the
/// decisions from the last ones swing at 300 poses.
#[test]
fn an_update_whose_decisions_swing_runs_the_whole_job() {
    let AnySimulation::Planar(sim) = aliased_anywhere(World::Grid2d, 10, 10) else {
        unreachable!()
    };
    let steps = every_poses(&sim, 20, 300);
    assert!(mismatched(&steps).is_empty(), "{steps:#?}");
    assert_eq!(whole_jobs(&steps, "swung"), [300], "{steps:#?}");
}

/// An update whose map holds loops back by their counts runs the whole
/// job: EM from the last decisions can hold back there true loops that
/// the annealing accepts. A sphere with aliases placed anywhere in groups
/// of 5, updated every 20 poses: at 160 poses the update holds loops back
/// (its gate's two components lower BIC by 3.6) and runs the whole job.
/// At 260 poses it once held back nine true loops in six clusters that
/// the batch job accepted (poses 8.5 % of the map's size apart), behind a
/// gate that split one population by chance (BIC 0.14): the gate now sees
/// one component there, and the update holds nothing back.
#[test]
fn an_update_that_holds_loops_back_runs_the_whole_job() {
    let AnySimulation::Spatial(sim) = aliased_anywhere(World::Sphere3d, 30, 5) else {
        unreachable!()
    };
    let steps = every_poses(&sim, 20, 260);
    assert!(mismatched(&steps).is_empty(), "{steps:#?}");
    assert_eq!(whole_jobs(&steps, "holds loops back"), [160], "{steps:#?}");
}

/// An update that leaves a candidate's posterior near ½ runs the whole
/// job. A sphere with aliases in groups of 5, updated every 20 poses: at
/// 220 poses a true loop at `ν²` 23.1 on 6 dof has posterior 0.52, and
/// rejected (beyond the true loops' reach of the update's fit) or accepted
/// (within the batch job's) are both fixed points of EM.
#[test]
fn an_update_with_a_posterior_near_half_runs_the_whole_job() {
    let sim = aliased_sphere(28, 5);
    let steps = every_poses(&sim, 20, 220);
    assert!(mismatched(&steps).is_empty(), "{steps:#?}");
    assert!(whole_jobs(&steps, "near ½").contains(&220), "{steps:#?}");
}

/// The replays of aliases placed anywhere, wider than CI runs (192
/// replays: a grid and a sphere, seeds 1–48, groups of 5 and 10, an update
/// every 20 poses, each compared with the batch job; about a minute in
/// release): `cargo test --release --test update_equals_optimize --
/// --ignored`. Prints every replay with a whole job or a mismatch, at each
/// mismatch the true loops the update and the batch job reject and the
/// wrong ones they accept, and the totals of those over every step. Fails
/// if any replay mismatches (the last, grid seed 48 with groups of 5,
/// kept four true loops its gate came to drop until such an update ran
/// the whole job: [`an_update_whose_gate_drops_an_accepted_loop_runs_the_whole_job`];
/// before the whole job at a posterior near ½, 6 did, each at another of
/// EM's fixed points than the batch job's annealing; docs/method.md §7b),
/// if any step accepts an alias, or if the true loops rejected over every
/// step grow (267 by the updates and by the batch jobs; 302 and 306 while
/// the gate drew a crossing through counts whose two components lowered
/// BIC by less than 2).
#[test]
#[ignore]
fn wider_aliased_replays() {
    aliased_replays_within(1..=48, 20, 0, 0, (267, 267));
}

/// The same replays on seeds no rule of the update was found on (49–72)
/// and at another interval (every 13 poses): 96 replays, about a minute
/// in release. 2 differ from the batch job at 2–3 updates each (3 before
/// an update whose gate drops an accepted loop ran the whole job, 8
/// before the whole job at a posterior near ½, 5 before the χ² search
/// gave back what the map without the aliases accepts and a cycle was
/// halved again): the update rejects a true loop the batch job keeps (grid
/// seed 71, both group sizes; docs/method.md §7b). Another, grid seed
/// 56, differed by
/// 1.2·10⁻⁶ in a check of the rotations that read SE(2)'s `y` with `θ`:
/// its rotations agree. Over every step the updates reject 199 true
/// loops and the batch jobs 193 (211 and 264 with a gate on chance splits
/// of the counts), and both accept 10 aliases. Fails if more
/// replays differ, or if the true loops rejected or the aliases accepted
/// grow.
#[test]
#[ignore]
fn unseen_aliased_replays() {
    aliased_replays_within(49..=72, 13, 2, 10, (199, 193));
}

/// The same replays on seeds 73–120, which no rule of the update was
/// found on nor checked against before it was written, at another interval
/// (every 17 poses): 192 replays, about two minutes in release. 3 differ
/// from the batch job, each at one or two updates, all of the kinds
/// docs/method.md §7b describes: the batch job's decisions did not settle
/// and it keeps a true loop the update leaves out (sphere seed 117, groups
/// of 5, at 391 poses), a young grid whose batch job holds two true loops
/// back by their counts (grid seed 99, groups of 10, at 170 and 187), and
/// a true loop the batch job's fit puts beyond the true loops' reach and
/// the update's does not (grid seed 107, groups of 5, at 272). Over every
/// step the updates reject 404 true loops and the batch jobs 408, and both
/// accept 88 aliases (4 replays differed, 400 and 405 true loops, before
/// flagged loops too light to name were tried without, docs/method.md
/// §7: grid seed 86 with groups of 10 no longer differs at 374). Fails if
/// more replays differ, or if the true loops rejected or the aliases
/// accepted grow.
#[test]
#[ignore]
fn fresh_aliased_replays() {
    aliased_replays_within(73..=120, 17, 3, 88, (404, 408));
}

/// Runs [`aliased_replays`] on `seeds` with an update every `every` poses
/// and checks their bounds: at most `mismatches` replays differ from the
/// batch job, the updates and the batch jobs each accept at most `aliases`
/// aliases over every step, and reject at most `true_loops` (updates,
/// batch jobs) true loops.
fn aliased_replays_within(
    seeds: std::ops::RangeInclusive<u64>,
    every: usize,
    mismatches: usize,
    aliases: usize,
    true_loops: (usize, usize),
) {
    let (mismatching, totals) = aliased_replays(seeds, every);
    let [(ut, uw), (bt, bw)] = totals;
    assert!(mismatching.len() <= mismatches, "{mismatching:?}");
    assert!(
        uw <= aliases && bw <= aliases,
        "aliases accepted: {totals:?}"
    );
    assert!(ut <= true_loops.0 && bt <= true_loops.1, "{totals:?}");
}

/// One replay of [`aliased_replays`]: the world, the seed, the group size.
type Replay = (World, u64, usize);

/// True loops rejected and wrong ones accepted summed over every step: by
/// the updates, by the batch jobs.
type Totals = [(usize, usize); 2];

/// Replays [`aliased_anywhere`] on a sphere and a grid for each of `seeds`
/// and groups of 5 and 10, an update every `every` poses up to 400, each
/// compared with the batch job; prints every replay with a whole job
/// (after 100 poses) or a mismatch. Returns the replays that differ, and
/// the true loops rejected and wrong ones accepted summed over every step:
/// by the updates, by the batch jobs.
fn aliased_replays(seeds: std::ops::RangeInclusive<u64>, every: usize) -> (Vec<Replay>, Totals) {
    let (mut mismatching, mut replays, mut whole) = (Vec::new(), 0, 0);
    let mut totals = [(0, 0), (0, 0)];
    for world in [World::Sphere3d, World::Grid2d] {
        for seed in seeds.clone() {
            for group in [5usize, 10] {
                let steps = match aliased_anywhere(world, seed, group) {
                    AnySimulation::Planar(s) => every_poses(&s, every, 400),
                    AnySimulation::Spatial(s) => every_poses(&s, every, 400),
                };
                replays += 1;
                let jobs: Vec<(usize, &String)> = (steps.iter())
                    .filter_map(|s| s.whole_job.as_ref().map(|r| (s.poses, r)))
                    .filter(|(p, _)| *p > 100)
                    .collect();
                whole += jobs.len();
                let bad = mismatched(&steps);
                if !jobs.is_empty() || !bad.is_empty() {
                    eprintln!("{world:?} seed {seed} group {group}: whole jobs {jobs:?}");
                }
                for s in &bad {
                    let [(ut, uw), (bt, bw)] = s.errors;
                    eprintln!(
                        "    at {}: {:?}; true loops rejected / wrong accepted: update {ut} / {uw}, batch {bt} / {bw}",
                        s.poses, s.mismatches
                    );
                }
                for s in &steps {
                    for (total, (t, w)) in totals.iter_mut().zip(s.errors) {
                        (total.0, total.1) = (total.0 + t, total.1 + w);
                    }
                }
                if !bad.is_empty() {
                    mismatching.push((world, seed, group));
                }
            }
        }
    }
    let [(ut, uw), (bt, bw)] = totals;
    eprintln!(
        "{} of {replays} replays differ from the batch job: {mismatching:?}\n\
         whole jobs after 100 poses: {whole}\n\
         over every step, true loops rejected / wrong accepted: updates {ut} / {uw}, batch jobs {bt} / {bw}",
        mismatching.len()
    );
    (mismatching, totals)
}

/// The first `poses` poses of [`aliased_sphere`] `seed` (groups of 5)
/// added as a front end adds them, and whether each candidate is wrong.
fn sphere_prefix(seed: u64, poses: usize) -> (PoseGraph<pgo::Se3, 6>, Vec<bool>) {
    let sim = aliased_sphere(seed, 5);
    let mut g = PoseGraph::<pgo::Se3, 6>::new();
    let mut wrong = Vec::new();
    for (k, due) in edges_due(&sim.noisy).iter().enumerate().take(poses) {
        let candidates = add_pose_and_edges(&mut g, &sim.noisy, k, due);
        wrong.extend(candidates.iter().map(|&i| sim.wrong[i]));
    }
    (g, wrong)
}

/// A cycle of the batch job's decision sets that a half step settles: on a
/// simulated sphere's first 380 poses (40 aliases placed anywhere in
/// groups of 5, every count true-like) the decisions swung between the set
/// without 9 true loops and 3 aliases near them and the set with all 12,
/// whose map rejects them all; the better fitting of the two left the 9
/// true loops out. Added half at a time, by increasing `ν²`, the true loops
/// go in first and the map with them rejects the aliases.
#[test]
fn a_cycle_of_decisions_is_settled_by_half_steps() {
    let (g, wrong) = sphere_prefix(8, 380);
    let b = g.optimize(&Options::default()).unwrap();
    // (true loops rejected, aliases accepted)
    assert_eq!(errors(&b, &wrong), (0, 0));
}

/// A true loop the χ² search took out while aliases bent the map comes
/// back once they are out. A sphere's first 338 poses (aliases placed
/// anywhere in groups of 5, seed 55): the search takes out true loop 46
/// first (its drop 999 on 6 dimensions), then an alias and two groups of
/// aliases; at the map without them the model accepts loop 46 by its own
/// innovation and count (posterior 0.9986), and the batch job now keeps
/// it, as the update replaying the same poses every 13 did.
#[test]
fn a_true_loop_the_search_took_out_before_the_aliases_comes_back() {
    let (g, wrong) = sphere_prefix(55, 338);
    let b = g.optimize(&Options::default()).unwrap();
    assert!(!wrong[46] && b.loops()[46].accepted, "{:?}", b.loops()[46]);
    assert_eq!(errors(&b, &wrong), (0, 0));
    let search = b.report().robust.search.as_ref().unwrap();
    let removed: Vec<usize> = (search.removed.iter())
        .flat_map(|r| r.loops.iter().copied())
        .collect();
    assert!(
        removed.len() >= 10 && removed.iter().all(|&k| wrong[k]),
        "{removed:?}"
    );
    assert!(b.report().chi2_test.as_ref().unwrap().passed);
}

/// A cycle that one half step does not settle is halved again. A
/// sphere's first 325 poses (aliases placed anywhere in groups of 5, seed
/// 60): at a map of 43 loops the model accepts 8 candidates of one place,
/// 3 true loops and 5 aliases, whose map rejects all 8; the half step adds
/// the 4 of least `ν²`, an alias among them, and their map rejects the 4.
/// Halved again (the alias and a true loop out), the map of the other two
/// accepts the third, and the set settles without the aliases: the batch job
/// keeps every true loop and no alias, as the update replaying the same
/// poses every 13 did (it kept 3 true loops fewer, the set of a cycle).
#[test]
fn a_cycle_one_half_step_leaves_is_halved_again() {
    let (g, wrong) = sphere_prefix(60, 325);
    let b = g.optimize(&Options::default()).unwrap();
    assert_eq!(errors(&b, &wrong), (0, 0));
    assert!(b.report().chi2_test.as_ref().unwrap().passed);
    assert_eq!(b.status(), pgo::MapStatus::Ok, "{:?}", b.report().warnings);
}

/// An update whose gate drops a loop the last update accepted runs the
/// whole job. A grid's first 160 poses (40 aliases placed anywhere in
/// groups of 5, seed 48), updated every 20: until 140 poses the counts
/// show one component and the gate keeps every candidate; at 160 it finds
/// two and drops four true loops the updates had accepted (counts 39–77,
/// below `T_GV` 99.7). The batch job decides them from their counts' low
/// priors and rejects them; EM's decisions from the last ones kept them
/// at a posterior near 1, and that update was not the batch job's.
#[test]
fn an_update_whose_gate_drops_an_accepted_loop_runs_the_whole_job() {
    let AnySimulation::Planar(sim) = aliased_anywhere(World::Grid2d, 48, 5) else {
        panic!("a grid is planar");
    };
    let steps = every_poses(&sim, 20, 160);
    assert!(mismatched(&steps).is_empty(), "{steps:#?}");
    assert_eq!(whole_jobs(&steps, "the gate drops"), [160], "{steps:#?}");
}
