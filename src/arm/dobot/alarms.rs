//! Names for the MG400 alarm ids rig handles.
//!
//! GetErrorID returns lists of numeric ids: list 0 from the controller, lists 1.. from the
//! servos. Dobot resolves them through `alarm_controller.json` and `alarm_servo.json` (vendor
//! tables, 204 and 80 entries). rig keeps only the ids it expects to meet when pressing
//! sensors against objects (kinematics, limits, collisions, stops, common servo faults) and
//! names every other id by its number, so an unknown id is still reported, just unnamed.

use crate::arm::Alarm;

/// Controller alarms (list 0 of GetErrorID), from the vendor's `alarm_controller.json`.
const CONTROLLER: &[(i64, &str)] = &[
    (16, "inverse kinematics error with singularity"),
    (17, "inverse kinematics error with no solution"),
    (18, "target position triggers joint limit"),
    (22, "wrong arm orientation switch"),
    (23, "plan point during linear motion out of working area"),
    (26, "wrong input parameters for speed"),
    (32, "inverse kinematics singularity during moving"),
    (33, "inverse kinematics with no solution during moving"),
    (34, "inverse kinematics with result out of working area"),
    (64, "joint 1 exceeds positive limit"),
    (65, "joint 1 exceeds negative limit"),
    (66, "joint 2 exceeds positive limit"),
    (67, "joint 2 exceeds negative limit"),
    (68, "joint 3 exceeds positive limit"),
    (69, "joint 3 exceeds negative limit"),
    (70, "joint 4 exceeds positive limit"),
    (71, "joint 4 exceeds negative limit"),
    (72, "parallelogram positive limit"),
    (73, "parallelogram negative limit"),
    (85, "hardware or software emergency stop"),
    (105, "robot servo on failed"),
    (112, "collision detection"),
    (12288, "emergency stop detected"),
    (12294, "collision detection"),
];

/// Servo alarms (lists 1.. of GetErrorID), from the vendor's `alarm_servo.json`.
const SERVO: &[(i64, &str)] = &[
    (8752, "hardware overcurrent"),
    (9040, "drive overload"),
    (12816, "main circuit over-voltage"),
    (12832, "main circuit under-voltage"),
    (17168, "radiator overheating"),
    (29056, "motor overload"),
    (33920, "overspeed"),
    (34321, "excessive position deviation"),
];

/// Controller alarm: collision detected (what the simulator raises for an injected collision).
pub const COLLISION: i64 = 112;
/// Controller alarm: no inverse-kinematics solution for the target.
pub const IK_NO_SOLUTION: i64 = 17;
/// Controller alarm: the target needs a joint beyond its limit.
pub const JOINT_LIMIT: i64 = 18;
/// Controller alarm: emergency stop (EmergencyStop() or the button).
pub const EMERGENCY_STOP: i64 = 85;

/// The name of an alarm id from list `source` (0 = controller, 1.. = servo `source`).
pub fn describe(source: usize, id: i64) -> String {
    let table = if source == 0 { CONTROLLER } else { SERVO };
    match table.iter().find(|(known, _)| *known == id) {
        Some((_, name)) => (*name).to_string(),
        None if source == 0 => format!("controller alarm {id} (not in rig's table)"),
        None => format!("servo {source} alarm {id} (not in rig's table)"),
    }
}

/// Turns the GetErrorID lists into named alarms, in list order.
pub fn from_lists(lists: &[Vec<i64>]) -> Vec<Alarm> {
    lists
        .iter()
        .enumerate()
        .flat_map(|(source, ids)| ids.iter().map(move |&id| Alarm { source, id, description: describe(source, id) }))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_known_and_unknown_ids() {
        let alarms = from_lists(&[vec![69, 72], vec![], vec![34321], vec![4242]]);
        assert_eq!(alarms.len(), 4);
        assert_eq!(alarms[0].description, "joint 3 exceeds negative limit");
        assert_eq!(alarms[1].description, "parallelogram positive limit");
        assert_eq!((alarms[2].source, alarms[2].description.as_str()), (2, "excessive position deviation"));
        assert!(alarms[3].description.contains("4242"));
        assert_eq!(describe(0, COLLISION), "collision detection");
    }
}
