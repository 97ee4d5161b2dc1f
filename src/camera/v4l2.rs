//! V4L2 camera backend (Linux, `v4l` crate): format choice, locked exposure, mmap streaming,
//! driver timestamps mapped onto the rig clock, warm-up, and no stale frames.
//!
//! Data flow: [`V4l2Camera::open`] resolves the configured [`DeviceSelector`] to `/dev/videoN`
//! (through the USB identity, so renumbering never swaps sensors), enumerates the formats the
//! camera offers, and [`choose_format`] picks YUYV when it reaches the configured rate at the
//! configured size (lossless) and MJPEG otherwise. It then locks the controls
//! ([`CameraSettings`]): manual exposure with *auto-priority off* (with it on, UVC cameras
//! stretch the exposure in dim light and drop from 25 to 15-18 fps, the rate users reported),
//! manual gain, manual white balance. A capture thread keeps dequeuing mmap buffers so the
//! driver's queue never holds old frames; it publishes the newest raw frame with its time on
//! the rig clock. [`Camera::frame_after`] waits for a frame whose exposure started no earlier
//! than the arm's arrival, and only then converts it to RGB ([`super::convert`]).
//!
//! Time: V4L2 stamps buffers with `CLOCK_MONOTONIC` (flag `TIMESTAMP_MONOTONIC`), at the start
//! of exposure (`TSTAMP_SRC_SOE`) or end of frame (`TSTAMP_SRC_EOF`, the UVC default).
//! [`TimeMapping`] shifts it onto the rig clock and to the middle of the exposure.
//!
//! The capture thread also feeds every buffer after warm-up (its `sequence` and driver stamp)
//! to a [`StreamMeter`], and publishes the counts with each frame, so
//! [`Camera::stream_stats`] gives the frames received, the frames the driver dropped and the
//! delivery rate. [`V4l2Camera::usb`] is the USB identity of the device opened, as sysfs gave
//! it (serial, vendor and product id), for the manifest.

#[cfg(target_os = "linux")]
use std::path::PathBuf;
#[cfg(target_os = "linux")]
use std::sync::Arc;
#[cfg(target_os = "linux")]
use std::time::Duration;

#[cfg(target_os = "linux")]
use tokio::sync::watch;

use super::convert::PixelFormat;
use super::usb::UsbIdentity;
#[cfg(target_os = "linux")]
use super::{Camera, CameraError, Frame, StreamStats, convert, meter::StreamMeter, usb::DeviceSelector};
#[cfg(target_os = "linux")]
use crate::clock::Clock;

/// Camera settings from the sensor's configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraSettings {
    pub width: u32,
    pub height: u32,
    pub fps: u32,
    /// Force a pixel format instead of letting [`choose_format`] pick.
    pub pixel_format: Option<PixelFormat>,
    /// Manual exposure time in units of 100 us (V4L2 `exposure_time_absolute`); `None` leaves
    /// the camera's automatic exposure on.
    pub exposure_100us: Option<i64>,
    pub gain: Option<i64>,
    /// Manual white balance temperature, K.
    pub white_balance_k: Option<i64>,
    /// mmap buffers; 4 leaves room for one being converted while the driver fills the others.
    pub buffers: u32,
    /// Frames thrown away after the stream starts (auto-exposure settling, USB start-up).
    pub warmup_frames: u32,
}

impl Default for CameraSettings {
    fn default() -> Self {
        Self {
            width: 640,
            height: 480,
            fps: 30,
            pixel_format: None,
            exposure_100us: None,
            gain: None,
            white_balance_k: None,
            buffers: 4,
            warmup_frames: 10,
        }
    }
}

/// One format/size the camera offers and the best rate it reaches there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FormatOffer {
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    pub max_fps: f64,
}

/// What [`choose_format`] decided.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FormatChoice {
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    pub fps: u32,
}

