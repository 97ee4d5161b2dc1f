//! The sensor calibration: sensor-frame millimetres to image pixels.
//!
//! [`model`] is the map itself ([`Calibration`]: centre, px/mm scales, rotation, depth term,
//! pose correction) and its TOML store, at the bottom: it uses nothing else in rig. Above it,
//! and above [`crate::geometry`]: [`detect`] finds a contact in a frame, [`fit`] fits a model
//! to detected points, [`press`] presses an indenter over a pattern with the [`crate::arm`]
//! and [`crate::camera`] seams and fits, [`wizard`] walks a person through the same presses,
//! and [`contact_fit`] fits one to real frames of a known object.

pub mod contact_fit;
pub mod detect;
pub mod fit;
pub mod model;
pub mod press;
pub mod wizard;

pub use model::{Calibration, CalibrationError, DEFAULT_SCALE_PX_PER_MM_AT_512, FitPoint, FitRecord, MAX_DEPTH_SCALE_PER_MM};
