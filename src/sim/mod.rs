//! Simulated hardware that speaks the real protocols.
//!
//! `mg400`: a simulated MG400 controller over TCP. `sensor`: simulated tactile sensors behind
//! the `Camera` trait. They share the ground truth of the arm through [`ArmTruth`], published by
//! the simulated controller on a `tokio::sync::watch` channel and read by the sensors at
//! capture time. `modbus`: simulated Modbus TCP peripherals (a force sensor that reads the
//! same truth, an illumination controller).

pub mod magician;
pub mod mg400;
pub mod modbus;
pub mod sensor;

use crate::pose::Pose;

/// The simulated arm's true state at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ArmTruth {
    /// Simulation time, s.
    pub t_s: f64,
    /// Base-frame tool pose.
    pub pose: Pose,
    /// Tool speed, mm/s.
    pub speed_mm_s: f64,
}
