//! Minimal NumPy `.npy` reading and writing for little-endian float32 arrays.
//!
//! Used to exchange latents and decoded images with Python (diffusers / onnxruntime runs):
//! `rig synth one --init-latents` reads one, `--dump-raw` writes one, and the parity tests read
//! the committed reference run.
//!
//! Format (NumPy's "NEP 1" `.npy`, versions 1.0, 2.0 and 3.0):
//!
//! | offset | size | content |
//! |---|---|---|
//! | 0 | 6 | magic `\x93NUMPY` |
//! | 6 | 1 | major version (1, 2 or 3) |
//! | 7 | 1 | minor version (0) |
//! | 8 | 2 (v1) or 4 (v2, v3) | header length `H`, little-endian |
//! | 10 or 12 | `H` | Python dict literal: `{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }`, space-padded, `\n`-terminated |
//! | after | 4 * prod(shape) | the data, C order |
//!
//! Only `descr` `<f4` (also written `float32` by some tools: not accepted, NumPy writes `<f4`)
//! and C order are accepted; anything else is a typed [`NpyError`]. The decoder never panics on
//! any input: every length is checked before it is used.

use std::path::{Path, PathBuf};

/// Largest `.npy` file rig reads: 256 MiB, room for a batch of 16 latents at the largest size
/// (16 x 4 x 256 x 256 float32, 16 MiB) and a decoded 2048 px image, and nothing near memory.
pub const MAX_NPY_BYTES: u64 = 256 << 20;

