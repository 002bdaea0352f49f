//! The C API called as C calls it: every bad argument refused with its
//! status and a message, no panic across, and a graph built call by call
//! (or read) through it optimised to the same poses, decisions and χ² as
//! the library's own `AnyPoseGraph::optimize`.

use pgo::{AnyPoseGraph, AnySolution, Options};
use pgo_c::*;
use std::ffi::{CStr, CString, c_char};
use std::path::PathBuf;
use std::ptr;

const IDENTITY3: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

fn sample(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../g2o_samples")
        .join(name)
}

fn c_path(path: &std::path::Path) -> CString {
    CString::new(path.to_str().unwrap()).unwrap()
}

fn last_error() -> String {
    let p = pgo_last_error();
    assert!(!p.is_null());
    unsafe { CStr::from_ptr(p) }.to_str().unwrap().to_owned()
}

/// Asserts the status of a call and that the message holds `needle`.
fn assert_fails(status: PgoStatus, expected: PgoStatus, needle: &str) {
    assert_eq!(status, expected, "message: {}", last_error());
    let message = last_error();
    assert!(message.contains(needle), "{message:?} lacks {needle:?}");
}

fn ok(status: PgoStatus) {
    assert_eq!(status, PgoStatus::PgoOk, "{}", last_error());
}

fn new_graph(dim: i32) -> *mut PgoGraph {
    let mut g = ptr::null_mut();
    ok(unsafe { pgo_graph_new(dim, &mut g) });
    assert!(!g.is_null());
    g
}

/// A 2D chain 0 → 1 → 2 of unit steps.
fn chain() -> *mut PgoGraph {
    let g = new_graph(2);
    for k in 0..3u64 {
        ok(unsafe { pgo_graph_add_pose(g, k, [k as f64, 0.0, 0.0].as_ptr(), 3) });
    }
    for k in 1..3u64 {
        let z = [1.0, 0.0, 0.0];
        ok(unsafe { pgo_graph_add_edge(g, k - 1, k, z.as_ptr(), 3, IDENTITY3.as_ptr(), 9) });
    }
    g
}

#[test]
fn the_version_is_the_crates() {
    let v = unsafe { CStr::from_ptr(pgo_version()) };
    assert_eq!(v.to_str().unwrap(), env!("CARGO_PKG_VERSION"));
}

#[test]
fn null_pointers_are_refused_and_outputs_cleared() {
    unsafe {
        assert_fails(
            pgo_graph_new(2, ptr::null_mut()),
            PgoStatus::PgoErrInvalidArgument,
            "out is NULL",
        );
        let mut g = ptr::dangling_mut::<PgoGraph>();
        assert_fails(
            pgo_graph_read_g2o(ptr::null(), &mut g),
            PgoStatus::PgoErrInvalidArgument,
            "path is NULL",
        );
        assert!(g.is_null(), "a failed call leaves NULL at *out");
        let pose = [0.0; 3];
        assert_fails(
            pgo_graph_add_pose(ptr::null_mut(), 0, pose.as_ptr(), 3),
            PgoStatus::PgoErrInvalidArgument,
            "graph is NULL",
        );
        let g = chain();
        assert_fails(
            pgo_graph_add_pose(g, 7, ptr::null(), 3),
            PgoStatus::PgoErrInvalidArgument,
            "pose is NULL",
        );
        assert_fails(
            pgo_graph_add_edge(g, 0, 2, pose.as_ptr(), 3, ptr::null(), 9),
            PgoStatus::PgoErrInvalidArgument,
            "information is NULL",
        );
        assert_fails(
            pgo_graph_len(g, ptr::null_mut()),
            PgoStatus::PgoErrInvalidArgument,
            "out is NULL",
        );
        assert_fails(
            pgo_graph_write_g2o(g, ptr::null()),
            PgoStatus::PgoErrInvalidArgument,
            "path is NULL",
        );
        let mut r = ptr::dangling_mut::<PgoResult>();
        assert_fails(
            pgo_graph_optimize(ptr::null(), ptr::null(), &mut r),
            PgoStatus::PgoErrInvalidArgument,
            "graph is NULL",
        );
        assert!(r.is_null());
        assert_fails(
            pgo_options_set(ptr::null_mut(), c"alpha".as_ptr(), c"0.1".as_ptr()),
            PgoStatus::PgoErrInvalidArgument,
            "options is NULL",
        );
        let mut x = 0.0;
        assert_fails(
            pgo_result_chi2(ptr::null(), &mut x),
            PgoStatus::PgoErrInvalidArgument,
            "result is NULL",
        );
        assert!(pgo_result_loop_reason(ptr::null(), 0).is_null());
        assert!(pgo_result_report_json(ptr::null()).is_null());
        assert!(last_error().contains("result is NULL"));
        // Freeing NULL does nothing.
        pgo_graph_free(ptr::null_mut());
        pgo_options_free(ptr::null_mut());
        pgo_result_free(ptr::null_mut());
        pgo_graph_free(g);
    }
}

