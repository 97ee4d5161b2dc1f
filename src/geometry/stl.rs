//! STL meshes: loading (binary and ASCII), validation and writing (binary).
//!
//! A [`Mesh`] is a triangle soup in millimetres, the unit of every STL file in rig. Loading
//! decides the dialect from the bytes, not the file name or the `solid` header (binary files
//! written by many CAD tools also begin with `solid`):
//!
//! 1. at least 84 bytes and `84 + 50 * count == len`: binary;
//! 2. otherwise, text starting with `solid`: ASCII;
//! 3. otherwise binary, and the length mismatch is the error.
//!
//! Binary layout (little endian), as in the de-facto STL specification:
//!
//! | offset      | size | type     | field                                  |
//! |-------------|------|----------|----------------------------------------|
//! | 0           | 80   | bytes    | header (free text, ignored)            |
//! | 80          | 4    | u32      | triangle count `n`                     |
//! | 84 + 50 i   | 12   | 3 x f32  | facet normal (ignored; recomputed)     |
//! | 96 + 50 i   | 36   | 9 x f32  | vertices 1..3, x y z in mm             |
//! | 132 + 50 i  | 2    | u16      | attribute byte count (ignored)         |
//!
//! Every mesh that loads has at least one triangle and only finite coordinates; the decoders
//! never panic on any input.

use std::fmt;
use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3};

/// Largest STL file read (a finely tessellated object is a few MB).
pub const MAX_STL_BYTES: u64 = 256 << 20;
/// Name used in errors for meshes parsed from memory.
const MEMORY_NAME: &str = "<memory>";
/// Size of the binary header plus triangle count.
const BINARY_HEADER_LEN: usize = 84;
/// Size of one binary triangle record.
const BINARY_TRIANGLE_LEN: usize = 50;

/// What is wrong with an STL file. Every variant names the file (`<memory>` for bytes).
#[derive(Debug, thiserror::Error)]
pub enum StlError {
    #[error("STL {file}: cannot read: {source}")]
    Io {
        file: String,
        #[source]
        source: std::io::Error,
    },
    #[error("STL {file}: {len} bytes is too short for a binary STL (header and count need 84) and it is not ASCII STL")]
    TooShort { file: String, len: usize },
    #[error("STL {file}: truncated: the header declares {declared} triangles ({expected_len} bytes) but the file has {len} bytes")]
    Truncated { file: String, declared: u32, expected_len: u64, len: usize },
    #[error(
        "STL {file}: wrong triangle count: the header declares {declared} triangles but the {len} bytes hold {implied} ({trailing} bytes left over)"
    )]
    CountMismatch { file: String, declared: u32, len: usize, implied: usize, trailing: usize },
    #[error("STL {file}: no triangles")]
    NoTriangles { file: String },
    #[error("STL {file}: triangle {triangle} vertex {vertex} is not finite ({value:?})")]
    NonFinite { file: String, triangle: usize, vertex: usize, value: [f32; 3] },
    /// `found` is kept for callers but not printed: it is the file's text.
    #[error("STL {file}: ASCII line {line}: expected {expected}")]
    AsciiSyntax { file: String, line: usize, expected: &'static str, found: String },
    #[error("STL {file}: ASCII file is not valid UTF-8 at byte {offset}")]
    AsciiEncoding { file: String, offset: usize },
    #[error("STL {file}: cannot write: {source}")]
    Write {
        file: String,
        #[source]
        source: std::io::Error,
    },
}

/// Axis-aligned bounding box, mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Aabb {
    /// Edge lengths, mm.
    pub fn size(&self) -> Vec3 {
        self.max - self.min
    }
}

/// A triangle mesh in millimetres (object frame: z up, the object's top is its largest z).
#[derive(Clone, PartialEq)]
pub struct Mesh {
    pub triangles: Vec<[Vec3; 3]>,
}

impl fmt::Debug for Mesh {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Thousands of vertices are no use in a debug print.
        let b = self.bounds();
        write!(f, "Mesh {{ {} triangles, bounds {:?}..{:?} }}", self.triangles.len(), b.min, b.max)
    }
}

impl Mesh {
    /// A mesh from triangles (not validated; for procedural meshes built in code).
    pub fn new(triangles: Vec<[Vec3; 3]>) -> Self {
        Self { triangles }
    }

    /// Loads and validates a binary or ASCII STL file.
    /// Reads at most [`MAX_STL_BYTES`] of a regular file.
    pub fn load(path: impl AsRef<Path>) -> Result<Mesh, StlError> {
        let path = path.as_ref();
        let name = path.display().to_string();
        let bytes = crate::untrusted::read_bytes(path, MAX_STL_BYTES).map_err(|source| StlError::Io { file: name.clone(), source })?;
        parse(&bytes, &name)
    }

