//! `pgo optimize` on small graphs through the public API: read, gate,
//! initialise, a few LM iterations (robust rounds included), χ² test,
//! report, atomic write. It must never panic; when it succeeds the written
//! file must read back with the same vertices and edges, finite poses, and
//! the JSON report must serialise; when it fails it must not have written
//! the output.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pgo::{AnyPoseGraph, Initialization, Options, SolverMethod};
use std::path::{Path, PathBuf};

/// Inputs above this size are skipped: the target is about small graphs
/// (a few hundred lines at most), so that an execution stays fast.
const MAX_INPUT: usize = 8 << 10;

fn scratch() -> PathBuf {
    let base = if Path::new("/dev/shm").is_dir() {
        PathBuf::from("/dev/shm")
    } else {
        std::env::temp_dir()
    };
    let dir = base.join(format!("pgo-fuzz-optimize-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

/// The graph in `path`, repairing information matrices when `repair`.
fn read(path: &Path, repair: bool) -> Result<AnyPoseGraph, pgo::Error> {
    if repair {
        AnyPoseGraph::read_g2o_repairing(path)
    } else {
        AnyPoseGraph::read_g2o(path)
    }
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
    // the repair of information matrices get exercised too.
    let flags = data.first().copied().unwrap_or(0);
    let repair = flags & 1 != 0;
    let mut options = Options::default();
    options.solver.max_iterations = Some(3);
    options.solver.threads = 1;
    if flags & 2 != 0 {
        options.solver.method = SolverMethod::GaussNewton;
    }
    if flags & 4 != 0 {
        options.solver.init = Initialization::File;
    }
    let run = read(&input, repair)
        .and_then(|graph| graph.optimize(&options))
        .and_then(|solution| solution.write_g2o(&output).map(|()| solution));
    match run {
        Ok(solution) => {
            let report = solution.report();
            serde_json::to_string(report).expect("the report serialises");
            let back = read(&output, repair)
                .unwrap_or_else(|e| panic!("the written graph does not read back: {e}"));
            assert_eq!((back.len(), back.num_edges()), (report.poses, report.edges));
            let finite = back.ids().iter().all(|&id| {
                back.pose(id)
                    .is_some_and(|p| p.iter().all(|v| v.is_finite()))
            });
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
