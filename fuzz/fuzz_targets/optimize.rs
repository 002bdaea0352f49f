//! `pgo optimize` on small graphs: read, gate, initialise, a few LM
//! iterations (robust rounds included), χ² test, report, atomic write, as
//! the command line does it (through `pgo::pipeline::run`). It must never
//! panic; when it succeeds the written file must read back with the same
//! vertices and edges, finite poses, and the JSON report must serialise;
//! when it fails it must not have written the output.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pgo::geometry::Pose;
use pgo::graph::AnyGraph;
use pgo::io::g2o::{ReadOptions, read};
use pgo::pipeline::{OptimizeConfig, run};
use std::path::PathBuf;

/// Inputs above this size are skipped: the target is about small graphs
/// (a few hundred lines at most), so that an execution stays fast.
const MAX_INPUT: usize = 8 << 10;

fn scratch() -> PathBuf {
    let base = if std::path::Path::new("/dev/shm").is_dir() {
        PathBuf::from("/dev/shm")
    } else {
        std::env::temp_dir()
    };
    let dir = base.join(format!("pgo-fuzz-optimize-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

fuzz_target!(|data: &[u8]| {
    if data.len() > MAX_INPUT {
        return;
    }
    let dir = scratch();
    let input = dir.join("in.g2o");
    let output = dir.join("out.g2o");
    std::fs::write(&input, data).expect("write the input");
    let _ = std::fs::remove_file(&output);
    // The first byte picks a few options, so that GN, the file's guess and
    // --fix-information get exercised too.
    let flags = data.first().copied().unwrap_or(0);
    let mut config = OptimizeConfig::new(&input);
    config.output = Some(output.clone());
    config.fix_information = flags & 1 != 0;
    config.solver.max_iterations = 3;
    config.solver.threads = 1;
    if flags & 2 != 0 {
        config.solver.method = pgo::solve::Method::GaussNewton;
    }
    if flags & 4 != 0 {
        config.initialization = pgo::solve::init::Initialization::File;
    }
    match run(&config, &mut |_: &pgo::solve::IterationRecord| {}) {
        Ok(report) => {
            serde_json::to_string(&report).expect("the report serialises");
            let back = read(
                &output,
                ReadOptions {
                    fix_information: config.fix_information,
                },
            )
            .unwrap_or_else(|e| panic!("the written graph does not read back: {e}"));
            let (vertices, edges, finite) = match &back.graph {
                AnyGraph::Planar(g) => (
                    g.num_vertices(),
                    g.edges.len(),
                    g.poses.iter().all(|p| p.is_finite()),
                ),
                AnyGraph::Spatial(g) => (
                    g.num_vertices(),
                    g.edges.len(),
                    g.poses.iter().all(|p| p.is_finite()),
                ),
            };
            assert_eq!((vertices, edges), (report.poses, report.edges));
            assert!(finite, "non-finite pose written");
        }
        Err(e) => {
            let message = e.to_string();
            assert!(!message.is_empty());
            assert!(
                !output.exists(),
                "failed run wrote {}: {message}",
                output.display()
            );
        }
    }
});
