//! Just enough of the ONNX file format to learn how many times a UNet halves its input: the
//! count of `Conv` nodes with stride 2 in the main graph.
//!
//! Why: a diffusers UNet downsamples its latent once per down block but the last (a `Conv`
//! of stride 2 in each `Downsample2D`), then upsamples and concatenates with the skips; a
//! latent side that does not divide by `2^downsamples` passes the first convolutions and fails
//! deep inside ONNX Runtime at the first concatenation. Knowing the count, a size is refused
//! up front with a message that says which multiple it must be. The shapes the session reports
//! cannot tell (the exports have symbolic spatial dimensions), the graph can.
//!
//! Wire format (protobuf, `onnx.proto`), the fields read:
//!
//! | message | field | number | wire type |
//! |---|---|---|---|
//! | `ModelProto` | `graph` | 7 | length-delimited |
//! | `GraphProto` | `node` (repeated) | 1 | length-delimited |
//! | `NodeProto` | `op_type` | 4 | length-delimited (UTF-8) |
//! | `NodeProto` | `attribute` (repeated) | 5 | length-delimited |
//! | `AttributeProto` | `name` | 1 | length-delimited (UTF-8) |
//! | `AttributeProto` | `ints` (repeated int64) | 8 | varint, or packed |
//!
//! Every other field is skipped by its length without being read (the weights, the bulk of a
//! file, are `GraphProto.initializer`), so a 2 GB model is scanned in a few reads. Any bytes
//! give a count or an error, never a panic.

use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

/// Largest node read into memory (a node is a few hundred bytes; a `Constant` node can carry
/// a tensor, which is skipped instead).
const MAX_NODE_BYTES: u64 = 1 << 20;

/// Why a graph could not be scanned.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct GraphScanError(pub &'static str);

/// The number of stride-2 `Conv` nodes in the main graph of the ONNX file at `path`.
pub fn count_stride2_convs(path: &Path) -> Result<usize, GraphScanError> {
    // A package file, already confined when the package was opened; opened again here so that
    // nothing swapped in since (a FIFO, a device) can block the scan.
    let file = crate::confine::open_operator_file(path).map_err(|_| GraphScanError("cannot open the model file"))?;
    let len = file.metadata().map_err(|_| GraphScanError("cannot read the model file"))?.len();
    let mut reader = BufReader::with_capacity(1 << 16, file);
    let mut count = 0;
    let mut at = 0u64;
    while at < len {
        let (field, wire) = read_tag(&mut reader, &mut at)?;
        match (field, wire) {
            (7, 2) => {
                let graph_len = read_varint(&mut reader, &mut at)?;
                let end = at.checked_add(graph_len).filter(|&e| e <= len).ok_or(GraphScanError("graph longer than the file"))?;
                count += scan_graph(&mut reader, &mut at, end)?;
            }
            (_, wire) => skip(&mut reader, &mut at, wire, len)?,
        }
    }
    Ok(count)
}

/// The `location`s of the external data the main graph's initializers name (tensors stored in
/// a file beside the model instead of inside it): ONNX Runtime opens each, relative to the
/// model's folder, so the package loader checks them through [`crate::confine`] first.
///
/// | message | field | number | wire type |
/// |---|---|---|---|
/// | `GraphProto` | `initializer` (repeated `TensorProto`) | 5 | length-delimited |
/// | `TensorProto` | `external_data` (repeated `StringStringEntryProto`) | 13 | length-delimited |
/// | `StringStringEntryProto` | `key`, `value` | 1, 2 | length-delimited (UTF-8) |
///
/// An initializer larger than 1 MiB holds its data inline and is skipped unread. `file` is the
/// model, opened by the caller (the package loader opens it through the opener).
pub fn external_data_locations(file: std::fs::File) -> Result<Vec<String>, GraphScanError> {
    let len = file.metadata().map_err(|_| GraphScanError("cannot read the model file"))?.len();
    let mut reader = BufReader::with_capacity(1 << 16, file);
    let mut locations = Vec::new();
    let mut at = 0u64;
    while at < len {
        let (field, wire) = read_tag(&mut reader, &mut at)?;
        if (field, wire) != (7, 2) {
            skip(&mut reader, &mut at, wire, len)?;
            continue;
        }
        let graph_len = read_varint(&mut reader, &mut at)?;
        let end = at.checked_add(graph_len).filter(|&e| e <= len).ok_or(GraphScanError("graph longer than the file"))?;
        while at < end {
            let (field, wire) = read_tag(&mut reader, &mut at)?;
            if (field, wire) != (5, 2) {
                skip(&mut reader, &mut at, wire, end)?;
                continue;
            }
            let tensor_len = read_varint(&mut reader, &mut at)?;
            if tensor_len > end - at {
                return Err(GraphScanError("initializer longer than its graph"));
            }
            if tensor_len > MAX_NODE_BYTES {
                seek(&mut reader, &mut at, tensor_len)?;
                continue;
            }
            let mut tensor = vec![0u8; tensor_len as usize];
            reader.read_exact(&mut tensor).map_err(|_| GraphScanError("truncated initializer"))?;
            at += tensor_len;
            for (f, v) in Fields::new(&tensor) {
                if let (13, Value::Bytes(entry)) = (f, v?) {
                    let (mut key, mut value) = (None, None);
                    for (ef, ev) in Fields::new(entry) {
                        match (ef, ev?) {
                            (1, Value::Bytes(k)) => key = Some(k),
                            (2, Value::Bytes(v)) => value = Some(v),
                            _ => {}
                        }
                    }
                    if key == Some(b"location".as_slice())
                        && let Some(v) = value
                    {
                        locations.push(String::from_utf8_lossy(v).into_owned());
                    }
                }
            }
        }
    }
    locations.sort();
    locations.dedup();
    Ok(locations)
}

