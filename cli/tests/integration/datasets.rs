//! The public benchmark datasets (../shared/datasets or $PGO_DATASETS)
//! through the binary: no file makes `pgo` panic. (The optimum against g2o
//! and GTSAM, the quirks of MANIFEST.md, and datasets with wrong candidates
//! planted as `pgo corrupt` plants them are the library's tests/datasets.rs.)
//! Each test prints a reason and passes when the datasets are absent
//! (and fails when `CI` is `true`).

use crate::common::{datasets, pgo, stderr};

#[test]
fn no_file_in_the_datasets_makes_pgo_panic() {
    let Some(dir) = datasets() else { return };
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    names.sort();
    for path in names {
        let p = path.to_str().unwrap();
        let out = pgo(&["optimize", p, "--max-iters", "2", "--init", "file", "-q"]);
        let code = out.status.code();
        assert!(
            matches!(code, Some(0) | Some(2) | Some(3) | Some(4)),
            "{p}: exit {code:?}: {}",
            stderr(&out)
        );
        if code == Some(2) {
            assert!(stderr(&out).starts_with("error: "), "{p}: {}", stderr(&out));
        }
    }
}
