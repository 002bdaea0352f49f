//! The labels CSV: which edges of a graph are wrong loop candidates.

use pgo::{GraphPose, PoseGraph};

/// Writes which edges are wrong as CSV, `edge,from,to,wrong` (edge index in
/// the graph's order, the vertex ids, 1 for wrong and 0 otherwise), the
/// labels of `pgo simulate --labels` and `pgo corrupt --labels`.
///
/// ```
/// use pgo_sim::{simulate_planar, write_labels, SimulationOptions};
/// let sim = simulate_planar(&SimulationOptions { poses: 50, loops: 5, outliers: 2, ..Default::default() }).unwrap();
/// let mut csv = Vec::new();
/// write_labels(&sim.noisy, &sim.wrong, &mut csv).unwrap();
/// let text = String::from_utf8(csv).unwrap();
/// assert!(text.starts_with("edge,from,to,wrong\n0,"));
/// assert_eq!(text.lines().filter(|l| l.ends_with(",1")).count(), 2);
/// ```
pub fn write_labels<P: GraphPose<D>, const D: usize>(
    graph: &PoseGraph<P, D>,
    wrong: &[bool],
    w: &mut impl std::io::Write,
) -> std::io::Result<()> {
    writeln!(w, "edge,from,to,wrong")?;
    for (k, (e, wrong)) in graph.edges().zip(wrong).enumerate() {
        writeln!(w, "{k},{},{},{}", e.from, e.to, u8::from(*wrong))?;
    }
    Ok(())
}
