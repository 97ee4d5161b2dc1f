//! The range of every number a configuration holds: `rig.toml` (arm, work frame, collection,
//! cameras, Modbus peripherals, injected faults), firmware profiles and the daemon's settings.
//!
//! A number outside its range is refused when the file is read (exit code 2), naming the key,
//! the range and the value, so that no setting can make rig wait for ever (a Modbus
//! `timeout_ms` of 2^64 - 1 ms), allocate without limit or drive hardware with a value no
//! device takes. Each [`Bound`] is one row of [`TABLE`]; the guide's table
//! (`docs/src/faults.md`, "Configuration ranges") is [`markdown_table`], and a test checks the
//! page holds it as generated. Plans are bounded by their own validation (a finite grid of at
//! most [`crate::plan::MAX_GRID_POINTS`] points, every pose inside the firmware profile's
//! workspace).

use std::fmt::Display;

/// Most pixels rig decodes in one image (4096 x 4096; a tactile frame is under 2 Mpx): the
/// dataset readers' bound, and the largest frame a configured camera may give.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 24;

/// One key's range: `min` to `max` inclusive (`min` itself excluded when `above_min`), in
/// `unit`, and why it stops there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bound {
    /// The key as written in the file (`modbus.<name>.timeout_ms`).
    pub key: &'static str,
    pub min: f64,
    /// The range is open at `min` (a timeout above 0, not 0).
    pub above_min: bool,
    pub max: f64,
    /// Unit for messages (`ms`, `mm`, `px`, or empty for a count).
    pub unit: &'static str,
    /// Why the range ends where it does, for the guide.
    pub why: &'static str,
}

/// A number rig reads from a configuration, as it compares and prints it.
pub trait Number: Copy + Display {
    fn as_f64(self) -> f64;
}

macro_rules! number {
    ($($t:ty),*) => {
        $(impl Number for $t {
            #[allow(clippy::cast_precision_loss, clippy::cast_lossless, clippy::unnecessary_cast)]
            fn as_f64(self) -> f64 {
                self as f64
            }
        })*
    };
}
number!(u8, u16, u32, u64, usize, i64, f64);

impl Bound {
    const fn new(key: &'static str, min: f64, max: f64, unit: &'static str, why: &'static str) -> Self {
        Self { key, min, above_min: false, max, unit, why }
    }

    const fn above(key: &'static str, min: f64, max: f64, unit: &'static str, why: &'static str) -> Self {
        Self { key, min, above_min: true, max, unit, why }
    }

    /// Whether `value` lies in the range (NaN never does).
    pub fn contains(&self, value: f64) -> bool {
        let low = if self.above_min { value > self.min } else { value >= self.min };
        low && value <= self.max
    }

    /// `value` when it lies in the range, else what is wrong ("must be 1 to 60000 ms, got 0").
    pub fn check<N: Number>(&self, value: N) -> Result<N, String> {
        if self.contains(value.as_f64()) { Ok(value) } else { Err(format!("must be {}, got {value}", self.range())) }
    }

    /// "1 to 60000 ms", "above 0 and at most 600 s".
    pub fn range(&self) -> String {
        let unit = if self.unit.is_empty() { String::new() } else { format!(" {}", self.unit) };
        if self.above_min {
            format!("above {} and at most {}{unit}", self.min, self.max)
        } else {
            format!("{} to {}{unit}", self.min, self.max)
        }
    }
}

// rig.toml
pub const ARM_PORT: Bound = Bound::new("arm.dashboard_port, motion_port, feedback_port", 1.0, 65535.0, "", "a TCP port (0 is none)");
pub const ARM_SPEED_FACTOR: Bound = Bound::new("arm.speed_factor", 1.0, 100.0, "%", "the controller's SpeedFactor range");
pub const ARM_SIM_TIME_SCALE: Bound =
    Bound::above("arm.sim_time_scale", 0.0, 1000.0, "x real time", "past 1000 the simulator's own steps are the limit");
pub const WORK_FRAME_ORIGIN_MM: Bound = Bound::new(
    "work_frame.origin x_mm, y_mm, z_mm",
    -2000.0,
    2000.0,
    "mm",
    "beyond any desktop arm's reach (each pose is also checked against the firmware profile's workspace)",
);
pub const WORK_FRAME_ORIGIN_YAW: Bound = Bound::new("work_frame.origin yaw_deg", -360.0, 360.0, "deg", "one turn either way");
pub const WORK_FRAME_CONTACT_DEPTH: Bound =
    Bound::new("work_frame.contact_depth_mm", -20.0, 20.0, "mm", "deeper than any tactile sensor's skin");
pub const WORK_FRAME_APPROACH: Bound =
    Bound::above("work_frame.approach_mm", 0.0, 200.0, "mm", "the descent starts above the contact, within the arm's height");
pub const WORK_FRAME_TOOL_OFFSET: Bound =
    Bound::new("work_frame.tool_offset_mm", -500.0, 500.0, "mm", "longer than any desktop arm's tool");
