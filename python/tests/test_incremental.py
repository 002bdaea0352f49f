"""PoseGraph.update: a graph fed as a mapping front end feeds it, the map
asked for every few poses. Each update says how it solved (Result.incremental,
the same as report["incremental"]) and which earlier decisions it changed;
odometry alone is composed, nothing added changes nothing, and the last
update's map and decisions are those of a batch optimize() of the graph."""

import math
import random

import pytest

import pgo
from conftest import SAMPLES, symmetric

SIDE = 4  # poses per side of the square
LAP = 4 * SIDE  # poses per lap
ODOMETRY_SIGMA = (0.03, 0.03, 0.01)
LOOP_SIGMA = (0.05, 0.05, 0.02)


def information(sigma):
    return [[1.0 / sigma[0] ** 2, 0.0, 0.0],
            [0.0, 1.0 / sigma[1] ** 2, 0.0],
            [0.0, 0.0, 1.0 / sigma[2] ** 2]]


def wrap(angle):
    return math.atan2(math.sin(angle), math.cos(angle))


def compose(a, b):
    """a ⊕ b for planar poses (x, y, θ)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2]))


def between(a, b):
    """a⁻¹ ⊕ b: the pose of b in the frame of a."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return (c * dx + s * dy, -s * dx + c * dy, wrap(b[2] - a[2]))


def noisy(pose, sigma, rng):
    return tuple(p + rng.gauss(0.0, s) for p, s in zip(pose, sigma))


def pose_difference(p, q):
    """The largest absolute difference of two planar poses' numbers (the
    angle wrapped)."""
    return max(abs(p[0] - q[0]), abs(p[1] - q[1]), abs(wrap(p[2] - q[2])))


def square_walk(laps=3, tail=8, seed=5):
    """A robot driving a 4 m square `laps` times, then `tail` more poses
    without loop closures. Returns the steps a front end makes, one per
    pose: (id, initial guess, [edges]) with each edge (i, j, measurement,
    information, inliers) — inliers None for odometry. Loop candidates:
    to the same place one lap before at every other pose (right, many
    inliers), and a few to a place 2 m away claimed to be the same (wrong,
    few inliers)."""
    rng = random.Random(seed)
    truth = [(0.0, 0.0, 0.0)]
    guess = [(0.0, 0.0, 0.0)]
    steps = [(0, guess[0], [])]
    odometry, loop_info = information(ODOMETRY_SIGMA), information(LOOP_SIGMA)
    for k in range(1, laps * LAP + tail + 1):
        turn = math.pi / 2 if k % SIDE == 0 else 0.0
        truth.append(compose(truth[-1], (1.0, 0.0, turn)))
        z = noisy(between(truth[k - 1], truth[k]), ODOMETRY_SIGMA, rng)
        guess.append(compose(guess[-1], z))
        edges = [(k - 1, k, z, odometry, None)]
        if LAP <= k <= laps * LAP:
            if k % 2 == 0:
                i = k - LAP
                meas = noisy(between(truth[i], truth[k]), LOOP_SIGMA, rng)
                edges.append((i, k, meas, loop_info, rng.randint(60, 150)))
            if k % 8 == 5:
                i = k - LAP + 2  # 2 m along the square from pose k
                meas = noisy((0.0, 0.0, 0.0), LOOP_SIGMA, rng)
                edges.append((i, k, meas, loop_info, rng.randint(5, 20)))
        steps.append((k, guess[k], edges))
    return steps


def add_step(graph, step):
    """Adds one step's pose and edges; returns (edges, candidates) added."""
    pose_id, pose, edges = step
    graph.add_pose(pose_id, pose)
    candidates = 0
    for i, j, meas, info, inliers in edges:
        if inliers is None:
            graph.add_edge(i, j, meas, info)
        else:
            graph.add_loop_candidate(i, j, meas, info, inliers=inliers)
            candidates += 1
    return len(edges), candidates


def accepted(result):
    return [d["index"] for d in result.loops if d["accepted"]]