    /// Parses and validates STL bytes (binary or ASCII).
    pub fn from_bytes(bytes: &[u8]) -> Result<Mesh, StlError> {
        parse(bytes, MEMORY_NAME)
    }

    /// Bounding box; a zero box at the origin for an empty mesh.
    pub fn bounds(&self) -> Aabb {
        let mut it = self.triangles.iter().flat_map(|t| t.iter().copied());
        let Some(first) = it.next() else {
            return Aabb { min: Vec3::ZERO, max: Vec3::ZERO };
        };
        let (min, max) = it.fold((first, first), |(lo, hi), v| (lo.min(v), hi.max(v)));
        Aabb { min, max }
    }

    /// Largest z, mm: the object's top, the height the sensor touches first.
    pub fn top_z_mm(&self) -> f32 {
        self.bounds().max.z
    }

    /// A copy with every vertex transformed by `m` (an affine transform).
    pub fn transformed(&self, m: Mat4) -> Mesh {
        Mesh { triangles: self.triangles.iter().map(|t| t.map(|v| m.transform_point3(v))).collect() }
    }

    /// Appends the triangles of `other`.
    pub fn append(&mut self, other: &Mesh) {
        self.triangles.extend_from_slice(&other.triangles);
    }

    /// Binary STL bytes (normals computed from the winding; zero for degenerate triangles).
    pub fn to_binary_bytes(&self, header_text: &str) -> Vec<u8> {
        let mut out = Vec::with_capacity(BINARY_HEADER_LEN + BINARY_TRIANGLE_LEN * self.triangles.len());
        let mut header = [b' '; 80];
        for (dst, src) in header.iter_mut().zip(header_text.bytes()) {
            *dst = src;
        }
        // A binary header must not start with "solid", or naive readers take it for ASCII.
        if header.starts_with(b"solid") {
            header[0] = b'S';
        }
        out.extend_from_slice(&header);
        out.extend_from_slice(&(self.triangles.len() as u32).to_le_bytes());
        for t in &self.triangles {
            let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
            for v in std::iter::once(n).chain(t.iter().copied()) {
                for c in v.to_array() {
                    out.extend_from_slice(&c.to_le_bytes());
                }
            }
            out.extend_from_slice(&0u16.to_le_bytes());
        }
        out
    }

    /// Writes a binary STL file.
    pub fn save(&self, path: impl AsRef<Path>, header_text: &str) -> Result<(), StlError> {
        let path: PathBuf = path.as_ref().to_path_buf();
        std::fs::write(&path, self.to_binary_bytes(header_text))
            .map_err(|source| StlError::Write { file: path.display().to_string(), source })
    }
}

fn parse(bytes: &[u8], name: &str) -> Result<Mesh, StlError> {
    let binary_count = binary_count(bytes);
    let mesh = match binary_count {
        Some(n) if BINARY_HEADER_LEN as u64 + BINARY_TRIANGLE_LEN as u64 * n as u64 == bytes.len() as u64 => {
            parse_binary(bytes, n as usize)
        }
        _ if looks_ascii(bytes) => parse_ascii(bytes, name)?,
        None => return Err(StlError::TooShort { file: name.to_string(), len: bytes.len() }),
        Some(declared) => {
            let expected_len = BINARY_HEADER_LEN as u64 + BINARY_TRIANGLE_LEN as u64 * declared as u64;
            if (bytes.len() as u64) < expected_len {
                return Err(StlError::Truncated { file: name.to_string(), declared, expected_len, len: bytes.len() });
            }
            let body = bytes.len() - BINARY_HEADER_LEN;
            return Err(StlError::CountMismatch {
                file: name.to_string(),
                declared,
                len: bytes.len(),
                implied: body / BINARY_TRIANGLE_LEN,
                trailing: body % BINARY_TRIANGLE_LEN,
            });
        }
    };
    validate(mesh, name)
}

fn binary_count(bytes: &[u8]) -> Option<u32> {
    let raw: [u8; 4] = bytes.get(80..84)?.try_into().ok()?;
    Some(u32::from_le_bytes(raw))
}

fn looks_ascii(bytes: &[u8]) -> bool {
    let start = bytes.iter().position(|b| !b.is_ascii_whitespace()).unwrap_or(bytes.len());
    bytes[start..].len() >= 5 && bytes[start..start + 5].eq_ignore_ascii_case(b"solid")
}

/// Caller has checked that `bytes` holds exactly `n` records.
fn parse_binary(bytes: &[u8], n: usize) -> Mesh {
    let f = |o: usize| -> f32 {
        let mut b = [0u8; 4];
        b.copy_from_slice(&bytes[o..o + 4]);
        f32::from_le_bytes(b)
    };
    let triangles = (0..n)
        .map(|i| {
            let base = BINARY_HEADER_LEN + BINARY_TRIANGLE_LEN * i + 12;
            let v = |k: usize| Vec3::new(f(base + 12 * k), f(base + 12 * k + 4), f(base + 12 * k + 8));
            [v(0), v(1), v(2)]
        })
        .collect();
    Mesh { triangles }
}

