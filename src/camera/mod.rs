//! The camera seam.
//!
//! [`Camera`] is the only way the collection job reads a sensor. A [`Frame`] carries the time
//! it was captured on the rig's clock, so the job can throw away frames exposed before the arm
//! arrived. Backends: simulated sensors (`sim::sensor`), V4L2, nokhwa.
//!
//! [`capture_settled`] is the capture step the jobs are built of: a number of frames exposed
//! after the arm settled, the last one or their mean.
//!
//! [`Camera::stream_stats`] says what the stream delivered since the camera was opened
//! ([`StreamStats`]: frames received, frames the driver dropped, the delivery rate); the
//! collection job takes it before and after a run and writes the difference into the
//! dataset manifests. V4L2 measures it ([`meter::StreamMeter`]), a simulated sensor counts
//! what it rendered and says it measured nothing, backends that cannot count give `None`.

/// A camera backend this platform does not build: `open` refuses with
/// [`CameraError::NotBuilt`] (exit 2: the rig config names it), so no value exists and the
/// rig's camera enum needs no per-platform variants. `$selector` and `$settings` are the
/// device selector and camera settings types `open` takes, as the real backends do.
macro_rules! absent_camera {
    ($camera:ident, $backend:literal, $hint:literal, $selector:ty, $settings:ty) => {
        #[doc = concat!("The `", $backend, "` backend, not built on this platform.")]
        pub struct $camera {
            never: std::convert::Infallible,
        }

        impl $camera {
            /// Always [`CameraError::NotBuilt`](crate::camera::CameraError::NotBuilt).
            pub fn open(
                name: &str,
                _selector: &$selector,
                _settings: &$settings,
                _clock: std::sync::Arc<dyn crate::clock::Clock>,
            ) -> Result<Self, crate::camera::CameraError> {
                Err(crate::camera::CameraError::NotBuilt { camera: name.to_string(), backend: $backend, hint: $hint })
            }
        }

        impl crate::camera::Camera for $camera {
            fn name(&self) -> &str {
                match self.never {}
            }
            async fn frame_after(&mut self, _not_before_s: f64) -> Result<crate::camera::Frame, crate::camera::CameraError> {
                match self.never {}
            }
        }
    };
}
pub(crate) use absent_camera;

pub mod convert;
pub mod meter;
#[cfg(all(any(target_os = "macos", target_os = "windows"), feature = "nokhwa"))]
pub mod nokhwa_backend;
/// nokhwa is built on macOS and Windows only (with the `nokhwa` feature, on by default): on
/// Linux the V4L2 backend does the same, with driver timestamps and locked exposure.
#[cfg(not(all(any(target_os = "macos", target_os = "windows"), feature = "nokhwa")))]
#[path = "nokhwa_absent.rs"]
pub mod nokhwa_backend;
pub mod usb;
pub mod v4l2;

use std::future::Future;

use image::RgbImage;

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
    /// The configured backend is not part of this platform's build.
    #[error("camera {camera}: backend \"{backend}\" is not built on this platform; {hint}")]
    NotBuilt { camera: String, backend: &'static str, hint: &'static str },
}

/// A frame source.
pub trait Camera: Send {
    /// Name used in logs and dataset paths (e.g. `tactip`).
    fn name(&self) -> &str;
    /// The next frame whose exposure started no earlier than `not_before_s` (rig clock);
    /// older buffered frames are dropped.
    fn frame_after(&mut self, not_before_s: f64) -> impl Future<Output = Result<Frame, CameraError>> + Send;
    /// What the stream delivered since the camera was opened; `None` when the backend cannot
    /// count it.
    fn stream_stats(&self) -> Option<StreamStats> {
        None
    }
}

/// Where the figures of a [`StreamStats`] come from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StreamOrigin {
    /// Counted from the driver's buffer sequence numbers and timestamps.
    Measured,
    /// A simulated sensor: the frames it rendered, none dropped, nothing timed; it renders at
    /// `nominal_fps`, a setting, not a measurement.
    Simulated { nominal_fps: f64 },
}

/// What a camera stream delivered, counted since the camera was opened. Counts only grow, so
/// the figures of a run are the difference of two snapshots ([`since`](Self::since)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamStats {
    /// Frames the stream handed to rig (after the warm-up frames).
    pub frames_received: u64,
    /// Frames the driver skipped in its sequence numbers: captured, never delivered.
    pub frames_dropped: u64,
    /// Frames that followed another one of the same stream with a later timestamp.
    pub timed_frames: u64,
    /// The time between those frames and the ones before them, s (driver time).
    pub timed_s: f64,
    /// Frames [`Camera::frame_after`] looked at and threw away because their exposure started
    /// before the instant asked for (buffered while the arm moved): [`StaleFrameFilter`].
    pub stale_discarded: u64,
    pub origin: StreamOrigin,
}