/// Picks the format for `settings` among `offers`: exact size, rate reached; a forced format
/// if configured, else YUYV (no compression artefacts) when it is fast enough, else MJPEG.
pub fn choose_format(offers: &[FormatOffer], settings: &CameraSettings) -> Result<FormatChoice, String> {
    let fits = |o: &&FormatOffer| o.width == settings.width && o.height == settings.height && o.max_fps + 1e-6 >= f64::from(settings.fps);
    let order: Vec<PixelFormat> = match settings.pixel_format {
        Some(f) => vec![f],
        None => vec![PixelFormat::Yuyv, PixelFormat::Mjpeg],
    };
    for format in order {
        if offers.iter().filter(fits).any(|o| o.format == format) {
            return Ok(FormatChoice { format, width: settings.width, height: settings.height, fps: settings.fps });
        }
    }
    let offered: Vec<String> =
        offers.iter().map(|o| format!("{}x{} {:?} up to {:.1} fps", o.width, o.height, o.format, o.max_fps)).collect();
    Err(format!(
        "no YUYV or MJPEG mode gives {}x{} at {} fps; offered: {}",
        settings.width,
        settings.height,
        settings.fps,
        if offered.is_empty() { "none".into() } else { offered.join(", ") }
    ))
}

/// Where in the exposure the driver put its timestamp.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampSource {
    StartOfExposure,
    EndOfFrame,
}

/// Maps driver timestamps (`CLOCK_MONOTONIC`, s) to the middle of the exposure on the rig clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeMapping {
    /// rig clock minus `CLOCK_MONOTONIC`, s, measured when the mapping was made.
    pub offset_s: f64,
    /// Exposure time, s (the locked exposure, or one frame interval when automatic).
    pub exposure_s: f64,
}

impl TimeMapping {
    /// A mapping from one simultaneous reading of both clocks.
    pub fn new(rig_now_s: f64, monotonic_now_s: f64, exposure_s: f64) -> Self {
        Self { offset_s: rig_now_s - monotonic_now_s, exposure_s }
    }
    /// Middle of the exposure of a frame stamped `driver_s` at `source`, rig clock.
    pub fn exposure_mid_s(&self, driver_s: f64, source: StampSource) -> f64 {
        let mid = match source {
            StampSource::StartOfExposure => driver_s + self.exposure_s / 2.0,
            StampSource::EndOfFrame => driver_s - self.exposure_s / 2.0,
        };
        mid + self.offset_s
    }
    /// Start of the exposure, rig clock: what `frame_after` compares with the arrival time.
    pub fn exposure_start_s(&self, driver_s: f64, source: StampSource) -> f64 {
        self.exposure_mid_s(driver_s, source) - self.exposure_s / 2.0
    }
}

/// `CLOCK_MONOTONIC` now, s.
pub fn monotonic_now_s() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes a timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// A raw frame as the capture thread publishes it.
#[cfg(target_os = "linux")]
#[derive(Debug, Clone)]
struct RawFrame {
    bytes: Arc<Vec<u8>>,
    seq: u64,
    t_start_s: f64,
    t_mid_s: f64,
    /// The stream's counts up to and including this frame.
    stats: StreamStats,
}

// V4L2 control ids (linux/v4l2-controls.h).
const CID_AUTO_WHITE_BALANCE: u32 = 0x0098_090c;
const CID_GAIN: u32 = 0x0098_0913;
const CID_AUTOGAIN: u32 = 0x0098_0912;
const CID_WHITE_BALANCE_TEMPERATURE: u32 = 0x0098_091a;
const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
const CID_EXPOSURE_AUTO_PRIORITY: u32 = 0x009a_0903;
/// `V4L2_EXPOSURE_MANUAL` of the exposure_auto menu.
const EXPOSURE_MANUAL: i64 = 1;

