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

use pgo::Pose;
use pgo::internals::{AnyGraph, Graph, Optimizer, ReadOptions, SolveSettings, read};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        eprintln!("usage: refactor_share FILE.g2o N [N ...]");
        std::process::exit(2);
    };
    let every: Vec<usize> = args[2..].iter().filter_map(|s| s.parse().ok()).collect();
    let file = match read(std::path::Path::new(path), ReadOptions::default()) {
        Ok(file) => file,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    for &n in &every {
        let (steps, fresh, share) = match &file.graph {
            AnyGraph::Planar(g) => replay(g, n.max(1)),
            AnyGraph::Spatial(g) => replay(g, n.max(1)),
        };
        println!(
            "{path} every {n} poses: {steps} steps factorise, {fresh} of them ordered afresh; \
             the changed paths hold {:.1} % of the factorisations' flops",
            100.0 * share
        );
    }
}

/// Steps, steps ordered afresh, and the flops of the changed paths over
/// those of whole factorisations, summed over the steps.
fn replay<P: Pose<D>, const D: usize>(full: &Graph<P, D>, every: usize) -> (usize, usize, f64) {
    let n = full.num_vertices();
    // The step at which each edge joins: once its later end exists.
    let mut edges: Vec<usize> = (0..full.edges.len()).collect();
    edges.sort_by_key(|&k| full.edges[k].from.max(full.edges[k].to));
    let mut graph = Graph::<P, D>::new();
    let mut ordering = Some(Default::default());
    let (mut next_edge, mut steps, mut fresh) = (0, 0, 0);
    let (mut redone, mut whole) = (0.0, 0.0);
    let mut last_positions: Vec<usize> = Vec::new();
    let ends = (every..n).step_by(every).chain(std::iter::once(n));
    // The graph at the last step that solved.
    let (mut old_vertices, mut old_edges) = (0, 0);
    for end in ends {
        for v in graph.num_vertices()..end {
            graph
                .add_vertex(full.id(v), full.poses[v])
                .expect("vertices of a file are distinct");
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
            next_edge += 1;
        }
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
