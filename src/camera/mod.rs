//! The camera seam.
//!
//! [`Camera`] is the only way the collection job reads a sensor. A [`Frame`] carries the time
//! it was captured on the rig's clock, so the job can throw away frames exposed before the arm
//! arrived. Backends: simulated sensors (`sim::sensor`), V4L2, nokhwa.

pub mod convert;
pub mod nokhwa_backend;
pub mod usb;
pub mod v4l2;

use std::future::Future;

/// One RGB frame with its capture time.
#[derive(Debug, Clone)]
pub struct Frame {
    pub image: image::RgbImage,
    /// Middle of the exposure, seconds on the rig clock.
    pub t_capture_s: f64,
    /// Frame counter of the stream.
    pub seq: u64,
}

/// Errors from a camera.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    #[error("camera {camera}: no frame within {timeout_ms} ms")]
    Timeout { camera: String, timeout_ms: u64 },
    #[error("camera {camera}: i/o error: {source}")]
    Io {
        camera: String,
        #[source]
        source: std::io::Error,
    },
    #[error("camera {camera}: cannot decode frame: {reason}")]
    Decode { camera: String, reason: String },
    #[error("camera {camera}: {reason}")]
    Device { camera: String, reason: String },
}

/// A frame source.
pub trait Camera: Send {
    /// Name used in logs and dataset paths (e.g. `tactip`).
    fn name(&self) -> &str;
    /// The next frame whose exposure started no earlier than `not_before_s` (rig clock);
    /// older buffered frames are dropped.
    fn frame_after(&mut self, not_before_s: f64) -> impl Future<Output = Result<Frame, CameraError>> + Send;
}
