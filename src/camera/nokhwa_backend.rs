//! nokhwa camera backend, for macOS (AVFoundation) and Windows (Media Foundation) users, behind
//! the same [`Camera`] trait as V4L2.
//!
//! nokhwa's camera handle is not `Send` on every platform, so it lives on its own capture
//! thread, which keeps reading frames (the platform queue never holds old ones) and publishes
//! the newest as RGB. nokhwa gives no driver timestamp: a frame's time is the rig clock when
//! the frame was handed over, minus half a frame interval, an estimate of the middle of the
//! exposure that errs late. `frame_after` therefore waits one extra frame interval past the
//! arrival so a frame exposed before the arrival is never taken. On Linux prefer the V4L2
//! backend, which has driver timestamps and locks exposure.
//!
//! nokhwa hands over no driver sequence numbers either, so it cannot tell a dropped frame
//! from one never captured: [`Camera::stream_stats`] stays `None` (its default), and the
//! manifest records no frame counts or measured rate for a nokhwa camera.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;

use super::convert::{self, PixelFormat};
use super::usb::DeviceSelector;
use super::v4l2::CameraSettings;
use super::{Camera, CameraError, Frame};
use crate::clock::Clock;

/// A camera opened through nokhwa.
pub struct NokhwaCamera {
    name: String,
    frames: watch::Receiver<Option<Frame>>,
    interval_s: f64,
    timeout: Duration,
}

/// Cameras nokhwa's native backend lists, as `(index, name, description)`; empty when the
/// backend cannot run.
pub fn list_nokhwa_cameras() -> Vec<(String, String, String)> {
    let Some(backend) = nokhwa::native_api_backend() else { return Vec::new() };
    match nokhwa::query(backend) {
        Ok(list) => list.into_iter().map(|c| (c.index().to_string(), c.human_name(), c.description().to_string())).collect(),
        Err(_) => Vec::new(),
    }
}

impl NokhwaCamera {
    /// Opens the camera at `selector` (`index:N`, or a `/dev/videoN` path on Linux).
    pub fn open(name: &str, selector: &DeviceSelector, settings: &CameraSettings, clock: Arc<dyn Clock>) -> Result<Self, CameraError> {
        use nokhwa::utils::{CameraFormat, CameraIndex, FrameFormat, RequestedFormat, RequestedFormatType, Resolution};
        let device_err = |reason: String| CameraError::Device { camera: name.to_string(), reason };
        let index = match selector {
            DeviceSelector::Index(i) => CameraIndex::Index(*i),
            DeviceSelector::Path(p) => CameraIndex::String(p.display().to_string()),
            other => {
                // USB identities are resolved to a node through sysfs on Linux only.
                let path = super::usb::resolve_video_device(other).map_err(|e| device_err(e.to_string()))?;
                CameraIndex::String(path.display().to_string())
            }
        };
        let frame_format = match settings.pixel_format {
            Some(PixelFormat::Yuyv) => FrameFormat::YUYV,
            _ => FrameFormat::MJPEG,
        };
        let wanted = CameraFormat::new(Resolution::new(settings.width, settings.height), frame_format, settings.fps);
        let (width, height, fps, warmup) = (settings.width, settings.height, settings.fps.max(1), settings.warmup_frames);
        let interval_s = 1.0 / f64::from(fps);
        let (tx, rx) = watch::channel(None);
        let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), String>>();
        let camera_name = name.to_string();
        std::thread::Builder::new()
            .name(format!("nokhwa-{name}"))
            .spawn(move || {
                let requested = RequestedFormat::new::<nokhwa::pixel_format::RgbFormat>(RequestedFormatType::Closest(wanted));
                let mut camera = match nokhwa::Camera::new(index, requested).and_then(|mut c| c.open_stream().map(|()| c)) {
                    Ok(c) => c,
                    Err(e) => {
                        let _ = ready_tx.send(Err(e.to_string()));
                        return;
                    }
                };
                let got = camera.camera_format();
                if (got.width(), got.height()) != (width, height) {
                    let _ = ready_tx.send(Err(format!("camera gives {}x{}, configured {width}x{height}", got.width(), got.height())));
                    return;
                }
                let _ = ready_tx.send(Ok(()));
                let mut seq: u64 = 0;
                while !tx.is_closed() {
                    let buffer = match camera.frame() {
                        Ok(b) => b,
                        Err(e) => {
                            tracing::warn!(camera = %camera_name, "nokhwa capture stopped: {e}");
                            return;
                        }
                    };
                    let t_capture_s = clock.now_s() - interval_s / 2.0;
                    seq += 1;
                    if seq <= u64::from(warmup) {
                        continue;
                    }
                    // rig's own decoders (nokhwa's `decoding` feature, mozjpeg, is not built).
                    let (w, h) = (buffer.resolution().width(), buffer.resolution().height());
                    let decoded = match buffer.source_frame_format() {
                        FrameFormat::MJPEG => convert::to_rgb(PixelFormat::Mjpeg, buffer.buffer(), w, h).map_err(|e| e.to_string()),
                        FrameFormat::YUYV => convert::to_rgb(PixelFormat::Yuyv, buffer.buffer(), w, h).map_err(|e| e.to_string()),
                        FrameFormat::RAWRGB => image::RgbImage::from_raw(w, h, buffer.buffer().to_vec())
                            .ok_or_else(|| format!("an RGB frame of {w}x{h} needs {} bytes, got {}", 3 * w * h, buffer.buffer().len())),
                        other => Err(format!("rig does not convert {other} frames; set pixel_format to MJPEG or YUYV")),
                    };
                    match decoded {
                        Ok(image) => {
                            let _ = tx.send(Some(Frame { image, t_capture_s, seq }));
                        }
                        Err(e) => tracing::debug!(camera = %camera_name, "nokhwa frame dropped: {e}"),
                    }
                }
                let _ = camera.stop_stream();
            })
            .map_err(|source| CameraError::Io { camera: name.to_string(), source })?;
        match ready_rx.recv_timeout(Duration::from_secs(10)) {
            Ok(Ok(())) => {}
            Ok(Err(reason)) => return Err(device_err(reason)),
            Err(_) => return Err(device_err("the camera did not start within 10 s".into())),
        }
        Ok(Self {
            name: name.to_string(),
            frames: rx,
            interval_s,
            timeout: Duration::from_secs_f64((interval_s * (f64::from(warmup) + 10.0)).max(2.0)),
        })
    }
}

impl Camera for NokhwaCamera {
    fn name(&self) -> &str {
        &self.name
    }

    async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
        // Host-side stamps: a frame is only surely exposed after the arrival once its stamp is
        // at least one more interval later.
        let threshold_s = not_before_s + self.interval_s;
        let camera = self.name.clone();
        let timeout = self.timeout;
        let wait = self.frames.wait_for(|f| f.as_ref().is_some_and(|f| f.t_capture_s >= threshold_s));
        match tokio::time::timeout(timeout, wait).await {
            Err(_) => Err(CameraError::Timeout { camera, timeout_ms: timeout.as_millis() as u64 }),
            Ok(Err(_closed)) => Err(CameraError::Device { camera, reason: "capture thread stopped".into() }),
            Ok(Ok(frame)) => frame.clone().ok_or(CameraError::Device { camera, reason: "no frame published".into() }),
        }
    }
}