fn scan_graph<R: Read + Seek>(r: &mut R, at: &mut u64, end: u64) -> Result<usize, GraphScanError> {
    let mut count = 0;
    while *at < end {
        let (field, wire) = read_tag(r, at)?;
        if (field, wire) == (1, 2) {
            let node_len = read_varint(r, at)?;
            if node_len > end - *at {
                return Err(GraphScanError("node longer than its graph"));
            }
            if node_len > MAX_NODE_BYTES {
                seek(r, at, node_len)?;
                continue;
            }
            let mut node = vec![0u8; node_len as usize];
            r.read_exact(&mut node).map_err(|_| GraphScanError("truncated node"))?;
            *at += node_len;
            if is_stride2_conv(&node)? {
                count += 1;
            }
        } else {
            skip(r, at, wire, end)?;
        }
    }
    Ok(count)
}

fn is_stride2_conv(node: &[u8]) -> Result<bool, GraphScanError> {
    let mut op_conv = false;
    let mut stride2 = false;
    for (field, value) in Fields::new(node) {
        match (field, value?) {
            (4, Value::Bytes(op)) => op_conv = op == b"Conv",
            (5, Value::Bytes(attribute)) => {
                let mut name_strides = false;
                let mut ints = Vec::new();
                for (f, v) in Fields::new(attribute) {
                    match (f, v?) {
                        (1, Value::Bytes(name)) => name_strides = name == b"strides",
                        (8, Value::Varint(v)) => ints.push(v),
                        (8, Value::Bytes(packed)) => {
                            let mut p = packed;
                            while !p.is_empty() {
                                ints.push(varint_from(&mut p)?);
                            }
                        }
                        _ => {}
                    }
                }
                if name_strides && ints.contains(&2) {
                    stride2 = true;
                }
            }
            _ => {}
        }
    }
    Ok(op_conv && stride2)
}

/// One field's value.
enum Value<'a> {
    Varint(u64),
    Bytes(&'a [u8]),
    Fixed,
}

/// The fields of a message held in memory.
struct Fields<'a> {
    rest: &'a [u8],
    failed: bool,
}

impl<'a> Fields<'a> {
    fn new(bytes: &'a [u8]) -> Self {
        Self { rest: bytes, failed: false }
    }

    fn next_field(&mut self) -> Result<(u64, Value<'a>), GraphScanError> {
        let tag = varint_from(&mut self.rest)?;
        let field = tag >> 3;
        let value = match tag & 7 {
            0 => Value::Varint(varint_from(&mut self.rest)?),
            1 => {
                self.rest = self.rest.get(8..).ok_or(GraphScanError("truncated fixed64"))?;
                Value::Fixed
            }
            2 => {
                let len = usize::try_from(varint_from(&mut self.rest)?).map_err(|_| GraphScanError("length too large"))?;
                let bytes = self.rest.get(..len).ok_or(GraphScanError("truncated field"))?;
                self.rest = &self.rest[len..];
                Value::Bytes(bytes)
            }
            5 => {
                self.rest = self.rest.get(4..).ok_or(GraphScanError("truncated fixed32"))?;
                Value::Fixed
            }
            _ => return Err(GraphScanError("unknown wire type")),
        };
        Ok((field, value))
    }
}

