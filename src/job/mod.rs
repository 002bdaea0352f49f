//! The job on a graph in memory, in the order the data flows: gate →
//! initialise → optimise (robustly) → test → report. [`run`] is the whole
//! job ([`crate::PoseGraph::optimize`]); [`incremental`] resumes it from
//! the last update's state ([`crate::PoseGraph::update`]).

mod candidates;
mod finish;
#[cfg(test)]
pub(crate) use finish::chi2_test;
mod incremental;

pub(crate) use incremental::{Updated, Warm, update};

use crate::error::Error;
use crate::gate::MixtureOptions;
use crate::graph::Graph;
use crate::io::g2o::G2oPose;
use crate::options::Options;
use crate::report::Report;
use crate::robust::{self, RobustMethod, Test};
use crate::solve::init::{ChordalInit, Initialization};
use crate::solve::{Observer, Optimizer, Session, SolveSettings};
use std::time::Instant;

/// What a job is told ([`Options`]) and what follows from it for the
/// solver and the gate's mixture fit.
#[derive(Clone, Debug)]
pub(crate) struct Settings<'a> {
    /// The caller's options.
    pub options: &'a Options,
    /// Each solve's method, bounds and tolerances.
    pub solver: SolveSettings,
    /// The gate's mixture fit.
    pub mixture: MixtureOptions,
}

impl<'a> Settings<'a> {
    /// The settings of a job run with `options`.
    pub fn new(options: &'a Options) -> Self {
        let defaults = SolveSettings::default();
        Self {
            options,
            solver: SolveSettings {
                method: options.solver.method,
                max_iterations: options
                    .solver
                    .max_iterations
                    .unwrap_or(defaults.max_iterations),
                time_limit: options.solver.time_limit,
                threads: options.solver.threads,
                ..defaults
            },
            mixture: MixtureOptions::default(),
        }
    }
}

/// The job on a graph in memory: gate → initial guess → robust solve → χ²
/// test → report. `missing` lists the vertices the file did not define.
/// Returns the initial guess (the poses the solve started from).
pub(crate) fn run<P: G2oPose<D> + ChordalInit<D>, const D: usize>(
    graph: &mut Graph<P, D>,
    missing: &[usize],
    config: &Settings<'_>,
    report: &mut Report,
    observer: &mut dyn Observer,
) -> Result<Vec<P>, Error> {
    let solve_error = Error::from;
    // Which edges are loop candidates, and what the gate makes of them.
    candidates::mark(graph, config.options.gate.candidates);
    let gating = Instant::now();
    let candidates = candidates::gate(graph, config, report);
    report.time.gate_s = gating.elapsed().as_secs_f64();
    let method = if candidates.iter().any(|c| c.kept) {
        config.options.robust.method
    } else {
        RobustMethod::None
    };

    // The initial guess, from the trusted edges (and the candidates that
    // alone join parts of the map), before any candidate is weighed.
    let mut weights = candidates::initial_weights(graph, &candidates, method == RobustMethod::None);
    let mut optimizer =
        Optimizer::new(graph, Some(&weights), config.solver.clone()).map_err(solve_error)?;
    let start = Instant::now();
    let given = finish::initialize(graph, missing, config, &weights, report, start)?;
    report.time.initialize_s = report.initialization.time_s;
    let initial = graph.poses.clone();

    // The robust solve within the budget, the χ² test of its map, the report.
    let solving = Instant::now();
    let chordal = config.options.solver.init == Initialization::Chordal;
    let weigh =
        |session: &mut Session<'_, P, D>, weights: &mut [f64], c: f64, test: &Test<'_, P, D>| {
            let job = robust::Job {
                candidates: &candidates,
                method,
                c,
                layers: &config.options.expert.layers,
                test,
                chordal,
                given: Some(&given),
            };
            robust::solve(session, weights, &job)
        };
    let run = finish::Run {
        config,
        solver: config.solver.clone(),
        candidates: &candidates,
        method,
    };
    run.solve_and_test(graph, &mut optimizer, &mut weights, weigh, report, observer)?;
    report.time.solve_s = solving.elapsed().as_secs_f64();
    Ok(initial)
}
