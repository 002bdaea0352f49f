//! How much of a factorisation an incremental one would redo: a g2o file
//! replayed as `update()` grows it (poses in file order, each edge once both
//! its ends exist, a step every N poses), each step that factorises (one
//! that adds more than odometry to new poses) with its pattern ordered as an
//! update orders it (the last step's elimination order with the new poses
//! appended, while that costs little more fill than a fresh order). A step
//! changes `H` in the rows and columns of its new poses and of the old
//! poses its new edges reach; only the factor's panels on those blocks'
//! paths to the root of the elimination tree then change
//! (`BlockSystem::refactor_flops`), the rest keep their values. That is
//! the least an incremental factorisation (iSAM2's Bayes tree) redoes at
//! such a step, where every other pose keeps its linearisation point.
//!
//! `cargo run --release --features internals --example refactor_share --
//! FILE.g2o N [N ...]` prints, for each N: the steps that factorise, how many were
//! ordered afresh (all of their factor counts as redone), and the flops of
//! the changed paths summed over the steps as a share of the flops of
//! whole factorisations (pgo's insides, through the hidden
//! `pgo::internals` hook: no stability promise).
//!
//! With `--capped THETA[,THETA…]` it also measures, for each `THETA`, what
//! a capped update (`update-iters` 1) would redo if it kept each pose's
//! part of the factor until that pose had moved by more than `THETA` (the
//! largest component of its tangent-space move, metres and radians, as
//! iSAM2's relinearisation threshold, 0.1 by default, is read): the file is
//! replayed through `PoseGraph::update` capped at one iteration, and at
//! each step the changed blocks are the new poses, the old poses the new
//! edges reach, and every pose that moved by more than `THETA` since its
//! block was last counted as changed, with every pose an edge joins it to
//! (whose Jacobian, and so whose block of `H`, that move changes). Blocks refreshed only as ancestors on those paths
//! are still counted as stale, so the share is an upper bound.

use pgo::internals::{AnyGraph, Graph, Optimizer, ReadOptions, SolveSettings, read};
use pgo::{GraphPose, Options, PoseGraph};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        eprintln!("usage: refactor_share FILE.g2o N [N ...]");
        std::process::exit(2);
    };
    let mut every: Vec<usize> = Vec::new();
    let mut thresholds: Vec<Option<f64>> = vec![None];
    let mut rest = args[2..].iter();
    while let Some(a) = rest.next() {
        if a == "--capped" {
            let list = rest.next().map(String::as_str).unwrap_or("");
            thresholds.extend(list.split(',').filter_map(|t| t.parse().ok()).map(Some));
        } else if let Ok(n) = a.parse() {
            every.push(n);
        }
    }
    let file = match read(std::path::Path::new(path), ReadOptions::default()) {
        Ok(file) => file,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    for &n in &every {
        for &theta in &thresholds {
            let (steps, fresh, share) = match &file.graph {
                AnyGraph::Planar(g) => replay(g, n.max(1), theta),
                AnyGraph::Spatial(g) => replay(g, n.max(1), theta),
            };
            let how = match theta {
                None => String::new(),
                Some(t) => format!(" (capped, poses kept until they move by {t})"),
            };
            println!(
                "{path} every {n} poses{how}: {steps} steps factorise, {fresh} of them ordered \
                 afresh; the changed paths hold {:.1} % of the factorisations' flops",
                100.0 * share
            );
        }
    }
}