impl<'a> Iterator for Fields<'a> {
    type Item = (u64, Result<Value<'a>, GraphScanError>);
    fn next(&mut self) -> Option<Self::Item> {
        if self.failed || self.rest.is_empty() {
            return None;
        }
        match self.next_field() {
            Ok((field, value)) => Some((field, Ok(value))),
            Err(e) => {
                self.failed = true;
                Some((0, Err(e)))
            }
        }
    }
}

fn varint_from(bytes: &mut &[u8]) -> Result<u64, GraphScanError> {
    let mut value = 0u64;
    for k in 0..10 {
        let (&b, rest) = bytes.split_first().ok_or(GraphScanError("truncated varint"))?;
        *bytes = rest;
        value |= u64::from(b & 0x7f) << (7 * k);
        if b < 0x80 {
            return Ok(value);
        }
    }
    Err(GraphScanError("varint longer than 10 bytes"))
}

fn read_varint<R: Read>(r: &mut R, at: &mut u64) -> Result<u64, GraphScanError> {
    let mut value = 0u64;
    for k in 0..10 {
        let mut b = [0u8; 1];
        r.read_exact(&mut b).map_err(|_| GraphScanError("truncated varint"))?;
        *at += 1;
        value |= u64::from(b[0] & 0x7f) << (7 * k);
        if b[0] < 0x80 {
            return Ok(value);
        }
    }
    Err(GraphScanError("varint longer than 10 bytes"))
}

fn read_tag<R: Read>(r: &mut R, at: &mut u64) -> Result<(u64, u64), GraphScanError> {
    let tag = read_varint(r, at)?;
    Ok((tag >> 3, tag & 7))
}

fn seek<R: Seek>(r: &mut R, at: &mut u64, n: u64) -> Result<(), GraphScanError> {
    let n_i64 = i64::try_from(n).map_err(|_| GraphScanError("length too large"))?;
    r.seek(SeekFrom::Current(n_i64)).map_err(|_| GraphScanError("cannot seek"))?;
    *at += n;
    Ok(())
}

/// Skips one field's value of wire type `wire`, which must end by `end`.
fn skip<R: Read + Seek>(r: &mut R, at: &mut u64, wire: u64, end: u64) -> Result<(), GraphScanError> {
    let n = match wire {
        0 => {
            read_varint(r, at)?;
            return Ok(());
        }
        1 => 8,
        2 => read_varint(r, at)?,
        5 => 4,
        _ => return Err(GraphScanError("unknown wire type")),
    };
    if n > end.saturating_sub(*at) {
        return Err(GraphScanError("field longer than its message"));
    }
    seek(r, at, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A protobuf length-delimited field.
    fn ld(field: u64, bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        for mut v in [(field << 3) | 2, bytes.len() as u64] {
            loop {
                let b = (v & 0x7f) as u8;
                v >>= 7;
                if v == 0 {
                    out.push(b);
                    break;
                }
                out.push(b | 0x80);
            }
        }
        out.extend_from_slice(bytes);
        out
    }

    #[test]
    fn external_data_locations_are_found() {
        let entry = |k: &str, v: &str| ld(13, &[ld(1, k.as_bytes()), ld(2, v.as_bytes())].concat());
        let tensor = [ld(8, b"w"), entry("location", "../../outside/secret"), entry("offset", "0")].concat();
        let other = [ld(8, b"b"), entry("location", "weights.bin")].concat();
        let graph = [ld(1, b"node"), ld(5, &tensor), ld(5, &other), ld(5, &ld(8, b"inline"))].concat();
        let model = [ld(2, b"producer"), ld(7, &graph)].concat();
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("m.onnx");
        std::fs::write(&path, &model).expect("write");
        let open = |p: &Path| std::fs::File::open(p).expect("open");
        assert_eq!(external_data_locations(open(&path)), Ok(vec!["../../outside/secret".to_string(), "weights.bin".to_string()]));
        std::fs::write(&path, &model[..model.len() - 3]).expect("write");
        assert!(external_data_locations(open(&path)).is_err(), "truncated");
        assert_eq!(external_data_locations(open(&tiny("unet"))), Ok(vec![]));
    }

    fn tiny(model: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tiny-package").join(model).join("model.onnx")
    }

    #[test]
    fn the_tiny_unet_downsamples_once() {
        // Two down blocks (tools/make_tiny_package.py): one Downsample2D.
        assert_eq!(count_stride2_convs(&tiny("unet")), Ok(1));
    }

    #[test]
    fn hand_made_graphs_count_only_stride2_convs() {
        fn field(n: u64, bytes: &[u8]) -> Vec<u8> {
            let mut out = vec![(n << 3 | 2) as u8, bytes.len() as u8];
            out.extend_from_slice(bytes);
            out
        }
        let strides = |packed: bool, s: u8| {
            let mut a = field(1, b"strides");
            if packed {
                a.extend(field(8, &[s, s]));
            } else {
                a.extend([8 << 3, s, 8 << 3, s]);
            }
            a
        };
        let node = |op: &[u8], s: u8, packed: bool| [field(4, op), field(5, &strides(packed, s))].concat();
        let graph = [
            field(1, &node(b"Conv", 2, true)),
            field(1, &node(b"Conv", 2, false)),
            field(1, &node(b"Conv", 1, true)),
            field(1, &node(b"MaxPool", 2, true)),
            field(5, b"weights skipped"),
        ]
        .concat();
        let model = [vec![0x08, 0x08], field(7, &graph)].concat();
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("m.onnx");
        std::fs::write(&path, &model).expect("write");
        assert_eq!(count_stride2_convs(&path), Ok(2));
        // Every truncation is an error or a count, never a panic.
        for cut in 0..model.len() {
            std::fs::write(&path, &model[..cut]).expect("write");
            let _ = count_stride2_convs(&path);
        }
        std::fs::write(&path, [0xffu8; 64]).expect("write");
        assert!(count_stride2_convs(&path).is_err());
    }
}