/// The controls rig locks, by their V4L2 names (as `v4l2-ctl --list-ctrls` prints them), in
/// the order [`read_back`] reports them.
pub const LOCKED_CONTROLS: [(&str, u32); 7] = [
    ("auto_exposure", CID_EXPOSURE_AUTO),
    ("exposure_time_absolute", CID_EXPOSURE_ABSOLUTE),
    ("exposure_dynamic_framerate", CID_EXPOSURE_AUTO_PRIORITY),
    ("gain_automatic", CID_AUTOGAIN),
    ("gain", CID_GAIN),
    ("white_balance_automatic", CID_AUTO_WHITE_BALANCE),
    ("white_balance_temperature", CID_WHITE_BALANCE_TEMPERATURE),
];

/// Every control of [`LOCKED_CONTROLS`] the device has, read back after locking: what the
/// driver holds, which may differ from what was written (drivers clamp and round, and some
/// ignore a write). `get` reads one control by id; a control it cannot read (the device has
/// none) is left out.
pub fn read_back(get: impl Fn(u32) -> std::io::Result<i64>) -> Vec<(&'static str, i64)> {
    LOCKED_CONTROLS.iter().filter_map(|&(name, id)| get(id).ok().map(|v| (name, v))).collect()
}

/// The settings asked for that the controls read back (from [`read_back`]) do not hold, as
/// `name: asked A, reads B` (a control that could not be read at all reads `-`).
pub fn lock_mismatches(settings: &CameraSettings, read: &[(&str, i64)]) -> Vec<String> {
    let value = |name: &str| read.iter().find(|(n, _)| *n == name).map(|&(_, v)| v);
    let mut asked: Vec<(&str, i64)> = Vec::new();
    if let Some(e) = settings.exposure_100us {
        asked.extend([("auto_exposure", EXPOSURE_MANUAL), ("exposure_time_absolute", e)]);
    }
    if let Some(g) = settings.gain {
        asked.push(("gain", g));
    }
    if let Some(k) = settings.white_balance_k {
        asked.extend([("white_balance_automatic", 0), ("white_balance_temperature", k)]);
    }
    asked
        .into_iter()
        .filter(|&(name, want)| value(name) != Some(want))
        .map(|(name, want)| format!("{name}: asked {want}, reads {}", value(name).map_or("-".to_string(), |v| v.to_string())))
        .collect()
}

