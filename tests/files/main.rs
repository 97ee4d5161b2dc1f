//! Reading files from outside: datasets, the MDS dialect, plans, STL, and decoders fed arbitrary bytes.
//!
//! One test binary per area; run one module with
//! `cargo test --test files <module>::`.

mod dataset_mds;
mod dataset_verify;
mod decoders_never_panic;
mod geometry_stl;
mod job_requests;
mod layers;
mod plan_toml;
