//! STL loading: bad files (truncated, NaN, wrong counts, empty), the real sample and the object library.

use std::path::PathBuf;

use glam::Vec3;
use proptest::prelude::*;
use rig::geometry::objects::{load_object, object_names, object_path};
use rig::geometry::shapes::object_mesh;
use rig::geometry::stl::{Mesh, StlError};

fn shared() -> PathBuf {
    PathBuf::from(std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string()))
}

fn two_triangles() -> Mesh {
    Mesh::new(vec![[Vec3::ZERO, Vec3::X, Vec3::Y], [Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0)]])
}

const ASCII_OK: &str =
    "solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 1 0\n  endloop\n endfacet\nendsolid t\n";

#[test]
fn binary_and_ascii_load() {
    let m = two_triangles();
    assert_eq!(Mesh::from_bytes(&m.to_binary_bytes("x")).unwrap(), m);
    let a = Mesh::from_bytes(ASCII_OK.as_bytes()).unwrap();
    assert_eq!(a.triangles, vec![[Vec3::ZERO, Vec3::X, Vec3::Y]]);
}

#[test]
fn nan_vertex_is_rejected_binary_and_ascii() {
    let mut bytes = two_triangles().to_binary_bytes("x");
    // Triangle 1, vertex 2, y: 84 + 50 + 12 (normal) + 2 * 12 + 4.
    let off = 84 + 50 + 12 + 24 + 4;
    bytes[off..off + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    match Mesh::from_bytes(&bytes) {
        Err(StlError::NonFinite { triangle: 1, vertex: 2, .. }) => {}
        other => panic!("expected NonFinite at 1/2, got {other:?}"),
    }
    let ascii = ASCII_OK.replace("vertex 1 0 0", "vertex 1 nan 0");
    assert!(matches!(Mesh::from_bytes(ascii.as_bytes()), Err(StlError::NonFinite { triangle: 0, vertex: 1, .. })));
    let inf = ASCII_OK.replace("vertex 0 1 0", "vertex 0 inf 0");
    assert!(matches!(Mesh::from_bytes(inf.as_bytes()), Err(StlError::NonFinite { .. })));
}

#[test]
fn no_triangles_is_rejected() {
    let empty = Mesh::new(Vec::new()).to_binary_bytes("empty");
    assert_eq!(empty.len(), 84);
    assert!(matches!(Mesh::from_bytes(&empty), Err(StlError::NoTriangles { .. })));
    assert!(matches!(Mesh::from_bytes(b"solid nothing\nendsolid nothing\n"), Err(StlError::NoTriangles { .. })));
}

#[test]
fn truncated_file_is_rejected() {
    let bytes = two_triangles().to_binary_bytes("x");
    match Mesh::from_bytes(&bytes[..bytes.len() - 7]) {
        Err(StlError::Truncated { declared: 2, expected_len: 184, len: 177, .. }) => {}
        other => panic!("expected Truncated, got {other:?}"),
    }
    assert!(matches!(Mesh::from_bytes(&bytes[..50]), Err(StlError::TooShort { len: 50, .. })));
    // ASCII cut inside a loop.
    let cut = &ASCII_OK[..ASCII_OK.find("endloop").unwrap()];
    assert!(matches!(Mesh::from_bytes(cut.as_bytes()), Err(StlError::AsciiSyntax { .. })));
}

#[test]
fn wrong_triangle_count_is_rejected() {
    let mut bytes = two_triangles().to_binary_bytes("x");
    // Header says 1 triangle, body holds 2.
    bytes[80..84].copy_from_slice(&1u32.to_le_bytes());
    match Mesh::from_bytes(&bytes) {
        Err(StlError::CountMismatch { declared: 1, implied: 2, trailing: 0, .. }) => {}
        other => panic!("expected CountMismatch, got {other:?}"),
    }
    // Header says 3: the file is too short for that.
    bytes[80..84].copy_from_slice(&3u32.to_le_bytes());
    assert!(matches!(Mesh::from_bytes(&bytes), Err(StlError::Truncated { declared: 3, .. })));
    // An absurd count must not allocate or panic.
    bytes[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(Mesh::from_bytes(&bytes), Err(StlError::Truncated { .. })));
}

#[test]
fn ascii_syntax_errors_name_the_line() {
    let two_numbers = ASCII_OK.replace("vertex 0 0 0", "vertex 0 0");
    match Mesh::from_bytes(two_numbers.as_bytes()) {
        Err(StlError::AsciiSyntax { line: 4, .. }) => {}
        other => panic!("expected a syntax error on line 4, got {other:?}"),
    }
    let four_vertices = ASCII_OK.replace("vertex 0 1 0\n", "vertex 0 1 0\n vertex 1 1 0\n");
    assert!(matches!(Mesh::from_bytes(four_vertices.as_bytes()), Err(StlError::AsciiSyntax { line: 8, .. })));
    let junk = ASCII_OK.replace("endfacet", "teapot");
    assert!(matches!(Mesh::from_bytes(junk.as_bytes()), Err(StlError::AsciiSyntax { .. })));
}

#[test]
fn errors_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("broken.stl");
    let bytes = two_triangles().to_binary_bytes("x");
    std::fs::write(&path, &bytes[..100]).unwrap();
    let err = Mesh::load(&path).unwrap_err();
    let text = err.to_string();
    assert!(text.contains("broken.stl") && text.contains("truncated"), "{text}");
    let missing = Mesh::load(dir.path().join("missing.stl")).unwrap_err();
    assert!(matches!(missing, StlError::Io { .. }) && missing.to_string().contains("missing.stl"));
}