impl StreamStats {
    /// Frames delivered per second of driver time; `None` when nothing was timed or the
    /// figures are not measured.
    pub fn measured_fps(&self) -> Option<f64> {
        if self.origin != StreamOrigin::Measured || self.timed_frames == 0 {
            return None;
        }
        let fps = self.timed_frames as f64 / self.timed_s;
        (fps.is_finite() && fps > 0.0).then_some(fps)
    }

    /// The figures between `earlier` (a snapshot of the same camera) and these; counts that
    /// went down (a camera reopened since) give 0.
    pub fn since(&self, earlier: &StreamStats) -> StreamStats {
        StreamStats {
            frames_received: self.frames_received.saturating_sub(earlier.frames_received),
            frames_dropped: self.frames_dropped.saturating_sub(earlier.frames_dropped),
            timed_frames: self.timed_frames.saturating_sub(earlier.timed_frames),
            timed_s: (self.timed_s - earlier.timed_s).max(0.0),
            stale_discarded: self.stale_discarded.saturating_sub(earlier.stale_discarded),
            origin: self.origin,
        }
    }
}

/// The fresh-frame rule every backend's [`Camera::frame_after`] applies, as the manifest
/// records it: a frame is kept only when its exposure started at or after the instant asked
/// for, which the collection job sets to the arm's arrival plus the settle time (and after the
/// peripherals' `before_capture` writes); older frames, queued in the driver while the arm
/// moved, are discarded and counted.
pub fn fresh_frame_rule(settle_s: f64) -> String {
    format!("exposure start >= arrival + settle_s ({settle_s} s) and after before_capture writes; earlier buffered frames discarded")
}

/// Applies the fresh-frame rule to the frames a backend has, oldest first, and counts what it
/// throws away.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StaleFrameFilter {
    discarded: u64,
}

impl StaleFrameFilter {
    /// True when a frame whose exposure started at `exposure_start_s` may be used for a
    /// request for frames from `not_before_s` on; false (and counted) when it is stale.
    pub fn admit(&mut self, exposure_start_s: f64, not_before_s: f64) -> bool {
        let fresh = !not_before_s.is_finite() || exposure_start_s >= not_before_s;
        if !fresh {
            self.discarded += 1;
        }
        fresh
    }

    /// Frames discarded so far.
    pub fn discarded(&self) -> u64 {
        self.discarded
    }
}

/// How [`capture_settled`] takes a pose's image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CaptureSettings {
    /// Frames captured (at least one is).
    pub frames: u32,
    /// Keep their pixel mean rather than the last frame.
    pub average: bool,
}

/// Captures `settings.frames` frames exposed after `not_before_s` (rig clock), each after the
/// one before; returns the last frame (or the pixel mean when averaging) and the mean capture
/// time.
pub async fn capture_settled<C: Camera>(
    camera: &mut C,
    not_before_s: f64,
    settings: CaptureSettings,
) -> Result<(RgbImage, f64), CameraError> {
    let n = settings.frames.max(1);
    let mut frames: Vec<Frame> = Vec::with_capacity(n as usize);
    let mut after = not_before_s;
    for _ in 0..n {
        let f = camera.frame_after(after).await?;
        after = f.t_capture_s;
        frames.push(f);
    }
    let t_mean = frames.iter().map(|f| f.t_capture_s).sum::<f64>() / frames.len() as f64;
    if settings.average && frames.len() > 1 {
        Ok((average(&frames), t_mean))
    } else {
        let last = frames.pop().map(|f| f.image).unwrap_or_default();
        Ok((last, t_mean))
    }
}

/// Pixel-wise mean of frames (frames of another size than the first are skipped), each
/// channel rounded half up ([`crate::imaging::MeanImage`]).
pub fn average(frames: &[Frame]) -> RgbImage {
    let images: Vec<&RgbImage> = frames.iter().map(|f| &f.image).collect();
    crate::imaging::mean_image(&images)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(v: u8) -> Frame {
        Frame { image: RgbImage::from_pixel(2, 2, image::Rgb([v, v, v])), t_capture_s: 0.0, seq: 0 }
    }

    #[test]
    fn average_rounds_the_mean() {
        let a = average(&[frame(10), frame(21)]);
        assert_eq!(a.get_pixel(1, 1).0, [16, 16, 16]);
    }
}