fn parse_ascii(bytes: &[u8], name: &str) -> Result<Mesh, StlError> {
    let text = std::str::from_utf8(bytes).map_err(|e| StlError::AsciiEncoding { file: name.to_string(), offset: e.valid_up_to() })?;
    let syntax = |line: usize, expected: &'static str, found: &str| StlError::AsciiSyntax {
        file: name.to_string(),
        line,
        expected,
        found: found.chars().take(60).collect(),
    };
    let mut triangles = Vec::new();
    let mut loop_vertices: Option<Vec<Vec3>> = None;
    let mut ended = false;
    for (i, raw_line) in text.lines().enumerate() {
        let line_no = i + 1;
        let line = raw_line.trim();
        if line.is_empty() {
            continue;
        }
        let mut words = line.split_whitespace();
        let keyword = words.next().unwrap_or_default().to_ascii_lowercase();
        if ended {
            // Some exporters write several solids into one file; anything else is junk.
            if keyword == "solid" {
                ended = false;
                continue;
            }
            return Err(syntax(line_no, "solid or nothing after endsolid", line));
        }
        match keyword.as_str() {
            "solid" if triangles.is_empty() && loop_vertices.is_none() => {}
            "facet" | "endfacet" => {}
            "outer" => {
                if loop_vertices.is_some() {
                    return Err(syntax(line_no, "endloop before a new loop", line));
                }
                loop_vertices = Some(Vec::with_capacity(3));
            }
            "vertex" => {
                let Some(vs) = loop_vertices.as_mut() else {
                    return Err(syntax(line_no, "vertex only inside outer loop", line));
                };
                let mut xyz = [0.0f32; 3];
                for c in &mut xyz {
                    *c = words
                        .next()
                        .and_then(|w| w.parse::<f32>().ok())
                        .ok_or_else(|| syntax(line_no, "vertex x y z (three numbers)", line))?;
                }
                vs.push(Vec3::from_array(xyz));
            }
            "endloop" => {
                let Some(vs) = loop_vertices.take() else {
                    return Err(syntax(line_no, "endloop only after outer loop", line));
                };
                if vs.len() != 3 {
                    return Err(syntax(line_no, "exactly 3 vertices per loop", line));
                }
                triangles.push([vs[0], vs[1], vs[2]]);
            }
            "endsolid" => ended = true,
            _ => return Err(syntax(line_no, "an STL keyword (facet, outer loop, vertex, endloop, endfacet)", line)),
        }
    }
    if loop_vertices.is_some() {
        return Err(syntax(text.lines().count(), "endloop before the end of the file (truncated?)", ""));
    }
    Ok(Mesh { triangles })
}

fn validate(mesh: Mesh, name: &str) -> Result<Mesh, StlError> {
    if mesh.triangles.is_empty() {
        return Err(StlError::NoTriangles { file: name.to_string() });
    }
    for (ti, t) in mesh.triangles.iter().enumerate() {
        for (vi, v) in t.iter().enumerate() {
            if !v.is_finite() {
                return Err(StlError::NonFinite { file: name.to_string(), triangle: ti, vertex: vi, value: v.to_array() });
            }
        }
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_triangle() -> Mesh {
        Mesh::new(vec![[Vec3::ZERO, Vec3::X, Vec3::Y]])
    }

    #[test]
    fn binary_round_trip() {
        let m = one_triangle();
        let bytes = m.to_binary_bytes("solid-looking header");
        assert_eq!(bytes.len(), 84 + 50);
        assert_eq!(Mesh::from_bytes(&bytes).unwrap(), m);
    }

    #[test]
    fn binary_header_starting_with_solid_still_binary() {
        let mut bytes = one_triangle().to_binary_bytes("");
        bytes[..5].copy_from_slice(b"solid");
        assert_eq!(Mesh::from_bytes(&bytes).unwrap().triangles.len(), 1);
    }

    #[test]
    fn arbitrary_prefixes_never_panic() {
        let bytes = one_triangle().to_binary_bytes("x");
        for len in 0..bytes.len() {
            let _ = Mesh::from_bytes(&bytes[..len]);
        }
        let ascii = b"solid a\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid a\n";
        for len in 0..ascii.len() {
            let _ = Mesh::from_bytes(&ascii[..len]);
        }
        assert_eq!(Mesh::from_bytes(ascii).unwrap().triangles.len(), 1);
        let two_solids = [&ascii[..], &ascii[..]].concat();
        assert_eq!(Mesh::from_bytes(&two_solids).unwrap().triangles.len(), 2);
        let trailing = [&ascii[..], b"garbage\n"].concat();
        assert!(matches!(Mesh::from_bytes(&trailing), Err(StlError::AsciiSyntax { line: 10, .. })));
    }
}