/// A V4L2 camera.
#[cfg(target_os = "linux")]
pub struct V4l2Camera {
    name: String,
    path: PathBuf,
    usb: Option<UsbIdentity>,
    choice: FormatChoice,
    frames: watch::Receiver<Option<RawFrame>>,
    timeout: Duration,
    controls: Vec<(&'static str, i64)>,
    /// Frames looked at and found exposed too early (the fresh-frame rule).
    stale: crate::camera::StaleFrameFilter,
    /// Sequence number of the newest frame already delivered or counted: the capture thread's
    /// watch shows a frame until the next replaces it, and one frame is counted once.
    last_seen_seq: Option<u64>,
}

#[cfg(target_os = "linux")]
impl V4l2Camera {
    /// Opens the camera selected by `selector`, configures it and starts streaming.
    pub fn open(name: &str, selector: &DeviceSelector, settings: &CameraSettings, clock: Arc<dyn Clock>) -> Result<Self, CameraError> {
        use v4l::video::Capture;
        let device_err = |reason: String| CameraError::Device { camera: name.to_string(), reason };
        let io_err = |source: std::io::Error| CameraError::Io { camera: name.to_string(), source };
        let (path, usb) = super::usb::resolve_video_node(selector).map_err(|e| device_err(e.to_string()))?;
        let device = v4l::Device::with_path(&path).map_err(io_err)?;
        let offers = enumerate_offers(&device).map_err(io_err)?;
        let choice = choose_format(&offers, settings).map_err(|reason| device_err(format!("{}: {reason}", path.display())))?;

        let mut format = device.format().map_err(io_err)?;
        format.width = choice.width;
        format.height = choice.height;
        format.fourcc = v4l::FourCC::new(&choice.format.fourcc());
        let set = device.set_format(&format).map_err(io_err)?;
        if (set.width, set.height) != (choice.width, choice.height) || set.fourcc.repr != choice.format.fourcc() {
            return Err(device_err(format!(
                "driver changed the format to {}x{} {} (asked {}x{} {:?})",
                set.width, set.height, set.fourcc, choice.width, choice.height, choice.format
            )));
        }
        let params = device.set_params(&v4l::video::capture::Parameters::with_fps(choice.fps)).map_err(io_err)?;
        let interval_s = f64::from(params.interval.numerator) / f64::from(params.interval.denominator.max(1));
        lock_controls(&device, settings).map_err(|e| device_err(format!("locking exposure/gain/white balance: {e}")))?;
        let controls = read_back(|id| match device.control(id)?.value {
            v4l::control::Value::Integer(v) => Ok(v),
            v4l::control::Value::Boolean(b) => Ok(i64::from(b)),
            _ => Err(std::io::Error::other("not an integer control")),
        });
        for mismatch in lock_mismatches(settings, &controls) {
            tracing::warn!(camera = name, device = %path.display(), "control not held as asked: {mismatch}");
        }
        let exposure_s = settings.exposure_100us.map_or(interval_s, |e| e as f64 * 1e-4);

        let (tx, rx) = watch::channel(None);
        let thread_name = name.to_string();
        let buffers = settings.buffers.max(2);
        let warmup = settings.warmup_frames;
        let width = choice.width;
        let height = choice.height;
        // The stream is created inside the thread: it owns the mmap buffers for its lifetime.
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name(format!("v4l2-{thread_name}"))
            .spawn(move || capture_loop(device, buffers, warmup, exposure_s, clock, tx, ready_tx, (width, height)))
            .map_err(io_err)?;
        match ready_rx.recv_timeout(Duration::from_secs(5)) {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(io_err(e)),
            Err(_) => return Err(device_err("the stream did not start within 5 s".into())),
        }
        tracing::info!(camera = name, device = %path.display(), ?choice, "v4l2 camera streaming");
        Ok(Self {
            name: name.to_string(),
            path,
            usb,
            choice,
            frames: rx,
            timeout: Duration::from_secs_f64((interval_s * (f64::from(warmup) + 10.0)).max(2.0)),
            controls,
            stale: crate::camera::StaleFrameFilter::default(),
            last_seen_seq: None,
        })
    }

