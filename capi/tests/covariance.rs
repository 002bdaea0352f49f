//! The covariances through the C API: the library's numbers, row by row,
//! into the caller's buffers; lengths, NULLs and ids refused with their
//! status.

use pgo::{AnyPoseGraph, Options};
use pgo_c::*;
use std::ffi::{CStr, CString};
use std::ptr;

fn last_error() -> String {
    unsafe { CStr::from_ptr(pgo_last_error()) }
        .to_str()
        .unwrap()
        .to_owned()
}

fn ok(status: PgoStatus) {
    assert_eq!(status, PgoStatus::PgoOk, "{}", last_error());
}

fn assert_fails(status: PgoStatus, expected: PgoStatus, needle: &str) {
    assert_eq!(status, expected, "message: {}", last_error());
    assert!(
        last_error().contains(needle),
        "{:?} lacks {needle:?}",
        last_error()
    );
}

/// The result of the 3D sample through the C API, and the library's
/// covariances of the same job.
fn sphere() -> (*mut PgoResult, pgo::AnyCovariances) {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../g2o_samples/sphere3d.g2o");
    let c_path = CString::new(path).unwrap();
    let mut graph = ptr::null_mut();
    let mut result = ptr::null_mut();
    unsafe {
        ok(pgo_graph_read_g2o(c_path.as_ptr(), &mut graph));
        ok(pgo_graph_optimize(graph, ptr::null(), &mut result));
        pgo_graph_free(graph);
    }
    let library = AnyPoseGraph::read_g2o(path).unwrap();
    let covariances = library
        .optimize(&Options::default())
        .unwrap()
        .covariances()
        .unwrap();
    (result, covariances)
}

/// `got` is `want` to 10⁻⁹ of `√(σ_r²·σ_c²)` (`n × n`, row by row).
fn assert_close(got: &[f64], want: &[f64], n: usize) {
    for r in 0..n {
        for c in 0..n {
            let scale = (want[r * n + r] * want[c * n + c]).sqrt();
            let (g, w) = (got[r * n + c], want[r * n + c]);
            assert!((g - w).abs() <= 1e-9 * scale, "({r}, {c}): {g} vs {w}");
        }
    }
}

#[test]
fn the_c_api_writes_the_library_s_covariances() {
    let (result, library) = sphere();
    unsafe {
        let mut one = [0.0; 36];
        ok(pgo_result_covariance(result, 40, one.as_mut_ptr(), 36));
        assert_close(&one, &library.pose(40).unwrap(), 6);
        let ids = [40u64, 0, 7];
        let mut three = [0.0; 108];
        ok(pgo_result_covariances(
            result,
            ids.as_ptr(),
            3,
            three.as_mut_ptr(),
            108,
        ));
        assert_eq!(three[..36], one);
        assert!(three[36..72].iter().all(|&v| v == 0.0), "the fixed pose");
        assert_close(&three[72..], &library.pose(7).unwrap(), 6);
        let mut joint = [0.0; 144];
        ok(pgo_result_joint_covariance(
            result,
            7,
            300,
            joint.as_mut_ptr(),
            144,
        ));
        assert_close(&joint, &library.joint(7, 300).unwrap(), 12);
        let mut relative = [0.0; 36];
        ok(pgo_result_relative_covariance(
            result,
            7,
            300,
            relative.as_mut_ptr(),
            36,
        ));
        assert_close(&relative, &library.relative(7, 300).unwrap(), 6);
        ok(pgo_result_covariances(
            result,
            ptr::null(),
            0,
            three.as_mut_ptr(),
            0,
        ));
        pgo_result_free(result);
    }
}

#[test]
fn bad_arguments_are_refused_with_their_status() {
    let (result, _) = sphere();
    let mut buffer = [0.0; 144];
    let out = buffer.as_mut_ptr();
    unsafe {
        assert_fails(
            pgo_result_covariance(result, 40, out, 9),
            PgoStatus::PgoErrLength,
            "expected a buffer of 36 numbers, got 9",
        );
        assert_fails(
            pgo_result_joint_covariance(result, 4, 5, out, 36),
            PgoStatus::PgoErrLength,
            "expected a buffer of 144 numbers",
        );
        assert_fails(
            pgo_result_covariance(result, 123456, out, 36),
            PgoStatus::PgoErrUnknownVertex,
            "unknown vertex id 123456",
        );
        assert_fails(
            pgo_result_relative_covariance(result, 1, 123456, out, 36),
            PgoStatus::PgoErrUnknownVertex,
            "123456",
        );
        assert_fails(
            pgo_result_covariance(result, 40, ptr::null_mut(), 36),
            PgoStatus::PgoErrInvalidArgument,
            "out is NULL",
        );
        assert_fails(
            pgo_result_covariance(ptr::null(), 40, out, 36),
            PgoStatus::PgoErrInvalidArgument,
            "result is NULL",
        );
        assert_fails(
            pgo_result_covariances(result, ptr::null(), 2, out, 72),
            PgoStatus::PgoErrInvalidArgument,
            "ids is NULL",
        );
        // An unknown id among several: nothing is written.
        let ids = [40u64, 99999];
        buffer.fill(-1.0);
        assert_fails(
            pgo_result_covariances(result, ids.as_ptr(), 2, out, 72),
            PgoStatus::PgoErrUnknownVertex,
            "99999",
        );
        assert!(buffer.iter().all(|&v| v == -1.0));
        pgo_result_free(result);
    }
}
