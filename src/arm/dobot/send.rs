//! One dashboard command typed by hand (`rig arm send`): checking the link to an MG400, reading
//! its mode, pose or alarms, clearing an error, without netcat.
//!
//! The text is parsed by the same codec the client uses ([`RequestCall::parse`], then
//! [`Request::from_call`], which interprets it as the controller does), so what is sent is a
//! command rig knows, encoded as rig encodes it. Motion commands (the motion port's `MovJ`,
//! `MovL`, `JointMovJ`, `Sync`) are refused before anything connects: rig moves the arm only
//! through a plan whose every pose was checked against the firmware profile's workspace.

use super::proto::{Port, ProtoError, Request, RequestCall};

/// The dashboard commands [`parse_dashboard_command`] accepts, for messages and `--help`.
pub const KNOWN_COMMANDS: &str = "EnableRobot, DisableRobot, ClearError, ResetRobot, EmergencyStop, Pause, Continue, \
     SpeedFactor, User, Tool, RobotMode, GetPose, GetAngle, GetErrorID, DI, DO, DOExecute, ToolDO, ToolDOExecute, \
     SpeedJ, SpeedL, AccJ, AccL, CP, SetCollisionLevel";

/// Why a typed command is not sent (bad input: nothing was sent).
#[derive(Debug, thiserror::Error)]
pub enum SendRefusal {
    #[error("{0}; write a command as the controller takes it, e.g. \"RobotMode()\"")]
    Malformed(#[from] ProtoError),
    #[error("{text:?}: {meaning}; rig sends the dashboard commands it knows: {KNOWN_COMMANDS}")]
    NotUnderstood { text: String, meaning: String },
    #[error(
        "{name} is a motion command, and rig arm send does not move the arm: rig moves it only through a plan whose poses \
         were checked against the firmware profile's workspace (rig collect --dry-run shows them)"
    )]
    Motion { name: &'static str },
}

/// The dashboard request `text` asks for, as the controller would read it; a motion command,
/// a malformed text or a command rig does not know is refused.
pub fn parse_dashboard_command(text: &str) -> Result<Request, SendRefusal> {
    let call = RequestCall::parse(text)?;
    let request = Request::from_call(&call).map_err(|e| SendRefusal::NotUnderstood { text: call.text.clone(), meaning: e.meaning() })?;
    if request.port() == Port::Motion {
        return Err(SendRefusal::Motion { name: request.name() });
    }
    Ok(request)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dashboard_commands_pass_and_motion_is_refused() {
        assert_eq!(parse_dashboard_command("RobotMode()").expect("known"), Request::RobotMode);
        assert_eq!(parse_dashboard_command(" getpose() ").expect("case and spaces as the controller takes them"), Request::GetPose);
        assert_eq!(parse_dashboard_command("SpeedFactor(20)").expect("known").encode(), "SpeedFactor(20)");
        for motion in ["MovJ(300,0,0,0)", "movl(300,0,0,0)", "JointMovJ(0,0,0,0)", "Sync()"] {
            assert!(matches!(parse_dashboard_command(motion), Err(SendRefusal::Motion { .. })), "{motion}");
        }
        assert!(matches!(parse_dashboard_command("Jump()"), Err(SendRefusal::NotUnderstood { .. })));
        assert!(matches!(parse_dashboard_command("EnableRobot(1,2)"), Err(SendRefusal::NotUnderstood { .. })));
        assert!(matches!(parse_dashboard_command("RobotMode"), Err(SendRefusal::Malformed(_))));
        assert!(matches!(parse_dashboard_command(""), Err(SendRefusal::Malformed(_))));
    }
}
