//! Hostile inputs, through the binary: every case either fails with exit
//! status 2 and a message naming the file, the line and the problem, or
//! does what the README's "Hostile input" table says, with exit status 0.
//! None may panic. (Parser details live in the unit tests of `io::g2o`; this
//! is what a user of the command line sees.)

use crate::common::{pgo, stderr, temp_dir, verdict_status};
use std::path::{Path, PathBuf};
use std::process::Output;

const V3: &str = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n";
const E3: &str = "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n";
const SE3_V: &str = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n";
/// The 21 upper-triangle entries of the 6×6 identity.
const I6: &str = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1";

/// Writes `bytes` to `dir/name` and returns the path as a string.
fn file(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> String {
    let p = dir.join(name);
    std::fs::write(&p, bytes).expect("write test file");
    p.to_string_lossy().into_owned()
}

/// Fails if the run panicked (exit status 101 or a panic message).
fn assert_no_panic(out: &Output, what: &str) {
    let err = stderr(out);
    assert!(
        out.status.code() != Some(101) && !err.contains("panicked"),
        "{what}: panicked: {err}"
    );
    assert!(out.status.code().is_some(), "{what}: killed by a signal");
}

/// `pgo optimize PATH -o OUT ARGS…`: the run must fail with status 2, name
/// `name:line:` (or `name:` when `line` is `None`) and `problem`, and write
/// nothing.
fn assert_rejected(dir: &Path, path: &str, args: &[&str], line: Option<usize>, problem: &str) {
    let out_path = dir.join("never-written.g2o");
    let mut all = vec![
        "optimize",
        path,
        "-o",
        out_path.to_str().expect("utf-8 path"),
    ];
    all.extend_from_slice(args);
    let out = pgo(&all);
    assert_no_panic(&out, path);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{path}: {err}");
    let name = Path::new(path)
        .file_name()
        .expect("file name")
        .to_string_lossy()
        .into_owned();
    let place = match line {
        Some(l) => format!("{name}:{l}: "),
        None => format!("{name}: "),
    };
    assert!(err.contains(&place), "{path}: expected '{place}' in: {err}");
    assert!(
        err.contains(problem),
        "{path}: expected '{problem}' in: {err}"
    );
    assert!(!out_path.exists(), "{path}: a failed run wrote its output");
}

/// `pgo optimize PATH --json -o OUT ARGS…` must succeed; returns the report
/// and the output text.
fn accepted(dir: &Path, path: &str, args: &[&str]) -> (serde_json::Value, String) {
    let out_path: PathBuf = dir.join(format!(
        "{}.out.g2o",
        Path::new(path).file_name().expect("name").to_string_lossy()
    ));
    let mut all = vec![
        "optimize",
        path,
        "--json",
        "-o",
        out_path.to_str().expect("utf-8 path"),
    ];
    all.extend_from_slice(args);
    let out = pgo(&all);
    assert_no_panic(&out, path);
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON report");
    let status = verdict_status(&report);
    assert_eq!(out.status.code(), Some(status), "{path}: {}", stderr(&out));
    let text = std::fs::read_to_string(&out_path).expect("output written");
    (report, text)
}

#[test]
fn empty_and_comment_only_files_say_there_is_no_pose_graph() {
    let dir = temp_dir("hostile-empty");
    let empty = file(&dir, "empty.g2o", "");
    assert_rejected(&dir, &empty, &[], None, "no VERTEX_SE2, EDGE_SE2");
    assert_rejected(&dir, &empty, &[], None, "in 0 lines");
    let comments = file(&dir, "comments.g2o", "# a pose graph\n\n   # indented\n");
    assert_rejected(&dir, &comments, &[], None, "in 3 lines");
}

#[test]
fn a_line_of_10_mb_is_rejected_by_number_without_reading_it_whole() {
    let dir = temp_dir("hostile-long");
    let long = format!("{V3}# {}\n{E3}", "x".repeat(10 << 20));
    let path = file(&dir, "long.g2o", long);
    assert_rejected(&dir, &path, &[], Some(4), "line is longer than 65536 bytes");
    // A 10 MB line without any newline at all, too.
    let path = file(&dir, "one-line.g2o", "7".repeat(10 << 20));
    assert_rejected(&dir, &path, &[], Some(1), "line is longer than 65536 bytes");
}

#[test]
fn binary_garbage_is_not_text_or_has_no_pose_graph() {
    let dir = temp_dir("hostile-binary");
    // A PNG header: not UTF-8 on line 1.
    let png = b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\x01\0";
    let path = file(&dir, "picture.g2o", png);
    assert_rejected(&dir, &path, &[], Some(1), "not UTF-8 text");
    // Pseudo-random bytes (a fixed LCG), and the same after a valid prefix:
    // the error names the first line that is not text.
    let mut x: u64 = 0x2545_f491_4f6c_dd1d;
    let noise: Vec<u8> = (0..200_000)
        .map(|_| {
            x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (x >> 56) as u8
        })
        .collect();
    let path = file(&dir, "noise.g2o", [V3.as_bytes(), &noise].concat());
    assert_rejected(&dir, &path, &[], Some(4), "not UTF-8 text");
    // Valid UTF-8 control characters: unknown tags, shown escaped, no graph.
    let controls: String = (1u8..32)
        .filter(|&b| b != b'\n')
        .map(|b| b as char)
        .collect::<String>()
        .repeat(3);
    let path = file(
        &dir,
        "controls.g2o",
        format!("{controls}\n\u{7f}\u{1b}[2J\n"),
    );
    let out = pgo(&["optimize", &path]);
    assert_no_panic(&out, &path);
    assert_eq!(out.status.code(), Some(2));
    let err = stderr(&out);
    assert!(err.contains("controls.g2o: no VERTEX_SE2"), "{err}");
    assert!(err.contains("\\u{7f}\\u{1b}"), "{err}");
    assert!(
        !err.chars().any(|c| c.is_control() && c != '\n'),
        "raw control characters on stderr: {err:?}"
    );
}

#[test]
fn crlf_tabs_and_a_missing_final_newline_read_like_the_plain_file() {
    let dir = temp_dir("hostile-layout");
    let plain = format!("{V3}{E3}EDGE_SE2 0 2 2.1 0 0 1 0 0 1 0 1\n");
    let (reference, reference_out) = accepted(&dir, &file(&dir, "plain.g2o", &plain), &[]);
    let variants = [
        ("crlf.g2o", plain.replace('\n', "\r\n")),
        ("tabs.g2o", plain.replace(' ', "\t")),
        ("spaces.g2o", plain.replace(' ', " \t  ")),
        ("no-final-newline.g2o", plain.trim_end().to_owned()),
        ("bom.g2o", format!("\u{feff}{plain}")),
    ];
    // Token by token, the outputs are the same; each keeps its layout.
    let tokens = |text: &str| -> Vec<Vec<String>> {
        text.trim_start_matches('\u{feff}')
            .lines()
            .map(|l| l.split_whitespace().map(str::to_owned).collect())
            .collect()
    };
    for (name, text) in variants {
        let (report, out) = accepted(&dir, &file(&dir, name, &text), &[]);
        assert_eq!(report["edges"], 3, "{name}");
        assert_eq!(
            report["optimizer"]["final_chi2"], reference["optimizer"]["final_chi2"],
            "{name}"
        );
        assert_eq!(
            tokens(&out),
            tokens(&reference_out),
            "{name}: different output"
        );
        assert_eq!(
            out.matches("\r\n").count(),
            text.matches("\r\n").count(),
            "{name}: line ends"
        );
        assert_eq!(out.ends_with('\n'), text.ends_with('\n'), "{name}");
        assert_eq!(
            out.starts_with('\u{feff}'),
            text.starts_with('\u{feff}'),
            "{name}"
        );
        // Lines without a vertex are the input's own.
        for (a, b) in out.lines().zip(text.lines()) {
            if !a.contains("VERTEX") {
                assert_eq!(a, b, "{name}");
            }
        }
    }
}

#[test]
fn a_truncated_last_line_names_the_line() {
    let dir = temp_dir("hostile-truncated");
    let path = file(&dir, "cut.g2o", format!("{V3}{E3}EDGE_SE2 0 2 2 0 0 1 0"));
    assert_rejected(
        &dir,
        &path,
        &[],
        Some(6),
        "EDGE_SE2 needs 12 tokens (13 with an inlier count), found 8",
    );
    // Cut inside a multi-byte character: not text.
    let path = file(
        &dir,
        "cut-utf8.g2o",
        [format!("{V3}{E3}# π").as_bytes(), &[0xcf]].concat(),
    );
    assert_rejected(&dir, &path, &[], Some(6), "not UTF-8 text");
    let path = file(
        &dir,
        "cut-3d.g2o",
        format!("{SE3_V}EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0"),
    );
    assert_rejected(&dir, &path, &[], Some(3), "EDGE_SE3:QUAT needs 31 tokens");
}

#[test]
fn nan_and_infinity_are_rejected_in_every_kind_of_number() {
    let dir = temp_dir("hostile-nan");
    let e = "1 0 0 1 0 0 1 0 1"; // measurement and information of EDGE_SE2 after the ids
    let mix = |w: &str, second: &str| {
        format!(
            "{V3}EDGE_SE2_MIXTURE 0 1 2 EDGE_SE2 {w} 0 1 1 0 0 1 0 0 1 0 1 EDGE_SE2 0.1 0 1 {second}\n"
        )
    };
    let cases: Vec<(String, usize, &str)> = vec![
        // Vertex poses, SE(2) and SE(3) (translation and quaternion).
        (
            format!("{V3}VERTEX_SE2 3 nan 0 0\n"),
            4,
            "'nan' is not finite",
        ),
        (
            format!("{V3}VERTEX_SE2 3 0 0 inf\n"),
            4,
            "'inf' is not finite",
        ),
        (
            format!("{SE3_V}VERTEX_SE3:QUAT 2 0 -inf 0 0 0 0 1\n"),
            3,
            "'-inf' is not finite",
        ),
        (
            format!("{SE3_V}VERTEX_SE3:QUAT 2 0 0 0 0 NaN 0 1\n"),
            3,
            "'NaN' is not finite",
        ),
        // Edge measurements and information entries.
        (
            format!("{V3}EDGE_SE2 0 1 1 infinity 0 1 0 0 1 0 1\n"),
            4,
            "'infinity' is not finite",
        ),
        (
            format!("{V3}EDGE_SE2 0 1 1 0 0 1 0 0 1 0 +Inf\n"),
            4,
            "'+Inf' is not finite",
        ),
        (
            format!("{V3}EDGE_SE2 0 1 1e999 0 0 1 0 0 1 0 1\n"),
            4,
            "'1e999' is not finite",
        ),
        (
            format!("{SE3_V}EDGE_SE3:QUAT 0 1 1 0 0 0 0 nan 1 {I6}\n"),
            3,
            "'nan' is not finite",
        ),
        (
            format!(
                "{SE3_V}EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 -nan\n"
            ),
            3,
            "'-nan' is not finite",
        ),
        // Ids (vertex, edge ends, FIX) and inlier counts are integers.
        (
            format!("{V3}VERTEX_SE2 nan 0 0 0\n"),
            4,
            "'nan' is not a vertex id",
        ),
        (
            format!("{V3}EDGE_SE2 0 inf {e}\n"),
            4,
            "'inf' is not a vertex id",
        ),
        (format!("{V3}{E3}FIX NaN\n"), 6, "'NaN' is not a vertex id"),
        (
            format!("{V3}EDGE_SE2 0 1 {e} nan\n"),
            4,
            "inlier count 'nan'",
        ),
        (
            format!("{V3}EDGE_SE2 0 1 {e} inf\n"),
            4,
            "inlier count 'inf'",
        ),
        // Max-mixture edges: the weight, the component count, and the
        // numbers of a component that is not even used.
        (mix("nan", "1 0 0 1 0 0 1 0 1"), 4, "'nan' is not finite"),
        (mix("1", "1 0 0 1 0 0 1 0 inf"), 4, "'inf' is not finite"),
        (
            format!("{V3}EDGE_SE2_MIXTURE 0 1 nan EDGE_SE2 1 0 1 1 0 0 1 0 0 1 0 1\n"),
            4,
            "'nan' is not a component count",
        ),
    ];
    for (k, (text, line, problem)) in cases.iter().enumerate() {
        let path = file(&dir, &format!("nan{k}.g2o"), text);
        assert_rejected(&dir, &path, &[], Some(*line), problem);
    }
    // The inlier CSV and `pgo gate` too.
    let graph = file(&dir, "graph.g2o", format!("{V3}{E3}"));
    let csv = file(&dir, "counts.csv", "from,to,inliers\n0,1,12\n1,2,nan\n");
    let out = pgo(&["optimize", &graph, "--inliers", &csv]);
    assert_no_panic(&out, "csv");
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("counts.csv:3: inlier count 'nan'"),
        "{}",
        stderr(&out)
    );
    let counts = file(&dir, "counts.txt", "12\n40\ninf\n");
    let out = pgo(&["gate", &counts]);
    assert_no_panic(&out, "gate");
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("counts.txt:3: inlier count 'inf'"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn ids_up_to_u64_max_work_and_negative_or_larger_ids_are_rejected() {
    let dir = temp_dir("hostile-ids");
    let max = u64::MAX;
    let text = format!(
        "VERTEX_SE2 {max} 0 0 0\nVERTEX_SE2 0 1 0.1 0\nEDGE_SE2 {max} 0 1 0 0 1 0 0 1 0 1\nFIX {max}\n"
    );
    let (report, out) = accepted(&dir, &file(&dir, "max.g2o", text), &[]);
    assert_eq!(report["poses"], 2);
    // The gauge vertex did not move: its line is kept as written.
    assert!(
        out.starts_with(&format!("VERTEX_SE2 {max} 0 0 0\n")),
        "{out}"
    );
    assert!(out.contains(&format!("EDGE_SE2 {max} 0 ")), "{out}");
    assert!(out.contains(&format!("FIX {max}\n")), "{out}");
    for (name, text, problem) in [
        (
            "neg.g2o",
            format!("{V3}VERTEX_SE2 -1 0 0 0\n"),
            "'-1' is not a vertex id",
        ),
        (
            "neg-edge.g2o",
            format!("{V3}EDGE_SE2 0 -2 1 0 0 1 0 0 1 0 1\n"),
            "'-2' is not a vertex id",
        ),
        (
            "over.g2o",
            format!("{V3}VERTEX_SE2 18446744073709551616 0 0 0\n"),
            "'18446744073709551616' is not a vertex id (a non-negative integer below 2^64)",
        ),
        (
            "float-id.g2o",
            format!("{V3}VERTEX_SE2 3.0 0 0 0\n"),
            "'3.0' is not a vertex id",
        ),
    ] {
        assert_rejected(&dir, &file(&dir, name, text), &[], Some(4), problem);
    }
}

#[test]
fn a_vertex_defined_twice_names_both_lines() {
    let dir = temp_dir("hostile-dup");
    let path = file(&dir, "dup.g2o", format!("{V3}{E3}VERTEX_SE2 1 5 5 5\n"));
    assert_rejected(
        &dir,
        &path,
        &[],
        Some(6),
        "vertex 1 is defined twice (first on line 2)",
    );
    // Even with the same pose: the file is ambiguous about its layout.
    let path = file(
        &dir,
        "dup-same.g2o",
        format!("{V3}VERTEX_SE2 2 2 0 0\n{E3}"),
    );
    assert_rejected(
        &dir,
        &path,
        &[],
        Some(4),
        "vertex 2 is defined twice (first on line 3)",
    );
}

#[test]
fn edges_to_vertices_without_a_line_get_composed_poses() {
    let dir = temp_dir("hostile-unknown");
    // Vertex 9 has no line: its pose is composed along the spanning tree and
    // written as a vertex line after the last vertex line.
    let text = format!("{V3}{E3}EDGE_SE2 2 9 1 0 0 1 0 0 1 0 1\n");
    let (report, out) = accepted(&dir, &file(&dir, "unknown.g2o", text), &[]);
    assert_eq!(report["poses"], 4);
    assert_eq!(report["initialization"]["vertices_without_line"], 1);
    let lines: Vec<&str> = out.lines().collect();
    assert!(
        lines[..3].iter().all(|l| l.starts_with("VERTEX_SE2 ")),
        "{out}"
    );
    assert!(
        lines[4..].iter().all(|l| l.starts_with("EDGE_SE2 ")),
        "{out}"
    );
    let first = lines[3];
    let numbers: Vec<f64> = first
        .strip_prefix("VERTEX_SE2 9 ")
        .expect("vertex 9 after the vertex lines")
        .split(' ')
        .map(|t| t.parse().expect("number"))
        .collect();
    assert!(
        (numbers[0] - 3.0).abs() < 1e-9 && numbers[1].abs() < 1e-9,
        "{first}"
    );
    // A file of edges alone works the same way.
    let (report, _) = accepted(&dir, &file(&dir, "edges-only.g2o", E3), &[]);
    assert_eq!(report["initialization"]["vertices_without_line"], 3);
}

#[test]
fn self_loops_are_rejected() {
    let dir = temp_dir("hostile-self");
    let path = file(
        &dir,
        "self.g2o",
        format!("{V3}{E3}EDGE_SE2 2 2 1 0 0 1 0 0 1 0 1\n"),
    );
    assert_rejected(&dir, &path, &[], Some(6), "edge from vertex 2 to itself");
    let path = file(
        &dir,
        "self3.g2o",
        format!("{SE3_V}EDGE_SE3:QUAT 1 1 0 0 0 0 0 0 1 {I6}\n"),
    );
    assert_rejected(&dir, &path, &[], Some(3), "edge from vertex 1 to itself");
}

#[test]
fn zero_and_negative_definite_information_is_rejected_or_projected_on_request() {
    let dir = temp_dir("hostile-info");
    let zero = file(
        &dir,
        "zero.g2o",
        format!("{V3}{E3}EDGE_SE2 0 2 2 0 0 0 0 0 0 0 0\n"),
    );
    assert_rejected(
        &dir,
        &zero,
        &[],
        Some(6),
        "information matrix is not positive definite (smallest eigenvalue 0e0); --fix-information",
    );
    assert_rejected(
        &dir,
        &zero,
        &["--fix-information"],
        Some(6),
        "information matrix is zero and cannot be made positive definite",
    );
    let negative = file(
        &dir,
        "negative.g2o",
        format!("{V3}{E3}EDGE_SE2 0 2 2 0 0 -1 0 0 -1 0 -1\n"),
    );
    assert_rejected(
        &dir,
        &negative,
        &[],
        Some(6),
        "not positive definite (smallest eigenvalue -1e0)",
    );
    // Projected: the eigenvalues are clamped at 1e-6·max|λ|, the edge counts
    // almost nothing, and the report says so.
    let (report, _) = accepted(&dir, &negative, &["--fix-information"]);
    assert_eq!(report["information_fixed"], 1);
    assert!(
        report["warnings"]
            .to_string()
            .contains("projected 1 information matrices"),
        "{}",
        report["warnings"]
    );
    // `pgo corrupt` names the same option, and takes it.
    let out = pgo(&["corrupt", &negative, "-o", "-"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("--fix-information"),
        "{}",
        stderr(&out)
    );
    let out = pgo(&[
        "corrupt",
        &negative,
        "--wrong",
        "1",
        "-o",
        "-",
        "--fix-information",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let written = String::from_utf8(out.stdout.clone()).unwrap();
    assert!(written.contains("EDGE_SE2 0 2 "), "{written}");
    assert!(
        stderr(&out).contains("warning: projected 1 information matrices"),
        "{}",
        stderr(&out)
    );
    let i3 = format!(
        "{SE3_V}EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 {}\n",
        I6.replace('1', "-1")
    );
    assert_rejected(
        &dir,
        &file(&dir, "negative3.g2o", i3),
        &[],
        Some(3),
        "not positive definite",
    );
}

#[test]
fn a_quaternion_of_norm_zero_is_rejected() {
    let dir = temp_dir("hostile-quat");
    let vertex = file(
        &dir,
        "q0.g2o",
        format!("{SE3_V}VERTEX_SE3:QUAT 2 0 0 0 0 0 0 0\n"),
    );
    assert_rejected(&dir, &vertex, &[], Some(3), "quaternion has zero norm");
    let edge = file(
        &dir,
        "q0e.g2o",
        format!("{SE3_V}EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 0 {I6}\n"),
    );
    assert_rejected(&dir, &edge, &[], Some(3), "quaternion has zero norm");
    // Too small to normalise is zero too.
    let tiny = file(
        &dir,
        "q-tiny.g2o",
        format!("{SE3_V}VERTEX_SE3:QUAT 2 0 0 0 0 0 0 1e-320\n"),
    );
    assert_rejected(&dir, &tiny, &[], Some(3), "quaternion has zero norm");
}

#[test]
fn two_disconnected_pieces_name_the_unreachable_vertices() {
    // (The 2D case with vertex lines is in cli.rs.) 3D, and edges only.
    let dir = temp_dir("hostile-pieces");
    let text = format!(
        "{SE3_V}EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 {I6}\nEDGE_SE3:QUAT 5 6 1 0 0 0 0 0 1 {I6}\n"
    );
    let path = file(&dir, "pieces3.g2o", text);
    assert_rejected(
        &dir,
        &path,
        &[],
        None,
        "not connected to the fixed vertex 0",
    );
    assert_rejected(&dir, &path, &[], None, "e.g. 5, 6");
    let path = file(
        &dir,
        "pieces-edges.g2o",
        format!("{E3}EDGE_SE2 10 11 1 0 0 1 0 0 1 0 1\n"),
    );
    assert_rejected(&dir, &path, &[], None, "2 vertices are not connected");
}

#[test]
fn a_single_vertex_is_written_back_unchanged() {
    let dir = temp_dir("hostile-single");
    for (name, text) in [
        ("single2.g2o", "VERTEX_SE2 4 1.5 -2 0.25\n"),
        ("single3.g2o", "VERTEX_SE3:QUAT 4 1 2 3 0 0 0 1\n"),
        ("single-fixed.g2o", "VERTEX_SE2 4 1.5 -2 0.25\nFIX 4\n"),
    ] {
        let (report, out) = accepted(&dir, &file(&dir, name, text), &[]);
        assert_eq!(report["poses"], 1, "{name}");
        assert_eq!(
            report["optimizer"]["stop_reason"], "nothing_to_optimize",
            "{name}"
        );
        assert_eq!(report["optimizer"]["final_chi2"], 0.0, "{name}");
        assert_eq!(
            report["input_chi2"], 0.0,
            "{name}: {}",
            report["input_chi2"]
        );
        assert_eq!(out.lines().count(), text.lines().count(), "{name}: {out}");
    }
}

#[test]
fn a_hundred_thousand_duplicate_edges_are_each_counted() {
    let dir = temp_dir("hostile-duplicate-edges");
    // Vertex 2's guess is off by 0.5; 10⁵ copies of one consistent edge 0 → 2.
    let mut text =
        String::from("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2.5 0.3 0.1\n");
    text.push_str(E3);
    text.push_str(&"EDGE_SE2 0 2 2 0 0 1 0 0 1 0 1\n".repeat(100_000));
    let (report, out) = accepted(&dir, &file(&dir, "dups.g2o", text), &["--init", "file"]);
    assert_eq!(report["edges"], 100_002);
    assert!(report["input_chi2"].as_f64().expect("finite") > 1e4);
    assert!(report["optimizer"]["final_chi2"].as_f64().expect("finite") < 1e-12);
    assert_eq!(report["optimizer"]["converged"], true);
    let v2: Vec<f64> = out
        .lines()
        .nth(2)
        .and_then(|l| l.strip_prefix("VERTEX_SE2 2 "))
        .expect("vertex 2 third")
        .split(' ')
        .map(|t| t.parse().expect("number"))
        .collect();
    assert!(
        (v2[0] - 2.0).abs() < 1e-9 && v2[1].abs() < 1e-9 && v2[2].abs() < 1e-9,
        "{v2:?}"
    );
    assert_eq!(out.lines().count(), 100_005);
}

/// The gate's verdict on a graph whose candidates carry `counts`.
fn gate_on_counts(dir: &Path, name: &str, counts: &[u64]) -> serde_json::Value {
    let mut text = format!("{V3}{E3}");
    for c in counts {
        text.push_str(&format!("EDGE_SE2 0 2 2 0 0 1 0 0 1 0 1 {c}\n"));
    }
    let (report, _) = accepted(dir, &file(dir, name, text), &[]);
    assert_eq!(report["loop_candidates"], counts.len(), "{name}");
    report["gate"].clone()
}

#[test]
fn degenerate_counts_give_a_verdict_and_leave_the_candidates_to_em() {
    let dir = temp_dir("hostile-counts");
    // keep-all (the default) keeps the non-zero counts for the robust back
    // end; a zero count is no loop.
    for (name, counts, reason, kept) in [
        ("zeros.g2o", vec![0; 20], "all 20 inlier counts are zero", 0),
        ("one.g2o", vec![57], "only 1 non-zero inlier counts", 1),
        (
            "equal.g2o",
            vec![57; 30],
            "all 30 non-zero inlier counts equal 57",
            30,
        ),
    ] {
        let gate = gate_on_counts(&dir, name, &counts);
        assert_eq!(gate["degenerate"], true, "{name}");
        assert!(
            gate["reason"].to_string().contains(reason),
            "{name}: {gate}"
        );
        assert_eq!(gate["kept"], kept, "{name}");
        assert!(gate["threshold"].is_null(), "{name}");
        // `pgo gate` on the same counts: exit status 1 and the reason.
        let list: String = counts.iter().map(|c| format!("{c}\n")).collect();
        let out = pgo(&["gate", &file(&dir, &format!("{name}.txt"), list)]);
        assert_no_panic(&out, name);
        assert_eq!(out.status.code(), Some(1), "{name}");
        assert!(stderr(&out).starts_with("degenerate: "), "{}", stderr(&out));
        assert!(stderr(&out).contains(reason), "{}", stderr(&out));
    }
    // No counts at all: `pgo gate` on an empty list.
    let out = pgo(&["gate", &file(&dir, "none.txt", "")]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("no inlier counts"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn counts_above_2_pow_63_are_fitted_and_above_2_pow_64_rejected() {
    let dir = temp_dir("hostile-big-counts");
    // Two populations in [2⁶³, 2⁶⁴): the ratios, not the magnitudes, matter.
    let mut x: u64 = 7;
    let mut next = || {
        x = x
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        x >> 8
    };
    let mut counts: Vec<u64> = (0..60).map(|_| (1 << 63) + next()).collect();
    counts.extend((0..40).map(|_| u64::MAX - next()));
    let gate = gate_on_counts(&dir, "big.g2o", &counts);
    let min = *counts.iter().min().expect("counts") as f64;
    let max = *counts.iter().max().expect("counts") as f64;
    assert_eq!(gate["max_inliers"].as_u64(), counts.iter().max().copied());
    if gate["degenerate"] == false {
        let t = gate["threshold"].as_f64().expect("a finite threshold");
        assert!(t > min && t <= max, "threshold {t} outside ({min}, {max}]");
        assert!(gate["kept"].as_u64().expect("kept") > 0);
    } else {
        assert!(gate["reason"].is_string(), "{gate}");
    }
    let list: String = counts.iter().map(|c| format!("{c}\n")).collect();
    let out = pgo(&["gate", &file(&dir, "big.txt", list)]);
    assert_no_panic(&out, "gate");
    assert!(matches!(out.status.code(), Some(0 | 1)), "{}", stderr(&out));
    // 2⁶⁴ itself is not a count.
    let text = format!("{V3}{E3}EDGE_SE2 0 2 2 0 0 1 0 0 1 0 1 18446744073709551616\n");
    assert_rejected(
        &dir,
        &file(&dir, "over.g2o", text),
        &[],
        Some(6),
        "inlier count '18446744073709551616' is not a non-negative integer below 2^64",
    );
    let out = pgo(&["gate", &file(&dir, "over.txt", "5\n18446744073709551616\n")]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("over.txt:2: "), "{}", stderr(&out));
}

#[test]
fn count_lists_that_are_not_text_or_too_long_name_the_line() {
    let dir = temp_dir("hostile-count-lists");
    let out = pgo(&["gate", &file(&dir, "bin.txt", b"12\n\xff\xfe\n")]);
    assert_no_panic(&out, "gate");
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("bin.txt:2: not UTF-8 text"),
        "{}",
        stderr(&out)
    );
    let out = pgo(&[
        "gate",
        &file(&dir, "long.txt", format!("12\n{}\n", "9".repeat(1 << 20))),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("long.txt:2: line is longer"),
        "{}",
        stderr(&out)
    );
    let graph = file(&dir, "g.g2o", format!("{V3}{E3}"));
    let csv = file(&dir, "bin.csv", b"from,to,inliers\n0,1,\xc3\x28\n");
    let out = pgo(&["optimize", &graph, "--inliers", &csv]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("bin.csv:2: not UTF-8 text"),
        "{}",
        stderr(&out)
    );
}

#[test]
#[cfg(unix)]
fn the_output_is_never_the_input_without_in_place() {
    let dir = temp_dir("hostile-same-file");
    let text = format!("{V3}{E3}");
    let input = file(&dir, "graph.g2o", &text);
    std::fs::create_dir_all(dir.join("sub")).expect("mkdir");
    let dotted = dir.join("sub/../graph.g2o");
    std::os::unix::fs::symlink(&input, dir.join("link.g2o")).expect("symlink");
    for out_path in [
        input.clone(),
        dotted.to_string_lossy().into_owned(),
        dir.join("link.g2o").to_string_lossy().into_owned(),
    ] {
        let out = pgo(&["optimize", &input, "-o", &out_path]);
        assert_no_panic(&out, &out_path);
        assert_eq!(out.status.code(), Some(2), "{out_path}");
        assert!(stderr(&out).contains("--in-place"), "{}", stderr(&out));
        assert_eq!(std::fs::read_to_string(&input).expect("input"), text);
    }
    let out = pgo(&["corrupt", &input, "-o", &input]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert_eq!(std::fs::read_to_string(&input).expect("input"), text);
}

/// Found by the `optimize` fuzz target: two parallel edges whose rotations
/// differ by half a turn made the chordal initialisation spin forever
/// (nalgebra's iterative `Rotation3::from_matrix`). It must finish.
#[test]
fn fuzz_regression_parallel_edges_half_a_turn_apart() {
    let dir = temp_dir("hostile-fuzz-half-turn");
    let text = format!(
        "{SE3_V}EDGE_SE3:QUAT 0 1 1 0 0 0 0 1 0 {I6}\nEDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 {I6}\n"
    );
    let path = file(&dir, "half-turn.g2o", text);
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_pgo"))
        .args(["optimize", &path, "-q"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start pgo");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    let status = loop {
        if let Some(status) = child.try_wait().expect("poll") {
            break status;
        }
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            panic!("pgo optimize did not finish within 60 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    assert_eq!(status.code(), Some(0));
}

/// Found by the `parse` fuzz target: a mixture component count whose token
/// count overflows made the debug binary panic ("attempt to add with
/// overflow").
#[test]
fn fuzz_regression_mixture_component_count_overflow() {
    let dir = temp_dir("hostile-fuzz-mixture");
    let path = file(
        &dir,
        "mixture.g2o",
        "5\r\nEDGE_SE2_MIXTURE 4 16111 11111111111222222222\n",
    );
    assert_rejected(
        &dir,
        &path,
        &[],
        Some(2),
        "EDGE_SE2_MIXTURE needs 4 + 13·n tokens (+1 with an inlier count), found 4",
    );
}

/// A graph with everything pgo does not model, as users' files have it: a
/// byte-order mark, comments, blank lines, CRLF line ends, tabs, a
/// parameter block, landmark vertices and edges, an unknown tag, FIX, no
/// final newline; vertex 3 has no line.
const ZOO: &str = "\u{feff}# landmarks, parameters and comments\r\n\
PARAMS_SE2OFFSET 0 0 0 0\r\n\
\r\n\
VERTEX_SE2 0 0 0 0\r\n\
VERTEX_SE2 1 1.1 0.1 0.05\r\n\
VERTEX_XY 100 2.0 1.0\r\n\
VERTEX_SE2\t2  2.2 -0.1 0.1\r\n\
EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\r\n\
EDGE_SE2 1 2 1.0 0.0 0.0 1 0 0 1 0 1\r\n\
EDGE_SE2_XY 1 100 1 1 10 0 10\r\n\
EDGE_SE2 2 3 1 0 0 1 0 0 1 0 1\r\n\
ROBOTLASER1 0 -1.5 0.01 0.1 8 0.1 0 3 1.0 1.1 1.2 0 0 0 0 0 0 0 0 0 0 0 0 host 0.5 lg 0.5\r\n\
# the end, without a newline\r\n\
FIX 0";

/// `line` up to the end of its second token (a vertex line's id).
fn up_to_id(line: &str) -> &str {
    let mut tokens = 0;
    let mut inside = false;
    for (i, c) in line.char_indices() {
        if c.is_whitespace() {
            if inside {
                tokens += 1;
                if tokens == 2 {
                    return &line[..i];
                }
            }
            inside = false;
        } else {
            inside = true;
        }
    }
    line
}

/// Checks that `out` is `ZOO` with new pose values in its vertex lines (and
/// vertex 3 added after the last one): every other byte as it was.
fn assert_zoo_kept(out: &str) {
    let lines_in: Vec<&str> = ZOO.split_inclusive('\n').collect();
    let lines_out: Vec<&str> = out.split_inclusive('\n').collect();
    assert_eq!(lines_out.len(), lines_in.len() + 1, "{out}");
    let added = lines_in
        .iter()
        .rposition(|l| l.starts_with("VERTEX_SE2"))
        .expect("vertex lines")
        + 1;
    let mut poses = Vec::new();
    for (k, line) in lines_out.iter().enumerate() {
        let original = match k {
            k if k < added => lines_in[k],
            k if k == added => "VERTEX_SE2 3 ?\r\n",
            k => lines_in[k - 1],
        };
        let tag = original
            .trim_start_matches('\u{feff}')
            .split_whitespace()
            .next();
        if tag != Some("VERTEX_SE2") {
            assert_eq!(*line, original, "line {}", k + 1);
            continue;
        }
        // Only the pose values changed: tag, spacing, id and CRLF kept.
        assert!(line.ends_with("\r\n"), "{line:?}");
        let prefix = up_to_id(original);
        assert!(line.starts_with(prefix), "{line:?} from {original:?}");
        let tokens: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(tokens.len(), 5, "{line:?}");
        let numbers: Vec<f64> = tokens[2..]
            .iter()
            .map(|t| t.parse().expect("number"))
            .collect();
        poses.push((tokens[1].to_owned(), numbers));
    }
    // And they are the optimum: a straight line along x.
    assert_eq!(poses.len(), 4);
    for (id, p) in poses {
        let x: f64 = id.parse().expect("id");
        assert!(
            (p[0] - x).abs() < 1e-6 && p[1].abs() < 1e-6 && p[2].abs() < 1e-6,
            "vertex {id}: {p:?}"
        );
    }
}

#[test]
fn in_place_keeps_every_line_it_does_not_change_byte_for_byte() {
    let dir = temp_dir("hostile-in-place-zoo");
    let path = file(&dir, "zoo.g2o", ZOO);
    let out = pgo(&["optimize", &path, "--in-place", "-q"]);
    assert_no_panic(&out, "in-place");
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let in_place = std::fs::read_to_string(&path).expect("rewritten");
    assert_zoo_kept(&in_place);
    // -o does the same.
    let path = file(&dir, "zoo2.g2o", ZOO);
    let (report, written) = accepted(&dir, &path, &[]);
    assert_eq!(written, in_place);
    assert_eq!(std::fs::read_to_string(&path).expect("input"), ZOO);
    let warnings = report["warnings"].to_string();
    for tag in [
        "VERTEX_XY",
        "EDGE_SE2_XY",
        "PARAMS_SE2OFFSET",
        "ROBOTLASER1",
    ] {
        assert!(warnings.contains(tag), "{tag}: {warnings}");
    }
    // A run that moves nothing writes the file back as it was, plus the
    // line of the vertex it composed.
    let path = file(&dir, "still.g2o", ZOO);
    let (_, same) = accepted(&dir, &path, &["--init", "file", "--max-iters", "0"]);
    let lines: Vec<&str> = same.split_inclusive('\n').collect();
    let added = lines
        .iter()
        .position(|l| l.starts_with("VERTEX_SE2 3 "))
        .expect("vertex 3 added");
    assert_eq!(added, 7, "{same}");
    let without: String = lines
        .iter()
        .enumerate()
        .filter(|(k, _)| *k != added)
        .map(|(_, l)| *l)
        .collect();
    assert_eq!(without, ZOO);
}

/// Runs `pgo ARGS` and kills it if it has not finished within `seconds`
/// (a run that waits on a FIFO forever fails the test instead of hanging it).
fn pgo_within(args: &[&str], seconds: u64) -> Output {
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_pgo"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start pgo");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(seconds);
    while child.try_wait().expect("poll").is_none() {
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("pgo {args:?} did not finish within {seconds} s");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().expect("output")
}

/// Makes a FIFO; `None` (and a note) where `mkfifo` is missing.
#[cfg(unix)]
fn fifo(dir: &Path, name: &str) -> Option<PathBuf> {
    let p = dir.join(name);
    let made = std::process::Command::new("mkfifo").arg(&p).status();
    if made.is_ok_and(|s| s.success()) {
        Some(p)
    } else {
        eprintln!("skipped: mkfifo unavailable");
        None
    }
}

fn is_root() -> bool {
    std::process::Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| o.stdout.starts_with(b"0\n"))
}

#[test]
#[cfg(unix)]
fn devices_fifos_sockets_and_directories_are_refused_as_outputs_before_reading() {
    use std::os::unix::fs::FileTypeExt;
    let dir = temp_dir("hostile-device-outputs");
    let input = file(&dir, "graph.g2o", format!("{V3}{E3}"));
    let mut targets: Vec<(PathBuf, &str)> = vec![(dir.join("subdir"), "is a directory")];
    std::fs::create_dir(dir.join("subdir")).expect("mkdir");
    if let Some(f) = fifo(&dir, "fifo") {
        targets.push((f, "is a FIFO (named pipe)"));
    }
    let socket = dir.join("socket");
    let _listener = std::os::unix::net::UnixListener::bind(&socket).expect("bind");
    targets.push((socket, "is a socket"));
    if is_root() {
        // Copies of /dev/null and /dev/full (never the real ones: a
        // regression would replace the machine's device nodes).
        for (name, minor) in [("null", "3"), ("full", "7")] {
            let node = dir.join(name);
            let made = std::process::Command::new("mknod")
                .args([node.to_str().expect("utf-8"), "c", "1", minor])
                .status();
            if made.is_ok_and(|s| s.success()) {
                targets.push((node, "is a character device"));
            }
        }
    } else {
        eprintln!("note: the device cases need root (mknod)");
    }
    for (target, problem) in &targets {
        let t = target.to_str().expect("utf-8");
        let link = dir.join(format!(
            "link-to-{}",
            target.file_name().expect("name").to_string_lossy()
        ));
        std::os::unix::fs::symlink(target, &link).expect("symlink");
        let l = link.to_str().expect("utf-8");
        let before = std::fs::symlink_metadata(target).expect("node").file_type();
        for args in [
            vec!["optimize", &input, "-o", t],
            vec!["optimize", &input, "-o", l],
            vec!["simulate", "--poses", "10", "--loops", "2", "-o", t],
            vec![
                "simulate", "--poses", "10", "--loops", "2", "-o", &input, "--labels", t,
            ],
            vec!["corrupt", &input, "--wrong", "1", "-o", t],
        ] {
            let out = pgo_within(&args, 60);
            assert_no_panic(&out, t);
            let err = stderr(&out);
            assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
            assert!(err.contains(problem), "{args:?}: {err}");
            assert!(
                err.contains(&format!("{}: is ", args[args.len() - 1])),
                "{err}"
            );
            assert!(err.contains("pgo writes only regular files"), "{err}");
        }
        let after = std::fs::symlink_metadata(target).expect("node").file_type();
        assert_eq!(
            (
                before.is_dir(),
                before.is_fifo(),
                before.is_socket(),
                before.is_char_device()
            ),
            (
                after.is_dir(),
                after.is_fifo(),
                after.is_socket(),
                after.is_char_device()
            ),
            "{t} was replaced"
        );
        assert!(
            std::fs::symlink_metadata(&link)
                .expect("link")
                .file_type()
                .is_symlink()
        );
    }
    assert_eq!(
        std::fs::read_to_string(&input).expect("input"),
        format!("{V3}{E3}")
    );
    // --in-place on a FIFO: refused before opening it (no writer ever comes,
    // so opening it would wait forever).
    if let Some(f) = fifo(&dir, "in-fifo") {
        let f = f.to_str().expect("utf-8");
        let out = pgo_within(&["optimize", f, "--in-place"], 60);
        assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
        assert!(stderr(&out).contains("is a FIFO"), "{}", stderr(&out));
    }
}

#[test]
#[cfg(unix)]
fn outputs_through_links_replace_the_linked_file_and_dangling_links_are_refused() {
    let dir = temp_dir("hostile-link-outputs");
    let input = file(
        &dir,
        "graph.g2o",
        format!("{V3}{E3}EDGE_SE2 0 2 2.1 0 0 1 0 0 1 0 1\n"),
    );
    std::fs::create_dir(dir.join("real")).expect("mkdir");
    let real = dir.join("real/out.g2o");
    std::fs::write(&real, "old").expect("old");
    let link = dir.join("out-link.g2o");
    std::os::unix::fs::symlink("real/out.g2o", &link).expect("symlink");
    let out = pgo(&[
        "optimize",
        &input,
        "-o",
        link.to_str().expect("utf-8"),
        "-q",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(
        std::fs::symlink_metadata(&link)
            .expect("link")
            .file_type()
            .is_symlink()
    );
    let written = std::fs::read_to_string(&real).expect("real");
    assert!(written.starts_with("VERTEX_SE2 0 0 0 0\n"), "{written}");
    // --in-place through a link: the file it leads to is rewritten.
    let in_link = dir.join("in-link.g2o");
    std::os::unix::fs::symlink("graph.g2o", &in_link).expect("symlink");
    let out = pgo(&[
        "optimize",
        in_link.to_str().expect("utf-8"),
        "--in-place",
        "-q",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(
        std::fs::symlink_metadata(&in_link)
            .expect("link")
            .file_type()
            .is_symlink()
    );
    assert_eq!(std::fs::read_to_string(&input).expect("input"), written);
    // A dangling link: refused, nothing created where it points.
    let dangling = dir.join("dangling.g2o");
    std::os::unix::fs::symlink("nowhere/new.g2o", &dangling).expect("symlink");
    let out = pgo(&["optimize", &input, "-o", dangling.to_str().expect("utf-8")]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(
        stderr(&out)
            .contains("dangling.g2o: is a symbolic link to nowhere/new.g2o, which does not exist"),
        "{}",
        stderr(&out)
    );
    assert!(!dir.join("nowhere").exists());
}

#[test]
#[cfg(unix)]
fn in_place_keeps_the_owner_and_mode_of_the_file() {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let dir = temp_dir("hostile-owner");
    let input = file(
        &dir,
        "graph.g2o",
        format!("{V3}{E3}EDGE_SE2 0 2 2.1 0 0 1 0 0 1 0 1\n"),
    );
    std::fs::set_permissions(&input, std::fs::Permissions::from_mode(0o640)).expect("chmod");
    let root = is_root();
    if root {
        std::os::unix::fs::chown(&input, Some(4321), Some(4322)).expect("chown");
    } else {
        eprintln!("note: the owner case needs root");
    }
    let out = pgo(&["optimize", &input, "--in-place", "-q"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let meta = std::fs::metadata(&input).expect("input");
    assert_eq!(meta.mode() & 0o7777, 0o640);
    if root {
        assert_eq!((meta.uid(), meta.gid()), (4321, 4322));
    }
}

#[test]
fn output_names_up_to_255_bytes_work() {
    let dir = temp_dir("hostile-long-name");
    let input = file(&dir, "graph.g2o", format!("{V3}{E3}"));
    for len in [241, 250, 255] {
        let name = format!("{}.g2o", "n".repeat(len - 4));
        let out_path = dir.join(&name);
        let out = pgo(&[
            "optimize",
            &input,
            "-o",
            out_path.to_str().expect("utf-8"),
            "-q",
        ]);
        assert_eq!(out.status.code(), Some(0), "{len}: {}", stderr(&out));
        assert!(out_path.is_file(), "{len}");
        // Again, over the existing file.
        let out = pgo(&[
            "optimize",
            &input,
            "-o",
            out_path.to_str().expect("utf-8"),
            "-q",
        ]);
        assert_eq!(out.status.code(), Some(0), "{len}: {}", stderr(&out));
    }
    let names: Vec<String> = std::fs::read_dir(&dir)
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 4, "temporaries left: {names:?}");
}

#[test]
#[cfg(unix)]
fn labels_or_truth_that_are_the_output_are_refused_before_writing() {
    let dir = temp_dir("hostile-same-outputs");
    let out_path = dir.join("out.g2o");
    let o = out_path.to_str().expect("utf-8");
    std::fs::write(&out_path, "old").expect("old");
    let link = dir.join("link.csv");
    std::os::unix::fs::symlink(&out_path, &link).expect("symlink");
    let l = link.to_str().expect("utf-8");
    let dotted = dir.join("sub/../out.g2o");
    std::fs::create_dir(dir.join("sub")).expect("mkdir");
    let d = dotted.to_str().expect("utf-8");
    let new = dir.join("new.g2o");
    let n = new.to_str().expect("utf-8");
    let sim = ["simulate", "--poses", "10", "--loops", "2"];
    let input = file(&dir, "in.g2o", format!("{V3}{E3}"));
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            [&sim[..], &["-o", o, "--labels", o]].concat(),
            "--labels is the same file as -o",
        ),
        (
            [&sim[..], &["-o", o, "--labels", l]].concat(),
            "--labels is the same file as -o",
        ),
        (
            [&sim[..], &["-o", o, "--truth", d]].concat(),
            "--truth is the same file as -o",
        ),
        (
            [&sim[..], &["-o", n, "--labels", n]].concat(),
            "--labels is the same file as -o",
        ),
        (
            [&sim[..], &["-o", "-", "--labels", "-"]].concat(),
            "-o and --labels both write to stdout",
        ),
        (
            vec!["corrupt", &input, "-o", o, "--labels", l],
            "--labels is the same file as -o",
        ),
        (
            vec!["corrupt", &input, "-o", n, "--labels", &input],
            "the output is the input file",
        ),
    ];
    for (args, problem) in cases {
        let out = pgo(&args);
        assert_no_panic(&out, problem);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", stderr(&out));
        assert!(stderr(&out).contains(problem), "{args:?}: {}", stderr(&out));
        assert_eq!(
            std::fs::read_to_string(&out_path).expect("old"),
            "old",
            "{args:?}"
        );
        assert!(!new.exists(), "{args:?} wrote {n}");
        assert!(out.stdout.is_empty(), "{args:?}");
    }
}
