//! The arm seam.
//!
//! [`Arm`] is the only way the collection job moves hardware. Implementations: the MG400 TCP
//! client in [`dobot`] (which also drives the simulated MG400 in `sim`), later the Magician.
//! Poses passed to an `Arm` are in the robot base frame.
//!
//! [`move_and_wait`] is the move-then-wait-for-arrival step the jobs are built of.
//!
//! Errors keep what the robot reported ([`ArmError::Fault`], [`ArmError::Refused`]) apart from
//! transport trouble ([`ArmError::Io`], [`ArmError::Timeout`]) and from targets rig refuses
//! itself before sending ([`ArmError::Unreachable`]).

pub mod dobot;
pub mod kinematics;
pub mod magician;
pub mod profile;

use std::future::Future;
use std::time::Duration;

use crate::pose::Pose;

/// How the arm should travel to a target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MoveKind {
    /// Joint-interpolated (MovJ): fastest, path not straight.
    Joint,
    /// Straight line in Cartesian space (MovL): used for the final descent.
    Linear,
}

/// One alarm the controller reported, resolved through the alarm table.
#[derive(Debug, Clone, PartialEq)]
pub struct Alarm {
    /// 0 for the controller list, 1.. for servo (joint) lists.
    pub source: usize,
    pub id: i64,
    pub description: String,
}

/// What a completed move reported.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arrival {
    /// Measured (feedback) base-frame pose at arrival.
    pub measured: Pose,
    /// Distance from the target, mm.
    pub error_mm: f64,
    /// Arrival time on the arm client's clock, s.
    pub t_s: f64,
}

/// Errors from an arm.
#[derive(Debug, thiserror::Error)]
pub enum ArmError {
    #[error("i/o error while {context}: {source}")]
    Io {
        context: String,
        #[source]
        source: std::io::Error,
    },
    #[error("timed out after {after:?} while {what}")]
    Timeout { what: String, after: Duration },
    /// The robot is in alarm (mode 9 or ErrorStatus set).
    #[error("robot fault: {}", describe_alarms(.alarms))]
    Fault { alarms: Vec<Alarm> },
    /// The robot answered a command with a non-zero ErrorID.
    #[error("robot refused {command}: error {error_id} ({meaning})")]
    Refused { command: String, error_id: i64, meaning: String },
    /// rig refused to send a target outside the firmware profile's workspace.
    #[error("target {pose} is unreachable: {limit}")]
    Unreachable { pose: Pose, limit: String },
    /// The peer sent something that does not follow the protocol.
    #[error("protocol error: {0}")]
    Protocol(String),
}

impl ArmError {
    /// Whether clearing the error and retrying the move is worth trying.
    pub fn is_recoverable(&self) -> bool {
        matches!(self, ArmError::Fault { .. } | ArmError::Timeout { .. } | ArmError::Io { .. })
    }
}

fn describe_alarms(alarms: &[Alarm]) -> String {
    if alarms.is_empty() {
        return "no alarm id reported".into();
    }
    alarms.iter().map(|a| format!("{} ({})", a.id, a.description)).collect::<Vec<_>>().join(", ")
}

/// Moves `arm` to `target` and waits for arrival: the step every job repeats (each pose of a
/// collection, each press of a calibration, the retract after a fault).
pub async fn move_and_wait<A: Arm>(arm: &mut A, target: Pose, kind: MoveKind, timeout: Duration) -> Result<Arrival, ArmError> {
    arm.move_to(target, kind).await?;
    arm.wait_arrived(target, timeout).await
}

/// A robot arm as the collection job sees it. Poses are in the base frame.
pub trait Arm: Send {
    /// Clear alarms, power on and enable; ready to take moves.
    fn enable(&mut self) -> impl Future<Output = Result<(), ArmError>> + Send;
    /// Check `target` against the workspace and queue a move to it.
    fn move_to(&mut self, target: Pose, kind: MoveKind) -> impl Future<Output = Result<(), ArmError>> + Send;
    /// Wait until the arm has come to rest at `target` (also when it already was there).
    fn wait_arrived(&mut self, target: Pose, timeout: Duration) -> impl Future<Output = Result<Arrival, ArmError>> + Send;
    /// The measured base-frame pose now.
    fn pose(&mut self) -> impl Future<Output = Result<Pose, ArmError>> + Send;
    /// Stop motion and drop queued moves.
    fn stop(&mut self) -> impl Future<Output = Result<(), ArmError>> + Send;
    /// Read, clear and return the active alarms; the arm is enabled again afterwards.
    fn clear_error(&mut self) -> impl Future<Output = Result<Vec<Alarm>, ArmError>> + Send;
    /// Disable the motors.
    fn disable(&mut self) -> impl Future<Output = Result<(), ArmError>> + Send;
    /// The controller's firmware version, as it reports it, for the manifest; `None` when the
    /// controller has no way to report it (the MG400's V1.x dashboard has no version command)
    /// or did not answer. Never fails a run.
    fn firmware_version(&mut self) -> impl Future<Output = Option<String>> + Send {
        async { None }
    }
}

/// Arms for the unit tests of the jobs above this module.
#[cfg(test)]
pub(crate) mod fake {
    use super::{Alarm, Arm, ArmError, Arrival, MoveKind};
    use crate::pose::Pose;
    use std::time::Duration;

    /// An arm that is wherever it is sent, at once, and counts the enables and moves it was
    /// asked for.
    #[derive(Debug, Default)]
    pub(crate) struct CountingArm {
        pub enables: usize,
        pub moves: usize,
        pub at: Pose,
    }

    impl Arm for CountingArm {
        async fn enable(&mut self) -> Result<(), ArmError> {
            self.enables += 1;
            Ok(())
        }
        async fn move_to(&mut self, target: Pose, _kind: MoveKind) -> Result<(), ArmError> {
            self.moves += 1;
            self.at = target;
            Ok(())
        }
        async fn wait_arrived(&mut self, target: Pose, _timeout: Duration) -> Result<Arrival, ArmError> {
            Ok(Arrival { measured: target, error_mm: 0.0, t_s: 0.0 })
        }
        async fn pose(&mut self) -> Result<Pose, ArmError> {
            Ok(self.at)
        }
        async fn stop(&mut self) -> Result<(), ArmError> {
            Ok(())
        }
        async fn clear_error(&mut self) -> Result<Vec<Alarm>, ArmError> {
            Ok(Vec::new())
        }
        async fn disable(&mut self) -> Result<(), ArmError> {
            Ok(())
        }
    }
}
