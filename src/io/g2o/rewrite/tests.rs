//! The line-preserving rewrite: everything but changed pose values is kept
//! byte for byte; added vertices; a changed input is refused.

use super::*;
use crate::geometry::{Se2, Se3};
use crate::graph::AnyGraph;
use crate::io::g2o::{ReadOptions, read, read_from};
use std::path::Path;

fn parse(text: &[u8]) -> G2oFile {
    read_from(text, Path::new("in.g2o"), ReadOptions::default()).unwrap()
}

fn rewritten(file: &G2oFile, text: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    file.rewrite_from(text, &mut out).unwrap();
    out
}

fn planar(file: &mut G2oFile) -> &mut Graph<Se2, 3> {
    match &mut file.graph {
        AnyGraph::Planar(g) => g,
        AnyGraph::Spatial(_) => panic!("expected SE(2)"),
    }
}

/// A file with everything pgo does not model: a byte-order mark, comments,
/// blank lines, CRLF and LF line ends, tabs, landmarks, PARAMS, unknown
/// tags, a mixture edge, FIX, and no final newline.
const ZOO: &[u8] = b"\xEF\xBB\xBF# a graph\r\n\
\r\n\
PARAMS_SE2OFFSET 0 0 0 0\r\n\
VERTEX_SE2 0 0 0 0\r\n\
VERTEX_XY 100 1.5 2.5\r\n\
VERTEX_SE2\t1  1.000 0.0 0\r\n\
\x20 VERTEX_SE2 2 2.1 0.1 0.05   \n\
EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\r\n\
EDGE_SE2_XY 1 100 0.5 2.5 10 0 10\r\n\
EDGE_SE2_MIXTURE 1 2 1 EDGE_SE2 1 1 2 1 0 0 1 0 0 1 0 1 57\r\n\
UNKNOWN_TAG whatever \xc3\xa9\r\n\
# trailing comment\r\n\
FIX 0";

#[test]
fn unchanged_poses_give_the_input_back_byte_for_byte() {
    let file = parse(ZOO);
    assert_eq!(rewritten(&file, ZOO), ZOO);
}

#[test]
fn changed_poses_replace_only_their_numbers() {
    let mut file = parse(ZOO);
    let g = planar(&mut file);
    g.poses[1] = Se2::new(0.5, -0.25, 0.125);
    g.poses[2] = Se2::new(2.0, 1e-300, -3.0);
    let out = rewritten(&file, ZOO);
    let expected = String::from_utf8(ZOO.to_vec())
        .unwrap()
        .replace(
            "VERTEX_SE2\t1  1.000 0.0 0\r\n",
            "VERTEX_SE2\t1 0.5 -0.25 0.125\r\n",
        )
        .replace(
            "  VERTEX_SE2 2 2.1 0.1 0.05   \n",
            "  VERTEX_SE2 2 2.0 1e-300 -3.0\n",
        );
    assert_eq!(String::from_utf8(out.clone()).unwrap(), expected);
    // Read back: the new poses, bit for bit.
    let mut back = parse(&out);
    assert_eq!(planar(&mut back).poses, planar(&mut file).poses);
}

#[test]
fn vertices_without_a_line_follow_the_last_vertex_line_with_its_line_end() {
    let text = b"# c\r\nVERTEX_SE2 0 0 0 0\r\nVERTEX_SE2 1 1 0 0\r\nEDGE_SE2 1 7 1 0 0 1 0 0 1 0 1\r\nEDGE_SE2 7 5 1 0 0 1 0 0 1 0 1\r\n";
    let mut file = parse(text);
    let g = planar(&mut file);
    let (seven, five) = (g.index_of(7).unwrap(), g.index_of(5).unwrap());
    g.poses[seven] = Se2::new(2.0, 0.0, 0.0);
    g.poses[five] = Se2::new(3.0, 0.0, 0.0);
    let out = String::from_utf8(rewritten(&file, text)).unwrap();
    assert_eq!(
        out,
        "# c\r\nVERTEX_SE2 0 0 0 0\r\nVERTEX_SE2 1 1 0 0\r\nVERTEX_SE2 7 2.0 0.0 0.0\r\nVERTEX_SE2 5 3.0 0.0 0.0\r\n\
         EDGE_SE2 1 7 1 0 0 1 0 0 1 0 1\r\nEDGE_SE2 7 5 1 0 0 1 0 0 1 0 1\r\n"
    );
}

#[test]
fn without_vertex_lines_the_added_ones_precede_the_first_edge() {
    let text = b"# header\nEDGE_SE2 4 5 1 0 0 1 0 0 1 0 1";
    let file = parse(text);
    let out = String::from_utf8(rewritten(&file, text)).unwrap();
    assert_eq!(
        out,
        "# header\nVERTEX_SE2 4 0.0 0.0 0.0\nVERTEX_SE2 5 0.0 0.0 0.0\nEDGE_SE2 4 5 1 0 0 1 0 0 1 0 1"
    );
}