def assert_same_as_batch(last, batch):
    """The last update's map, decisions and χ² are the batch job's."""
    assert batch.incremental is None and "incremental" not in batch.report
    assert last.poses.keys() == batch.poses.keys()
    worst = max(pose_difference(last.pose(i), batch.pose(i)) for i in batch.poses)
    assert worst < 1e-5, f"poses differ from the batch ones by {worst:e}"
    assert accepted(last) == accepted(batch)
    assert [d["reason"] for d in last.loops] == [d["reason"] for d in batch.loops]
    assert abs(last.chi2 / batch.chi2 - 1.0) < 1e-6, (last.chi2, batch.chi2)
    assert last.passed == batch.passed


def assert_changed_lists_the_flips(result, previous):
    """`changed` lists exactly the earlier candidates whose decision differs
    from the previous update's, as they are now."""
    before = {d["index"]: d["accepted"] for d in previous.loops}
    flipped = [
        {"index": d["index"], "from": d["from"], "to": d["to"],
         "accepted": d["accepted"], "reason": d["reason"]}
        for d in result.loops
        if d["index"] in before and before[d["index"]] != d["accepted"]
    ]
    assert result.incremental["changed"] == flipped


def test_a_replay_of_a_square_walk_ends_with_the_batch_job():
    steps = square_walk()
    graph = pgo.PoseGraph(2)
    every = 4
    previous, added = None, [0, 0, 0]  # poses, edges, candidates
    kinds = []
    for k, step in enumerate(steps):
        edges, candidates = add_step(graph, step)
        added = [added[0] + 1, added[1] + edges, added[2] + candidates]
        if (k + 1) % every != 0 and k + 1 != len(steps):
            continue
        result = graph.update()
        inc = result.incremental
        kinds.append(inc["solve"])
        assert inc == result.report["incremental"]
        if previous is None:
            assert (inc["solve"], inc["reason"]) == ("batch", "no earlier solution")
            assert inc["changed"] == []
        elif inc["solve"] == "batch":
            # A young map: too few candidates for EM's model, or no model
            # or accepted loop to resume from (docs/method.md §7b).
            assert "swung" not in inc["reason"] and "warm" not in kinds[:-1], (k, inc)
            assert_changed_lists_the_flips(result, previous)
        else:
            assert [inc["new_poses"], inc["new_edges"], inc["new_candidates"]] == added
            assert_changed_lists_the_flips(result, previous)
        new_ids = [s[0] for s in steps[k + 1 - added[0]:k + 1]]
        if previous is not None and added[2] == 0 and added[1] == added[0]:
            # Odometry alone: the new poses are the last map's composed
            # with it, and the rest of the map is the last one.
            assert inc["solve"] == "extended", (k, inc)
            assert inc["changed"] == []
            pose = previous.pose(new_ids[0] - 1)
            for step in steps[k + 1 - added[0]:k + 1]:
                pose = compose(pose, step[2][0][2])
                assert pose_difference(result.pose(step[0]), pose) < 1e-9, step[0]
            for i in previous.poses:
                assert pose_difference(result.pose(i), previous.pose(i)) < 1e-12, i
            assert accepted(result) == accepted(previous)
        elif previous is not None:
            assert inc["solve"] in ("warm", "batch"), (k, inc)
        previous, added = result, [0, 0, 0]
    assert kinds.count("extended") >= 4 and kinds.count("warm") + kinds.count("batch") - 1 >= 4, kinds

    # Nothing added: the last map stands.
    again = graph.update()
    assert again.incremental["solve"] == "none"
    assert again.incremental["new_poses"] == again.incremental["new_edges"] == 0
    assert again.poses == previous.poses and again.chi2 == previous.chi2
    assert again.loops == previous.loops

    batch = graph.optimize()
    assert_same_as_batch(again, batch)
    # The map is right: every right loop in, every wrong one out.
    right = {d["index"] for d in batch.loops if d["inliers"] >= 60}
    assert set(accepted(batch)) == right and 0 < len(right) < len(batch.loops)