#[test]
fn a_graph_is_2d_or_3d() {
    for dim in [0, 1, 4, -1, i32::MIN] {
        let mut g = ptr::dangling_mut::<PgoGraph>();
        assert_fails(
            unsafe { pgo_graph_new(dim, &mut g) },
            PgoStatus::PgoErrDimension,
            "a pose graph is 2D or 3D",
        );
        assert!(g.is_null());
    }
    assert_eq!(
        last_error(),
        format!("a pose graph is 2D or 3D, not {}D", i32::MIN)
    );
    for dim in [2, 3] {
        let g = new_graph(dim);
        let (mut d, mut n) = (0, 1);
        ok(unsafe { pgo_graph_dim(g, &mut d) });
        ok(unsafe { pgo_graph_len(g, &mut n) });
        assert_eq!((d, n), (dim, 0));
        unsafe { pgo_graph_free(g) };
    }
}

#[test]
fn wrong_lengths_name_what_was_expected() {
    let g = chain();
    unsafe {
        let pose = [0.0; 7];
        assert_fails(
            pgo_graph_add_pose(g, 9, pose.as_ptr(), 2),
            PgoStatus::PgoErrLength,
            "pose: expected 3 numbers for a 2D graph, got 2",
        );
        assert_fails(
            pgo_graph_add_edge(g, 0, 2, pose.as_ptr(), 7, IDENTITY3.as_ptr(), 9),
            PgoStatus::PgoErrLength,
            "measurement: expected 3 numbers for a 2D graph, got 7",
        );
        assert_fails(
            pgo_graph_add_loop_candidate(
                g,
                0,
                2,
                pose.as_ptr(),
                3,
                IDENTITY3.as_ptr(),
                6,
                10,
                ptr::null_mut(),
            ),
            PgoStatus::PgoErrLength,
            "information: expected 9 numbers",
        );
        let g3 = new_graph(3);
        assert_fails(
            pgo_graph_add_pose(g3, 0, pose.as_ptr(), 3),
            PgoStatus::PgoErrLength,
            "expected 7 numbers for a 3D graph, got 3",
        );
        pgo_graph_free(g3);
        let mut n = 0;
        ok(pgo_graph_num_edges(g, &mut n));
        assert_eq!(n, 2, "refused edges are not added");
        pgo_graph_free(g);
    }
}