    /// The device node in use.
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }
    /// The USB identity of the device opened (serial, vendor and product id, port), when
    /// sysfs leads from its node to a USB device.
    pub fn usb(&self) -> Option<&UsbIdentity> {
        self.usb.as_ref()
    }
    /// The format, size and rate in use.
    pub fn format(&self) -> FormatChoice {
        self.choice
    }
    /// The locked controls as read back after locking ([`read_back`]).
    pub fn controls(&self) -> &[(&'static str, i64)] {
        &self.controls
    }
}

/// Every YUYV/MJPEG size the device node at `path` offers with its best rate.
#[cfg(target_os = "linux")]
pub fn offers_at(path: &std::path::Path) -> std::io::Result<Vec<FormatOffer>> {
    enumerate_offers(&v4l::Device::with_path(path)?)
}

/// No V4L2 here: every node is refused as unsupported.
#[cfg(not(target_os = "linux"))]
pub fn offers_at(_path: &std::path::Path) -> std::io::Result<Vec<FormatOffer>> {
    Err(std::io::Error::new(std::io::ErrorKind::Unsupported, "V4L2 is built on Linux only"))
}

#[cfg(not(target_os = "linux"))]
super::absent_camera!(
    V4l2Camera,
    "v4l2",
    "V4L2 is Linux's camera interface: on macOS and Windows use backend = \"nokhwa\"",
    super::usb::DeviceSelector,
    CameraSettings
);

#[cfg(not(target_os = "linux"))]
impl V4l2Camera {
    pub fn path(&self) -> &std::path::Path {
        match self.never {}
    }
    pub fn usb(&self) -> Option<&UsbIdentity> {
        match self.never {}
    }
    pub fn format(&self) -> FormatChoice {
        match self.never {}
    }
    pub fn controls(&self) -> &[(&'static str, i64)] {
        match self.never {}
    }
}

/// Every YUYV/MJPEG size the device offers with its best rate.
#[cfg(target_os = "linux")]
pub fn enumerate_offers(device: &v4l::Device) -> std::io::Result<Vec<FormatOffer>> {
    use v4l::frameinterval::FrameIntervalEnum;
    use v4l::framesize::FrameSizeEnum;
    use v4l::video::Capture;
    let mut offers = Vec::new();
    for desc in device.enum_formats()? {
        let Some(format) = PixelFormat::from_fourcc(desc.fourcc.repr) else { continue };
        for size in device.enum_framesizes(desc.fourcc)? {
            let sizes: Vec<(u32, u32)> = match size.size {
                FrameSizeEnum::Discrete(d) => vec![(d.width, d.height)],
                // Stepwise ranges can hold thousands of sizes; the largest is enough to list.
                FrameSizeEnum::Stepwise(s) => vec![(s.max_width, s.max_height)],
            };
            for (width, height) in sizes {
                let intervals = device.enum_frameintervals(desc.fourcc, width, height).unwrap_or_default();
                let max_fps = intervals
                    .iter()
                    .map(|i| match &i.interval {
                        FrameIntervalEnum::Discrete(f) => f64::from(f.denominator) / f64::from(f.numerator.max(1)),
                        FrameIntervalEnum::Stepwise(s) => f64::from(s.min.denominator) / f64::from(s.min.numerator.max(1)),
                    })
                    .fold(0.0, f64::max);
                offers.push(FormatOffer { format, width, height, max_fps });
            }
        }
    }
    Ok(offers)
}

#[cfg(target_os = "linux")]
fn lock_controls(device: &v4l::Device, s: &CameraSettings) -> std::io::Result<()> {
    use v4l::control::{Control, Value};
    let set = |id: u32, value: i64| device.set_control(Control { id, value: Value::Integer(value) });
    if let Some(exposure) = s.exposure_100us {
        set(CID_EXPOSURE_AUTO, EXPOSURE_MANUAL)?;
        set(CID_EXPOSURE_ABSOLUTE, exposure)?;
    }
    // Not every camera has auto-priority; where it exists it must be off to hold the rate.
    if let Err(e) = set(CID_EXPOSURE_AUTO_PRIORITY, 0) {
        tracing::debug!("exposure_auto_priority not set: {e}");
    }
    if let Some(gain) = s.gain {
        if let Err(e) = set(CID_AUTOGAIN, 0) {
            tracing::debug!("autogain not present: {e}");
        }
        set(CID_GAIN, gain)?;
    }
    if let Some(k) = s.white_balance_k {
        set(CID_AUTO_WHITE_BALANCE, 0)?;
        set(CID_WHITE_BALANCE_TEMPERATURE, k)?;
    }
    Ok(())
}

#[cfg(target_os = "linux")]
#[allow(clippy::too_many_arguments)]
fn capture_loop(
    device: v4l::Device,
    buffers: u32,
    warmup: u32,
    exposure_s: f64,
    clock: Arc<dyn Clock>,
    tx: watch::Sender<Option<RawFrame>>,
    ready: std::sync::mpsc::Sender<std::io::Result<()>>,
    size: (u32, u32),
) {
    use v4l::buffer::Flags;
    use v4l::io::traits::CaptureStream;
    let mut stream = match v4l::io::mmap::Stream::with_buffers(&device, v4l::buffer::Type::VideoCapture, buffers) {
        Ok(s) => s,
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    stream.set_timeout(Duration::from_secs(2));
    let _ = ready.send(Ok(()));
    let mut mapping = TimeMapping::new(clock.now_s(), monotonic_now_s(), exposure_s);
    let mut meter = StreamMeter::new();
    let mut n: u64 = 0;
    // Ends when every receiver is gone (the camera was dropped) or the device fails.
    while !tx.is_closed() {
        let (bytes, meta) = match stream.next() {
            Ok(x) => x,
            Err(e) => {
                tracing::warn!(?size, "v4l2 capture stopped: {e}");
                return;
            }
        };
        n += 1;
        if n <= u64::from(warmup) {
            continue;
        }
        // Re-measure the clock offset now and then: rig clock and CLOCK_MONOTONIC may drift.
        if n.is_multiple_of(300) {
            mapping = TimeMapping::new(clock.now_s(), monotonic_now_s(), exposure_s);
        }
        let driver_s = meta.timestamp.sec as f64 + meta.timestamp.usec as f64 * 1e-6;
        let monotonic = meta.flags.contains(Flags::TIMESTAMP_MONOTONIC);
        let source = if meta.flags.contains(Flags::TSTAMP_SRC_SOE) { StampSource::StartOfExposure } else { StampSource::EndOfFrame };
        // A driver without monotonic stamps: use the dequeue time (end of frame, roughly).
        let driver_s = if monotonic { driver_s } else { monotonic_now_s() };
        meter.record(meta.sequence, driver_s);
        let used = (meta.bytesused as usize).min(bytes.len());
        let frame = RawFrame {
            bytes: Arc::new(bytes[..used].to_vec()),
            seq: u64::from(meta.sequence),
            t_start_s: mapping.exposure_start_s(driver_s, source),
            t_mid_s: mapping.exposure_mid_s(driver_s, source),
            stats: meter.stats(),
        };
        let _ = tx.send(Some(frame));
    }
}

#[cfg(target_os = "linux")]
impl Camera for V4l2Camera {
    fn name(&self) -> &str {
        &self.name
    }

    async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
        let camera = self.name.clone();
        let timeout = self.timeout;
        let (stale, last_seen_seq) = (&mut self.stale, &mut self.last_seen_seq);
        let wait = self.frames.wait_for(|f| {
            let Some(f) = f.as_ref() else { return false };
            if last_seen_seq.is_some_and(|seen| f.seq <= seen) {
                // Already delivered or counted: never a fresh frame for a later request.
                return f.t_start_s >= not_before_s;
            }
            *last_seen_seq = Some(f.seq);
            stale.admit(f.t_start_s, not_before_s)
        });
        let raw = match tokio::time::timeout(timeout, wait).await {
            Err(_) => return Err(CameraError::Timeout { camera, timeout_ms: timeout.as_millis() as u64 }),
            Ok(Err(_closed)) => return Err(CameraError::Device { camera, reason: "capture thread stopped".into() }),
            Ok(Ok(frame)) => frame.clone(),
        };
        let Some(raw) = raw else {
            return Err(CameraError::Device { camera, reason: "no frame published".into() });
        };
        let (format, width, height) = (self.choice.format, self.choice.width, self.choice.height);
        let image = tokio::task::spawn_blocking(move || convert::to_rgb(format, &raw.bytes, width, height))
            .await
            .map_err(|e| CameraError::Device { camera: camera.clone(), reason: e.to_string() })?
            .map_err(|e| CameraError::Decode { camera: camera.clone(), reason: e.to_string() })?;
        Ok(Frame { image, t_capture_s: raw.t_mid_s, seq: raw.seq })
    }

    /// The counts the capture thread published with its newest frame: every buffer since
    /// warm-up, also those no job asked for. Before the first frame, nothing yet.
    fn stream_stats(&self) -> Option<StreamStats> {
        let stats = self.frames.borrow().as_ref().map_or_else(|| StreamMeter::new().stats(), |f| f.stats);
        Some(StreamStats { stale_discarded: self.stale.discarded(), ..stats })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A device whose controls read from `values` (by id); ids not there cannot be read.
    fn device(values: &[(u32, i64)]) -> impl Fn(u32) -> std::io::Result<i64> + '_ {
        move |id| values.iter().find(|(i, _)| *i == id).map(|&(_, v)| v).ok_or_else(|| std::io::Error::other("no such control"))
    }

    #[test]
    fn read_back_names_the_controls_the_device_has() {
        let read = read_back(device(&[(CID_EXPOSURE_ABSOLUTE, 150), (CID_EXPOSURE_AUTO, 1), (CID_GAIN, 12)]));
        assert_eq!(read, vec![("auto_exposure", 1), ("exposure_time_absolute", 150), ("gain", 12)]);
        assert!(read_back(device(&[])).is_empty());
    }

    #[test]
    fn mismatches_are_what_the_device_does_not_hold() {
        let settings = CameraSettings { exposure_100us: Some(150), gain: Some(10), white_balance_k: Some(4600), ..Default::default() };
        let held = [
            ("auto_exposure", 1),
            ("exposure_time_absolute", 150),
            ("gain", 10),
            ("white_balance_automatic", 0),
            ("white_balance_temperature", 4600),
        ];
        assert!(lock_mismatches(&settings, &held).is_empty());
        // The driver rounded the exposure, left auto white balance on and has no gain control.
        let read =
            [("auto_exposure", 1), ("exposure_time_absolute", 156), ("white_balance_automatic", 1), ("white_balance_temperature", 4600)];
        assert_eq!(
            lock_mismatches(&settings, &read),
            vec!["exposure_time_absolute: asked 150, reads 156", "gain: asked 10, reads -", "white_balance_automatic: asked 0, reads 1"]
        );
        // Nothing asked, nothing to hold.
        assert!(lock_mismatches(&CameraSettings::default(), &read).is_empty());
    }

    fn offer(format: PixelFormat, width: u32, height: u32, max_fps: f64) -> FormatOffer {
        FormatOffer { format, width, height, max_fps }
    }

    #[test]
    fn yuyv_when_fast_enough_else_mjpeg() {
        let offers = [
            offer(PixelFormat::Yuyv, 640, 480, 30.0),
            offer(PixelFormat::Yuyv, 1280, 720, 10.0),
            offer(PixelFormat::Mjpeg, 640, 480, 30.0),
            offer(PixelFormat::Mjpeg, 1280, 720, 30.0),
        ];
        let mut s = CameraSettings { width: 640, height: 480, fps: 30, ..CameraSettings::default() };
        assert_eq!(choose_format(&offers, &s).unwrap().format, PixelFormat::Yuyv);
        s.width = 1280;
        s.height = 720;
        assert_eq!(choose_format(&offers, &s).unwrap().format, PixelFormat::Mjpeg);
        s.fps = 60;
        let e = choose_format(&offers, &s).unwrap_err();
        assert!(e.contains("1280x720 at 60 fps") && e.contains("Mjpeg up to 30.0"), "{e}");
        s.fps = 25;
        s.pixel_format = Some(PixelFormat::Yuyv);
        assert!(choose_format(&offers, &s).is_err(), "forced YUYV cannot do 720p at 25 fps");
        assert!(choose_format(&[], &s).unwrap_err().contains("offered: none"));
    }

    #[test]
    fn driver_stamps_land_mid_exposure_on_the_rig_clock() {
        // Rig clock read 10.0 s while CLOCK_MONOTONIC read 5000.0 s; 20 ms exposure.
        let m = TimeMapping::new(10.0, 5000.0, 0.020);
        let eof = m.exposure_mid_s(5001.0, StampSource::EndOfFrame);
        let soe = m.exposure_mid_s(5001.0, StampSource::StartOfExposure);
        assert!((eof - 10.990).abs() < 1e-9, "{eof}");
        assert!((soe - 11.010).abs() < 1e-9, "{soe}");
        assert!((m.exposure_start_s(5001.0, StampSource::EndOfFrame) - 10.980).abs() < 1e-9);
        // A frame whose exposure started before the arm arrived is older than the arrival.
        let arrival_s = 10.985;
        assert!(m.exposure_start_s(5001.0, StampSource::EndOfFrame) < arrival_s);
        assert!(m.exposure_start_s(5001.033, StampSource::EndOfFrame) >= arrival_s);
    }

    #[test]
    fn monotonic_clock_moves_forward() {
        let a = monotonic_now_s();
        let b = monotonic_now_s();
        assert!(b >= a && a > 0.0);
    }
}