/// Steps, steps ordered afresh, and the flops of the changed paths over
/// those of whole factorisations, summed over the steps.
fn replay<P: GraphPose<D>, const D: usize>(
    full: &Graph<P, D>,
    every: usize,
    theta: Option<f64>,
) -> (usize, usize, f64) {
    let n = full.num_vertices();
    // The step at which each edge joins: once its later end exists.
    let mut edges: Vec<usize> = (0..full.edges.len()).collect();
    edges.sort_by_key(|&k| full.edges[k].from.max(full.edges[k].to));
    let mut graph = Graph::<P, D>::new();
    let mut ordering = Some(Default::default());
    let (mut next_edge, mut steps, mut fresh) = (0, 0, 0);
    let (mut redone, mut whole) = (0.0, 0.0);
    let mut last_positions: Vec<usize> = Vec::new();
    // The capped replay (with `theta`): its graph, options, and the pose of
    // each vertex when its block was last counted as changed.
    let mut capped = theta.map(|_| (PoseGraph::<P, D>::new(), Vec::<Option<P>>::new()));
    let mut options = Options::default();
    options.solver.update_iterations = Some(1);
    let ends = (every..n).step_by(every).chain(std::iter::once(n));
    // The graph at the last step that solved.
    let (mut old_vertices, mut old_edges) = (0, 0);
    for end in ends {
        for v in graph.num_vertices()..end {
            graph
                .add_vertex(full.id(v), full.poses[v])
                .expect("vertices of a file are distinct");
            if let Some((pg, _)) = &mut capped {
                pg.add_pose(full.id(v), full.poses[v]).expect("distinct");
            }
        }
        while next_edge < edges.len() {
            let e = &full.edges[edges[next_edge]];
            if e.from.max(e.to) >= end {
                break;
            }
            graph
                .add_edge(
                    full.id(e.from),
                    full.id(e.to),
                    e.measurement,
                    e.information,
                    None,
                )
                .expect("the ends were added");
            if let Some((pg, _)) = &mut capped {
                (pg.add_edge(full.id(e.from), full.id(e.to), e.measurement, e.information))
                    .expect("the ends were added");
            }
            next_edge += 1;
        }
        // The capped map after this step's update, by vertex index.
        let moved_to: Option<Vec<P>> = capped.as_mut().map(|(pg, _)| {
            let solution = pg.update(&options).expect("the replay's update solves");
            (0..graph.num_vertices())
                .map(|v| *solution.pose(full.id(v)).expect("every pose is in the map"))
                .collect()
        });
        // New poses each hung on the map by one edge (odometry to a new
        // keyframe): an update composes them and factorises nothing.
        if graph.edges.len() - old_edges <= graph.num_vertices() - old_vertices && old_edges > 0 {
            continue;
        }
        let Ok(optimizer) =
            Optimizer::with_ordering(&graph, None, SolveSettings::default(), ordering.clone())
        else {
            // A prefix not joined to its first pose yet: no factorisation.
            continue;
        };
        ordering = optimizer.ordering().cloned();
        let system = optimizer.system();
        // Variable blocks: the vertices other than the gauge, in order.
        let gauge = graph.gauge();
        let block_of = |v: usize| v - gauge.iter().filter(|&&g| g < v).count();
        let old_blocks = old_vertices.saturating_sub(gauge.len());
        let mut changed: Vec<usize> = (old_blocks..system.num_blocks()).collect();
        for e in &graph.edges[old_edges..] {
            for v in [e.from, e.to] {
                if v < old_vertices && !gauge.contains(&v) {
                    changed.push(block_of(v));
                }
            }
        }
        if let (Some((_, kept_at)), Some(now), Some(theta)) = (&mut capped, &moved_to, theta) {
            kept_at.resize(graph.num_vertices(), None);
            let is_block = |v: usize| !gauge.contains(&v);
            let mut moved = vec![false; graph.num_vertices()];
            for v in 0..old_vertices {
                if let Some(at) = kept_at[v] {
                    let d = P::error(&at, &now[v], &P::identity());
                    moved[v] = is_block(v) && d.amax() > theta;
                }
            }
            // An edge at a moved pose changes both its ends' Jacobians: the
            // diagonal block of `H` at its other end changes too.
            for e in &graph.edges {
                for (a, b) in [(e.from, e.to), (e.to, e.from)] {
                    if moved[a] && is_block(b) {
                        changed.push(block_of(b));
                    }
                }
            }
            changed.extend((0..old_vertices).filter(|&v| moved[v]).map(block_of));
            changed.sort_unstable();
            changed.dedup();
            for v in 0..graph.num_vertices() {
                if is_block(v) && (v >= old_vertices || changed.binary_search(&block_of(v)).is_ok())
                {
                    kept_at[v] = Some(now[v]);
                }
            }
        }
        let all = system.factor_stats().1;
        let positions = system.positions();
        let kept = old_blocks > 0
            && last_positions.len() >= old_blocks
            && positions[..old_blocks] == last_positions[..old_blocks];
        redone += if kept {
            system.refactor_flops(&changed)
        } else {
            fresh += 1;
            all
        };
        whole += all;
        steps += 1;
        last_positions = positions.to_vec();
        (old_vertices, old_edges) = (graph.num_vertices(), graph.edges.len());
    }
    (steps, fresh, redone / whole.max(f64::MIN_POSITIVE))
}