pub const COLLECT_SETTLE: Bound = Bound::new("collect.settle_s", 0.0, 60.0, "s", "a skin settles in well under a minute");
pub const COLLECT_FRAMES: Bound = Bound::new("collect.frames_per_pose", 1.0, 100.0, "", "frames are held in memory to average");
pub const COLLECT_MOVE_TIMEOUT: Bound =
    Bound::above("collect.move_timeout_s", 0.0, 600.0, "s", "a move that takes longer is stuck (a cancel does not wait for it)");
pub const COLLECT_RETRIES: Bound =
    Bound::new("collect.retries_per_pose", 0.0, 100.0, "", "a fault that persists past 100 tries is not passing");
pub const SENSOR_SIDE: Bound = Bound::new(
    "sensors.<name>.width, height",
    16.0,
    8192.0,
    "px",
    "the largest image the dataset readers decode (and at most 16777216 px in all)",
);
pub const SENSOR_FPS: Bound = Bound::new("sensors.<name>.fps", 1.0, 240.0, "Hz", "what USB cameras offer");
pub const SENSOR_BUFFERS: Bound = Bound::new("sensors.<name>.buffers", 2.0, 32.0, "", "V4L2 needs two to stream; more only adds latency");
pub const SENSOR_WARMUP: Bound = Bound::new("sensors.<name>.warmup_frames", 0.0, 1000.0, "", "auto controls settle in a few seconds");
pub const SENSOR_EXPOSURE: Bound = Bound::new("sensors.<name>.exposure_100us", 1.0, 100_000.0, "x 100 us", "10 s, longer than any frame");
pub const SENSOR_GAIN: Bound = Bound::new("sensors.<name>.gain", 0.0, 100_000.0, "", "above any UVC camera's gain range");
pub const SENSOR_WHITE_BALANCE: Bound =
    Bound::new("sensors.<name>.white_balance_k", 1000.0, 15_000.0, "K", "the colour temperatures cameras take");
pub const SIM_STALE_FRAMES: Bound = Bound::new("sim.stale_buffer_frames", 0.0, 64.0, "", "more than any driver queues");
pub const FAULT_REPLY_DELAY: Bound =
    Bound::new("sim.faults.reply_delay_ms", 0.0, 10_000.0, "ms", "past the client's reply timeout every command would time out");
pub const FAULT_EVERY: Bound = Bound::new("sim.faults.feedback_garbage_every", 1.0, 1_000_000.0, "", "counts feedback frames from 1");
pub const FAULT_COUNTS: Bound = Bound::new(
    "sim.faults.collision_at_moves, camera_timeout_at_frames (each, and their count)",
    1.0,
    10_000.0,
    "",
    "counts from 1; a longer list is not a test",
);
pub const FAULT_DROP_SOCKETS: Bound = Bound::above("sim.faults.drop_sockets_every_s", 0.0, 3600.0, "s", "once an hour is the longest run");
pub const FAULT_CAMERA_TIMEOUT: Bound = Bound::new("sim.faults.camera_timeout_ms", 0.0, 60_000.0, "ms", "a stalled frame for a minute");
pub const MODBUS_TIMEOUT: Bound = Bound::new(
    "modbus.<name>.timeout_ms",
    1.0,
    60_000.0,
    "ms",
    "a device silent for a minute is gone (the collection waits this long per request)",
);
pub const MODBUS_BAUD: Bound = Bound::new("modbus.<name>.baud", 50.0, 4_000_000.0, "Bd", "what UARTs offer");
pub const MODBUS_STIFFNESS: Bound =
    Bound::new("modbus.<name>.sim_stiffness_n_per_mm", 0.0, 1_000_000.0, "N/mm", "stiffer than steel at this scale");
pub const MODBUS_OPERATIONS: Bound =
    Bound::new("modbus.<name>.read, before_capture, after_capture (entries each)", 0.0, 64.0, "", "each is a request at every pose");
// Firmware profiles (firmware-profiles/*.toml)
pub const PROFILE_PORT: Bound = Bound::new("transport.*_port (MG400 profile)", 1.0, 65535.0, "", "a TCP port");
pub const PROFILE_FRAME_LEN: Bound =
    Bound::new("transport.feedback_frame_len (MG400 profile)", 1.0, 65_536.0, "bytes", "the MG400's frame is 1440 bytes");
pub const PROFILE_FEEDBACK_PERIOD: Bound =
    Bound::new("transport.feedback_period_ms (MG400 profile)", 1.0, 10_000.0, "ms", "the MG400 sends a frame every 8 ms");
pub const PROFILE_QUEUE: Bound =
    Bound::new("transport.max_queued_commands (MG400 profile)", 1.0, 1000.0, "", "the controller's queue is far shorter");
pub const PROFILE_JOINT: Bound = Bound::new("joint_limits.* (MG400 profile)", -360.0, 360.0, "deg", "one turn either way");
pub const PROFILE_REACH: Bound = Bound::new(
    "workspace.radius_mm, z_mm (both profiles), kinematics lengths and offsets",
    -2000.0,
    2000.0,
    "mm",
    "beyond any desktop arm (a radius also at least 0, a link length above 0)",
);
pub const PROFILE_SPEED: Bound =
    Bound::above("speed.* (MG400 profile)", 0.0, 1_000_000.0, "deg/s or mm/s (accelerations: per s)", "positive and finite");
