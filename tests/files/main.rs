//! Reading files from outside: datasets, the MDS dialect, plans, STL, and decoders fed arbitrary bytes.
//!
//! One test binary per area; run one module with
//! `cargo test --test files <module>::`.

#[cfg(feature = "lerobot")]
mod dataset_lerobot;
mod dataset_mds;
mod dataset_verify;
mod decoders_never_panic;
mod geometry_stl;
mod job_requests;
mod layers;
mod plan_toml;

/// Applies byte edits (overwrite, insert, delete) at positions chosen by `edits`.
pub(crate) fn mutate(seed: &[u8], edits: &[(usize, u8, u8)]) -> Vec<u8> {
    let mut out = seed.to_vec();
    for &(at, kind, byte) in edits {
        let i = if out.is_empty() { 0 } else { at % out.len() };
        match kind % 3 {
            0 if !out.is_empty() => out[i] = byte,
            1 => out.insert(i, byte),
            _ if !out.is_empty() => {
                out.remove(i);
            }
            _ => out.push(byte),
        }
    }
    out
}