def test_capped_updates_iterate_at_most_so_often_and_a_closing_update_reaches_batch():
    # The right loops only, as trusted edges: no candidate for EM to
    # decide, so every solve is capped.
    graph = pgo.PoseGraph(2)
    cut_short = 0
    steps = square_walk(laps=4, tail=0)
    for k, (pose_id, pose, edges) in enumerate(steps):
        graph.add_pose(pose_id, pose)
        for i, j, meas, info, inliers in edges:
            if inliers is None or inliers >= 60:
                graph.add_edge(i, j, meas, info)
        if k % 4 == 3 or k + 1 == len(steps):
            result = graph.update(update_iters=1)
            optimizer = result.report["optimizer"]
            assert optimizer["iterations"] <= 1
            cut_short += not optimizer["converged"]
            assert result.incremental["solve"] != "batch" or k == 3
    assert cut_short > 0, "no update was cut short"
    closing = graph.update()  # nothing added, no cap: the same job
    assert solve(closing)[0] == "warm" and closing.incremental["new_edges"] == 0
    assert closing.report["optimizer"]["converged"]
    assert_same_as_batch(closing, graph.optimize())
    with pytest.raises(pgo.InvalidOptionError, match="option update_iters must be at least 1"):
        graph.update(update_iters=0)


def walk(n):
    """n poses 1 m apart along x, odometry between neighbours, and one loop
    candidate from the first to the last."""
    graph = pgo.PoseGraph(2)
    info = information(ODOMETRY_SIGMA)
    for k in range(n):
        graph.add_pose(k, (0.0, 0.0, 0.0))
        if k > 0:
            graph.add_edge(k - 1, k, (1.0, 0.0, 0.0), info)
    graph.add_loop_candidate(0, n - 1, (n - 1.02, 0.01, 0.0), information(LOOP_SIGMA), inliers=90)
    return graph


def solve(result):
    return result.incremental["solve"], result.incremental["reason"]


def test_other_options_fix_and_forget_start_again():
    graph = walk(6)
    assert solve(graph.update(alpha=0.05)) == ("batch", "no earlier solution")
    assert solve(graph.update(alpha=0.05))[0] == "none"
    assert solve(graph.update(alpha=0.01)) == ("batch", "options changed")
    assert solve(graph.update(alpha=0.01))[0] == "none"
    # An option given its default value is the same options.
    assert solve(graph.update(alpha=0.01, robust=None))[0] == "none"
    graph.fix(3)
    assert solve(graph.update(alpha=0.01))[0] == "batch"
    assert solve(graph.update(alpha=0.01))[0] == "none"
    graph.forget()
    first = graph.update(alpha=0.01)
    assert solve(first)[0] == "batch"
    inc = first.incremental
    # A batch update counts the whole graph as new.
    assert (inc["new_poses"], inc["new_edges"], inc["new_candidates"]) == (6, 6, 1)
    graph.forget()
    graph.forget()  # twice is once
    assert solve(graph.update(alpha=0.01))[0] == "batch"


def test_optimize_is_no_update_and_leaves_the_state_alone():
    graph = walk(5)
    batch = graph.optimize()
    assert batch.incremental is None and "incremental" not in batch.report
    first = graph.update()
    assert solve(first)[0] == "batch"
    graph.optimize(alpha=0.2)
    assert solve(graph.update())[0] == "none"
    assert_same_as_batch(first, batch)


def test_failed_updates_keep_the_earlier_state():
    with pytest.raises(pgo.Error, match="no poses"):
        pgo.PoseGraph(2).update()
    graph = walk(5)
    graph.update()
    with pytest.raises(pgo.Error, match="alpha"):
        graph.update(alpha=2.0)
    with pytest.raises(pgo.Error, match="unknown option"):
        graph.update(no_such_option=1)
    assert solve(graph.update())[0] == "none"


