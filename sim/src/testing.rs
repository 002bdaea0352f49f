//! The unit tests' view of the simulator: the simulations and corruption
//! in working graphs (poses and edges by index, as the steps see them),
//! under the names of the public functions, and what the tests measure on
//! them.

use crate::graph::{Edge, Graph};
use crate::{CorruptionOptions, ErrorCoordinates, SimulationError, SimulationOptions};
use pgo::{Pose, Se2, Se3};
use rand::Rng;

pub(crate) use crate::Simulated as Simulation;
pub(crate) use crate::simulate_planar_graphs as simulate_planar;
pub(crate) use crate::simulate_spatial_graphs as simulate_spatial;

impl<P, const D: usize> Simulation<P, D> {
    /// Number of planted wrong loops.
    pub(crate) fn num_wrong(&self) -> usize {
        self.wrong.iter().filter(|&&w| w).count()
    }
}

/// A simulation of either dimension in working graphs.
pub(crate) enum AnySimulation {
    Planar(Simulation<Se2, 3>),
    Spatial(Simulation<Se3, 6>),
}

/// [`crate::simulate`] in working graphs.
pub(crate) fn simulate(options: &SimulationOptions) -> Result<AnySimulation, SimulationError> {
    if options.world.is_planar() {
        simulate_planar(options).map(AnySimulation::Planar)
    } else {
        simulate_spatial(options).map(AnySimulation::Spatial)
    }
}

/// What [`corrupt`] says besides the corrupted graph.
#[derive(Debug, PartialEq)]
pub(crate) struct Corruption {
    pub(crate) wrong: Vec<bool>,
    pub(crate) marked: usize,
}

/// [`crate::corrupt`] of a working graph, in place.
pub(crate) fn corrupt<P: ErrorCoordinates<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    options: &CorruptionOptions,
    rng: &mut impl Rng,
) -> Result<Corruption, SimulationError> {
    crate::corrupt_graph(graph, options, rng).map(|(wrong, marked)| Corruption { wrong, marked })
}

impl<P: Pose<D>, const D: usize> Graph<P, D> {
    /// The error of one edge at the graph's poses.
    pub(crate) fn edge_error(&self, edge: &Edge<P, D>) -> nalgebra::SVector<f64, D> {
        P::error(
            &self.poses[edge.from],
            &self.poses[edge.to],
            &edge.measurement,
        )
    }

    /// `eᵀΩe` of one edge at the graph's poses.
    pub(crate) fn edge_chi2(&self, edge: &Edge<P, D>) -> f64 {
        let e = self.edge_error(edge);
        e.dot(&(edge.information * e))
    }

    /// `Σ eᵀΩe` over all edges.
    pub(crate) fn chi2(&self) -> f64 {
        self.edges.iter().map(|e| self.edge_chi2(e)).sum()
    }

    /// Whether every vertex is joined to the first by a chain of edges.
    pub(crate) fn is_connected(&self) -> bool {
        let n = self.poses.len();
        let mut seen = vec![false; n];
        let mut stack = vec![0];
        let mut next: Vec<Vec<usize>> = vec![Vec::new(); n];
        for e in &self.edges {
            next[e.from].push(e.to);
            next[e.to].push(e.from);
        }
        while let Some(v) = stack.pop() {
            if !std::mem::replace(&mut seen[v], true) {
                stack.extend(&next[v]);
            }
        }
        seen.iter().all(|&s| s)
    }
}