#[test]
fn real_sample_straight_edge() {
    let path = shared().join("real-sample/multidiffsense-example/stl/1.stl");
    let m = Mesh::load(&path).unwrap_or_else(|e| panic!("{e} (set RIG_SHARED)"));
    assert_eq!(m.triangles.len(), 44);
    let b = m.bounds();
    assert_eq!(b.min, Vec3::new(-8.0, -8.0, 0.0));
    assert_eq!(b.max, Vec3::new(8.0, 8.0, 20.0));
}

#[test]
fn library_files_match_the_generator_and_the_real_size() {
    let real = Mesh::load(shared().join("real-sample/multidiffsense-example/stl/1.stl")).unwrap().bounds();
    assert_eq!(object_names().len(), 8);
    for name in object_names() {
        let path = object_path(env!("CARGO_MANIFEST_DIR"), name);
        let file = Mesh::load(&path).unwrap_or_else(|e| panic!("{e}: run `rig objects generate`"));
        let generated = object_mesh(name).unwrap();
        assert_eq!(file.triangles.len(), generated.triangles.len(), "{name}");
        // Tolerance, not equality: sin/cos may differ in the last bit between platforms.
        let worst = file
            .triangles
            .iter()
            .flatten()
            .zip(generated.triangles.iter().flatten())
            .map(|(a, b)| (*a - *b).abs().max_element())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "{name}: committed STL differs from the generator by {worst} mm");
        assert_eq!(load_object(name).unwrap(), file);
        let b = file.bounds();
        assert!((b.size() - real.size()).abs().max_element() < 1e-4, "{name}: {:?} vs real {:?}", b.size(), real.size());
    }
    assert!(load_object("teapot").unwrap_err().to_string().contains("sphere"));
}

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = Mesh::from_bytes(&bytes);
    }

    #[test]
    fn corrupted_binary_never_panics_and_stays_finite(flips in proptest::collection::vec((0usize..184, any::<u8>()), 1..8)) {
        let mut bytes = two_triangles().to_binary_bytes("x");
        for (i, v) in flips {
            bytes[i] = v;
        }
        if let Ok(m) = Mesh::from_bytes(&bytes) {
            prop_assert!(m.triangles.iter().flatten().all(|v| v.is_finite()));
            prop_assert!(!m.triangles.is_empty());
        }
    }

    #[test]
    fn ascii_prefixes_never_panic(cut in 0usize..200) {
        let text = ASCII_OK.repeat(2);
        let _ = Mesh::from_bytes(&text.as_bytes()[..cut.min(text.len())]);
    }
}
