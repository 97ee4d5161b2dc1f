//! The seams between the rig and the daemon's view of it: [`LiveArm`] and [`LiveCamera`]
//! wrap the opened rig's arm and cameras (borrowed, so they stay open after a job) and
//! publish what passes through them (the arm's pose and mode, the plan pose being visited,
//! every captured frame) into the [`DaemonState`]. The jobs see an ordinary [`Arm`] and
//! [`Camera`].

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use super::state::{DaemonState, EncodedFrame};
use crate::arm::{Alarm, Arm, ArmError, Arrival, MoveKind};
use crate::camera::{Camera, CameraError, Frame};
use crate::plan::PlannedPose;
use crate::pose::{Pose, WorkFrame};
use crate::rigs::{RigArm, RigCamera};

/// JPEG quality of the live frames (small and quick to encode; the dataset keeps PNGs).
const LIVE_JPEG_QUALITY: u8 = 85;

/// The rig's arm, publishing its state.
pub struct LiveArm<'a> {
    pub arm: &'a mut RigArm,
    pub state: Arc<DaemonState>,
    /// Base-frame approach and contact poses of the running plan, by their rounded
    /// coordinates, to name the plan pose a move goes to.
    targets: HashMap<[i64; 4], u32>,
}

fn key(p: &Pose) -> [i64; 4] {
    // Micrometre and millidegree resolution: the targets are computed the same way each time.
    [(p.x_mm * 1e3).round() as i64, (p.y_mm * 1e3).round() as i64, (p.z_mm * 1e3).round() as i64, (p.yaw_deg * 1e3).round() as i64]
}

impl<'a> LiveArm<'a> {
    /// Wraps `arm`; `plan` (with `work_frame`) names the plan poses the moves go to.
    pub fn new(arm: &'a mut RigArm, state: Arc<DaemonState>, plan: &[PlannedPose], work_frame: &WorkFrame) -> Self {
        let mut targets = HashMap::new();
        for p in plan {
            targets.insert(key(&work_frame.approach_pose(&p.pose)), p.pose_id);
            targets.insert(key(&work_frame.contact_pose(&p.pose)), p.pose_id);
        }
        Self { arm, state, targets }
    }

    /// Publishes the mode a command just set. Not the feedback's mode: the controller
    /// accepted the command, and the next feedback frames may still show the old mode.
    fn publish_mode(&self, mode: &str) {
        self.state.set_arm(Some(mode.to_string()), None);
    }
}

/// The robot mode the controller itself reports (MG400 feedback, up to one feedback period
/// old), lower case.
pub fn reported_mode(arm: &RigArm) -> Option<String> {
    match arm {
        RigArm::Mg400(client) => client.latest_feedback().map(|s| format!("{:?}", s.frame.mode()).to_lowercase()),
        RigArm::Magician(_) => None,
    }
}

impl Arm for LiveArm<'_> {
    async fn enable(&mut self) -> Result<(), ArmError> {
        let r = self.arm.enable().await;
        self.publish_mode(if r.is_ok() { "enabled" } else { "error" });
        r
    }
    async fn move_to(&mut self, target: Pose, kind: MoveKind) -> Result<(), ArmError> {
        self.state.set_pose_id(self.targets.get(&key(&target)).copied());
        self.arm.move_to(target, kind).await
    }
    async fn wait_arrived(&mut self, target: Pose, timeout: Duration) -> Result<Arrival, ArmError> {
        let r = self.arm.wait_arrived(target, timeout).await;
        match &r {
            Ok(arrival) => {
                self.state.set_arm(reported_mode(self.arm), Some(arrival.measured));
            }
            Err(_) => self.state.set_arm(reported_mode(self.arm), None),
        }
        r
    }
    async fn pose(&mut self) -> Result<Pose, ArmError> {
        let r = self.arm.pose().await;
        if let Ok(p) = &r {
            self.state.set_arm(None, Some(*p));
        }
        r
    }
    async fn stop(&mut self) -> Result<(), ArmError> {
        self.arm.stop().await
    }
    async fn clear_error(&mut self) -> Result<Vec<Alarm>, ArmError> {
        let r = self.arm.clear_error().await;
        self.publish_mode(if r.is_ok() { "enabled" } else { "error" });
        r
    }
    async fn disable(&mut self) -> Result<(), ArmError> {
        let r = self.arm.disable().await;
        self.publish_mode(if r.is_ok() { "disabled" } else { "error" });
        r
    }
    async fn firmware_version(&mut self) -> Option<String> {
        self.arm.firmware_version().await
    }
}

/// One of the rig's cameras, publishing every frame it gives.
pub struct LiveCamera<'a> {
    pub camera: &'a mut RigCamera,
    pub state: Arc<DaemonState>,
}

impl Camera for LiveCamera<'_> {
    fn name(&self) -> &str {
        self.camera.name()
    }
    async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
        let frame = self.camera.frame_after(not_before_s).await?;
        publish_frame(&self.state, &self.camera.sensor_dir(), &frame);
        Ok(frame)
    }
    fn stream_stats(&self) -> Option<crate::camera::StreamStats> {
        self.camera.stream_stats()
    }
}

/// Encodes `frame` as JPEG and publishes it as `sensor`'s latest frame. A frame that does
/// not encode (empty) is skipped: the view keeps the previous one.
pub fn publish_frame(state: &DaemonState, sensor: &str, frame: &Frame) {
    let mut bytes = Vec::new();
    let encoder = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, LIVE_JPEG_QUALITY);
    if frame.image.write_with_encoder(encoder).is_err() {
        return;
    }
    state.set_frame(
        sensor,
        EncodedFrame {
            seq: 0,
            width: frame.image.width(),
            height: frame.image.height(),
            t_capture_s: frame.t_capture_s,
            content_type: "image/jpeg",
            bytes: Arc::new(bytes),
        },
    );
}

/// PNG bytes of an image (empty on the impossible encoding failure of an in-memory buffer).
pub fn png_bytes(image: &image::RgbImage) -> Vec<u8> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    match image.write_to(&mut bytes, image::ImageFormat::Png) {
        Ok(()) => bytes.into_inner(),
        Err(_) => Vec::new(),
    }
}