#[test]
fn numbers_that_are_no_pose_or_information_are_refused() {
    let g = chain();
    unsafe {
        let nan = [0.0, f64::NAN, 0.0];
        assert_fails(
            pgo_graph_add_pose(g, 5, nan.as_ptr(), 3),
            PgoStatus::PgoErrInvalidPose,
            "vertex 5: is not finite",
        );
        assert_fails(
            pgo_graph_add_edge(g, 0, 2, nan.as_ptr(), 3, IDENTITY3.as_ptr(), 9),
            PgoStatus::PgoErrInvalidPose,
            "measurement is not finite",
        );
        let mut info = IDENTITY3;
        info[4] = f64::INFINITY;
        let z = [2.0, 0.0, 0.0];
        assert_fails(
            pgo_graph_add_edge(g, 0, 2, z.as_ptr(), 3, info.as_ptr(), 9),
            PgoStatus::PgoErrInvalidInformation,
            "non-finite entry at (1, 1)",
        );
        let negative = [-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        assert_fails(
            pgo_graph_add_edge(g, 0, 2, z.as_ptr(), 3, negative.as_ptr(), 9),
            PgoStatus::PgoErrInvalidInformation,
            "not positive definite",
        );
        ok(pgo_graph_set_repair_information(g, true));
        ok(pgo_graph_add_edge(
            g,
            0,
            2,
            z.as_ptr(),
            3,
            negative.as_ptr(),
            9,
        ));
        pgo_graph_free(g);
    }
}

#[test]
fn vertices_must_exist_once_and_messages_name_them() {
    let g = chain();
    unsafe {
        let z = [1.0, 0.0, 0.0];
        assert_fails(
            pgo_graph_add_pose(g, 1, z.as_ptr(), 3),
            PgoStatus::PgoErrDuplicateVertex,
            "vertex 1 already exists",
        );
        assert_fails(
            pgo_graph_add_edge(g, 0, 42, z.as_ptr(), 3, IDENTITY3.as_ptr(), 9),
            PgoStatus::PgoErrUnknownVertex,
            "unknown vertex id 42",
        );
        assert_fails(
            pgo_graph_add_loop_candidate(
                g,
                2,
                2,
                z.as_ptr(),
                3,
                IDENTITY3.as_ptr(),
                9,
                5,
                ptr::null_mut(),
            ),
            PgoStatus::PgoErrSelfLoop,
            "edge from vertex 2 to itself",
        );
        assert_fails(
            pgo_graph_fix(g, 77),
            PgoStatus::PgoErrUnknownVertex,
            "unknown vertex id 77",
        );
        // The message stays until the next failure, whatever succeeds.
        ok(pgo_graph_fix(g, 0));
        assert!(last_error().contains("77"));
        let mut index = usize::MAX;
        ok(pgo_graph_add_loop_candidate(
            g,
            0,
            2,
            [2.0, 0.0, 0.0].as_ptr(),
            3,
            IDENTITY3.as_ptr(),
            9,
            -1,
            &mut index,
        ));
        assert_eq!(index, 2, "edges and candidates are numbered together");
        let mut r = ptr::null_mut();
        ok(pgo_graph_optimize(g, ptr::null(), &mut r));
        let mut out = [0.0; 3];
        assert_fails(
            pgo_result_pose(r, 3, out.as_mut_ptr(), 3),
            PgoStatus::PgoErrUnknownVertex,
            "unknown vertex id 3",
        );
        assert_fails(
            pgo_result_pose(r, 2, out.as_mut_ptr(), 7),
            PgoStatus::PgoErrLength,
            "pose: expected 3 numbers for a 2D graph, got 7",
        );
        ok(pgo_result_pose(r, 2, out.as_mut_ptr(), 3));
        assert!((out[0] - 2.0).abs() < 1e-9, "{out:?}");
        let mut d = PgoLoopDecision {
            index: 0,
            from: 0,
            to: 0,
            inliers: 0,
            gated: false,
            weight: 0.0,
            accepted: false,
            posterior: 0.0,
            innovation: 0.0,
        };
        ok(pgo_result_loop(r, 0, &mut d));
        assert_eq!((d.index, d.from, d.to, d.inliers), (2, 0, 2, -1));
        assert_fails(
            pgo_result_loop(r, 1, &mut d),
            PgoStatus::PgoErrInvalidArgument,
            "loop 1 out of range: the result has 1 loops",
        );
        assert!(pgo_result_loop_reason(r, 1).is_null());
        pgo_result_free(r);
        pgo_graph_free(g);
    }
}

#[test]
fn options_are_set_by_their_flag_names() {
    unsafe {
        let mut o = ptr::null_mut();
        ok(pgo_options_new(&mut o));
        assert_fails(
            pgo_options_set(o, c"no-such-flag".as_ptr(), c"1".as_ptr()),
            PgoStatus::PgoErrUnknownOption,
            "unknown option 'no-such-flag'",
        );
        assert!(
            last_error().contains("alpha"),
            "the message lists the options"
        );
        assert_fails(
            pgo_options_set(o, c"alpha".as_ptr(), c"2".as_ptr()),
            PgoStatus::PgoErrInvalidOption,
            "--alpha",
        );
        assert_fails(
            pgo_options_set(o, c"robust-c".as_ptr(), c"NaN".as_ptr()),
            PgoStatus::PgoErrInvalidOption,
            "--robust-c",
        );
        let not_utf8 = [0xffu8, 0];
        assert_fails(
            pgo_options_set(o, c"alpha".as_ptr(), not_utf8.as_ptr().cast::<c_char>()),
            PgoStatus::PgoErrInvalidArgument,
            "value is not UTF-8",
        );
        ok(pgo_options_set(o, c"max_iters".as_ptr(), c"3".as_ptr()));
        ok(pgo_options_set(o, c"robust".as_ptr(), c"none".as_ptr()));
        // The options reach the job: the same graph, the same options, in
        // the library, gives the same χ².
        let g = chain();
        let mut r = ptr::null_mut();
        ok(pgo_graph_optimize(g, o, &mut r));
        let mut options = Options::default();
        options.set("max-iters", "3").unwrap();
        options.set("robust", "none").unwrap();
        let mut chi2 = f64::NAN;
        ok(pgo_result_chi2(r, &mut chi2));
        let same = chain_in_rust().optimize(&options).unwrap();
        assert!(close(chi2, same.chi2()), "{chi2} vs {}", same.chi2());
        pgo_result_free(r);
        pgo_options_free(o);
        pgo_graph_free(g);
    }
}

fn chain_in_rust() -> AnyPoseGraph {
    let mut g = AnyPoseGraph::new(2).unwrap();
    for k in 0..3u64 {
        g.add_pose(k, &[k as f64, 0.0, 0.0]).unwrap();
    }
    for k in 1..3u64 {
        g.add_edge(k - 1, k, &[1.0, 0.0, 0.0], &IDENTITY3).unwrap();
    }
    g
}

#[test]
fn files_that_cannot_be_read_or_written_are_io_and_parse_errors() {
    unsafe {
        let mut g = ptr::null_mut();
        let missing = c"/nonexistent/pgo-capi/missing.g2o";
        assert_fails(
            pgo_graph_read_g2o(missing.as_ptr(), &mut g),
            PgoStatus::PgoErrIo,
            "missing.g2o",
        );
        let dir = std::env::temp_dir().join(format!("pgo-capi-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let bad = dir.join("bad.g2o");
        std::fs::write(&bad, "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 oops\n").unwrap();
        assert_fails(
            pgo_graph_read_g2o(c_path(&bad).as_ptr(), &mut g),
            PgoStatus::PgoErrParse,
            "bad.g2o:2",
        );
        assert!(g.is_null());
        let chain = chain();
        assert_fails(
            pgo_graph_write_g2o(chain, missing.as_ptr()),
            PgoStatus::PgoErrIo,
            "cannot write",
        );
        let copy = dir.join("chain.g2o");
        ok(pgo_graph_write_g2o(chain, c_path(&copy).as_ptr()));
        ok(pgo_graph_read_g2o(c_path(&copy).as_ptr(), &mut g));
        let mut n = 0;
        ok(pgo_graph_len(g, &mut n));
        assert_eq!(n, 3);
        let empty = new_graph(3);
        let mut r = ptr::null_mut();
        assert_fails(
            pgo_graph_optimize(empty, ptr::null(), &mut r),
            PgoStatus::PgoErrEmptyGraph,
            "no poses",
        );
        pgo_graph_free(empty);
        pgo_graph_free(g);
        pgo_graph_free(chain);
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn every_thread_has_its_own_last_error() {
    let g = chain() as usize;
    let other = std::thread::spawn(move || {
        let z = [0.0; 3];
        let s = unsafe { pgo_graph_add_pose(g as *mut PgoGraph, 0, z.as_ptr(), 3) };
        assert_eq!(s, PgoStatus::PgoErrDuplicateVertex);
        last_error()
    });
    let theirs = other.join().unwrap();
    assert_fails(
        unsafe { pgo_graph_fix(g as *mut PgoGraph, 99) },
        PgoStatus::PgoErrUnknownVertex,
        "99",
    );
    assert_eq!(theirs, "vertex 0 already exists");
    unsafe { pgo_graph_free(g as *mut PgoGraph) };
}

/// The numbers of a g2o line's fields from `start` on.
fn numbers(fields: &[&str]) -> Vec<f64> {
    fields.iter().map(|x| x.parse().unwrap()).collect()
}

/// The row-major `d × d` symmetric matrix whose upper triangle is `v`.
fn full(v: &[f64], d: usize) -> Vec<f64> {
    let mut m = vec![0.0; d * d];
    let mut k = 0;
    for r in 0..d {
        for c in r..d {
            (m[r * d + c], m[c * d + r]) = (v[k], v[k]);
            k += 1;
        }
    }
    m
}

/// A g2o sample added line by line through the C calls, as a C front
/// end would.
fn build_through_c(name: &str, dim: i32) -> *mut PgoGraph {
    let (n, d) = if dim == 2 { (3, 3) } else { (7, 6) };
    let g = new_graph(dim);
    for line in std::fs::read_to_string(sample(name)).unwrap().lines() {
        let t: Vec<&str> = line.split_whitespace().collect();
        let id = |k: usize| t[k].parse::<u64>().unwrap();
        if t[0].starts_with("VERTEX") {
            ok(unsafe { pgo_graph_add_pose(g, id(1), numbers(&t[2..]).as_ptr(), n) });
            continue;
        }
        let z = numbers(&t[3..3 + n]);
        let end = 3 + n + d * (d + 1) / 2;
        let info = full(&numbers(&t[3 + n..end]), d);
        let status = match t.get(end) {
            Some(inliers) => unsafe {
                let mut index = usize::MAX;
                let s = pgo_graph_add_loop_candidate(
                    g,
                    id(1),
                    id(2),
                    z.as_ptr(),
                    n,
                    info.as_ptr(),
                    d * d,
                    inliers.parse().unwrap(),
                    &mut index,
                );
                assert_ne!(index, usize::MAX);
                s
            },
            None => unsafe {
                pgo_graph_add_edge(g, id(1), id(2), z.as_ptr(), n, info.as_ptr(), d * d)
            },
        };
        ok(status);
    }
    g
}

/// Equal to 10⁻⁹ of their size (both NaN counts as equal). Not bit for
/// bit: in a release build two instances of the same graph, read from the
/// same file, optimise to poses a few ulps apart.
fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * b.abs().max(1.0) || (a.is_nan() && b.is_nan())
}

/// The C result holds the library's solution: the poses, the decisions,
/// χ², D² and the verdict.
fn assert_same(r: *const PgoResult, expected: &AnySolution, ids: &[u64]) {
    for &id in ids {
        let want = expected.pose(id).unwrap();
        let mut got = vec![f64::NAN; want.len()];
        ok(unsafe { pgo_result_pose(r, id, got.as_mut_ptr(), got.len()) });
        let same = got.iter().zip(&want).all(|(&a, &b)| close(a, b));
        assert!(same, "vertex {id}: {got:?} vs {want:?}");
    }
    let mut n = usize::MAX;
    ok(unsafe { pgo_result_num_loops(r, &mut n) });
    assert_eq!(n, expected.loops().len());
    let mut names = std::collections::HashMap::new();
    for (k, want) in expected.loops().iter().enumerate() {
        let mut got = PgoLoopDecision {
            index: 0,
            from: 0,
            to: 0,
            inliers: 0,
            gated: false,
            weight: f64::NAN,
            accepted: false,
            posterior: f64::NAN,
            innovation: f64::NAN,
        };
        ok(unsafe { pgo_result_loop(r, k, &mut got) });
        let mut want_c = PgoLoopDecision::from(want);
        assert!(
            close(got.weight, want_c.weight),
            "loop {k}: {got:?} vs {want_c:?}"
        );
        // NaN (none) on both sides, or the same number.
        for (a, b) in [
            (got.posterior, want_c.posterior),
            (got.innovation, want_c.innovation),
        ] {
            assert!(
                (a.is_nan() && b.is_nan()) || close(a, b),
                "loop {k}: {got:?} vs {want_c:?}"
            );
        }
        got.weight = want_c.weight;
        (got.posterior, got.innovation) = (0.0, 0.0);
        (want_c.posterior, want_c.innovation) = (0.0, 0.0);
        assert_eq!(got, want_c);
        let reason = unsafe { CStr::from_ptr(pgo_result_loop_reason(r, k)) };
        let debug = format!("{:?}", want.reason).to_lowercase();
        let name = reason.to_str().unwrap().replace('_', "");
        assert!(
            !name.is_empty() && debug.starts_with(&name),
            "{reason:?} for {debug}"
        );
        // One static string per name.
        let first = *names.entry(reason.to_owned()).or_insert(reason.as_ptr());
        assert_eq!(first, reason.as_ptr());
    }
    let (mut chi2, mut d2, mut verdict) = (f64::NAN, f64::NAN, 7);
    unsafe {
        ok(pgo_result_chi2(r, &mut chi2));
        ok(pgo_result_d2(r, &mut d2));
        ok(pgo_result_verdict(r, &mut verdict));
    }
    assert!(
        close(chi2, expected.chi2()),
        "{chi2} vs {}",
        expected.chi2()
    );
    assert!(close(d2, expected.d2().unwrap_or(f64::NAN)), "D² {d2}");
    assert_eq!(verdict, expected.passed().map_or(-1, i32::from));
}

/// Built through C, read through C, and read by the library: one job.
fn check_sample(name: &str, dim: i32) {
    let library = AnyPoseGraph::read_g2o(sample(name)).unwrap();
    let expected = library.optimize(&Options::default()).unwrap();
    let built = build_through_c(name, dim);
    let mut read = ptr::null_mut();
    ok(unsafe { pgo_graph_read_g2o(c_path(&sample(name)).as_ptr(), &mut read) });
    for g in [built, read] {
        let mut r = ptr::null_mut();
        ok(unsafe { pgo_graph_optimize(g, ptr::null(), &mut r) });
        assert_same(r, &expected, library.ids());
        let json = unsafe { pgo_result_report_json(r) };
        assert!(!json.is_null(), "{}", last_error());
        assert_eq!(
            json,
            unsafe { pgo_result_report_json(r) },
            "the result keeps its string"
        );
        let text = unsafe { CStr::from_ptr(json) }.to_str().unwrap();
        let report: serde_json::Value = serde_json::from_str(text).unwrap();
        assert!(report.is_object());
        unsafe {
            pgo_result_free(r);
            pgo_graph_free(g);
        }
    }
    // Decisions that went both ways, so that the comparison means something.
    let accepted = expected.loops().iter().filter(|d| d.accepted).count();
    assert!(accepted > 0 && accepted < expected.loops().len());
}

#[test]
fn a_planar_sample_through_c_is_the_librarys_job() {
    check_sample("grid2d.g2o", 2);
}

#[test]
fn a_spatial_sample_through_c_is_the_librarys_job() {
    check_sample("sphere3d.g2o", 3);
}
