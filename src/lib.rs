//! rig: a controller for tactile-robotics labs.
//!
//! Data flow: a [`plan`] of contact poses drives the collection job ([`collect`]) which moves
//! an [`arm`], captures [`camera`] frames and writes a [`dataset`]. [`geometry`] renders
//! pose-aligned depth maps of the object, [`calibration`] maps robot mm to image pixels, and
//! [`synth`] fills the poses not collected through an ONNX diffusion model. [`sim`] provides
//! the simulated MG400 and sensors behind the same seams.

// A build without the `synth` or `lerobot` feature leaves out items the documentation links to
// (the ONNX Runtime pipeline, the LeRobot writer): there those links stay plain text. The
// default build's documentation is checked with every link resolving.
#![cfg_attr(not(all(feature = "synth", feature = "lerobot")), allow(rustdoc::broken_intra_doc_links))]

pub mod arm;
pub mod bench;
pub mod bounds;
pub mod calibration;
pub mod camera;
pub mod cli;
pub mod clock;
pub mod collect;
pub mod config;
pub mod confine;
pub mod daemon;
pub mod dataset;
pub mod eval;
pub mod features;
pub mod fence;
pub mod geometry;
pub mod imaging;
pub mod io;
pub mod jobs;
pub mod metrics;
pub mod plan;
pub mod pose;
pub mod progress;
pub mod record;
pub mod report;
pub mod rigs;
pub mod roots;
pub mod sensor;
pub mod sim;
pub mod synth;
pub mod untrusted;

/// rig's version, written into manifests.
pub fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}