#[test]
fn a_last_vertex_line_without_a_newline_gets_one_before_the_added_vertices() {
    let text = b"EDGE_SE2 0 9 1 0 0 1 0 0 1 0 1\r\nVERTEX_SE2 0 0 0 0";
    let file = parse(text);
    let out = String::from_utf8(rewritten(&file, text)).unwrap();
    assert_eq!(
        out,
        "EDGE_SE2 0 9 1 0 0 1 0 0 1 0 1\r\nVERTEX_SE2 0 0 0 0\r\nVERTEX_SE2 9 0.0 0.0 0.0\r\n"
    );
}

#[test]
fn se3_vertex_lines_keep_their_text_unless_the_pose_moved() {
    let text = b"VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0.7071067811865476 0.7071067811865476\n# end\n";
    let mut file = parse(text);
    assert_eq!(rewritten(&file, text), text);
    let AnyGraph::Spatial(g) = &mut file.graph else {
        panic!("expected SE(3)");
    };
    g.poses[1] = Se3::from_translation_quaternion([2.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]).unwrap();
    let out = String::from_utf8(rewritten(&file, text)).unwrap();
    assert_eq!(
        out,
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 2.0 0.0 0.0 0.0 0.0 0.0 1.0\n# end\n"
    );
}

#[test]
fn a_text_that_is_not_the_one_read_is_refused() {
    let text = b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n# note\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n";
    let file = parse(text);
    let cases: [(&[u8], Option<usize>); 4] = [
        // A comment changed: only the fingerprint tells.
        (b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n# NOTE\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", None),
        // Another vertex id on line 2.
        (b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 3 1 0 0\n# note\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", Some(2)),
        // A vertex line more.
        (b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", Some(3)),
        // Cut short.
        (b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n", None),
    ];
    for (other, line) in cases {
        let mut out = Vec::new();
        match file.rewrite_from(other, &mut out) {
            Err(RewriteError::Changed { line: l, input }) => {
                assert_eq!(l, line, "{}", String::from_utf8_lossy(other));
                assert_eq!(input, Path::new("in.g2o"));
            }
            r => panic!("expected Changed, got {r:?}"),
        }
    }
}

#[test]
fn text_read_from_memory_is_not_kept() {
    let file = parse(b"VERTEX_SE2 0 0 0 0\n");
    let err = file.rewrite(&mut Vec::new()).unwrap_err();
    assert!(matches!(err, RewriteError::NoText { .. }), "{err}");
    assert!(
        err.to_string()
            .starts_with("in.g2o: its text cannot be read again"),
        "{err}"
    );
}

#[test]
fn a_file_is_read_again_through_its_handle_and_a_change_on_disk_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("g.g2o");
    let text =
        "VERTEX_SE2 0 0 0 0\n# keep me\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n";
    std::fs::write(&path, text).unwrap();
    let file = read(&path, ReadOptions::default()).unwrap();
    // Another file renamed over the path: the handle still reads the old one.
    let other = dir.path().join("other.g2o");
    std::fs::write(&other, "VERTEX_SE2 5 0 0 0\n").unwrap();
    std::fs::rename(&other, &path).unwrap();
    let mut out = Vec::new();
    file.rewrite(&mut out).unwrap();
    assert_eq!(String::from_utf8(out).unwrap(), text);
    // The file itself changed in place (same length, one byte).
    let path = dir.path().join("h.g2o");
    std::fs::write(&path, text).unwrap();
    let file = read(&path, ReadOptions::default()).unwrap();
    std::fs::write(&path, text.replace("keep", "lose")).unwrap();
    let err = file.rewrite(&mut Vec::new()).unwrap_err();
    assert!(
        matches!(err, RewriteError::Changed { line: None, .. }),
        "{err}"
    );
    assert!(
        err.to_string().contains("h.g2o: changed while pgo ran"),
        "{err}"
    );
}

#[test]
fn token_ends_count_any_whitespace() {
    assert_eq!(token_end("VERTEX_SE2 12 0 0 0\n", 2), 13);
    assert_eq!(token_end("  A\t\u{3000}b  c", 2), 8);
    assert_eq!(token_end("A b", 2), 3);
    assert_eq!(token_end("A", 2), 1);
}

#[test]
fn write_errors_keep_their_kind() {
    struct Broken;
    impl Write for Broken {
        fn write(&mut self, _: &[u8]) -> io::Result<usize> {
            Err(io::ErrorKind::BrokenPipe.into())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }
    let text = b"VERTEX_SE2 0 0 0 0\n";
    let err = parse(text)
        .rewrite_from(&text[..], &mut Broken)
        .unwrap_err();
    assert_eq!(io::Error::from(err).kind(), io::ErrorKind::BrokenPipe);
}