/// A float32 array with its shape (C order).
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// Why a `.npy` file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    /// Not a regular file, missing, or larger than [`MAX_NPY_BYTES`] ([`crate::confine`]).
    #[error(transparent)]
    File(#[from] crate::confine::ConfineError),
    #[error("not a .npy file: the first bytes are not \\x93NUMPY")]
    BadMagic,
    #[error(".npy version {major}.{minor} is not supported (1.0, 2.0, 3.0 are)")]
    UnsupportedVersion { major: u8, minor: u8 },
    #[error(".npy file truncated: needed {needed} bytes, have {have}")]
    Truncated { needed: usize, have: usize },
    #[error(".npy header is not valid: {reason} (header: {header:?})")]
    BadHeader { reason: &'static str, header: String },
    #[error(".npy dtype {descr:?} is not supported: rig reads little-endian float32 ('<f4') only")]
    UnsupportedDtype { descr: String },
    #[error(".npy array is in Fortran order; save it with np.ascontiguousarray first")]
    FortranOrder,
    #[error(".npy shape {shape:?} has {elements} elements but the array holds {data_len}")]
    ShapeMismatch { shape: Vec<usize>, elements: usize, data_len: usize },
}

impl NpyArray {
    /// An array of `shape` filled from `data`; fails when the element counts differ.
    pub fn new(shape: Vec<usize>, data: Vec<f32>) -> Result<Self, NpyError> {
        let elements =
            element_count(&shape).ok_or(NpyError::ShapeMismatch { shape: shape.clone(), elements: usize::MAX, data_len: data.len() })?;
        if elements != data.len() {
            return Err(NpyError::ShapeMismatch { shape, elements, data_len: data.len() });
        }
        Ok(Self { shape, data })
    }

    /// Decodes `.npy` bytes.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, NpyError> {
        if bytes.len() < 8 {
            return Err(NpyError::Truncated { needed: 8, have: bytes.len() });
        }
        if &bytes[..6] != b"\x93NUMPY" {
            return Err(NpyError::BadMagic);
        }
        let (major, minor) = (bytes[6], bytes[7]);
        let (header_len, header_start) = match (major, minor) {
            (1, 0) => {
                let b = bytes.get(8..10).ok_or(NpyError::Truncated { needed: 10, have: bytes.len() })?;
                (u16::from_le_bytes([b[0], b[1]]) as usize, 10usize)
            }
            (2, 0) | (3, 0) => {
                let b = bytes.get(8..12).ok_or(NpyError::Truncated { needed: 12, have: bytes.len() })?;
                (u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize, 12usize)
            }
            _ => return Err(NpyError::UnsupportedVersion { major, minor }),
        };
        let header_end = header_start.checked_add(header_len).ok_or(NpyError::Truncated { needed: usize::MAX, have: bytes.len() })?;
        let header_bytes = bytes.get(header_start..header_end).ok_or(NpyError::Truncated { needed: header_end, have: bytes.len() })?;
        let header = String::from_utf8_lossy(header_bytes).into_owned();
        let parsed = parse_header(&header)?;
        if parsed.descr != "<f4" {
            return Err(NpyError::UnsupportedDtype { descr: parsed.descr });
        }
        if parsed.fortran_order {
            return Err(NpyError::FortranOrder);
        }
        let elements = element_count(&parsed.shape).ok_or(NpyError::BadHeader { reason: "shape overflows", header: header.clone() })?;
        let data_bytes = &bytes[header_end..];
        let needed = elements.checked_mul(4).ok_or(NpyError::BadHeader { reason: "shape overflows", header })?;
        if data_bytes.len() < needed {
            return Err(NpyError::Truncated { needed: header_end + needed, have: bytes.len() });
        }
        let data = data_bytes[..needed].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        Ok(Self { shape: parsed.shape, data })
    }

    /// Encodes as a version 1.0 `.npy` (what `np.save` writes for small headers).
    pub fn to_bytes(&self) -> Vec<u8> {
        let shape = match self.shape.len() {
            0 => "()".to_string(),
            1 => format!("({},)", self.shape[0]),
            _ => format!("({})", self.shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")),
        };
        let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
        // Pad so that the data starts on a 64-byte boundary, as NumPy does.
        let unpadded = 10 + header.len() + 1;
        let pad = (64 - unpadded % 64) % 64;
        header.extend(std::iter::repeat_n(' ', pad));
        header.push('\n');
        let mut out = Vec::with_capacity(10 + header.len() + self.data.len() * 4);
        out.extend_from_slice(b"\x93NUMPY\x01\x00");
        out.extend_from_slice(&(header.len() as u16).to_le_bytes());
        out.extend_from_slice(header.as_bytes());
        for v in &self.data {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    /// Reads a `.npy` file the operator named: a regular file (their symlinks followed) of at
    /// most [`MAX_NPY_BYTES`], through [`crate::confine::read_operator_file`].
    pub fn read(path: &Path) -> Result<Self, NpyError> {
        let bytes = crate::confine::read_operator_file(path, MAX_NPY_BYTES)?;
        Self::from_bytes(&bytes)
    }

    /// Writes a `.npy` file.
    pub fn write(&self, path: &Path) -> Result<(), NpyError> {
        std::fs::write(path, self.to_bytes()).map_err(|source| NpyError::Io { path: path.to_path_buf(), source })
    }
}

fn element_count(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

struct Header {
    descr: String,
    fortran_order: bool,
    shape: Vec<usize>,
}

/// Parses the header dict. NumPy always writes the three keys `descr`, `fortran_order`,
/// `shape`; this reads each by key, so their order does not matter.
fn parse_header(header: &str) -> Result<Header, NpyError> {
    let bad = |reason| NpyError::BadHeader { reason, header: header.to_string() };
    let descr = {
        let rest = after_key(header, "descr").ok_or_else(|| bad("no 'descr' key"))?;
        let quote = rest.chars().next().ok_or_else(|| bad("'descr' has no value"))?;
        if quote != '\'' && quote != '"' {
            return Err(bad("'descr' is not a string"));
        }
        let body = &rest[1..];
        let end = body.find(quote).ok_or_else(|| bad("'descr' string is not closed"))?;
        body[..end].to_string()
    };
    let fortran_order = {
        let rest = after_key(header, "fortran_order").ok_or_else(|| bad("no 'fortran_order' key"))?;
        if rest.starts_with("True") {
            true
        } else if rest.starts_with("False") {
            false
        } else {
            return Err(bad("'fortran_order' is neither True nor False"));
        }
    };
    let shape = {
        let rest = after_key(header, "shape").ok_or_else(|| bad("no 'shape' key"))?;
        let body = rest.strip_prefix('(').ok_or_else(|| bad("'shape' is not a tuple"))?;
        let end = body.find(')').ok_or_else(|| bad("'shape' tuple is not closed"))?;
        let mut dims = Vec::new();
        for part in body[..end].split(',') {
            let part = part.trim().trim_end_matches('L');
            if part.is_empty() {
                continue;
            }
            dims.push(part.parse::<usize>().map_err(|_| bad("'shape' holds a non-integer"))?);
        }
        dims
    };
    Ok(Header { descr, fortran_order, shape })
}

/// The text after `'key':` (or `"key":`), leading spaces skipped.
fn after_key<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    for quote in ['\'', '"'] {
        let pattern = format!("{quote}{key}{quote}");
        if let Some(i) = header.find(&pattern) {
            let rest = header[i + pattern.len()..].trim_start();
            let rest = rest.strip_prefix(':')?;
            return Some(rest.trim_start());
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let a = NpyArray::new(vec![2, 3], vec![1.0, -2.5, 3.25, 0.0, f32::MAX, 1e-8]).unwrap();
        let bytes = a.to_bytes();
        assert_eq!((10 + u16::from_le_bytes([bytes[8], bytes[9]]) as usize) % 64, 0);
        assert_eq!(NpyArray::from_bytes(&bytes).unwrap(), a);
        let scalar = NpyArray::new(vec![], vec![7.0]).unwrap();
        assert_eq!(NpyArray::from_bytes(&scalar.to_bytes()).unwrap(), scalar);
        let one = NpyArray::new(vec![3], vec![1.0, 2.0, 3.0]).unwrap();
        assert_eq!(NpyArray::from_bytes(&one.to_bytes()).unwrap(), one);
    }

    #[test]
    fn literal_numpy_bytes() {
        // np.save of np.array([[1, 2]], dtype='<f4'), header as NumPy 1.x/2.x writes it.
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        let mut header = "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 2), }".to_string();
        while !(10 + header.len() + 1).is_multiple_of(64) {
            header.push(' ');
        }
        header.push('\n');
        bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
        bytes.extend_from_slice(header.as_bytes());
        bytes.extend_from_slice(&1.0f32.to_le_bytes());
        bytes.extend_from_slice(&2.0f32.to_le_bytes());
        let a = NpyArray::from_bytes(&bytes).unwrap();
        assert_eq!(a.shape, vec![1, 2]);
        assert_eq!(a.data, vec![1.0, 2.0]);
    }

    #[test]
    fn rejects_bad_files() {
        assert!(matches!(NpyArray::from_bytes(b"hello world"), Err(NpyError::BadMagic)));
        assert!(matches!(NpyArray::from_bytes(b"\x93NU"), Err(NpyError::Truncated { .. })));
        let f64_header = "{'descr': '<f8', 'fortran_order': False, 'shape': (1,), }\n";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(f64_header.len() as u16).to_le_bytes());
        bytes.extend_from_slice(f64_header.as_bytes());
        bytes.extend_from_slice(&[0u8; 8]);
        assert!(matches!(NpyArray::from_bytes(&bytes), Err(NpyError::UnsupportedDtype { .. })));
        let a = NpyArray::new(vec![4], vec![1.0; 4]).unwrap();
        let full = a.to_bytes();
        assert!(matches!(NpyArray::from_bytes(&full[..full.len() - 1]), Err(NpyError::Truncated { .. })));
        assert!(NpyArray::new(vec![2, 2], vec![0.0; 3]).is_err());
    }

    #[test]
    fn files_are_read_bounded_and_regular_only() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("a.npy");
        let a = NpyArray::new(vec![1, 4, 2, 2], (0..16).map(|i| i as f32).collect()).expect("array");
        a.write(&path).expect("write");
        assert_eq!(NpyArray::read(&path).expect("read"), a);
        // A file larger than the bound is refused before it is read (a sparse file: no disk used).
        let big = dir.path().join("big.npy");
        std::fs::File::create(&big).and_then(|f| f.set_len(MAX_NPY_BYTES + 1)).expect("sparse file");
        let e = NpyArray::read(&big).expect_err("too large");
        assert!(matches!(e, NpyError::File(crate::confine::ConfineError::TooLarge { .. })), "{e}");
        let e = NpyArray::read(dir.path()).expect_err("a folder");
        assert!(matches!(e, NpyError::File(crate::confine::ConfineError::NotRegular { .. })), "{e}");
    }

    proptest::proptest! {
        #[test]
        fn never_panics(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..200)) {
            let _ = NpyArray::from_bytes(&bytes);
            let mut with_magic = b"\x93NUMPY\x01\x00".to_vec();
            with_magic.extend_from_slice(&bytes);
            let _ = NpyArray::from_bytes(&with_magic);
        }
    }
}
