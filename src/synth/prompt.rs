//! The MultiDiffSense prompt: the Python `str()` of a dict naming the sensor and the pose.
//!
//! MultiDiffSense's data preparation (`prompt_creation.py`) writes, per frame,
//! `{"sensor_context": ..., "object_pose": {"x": x, "y": y, "z": z, "yaw": yaw}}` into a JSONL
//! file, and its data loader feeds the model `str(item["prompt"])`, i.e. the Python repr of the
//! dict:
//!
//! ```text
//! {'sensor_context': 'captured by a high-resolution vision only sensor ViTac.', 'object_pose': {'x': 0.12, 'y': -0.34, 'z': 1.5, 'yaw': 15.0}}
//! ```
//!
//! Number format, matched here exactly:
//! - each pose value is rounded to 2 decimals the way NumPy rounds a `float64` (the CSV is read
//!   with pandas, so `round(v, 2)` is `numpy.round`): multiply by 100, round half to even,
//!   divide by 100. This differs from Python's own `round` on values such as 1.115 (NumPy: 1.12,
//!   Python: 1.11);
//! - the rounded value is printed as Python's `repr(float)`: shortest round-trip digits, always
//!   with a decimal point (`15.0`, `-0.0`), exponent form below 1e-4 and from 1e16 on.
//!
//! The pose fields are the Lepora-dialect columns `pose_1` (x mm), `pose_2` (y mm), `pose_3`
//! (z mm, indentation) and `pose_6` (yaw deg), i.e. [`Pose`] in the work frame.

use crate::pose::Pose;
use crate::sensor::SensorKind;

/// The MultiDiffSense prompt for `sensor` at the work-frame `pose`.
///
/// The sensor is a [`SensorKind`], parsed once from whatever named it (any case, see
/// [`crate::sensor`]), so `vitac` and `ViTac` build the same prompt. MultiDiffSense's own code
/// compares case-sensitive labels and gives any other text a generic sentence (`captured by
/// vitac sensor.`), a prompt the model was never trained on; rig has no such path.
pub fn mds_prompt(sensor: SensorKind, pose: &Pose) -> String {
    format!(
        "{{'sensor_context': {}, 'object_pose': {{'x': {}, 'y': {}, 'z': {}, 'yaw': {}}}}}",
        python_str_repr(sensor.prompt_context()),
        python_float_repr(numpy_round2(pose.x_mm)),
        python_float_repr(numpy_round2(pose.y_mm)),
        python_float_repr(numpy_round2(pose.z_mm)),
        python_float_repr(numpy_round2(pose.yaw_deg)),
    )
}

/// `numpy.round(v, 2)` for a float64: `rint(v * 100) / 100`.
pub fn numpy_round2(v: f64) -> f64 {
    (v * 100.0).round_ties_even() / 100.0
}

/// Python's `repr()` of a float.
pub fn python_float_repr(v: f64) -> String {
    if v.is_nan() {
        return "nan".to_string();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf".to_string() } else { "-inf".to_string() };
    }
    // Rust's Debug format prints the same shortest round-trip digits as Python and switches to
    // exponent form at the same thresholds (below 1e-4, from 1e16); only the exponent is
    // written differently (`1e16` vs Python's `1e+16`, `1e-5` vs `1e-05`).
    let s = format!("{v:?}");
    match s.split_once('e') {
        None => s,
        Some((mantissa, exp)) => {
            let (sign, digits) = match exp.strip_prefix('-') {
                Some(d) => ('-', d),
                None => ('+', exp),
            };
            format!("{mantissa}e{sign}{digits:0>2}")
        }
    }
}

/// Python's `repr()` of a str, for the characters a sensor sentence can hold: single quotes
/// unless the text contains a single quote and no double quote, backslash escapes otherwise.
pub fn python_str_repr(s: &str) -> String {
    let quote = if s.contains('\'') && !s.contains('"') { '"' } else { '\'' };
    let mut out = String::with_capacity(s.len() + 2);
    out.push(quote);
    for c in s.chars() {
        match c {
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if c == quote => {
                out.push('\\');
                out.push(c);
            }
            c if (c as u32) < 0x20 || c as u32 == 0x7f => out.push_str(&format!("\\x{:02x}", c as u32)),
            c => out.push(c),
        }
    }
    out.push(quote);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn architecture_example() {
        let p = Pose::new(0.12, -0.34, 1.5, 15.0);
        assert_eq!(
            mds_prompt(SensorKind::ViTac, &p),
            "{'sensor_context': 'captured by a high-resolution vision only sensor ViTac.', \
             'object_pose': {'x': 0.12, 'y': -0.34, 'z': 1.5, 'yaw': 15.0}}"
        );
    }

    #[test]
    fn real_csv_row() {
        // Row frame_0 of the MultiDiffSense example CSV (object 1); the expected text is what
        // `str(json.loads(json.dumps(entry))["prompt"])` gives for that row in its pipeline.
        let p = Pose::new(-3.06193989, -2.038885835, 0.7995462253753978, -89.79246118);
        assert_eq!(
            mds_prompt(SensorKind::TacTip, &p),
            "{'sensor_context': 'captured by a high-resolution tactile only sensor TacTip.', \
             'object_pose': {'x': -3.06, 'y': -2.04, 'z': 0.8, 'yaw': -89.79}}"
        );
        assert!(
            mds_prompt(SensorKind::ViTacTip, &p)
                .starts_with("{'sensor_context': 'captured by a high-resolution visuo-tactile sensor ViTacTip.'")
        );
    }

    #[test]
    fn numpy_rounding_and_python_repr() {
        assert_eq!(python_float_repr(numpy_round2(1.115)), "1.12");
        assert_eq!(python_float_repr(numpy_round2(2.675)), "2.68");
        assert_eq!(python_float_repr(numpy_round2(0.125)), "0.12");
        assert_eq!(python_float_repr(numpy_round2(-0.001)), "-0.0");
        assert_eq!(python_float_repr(numpy_round2(3.0)), "3.0");
        assert_eq!(python_float_repr(1e16), "1e+16");
        assert_eq!(python_float_repr(1e-5), "1e-05");
        assert_eq!(python_float_repr(0.0001), "0.0001");
        assert_eq!(python_float_repr(f64::NAN), "nan");
        assert_eq!(python_str_repr("it's"), "\"it's\"");
        assert_eq!(python_str_repr("a'\"b"), "'a\\'\"b'");
    }
}
