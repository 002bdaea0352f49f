//! Writing what the job found from C: `pgo_result_write_g2o` (the
//! optimised map), `pgo_result_write_tum` and `pgo_result_write_kitti`
//! (the trajectory as evo reads it), after listing a file's pose ids with
//! `pgo_graph_ids`; `pgo_result_write_plots` (the pictures).

use pgo::AnyPoseGraph;
use pgo_c::*;
use std::ffi::{CStr, CString};
use std::path::{Path, PathBuf};
use std::ptr;

fn sample(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../g2o_samples")
        .join(name)
}

fn c_path(path: &Path) -> CString {
    CString::new(path.to_str().unwrap()).unwrap()
}

fn last_error() -> String {
    let p = pgo_last_error();
    assert!(!p.is_null());
    unsafe { CStr::from_ptr(p) }.to_str().unwrap().to_owned()
}

fn ok(status: PgoStatus) {
    assert_eq!(status, PgoStatus::PgoOk, "{}", last_error());
}

fn assert_fails(status: PgoStatus, expected: PgoStatus, needle: &str) {
    assert_eq!(status, expected, "message: {}", last_error());
    let message = last_error();
    assert!(message.contains(needle), "{message:?} lacks {needle:?}");
}

/// A fresh temporary directory, removed when dropped.
fn temp_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("pgo-capi-{name}-"))
        .tempdir()
        .unwrap()
}

/// The numbers of each line of a file.
fn numbers(path: &Path) -> Vec<Vec<f64>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
        .collect()
}

/// The graph read from `path` and its job's result, with the default
/// options (free them with `pgo_graph_free` and `pgo_result_free`).
unsafe fn optimised(path: &Path) -> (*mut PgoGraph, *mut PgoResult) {
    let mut g = ptr::null_mut();
    let mut r = ptr::null_mut();
    unsafe {
        ok(pgo_graph_read_g2o(c_path(path).as_ptr(), &mut g));
        ok(pgo_graph_optimize(g, ptr::null(), &mut r));
    }
    (g, r)
}

#[test]
fn a_file_s_map_and_trajectories_are_written_by_its_ids() {
    let scratch = temp_dir("outputs");
    let dir = scratch.path();
    unsafe {
        for (name, width) in [("grid2d.g2o", 3), ("sphere3d.g2o", 7)] {
            let mut g = ptr::null_mut();
            ok(pgo_graph_read_g2o(c_path(&sample(name)).as_ptr(), &mut g));
            let mut n = 0;
            ok(pgo_graph_len(g, &mut n));
            let mut ids = vec![0u64; n];
            ok(pgo_graph_ids(g, ids.as_mut_ptr(), n));
            let mut r = ptr::null_mut();
            ok(pgo_graph_optimize(g, ptr::null(), &mut r));
            let (g2o, tum, kitti) = (
                dir.join("map.g2o"),
                dir.join("map.tum"),
                dir.join("map.kitti"),
            );
            ok(pgo_result_write_g2o(r, c_path(&g2o).as_ptr()));
            ok(pgo_result_write_tum(r, c_path(&tum).as_ptr()));
            ok(pgo_result_write_kitti(r, c_path(&kitti).as_ptr()));
            // The map: every pose as pgo_result_pose gives it, to the bit,
            // in the file's order.
            let map = AnyPoseGraph::read_g2o(&g2o).unwrap();
            assert_eq!(map.ids(), ids, "{name}");
            let mut pose = vec![0.0; width];
            for &id in &ids {
                ok(pgo_result_pose(r, id, pose.as_mut_ptr(), width));
                assert_eq!(map.pose(id).unwrap(), pose, "{name} pose {id}");
            }
            // TUM: the ids as timestamps and the translations; KITTI: one
            // line per pose, its translation in the last column.
            let (tum, kitti) = (numbers(&tum), numbers(&kitti));
            assert_eq!((tum.len(), kitti.len()), (n, n), "{name}");
            for ((&id, t), k) in ids.iter().zip(&tum).zip(&kitti) {
                ok(pgo_result_pose(r, id, pose.as_mut_ptr(), width));
                let z = if width == 3 { 0.0 } else { pose[2] };
                assert_eq!(t[..4], [id as f64, pose[0], pose[1], z], "{name} pose {id}");
                assert_eq!(
                    [k[3], k[7], k[11]],
                    [pose[0], pose[1], z],
                    "{name} pose {id}"
                );
            }
            pgo_result_free(r);
            pgo_graph_free(g);
        }
    }
}