def test_a_decision_an_update_changes_is_listed():
    """A loop candidate 1 m off the odometry, accepted while it is alone
    (the odometry gives way), then outvoted by three that agree with the
    odometry: the update lists it as changed, rejected now."""
    graph = pgo.PoseGraph(2)
    odometry, loop = information((0.05, 0.05, 0.02)), information(LOOP_SIGMA)
    for k in range(9):
        graph.add_pose(k, (0.0, 0.0, 0.0))
        if k > 0:
            graph.add_edge(k - 1, k, (1.0, 0.0, 0.0), odometry)
        if k == 7:
            off = graph.add_loop_candidate(0, 7, (8.0, 0.0, 0.0), loop, inliers=90)
            first = graph.update()
    assert accepted(first) == [off]
    agreeing = [graph.add_loop_candidate(i, 8, (8.0 - i, 0.0, 0.0), loop, inliers=100)
                for i in (1, 2, 3)]
    result = graph.update()
    inc = result.incremental
    # Four candidates are too few for EM to resume from: the whole job
    # (the documented fall-back), which still lists what it changed.
    assert inc["solve"] == "batch" and "fewer candidates" in inc["reason"], inc
    assert (inc["new_poses"], inc["new_edges"], inc["new_candidates"]) == (1, 4, 3)
    assert [c["index"] for c in inc["changed"]] == [off]
    assert inc["changed"][0]["accepted"] is False
    assert inc["changed"][0]["reason"] in ("kernel", "inconsistent", "explains_chi2")
    assert_changed_lists_the_flips(result, first)
    assert accepted(result) == agreeing
    assert_same_as_batch(result, graph.optimize())


def g2o_steps(path):
    """The additions of a 2D g2o file in the order a front end makes them:
    each VERTEX_SE2 in file order, with the EDGE_SE2 lines whose later end
    it is (a trailing inlier count makes a loop candidate)."""
    vertices, edges = [], []
    for line in path.read_text().splitlines():
        t = line.split()
        if not t:
            continue
        if t[0] == "VERTEX_SE2":
            vertices.append((int(t[1]), tuple(float(x) for x in t[2:5])))
        elif t[0] == "EDGE_SE2":
            i, j = int(t[1]), int(t[2])
            meas = tuple(float(x) for x in t[3:6])
            info = symmetric([float(x) for x in t[6:12]], 3)
            inliers = int(t[12]) if len(t) > 12 else None
            edges.append((i, j, meas, info, inliers))
    order = {v: k for k, (v, _) in enumerate(vertices)}
    due = [[] for _ in vertices]
    for e in edges:
        due[max(order[e[0]], order[e[1]])].append(e)
    return [(v, pose, due[k]) for k, (v, pose) in enumerate(vertices)]


def replay(name, every=50):
    """Replays the sample `name` with an update every `every` poses (and
    after the last), checking each update's account of itself and that
    `changed` lists exactly the decisions that flipped; returns the graph,
    the last result, the kinds of solve and the number of changes."""
    steps = g2o_steps(SAMPLES / name)
    graph = pgo.PoseGraph(2)
    kinds, changes, previous = [], 0, None
    for k, step in enumerate(steps):
        add_step(graph, step)
        if (k + 1) % every != 0 and k + 1 != len(steps):
            continue
        result = graph.update()
        kinds.append((result.incremental["solve"], result.incremental["reason"]))
        assert result.incremental == result.report["incremental"]
        if previous is not None:
            assert_changed_lists_the_flips(result, previous)
        changes += len(result.incremental["changed"])
        previous = result
    # The whole job again only while the map is too young for EM to resume
    # from (too few candidates, no loop model yet), and once EM's decisions
    # were resumed only where they swung or, once per loop, where an
    # accepted loop lies beyond the information as stated (the batch job's
    # second start looks at it): the documented fall-backs.
    assert kinds[0][0] == "batch", kinds
    solves = [s for s, _ in kinds]
    assert "warm" in solves, kinds
    resumed = solves.index("warm")
    later = [why for s, why in kinds[resumed:] if s == "batch"]
    assert all("swung" in why or "calls an outlier" in why for why in later), kinds
    assert sum("calls an outlier" in why for why in later) <= 1, kinds
    return graph, previous, changes


def test_a_replay_of_the_aliased_sample_ends_with_the_batch_job():
    steps = g2o_steps(SAMPLES / "aliased.g2o")
    assert len(steps) == 800 and sum(len(s[2]) for s in steps) == 1059
    graph, last, _ = replay("aliased.g2o")
    assert graph.num_loop_candidates == len(last.loops) > 0
    assert_same_as_batch(last, graph.optimize())


def test_updates_that_change_earlier_decisions_list_them_and_end_with_the_batch_job():
    # On the grid2d sample later updates change some earlier decisions:
    # `changed` is checked against the flips on real changes.
    graph, last, changes = replay("grid2d.g2o")
    assert changes > 0
    assert_same_as_batch(last, graph.optimize())
