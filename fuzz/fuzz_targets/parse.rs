//! The g2o reader on arbitrary bytes: it must return a graph or an error
//! naming the file (and, for line problems, a line inside the input), never
//! panic, and whatever it reads must write back and read again to the same
//! graph.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pgo::ReadError;
use pgo::internals::{AnyGraph, ReadOptions, read_from, write_graph};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    for fix_information in [false, true] {
        let options = ReadOptions { fix_information };
        let file = match read_from(data, Path::new("fuzz.g2o"), options) {
            Ok(file) => file,
            Err(e) => {
                let message = e.to_string();
                assert!(message.starts_with("fuzz.g2o"), "{message}");
                if let ReadError::Line { line, .. } = e {
                    let lines = data.split(|&b| b == b'\n').count();
                    assert!(line >= 1 && line <= lines, "line {line} of {lines}");
                }
                continue;
            }
        };
        let mut text = Vec::new();
        match &file.graph {
            AnyGraph::Planar(g) => write_graph(g, &mut text),
            AnyGraph::Spatial(g) => write_graph(g, &mut text),
        }
        .expect("write to memory");
        let again = read_from(text.as_slice(), Path::new("again.g2o"), options)
            .unwrap_or_else(|e| panic!("written file does not read back: {e}"));
        match (&file.graph, &again.graph) {
            (AnyGraph::Planar(a), AnyGraph::Planar(b)) => {
                assert_eq!(a.num_vertices(), b.num_vertices());
                assert_eq!(a.edges.len(), b.edges.len());
            }
            (AnyGraph::Spatial(a), AnyGraph::Spatial(b)) => {
                assert_eq!(a.num_vertices(), b.num_vertices());
                assert_eq!(a.edges.len(), b.edges.len());
            }
            _ => panic!("the dimension changed on writing"),
        }
    }
});