#[test]
fn a_graph_built_in_memory_writes_its_map() {
    let scratch = temp_dir("outputs-memory");
    let dir = scratch.path();
    unsafe {
        let mut g = ptr::null_mut();
        ok(pgo_graph_new(2, &mut g));
        let info = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        for k in 0..3u64 {
            ok(pgo_graph_add_pose(g, k, [0.0, 0.0, 0.0].as_ptr(), 3));
        }
        for k in 1..3u64 {
            let z = [1.0, 0.0, 0.0];
            ok(pgo_graph_add_edge(
                g,
                k - 1,
                k,
                z.as_ptr(),
                3,
                info.as_ptr(),
                9,
            ));
        }
        let mut r = ptr::null_mut();
        ok(pgo_graph_optimize(g, ptr::null(), &mut r));
        let path = dir.join("map.g2o");
        ok(pgo_result_write_g2o(r, c_path(&path).as_ptr()));
        let map = AnyPoseGraph::read_g2o(&path).unwrap();
        assert_eq!(map.ids(), [0, 1, 2]);
        assert!((map.pose(2).unwrap()[0] - 2.0).abs() < 1e-9);
        assert_eq!(map.num_edges(), 2);
        ok(pgo_result_write_kitti(
            r,
            c_path(&dir.join("map.kitti")).as_ptr(),
        ));
        let kitti = numbers(&dir.join("map.kitti"));
        assert_eq!(
            kitti[0],
            [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        );
        pgo_result_free(r);
        pgo_graph_free(g);
    }
}

#[test]
fn bad_paths_and_results_are_refused_and_leave_nothing() {
    let scratch = temp_dir("outputs-bad");
    let dir = scratch.path();
    unsafe {
        let (g, r) = optimised(&sample("grid2d.g2o"));
        let writers: [(&str, unsafe extern "C" fn(_, _) -> _); 3] = [
            ("g2o", pgo_result_write_g2o),
            ("tum", pgo_result_write_tum),
            ("kitti", pgo_result_write_kitti),
        ];
        let missing = dir.join("missing").join("out.txt");
        for (name, write) in writers {
            assert_fails(
                write(r, c_path(&missing).as_ptr()),
                PgoStatus::PgoErrIo,
                &format!("{}: cannot write", missing.display()),
            );
            assert!(!dir.join("missing").exists(), "{name}");
            // A directory is no file: refused and left as it was.
            assert_fails(
                write(r, c_path(dir).as_ptr()),
                PgoStatus::PgoErrIo,
                "directory",
            );
            assert_fails(
                write(r, ptr::null()),
                PgoStatus::PgoErrInvalidArgument,
                "path is NULL",
            );
            assert_fails(
                write(ptr::null(), c_path(&missing).as_ptr()),
                PgoStatus::PgoErrInvalidArgument,
                "result is NULL",
            );
        }
        assert_eq!(std::fs::read_dir(dir).unwrap().count(), 0);
        pgo_result_free(r);
        pgo_graph_free(g);
    }
}

#[test]
fn the_pictures_of_a_file_are_written_into_a_directory_made_for_them() {
    let scratch = temp_dir("plots");
    let dir = scratch.path();
    unsafe {
        let (g, r) = optimised(&sample("grid2d.g2o"));
        let pictures = dir.join("made").join("pictures");
        ok(pgo_result_write_plots(r, c_path(&pictures).as_ptr()));
        let mut names: Vec<String> = std::fs::read_dir(&pictures)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["counts.svg", "loops.svg", "trajectory.svg"]);
        for name in &names {
            let svg = std::fs::read_to_string(pictures.join(name)).unwrap();
            assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        }
        let trajectory = std::fs::read_to_string(pictures.join("trajectory.svg")).unwrap();
        assert!(trajectory.contains("grid2d.g2o"));
        // A file where the directory should be: refused, left as it was.
        let file = dir.join("a-file");
        std::fs::write(&file, "x").unwrap();
        let below = file.join("pictures");
        assert_fails(
            pgo_result_write_plots(r, c_path(&below).as_ptr()),
            PgoStatus::PgoErrIo,
            &format!("{}: cannot write", below.display()),
        );
        assert_fails(
            pgo_result_write_plots(r, c_path(&file).as_ptr()),
            PgoStatus::PgoErrIo,
            "a-file",
        );
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "x");
        assert_fails(
            pgo_result_write_plots(r, ptr::null()),
            PgoStatus::PgoErrInvalidArgument,
            "dir is NULL",
        );
        assert_fails(
            pgo_result_write_plots(ptr::null(), c_path(&pictures).as_ptr()),
            PgoStatus::PgoErrInvalidArgument,
            "result is NULL",
        );
        pgo_result_free(r);
        pgo_graph_free(g);
    }
}