pub const MAGICIAN_BAUD: Bound = Bound::new("serial.baud (Magician profile)", 50.0, 4_000_000.0, "Bd", "what UARTs offer");
pub const MAGICIAN_REPLY_TIMEOUT: Bound =
    Bound::new("serial.reply_timeout_ms (Magician profile)", 1.0, 60_000.0, "ms", "a silent arm for a minute is gone");
pub const MAGICIAN_POLL: Bound = Bound::new("arrival.poll_ms (Magician profile)", 1.0, 10_000.0, "ms", "how often arrival is asked");
pub const MAGICIAN_TOLERANCE: Bound =
    Bound::above("arrival.tolerance_mm (Magician profile)", 0.0, 100.0, "mm", "positive, and well inside the workspace");
pub const MAGICIAN_ROTATION: Bound = Bound::new("workspace.r_deg (Magician profile)", -360.0, 360.0, "deg", "one turn either way");
// The daemon's settings
pub const DAEMON_IDLE_REFRESH: Bound = Bound::new(
    "rig daemon --idle-refresh-ms (0: off)",
    50.0,
    3_600_000.0,
    "ms",
    "faster would keep the cameras and the arm busy; slower than an hour is off",
);

/// Every bound, in the order the guide lists them.
pub const TABLE: &[Bound] = &[
    ARM_PORT,
    ARM_SPEED_FACTOR,
    ARM_SIM_TIME_SCALE,
    WORK_FRAME_ORIGIN_MM,
    WORK_FRAME_ORIGIN_YAW,
    WORK_FRAME_CONTACT_DEPTH,
    WORK_FRAME_APPROACH,
    WORK_FRAME_TOOL_OFFSET,
    COLLECT_SETTLE,
    COLLECT_FRAMES,
    COLLECT_MOVE_TIMEOUT,
    COLLECT_RETRIES,
    SENSOR_SIDE,
    SENSOR_FPS,
    SENSOR_BUFFERS,
    SENSOR_WARMUP,
    SENSOR_EXPOSURE,
    SENSOR_GAIN,
    SENSOR_WHITE_BALANCE,
    SIM_STALE_FRAMES,
    FAULT_REPLY_DELAY,
    FAULT_EVERY,
    FAULT_COUNTS,
    FAULT_DROP_SOCKETS,
    FAULT_CAMERA_TIMEOUT,
    MODBUS_TIMEOUT,
    MODBUS_BAUD,
    MODBUS_STIFFNESS,
    MODBUS_OPERATIONS,
    PROFILE_PORT,
    PROFILE_FRAME_LEN,
    PROFILE_FEEDBACK_PERIOD,
    PROFILE_QUEUE,
    PROFILE_JOINT,
    PROFILE_REACH,
    PROFILE_SPEED,
    MAGICIAN_BAUD,
    MAGICIAN_REPLY_TIMEOUT,
    MAGICIAN_POLL,
    MAGICIAN_TOLERANCE,
    MAGICIAN_ROTATION,
    DAEMON_IDLE_REFRESH,
];

/// The guide's table of [`TABLE`] (`docs/src/faults.md`, "Configuration ranges").
pub fn markdown_table() -> String {
    let mut table = String::from("| key | range | why |\n|---|---|---|\n");
    for b in TABLE {
        table.push_str(&format!("| `{}` | {} | {} |\n", b.key, b.range(), b.why));
    }
    table
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_hold_their_ends_and_refuse_past_them_and_nan() {
        assert_eq!(MODBUS_TIMEOUT.check(1u64), Ok(1));
        assert_eq!(MODBUS_TIMEOUT.check(60_000u64), Ok(60_000));
        let e = MODBUS_TIMEOUT.check(u64::MAX).unwrap_err();
        assert_eq!(e, "must be 1 to 60000 ms, got 18446744073709551615");
        assert!(MODBUS_TIMEOUT.check(0u64).is_err());
        assert!(COLLECT_MOVE_TIMEOUT.check(0.0).is_err() && COLLECT_MOVE_TIMEOUT.check(600.0).is_ok());
        assert!(COLLECT_MOVE_TIMEOUT.check(f64::NAN).is_err() && COLLECT_MOVE_TIMEOUT.check(f64::INFINITY).is_err());
        assert_eq!(COLLECT_MOVE_TIMEOUT.range(), "above 0 and at most 600 s");
    }

    #[test]
    fn every_key_is_listed_once_with_an_ordered_range() {
        for (i, b) in TABLE.iter().enumerate() {
            assert!(b.min <= b.max && !b.why.is_empty(), "{b:?}");
            assert!(TABLE[..i].iter().all(|o| o.key != b.key), "{} twice", b.key);
        }
    }

    /// The guide holds the table as generated, so the page and the checks cannot drift apart.
    #[test]
    fn the_guide_holds_the_table() {
        let page = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/src/faults.md")).expect("faults.md");
        assert!(page.contains(&markdown_table()), "docs/src/faults.md must hold bounds::markdown_table() verbatim:\n{}", markdown_table());
    }
}
