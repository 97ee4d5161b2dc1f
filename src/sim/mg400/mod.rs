//! A simulated MG400 controller that speaks the real protocol over TCP.
//!
//! Two parts: [`controller`], the controller without sockets (the [`Controller`] state machine,
//! advanced with the time passed in, and [`CommandSession`], one connection's request bytes
//! in and answers out), and [`server`], the TCP server on top ([`SimMg400`]).
//!
//! [`SimMg400::start`] binds the three ports (dashboard, motion, feedback; port 0 picks a free
//! one) and runs:
//!
//! - a motion task that advances the [`Controller`] state machine every feedback period on
//!   the passed [`Clock`] (so `MonotonicClock::scaled(10.0)` runs ten times faster than real
//!   time) and publishes [`ArmTruth`] for the simulated sensors;
//! - per connection on the dashboard and motion ports: a [`CommandSession`] (requests framed
//!   with [`RequestFramer`]), answered `ErrorID,{values},Echo;` as the real controller does,
//!   `Sync()` held back until the motion queue has drained;
//! - per connection on the feedback port: a valid 1440-byte [`FeedbackFrame`] every 8 ms of
//!   simulated time.
//!
//! [`Clock`]: crate::clock::Clock
//! [`ArmTruth`]: crate::sim::ArmTruth
//! [`RequestFramer`]: crate::arm::dobot::proto::RequestFramer
//! [`FeedbackFrame`]: crate::arm::dobot::proto::FeedbackFrame
//!
//! The controller starts DISABLED (mode 4). Moves run in queue order with trapezoidal
//! profiles scaled by SpeedFactor (MovJ in joint space, MovL in a straight line) and end
//! exactly on the commanded target. Mode is 7 while moving, 5 when idle, 9 with alarm ids for
//! unreachable targets, injected collisions and emergency stops. An alarm stops the arm,
//! empties the queue and stops the queue runner: further motion is refused (-1) until
//! ClearError, and queued motion waits for Continue. Pause holds the arm mid-move until
//! Continue. A collision or emergency stop also
//! disables the arm, so EnableRobot is needed again (as \[WS\] reports for the real arm).
//!
//! Fault injection ([`SimFaults`], changeable at run time with [`SimMg400::set_faults`]):
//! reply delays, replies split across writes, garbage in the feedback stream, feedback that
//! starts mid-frame, a collision at the k-th move, dashboard connections closed after n
//! commands; [`SimMg400::drop_connections`] closes every open connection of one port.

pub mod controller;
pub mod server;

use std::time::Duration;

pub use controller::{Answer, CommandSession, Controller, SessionStep, SimStats};
pub use server::{ConnectionDropper, SimFaults, SimMg400, SimMg400Config, SimPort};

/// Feedback and motion step period in simulated time (the real controller's 30004 period).
pub const FEEDBACK_PERIOD: Duration = Duration::from_millis(8);
