//! `manifest.toml`: what a dataset is (plan, object, sensor) and how it was made (calibration,
//! firmware profile, rig version, times, and the capture chain: which arm, sensors and Modbus
//! peripherals took the frames, and which of them were simulated). Written atomically (temp
//! file, fsync, rename).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::DatasetError;
use crate::plan::PlanSpec;
use crate::pose::WorkFrame;
use crate::sensor::SensorKind;

/// The object pressed by the sensor.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObjectInfo {
    /// Short name used in paths (`datasets/<name>/...`).
    pub name: String,
    /// STL file the control images are rendered from: relative to the dataset folder when the
    /// file lies inside it, else absolute ([`ObjectInfo::stored_stl_path`]), so it resolves from
    /// wherever the dataset is used. Manifests written before this rule hold the path as the
    /// user gave it, relative to where `rig collect` ran; [`ObjectInfo::stl_bytes`] still reads
    /// those where they resolve.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stl_path: Option<String>,
    /// Hex sha256 of the STL file's bytes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stl_sha256: Option<String>,
}

impl ObjectInfo {
    /// An object without geometry.
    pub fn named(name: &str) -> Self {
        Self { name: name.to_string(), stl_path: None, stl_sha256: None }
    }

    /// An object with its STL file, for the dataset at `dataset_dir`, hashing the file.
    pub fn with_stl(name: &str, stl: &Path, dataset_dir: &Path) -> Result<Self, DatasetError> {
        Ok(Self { name: name.to_string(), stl_path: Some(Self::stored_stl_path(stl, dataset_dir)), stl_sha256: Some(sha256_file(stl)?) })
    }

    /// How a manifest of the dataset at `dataset_dir` names the STL file `stl` (a path as the
    /// user gave it, relative to the working directory or absolute): relative to the dataset
    /// folder when the file lies inside it (the dataset can move with its STL), else absolute.
    /// Symlinks in either path are resolved first where the path exists, so the two compare.
    pub fn stored_stl_path(stl: &Path, dataset_dir: &Path) -> String {
        let absolute = |p: &Path| p.canonicalize().or_else(|_| std::path::absolute(p)).unwrap_or_else(|_| p.to_path_buf());
        let stl_abs = absolute(stl);
        // The dataset folder may not exist yet: resolve its nearest existing ancestor.
        let mut existing = dataset_dir.to_path_buf();
        let mut rest = Vec::new();
        while !existing.exists() {
            match (existing.parent(), existing.file_name()) {
                (Some(parent), Some(name)) => {
                    rest.push(name.to_os_string());
                    existing = parent.to_path_buf();
                }
                _ => break,
            }
        }
        let mut dir_abs = absolute(if existing.as_os_str().is_empty() { Path::new(".") } else { &existing });
        dir_abs.extend(rest.iter().rev());
        match stl_abs.strip_prefix(&dir_abs) {
            Ok(inside) => inside.display().to_string(),
            Err(_) => stl_abs.display().to_string(),
        }
    }

    /// The bytes of the STL file this manifest names, for the dataset at `dataset_dir` whose
    /// manifest is `manifest`: `None` when it names none; else the file, read by the rules of
    /// [`crate::dataset::named`] (below the dataset, then below the working folder for
    /// manifests written before paths were stored relative to the dataset; elsewhere only the
    /// file its sha256 names) and checked against `stl_sha256`.
    ///
    /// A relative path found in neither folder is [`DatasetError::StlMissing`] naming it and the
    /// manifest; a file whose bytes differ from the recorded hash is [`DatasetError::StlChanged`];
    /// a path outside both folders is refused in the same words whether or not a file is there.
    /// `max_bytes` bounds the read (the STL decoder's limit).
    pub fn stl_bytes(&self, dataset_dir: &Path, manifest: &Path, max_bytes: u64) -> Result<Option<Vec<u8>>, DatasetError> {
        let Some(stored) = self.stl_path.as_deref() else { return Ok(None) };
        let sha = self.stl_sha256.as_deref();
        let read = crate::dataset::named::read_named(dataset_dir, "object.stl_path", stored, sha, max_bytes);
        let Some(bytes) = read.map_err(|e| match e {
            crate::dataset::named::NamedFileError::Outside { .. } => {
                DatasetError::StlUnusable { path: stored.to_string(), manifest: manifest.to_path_buf() }
            }
            other => DatasetError::Named(other),
        })?
        else {
            return Err(DatasetError::StlMissing { path: stored.to_string(), manifest: manifest.to_path_buf() });
        };
        if let Some(expected) = sha
            && !hex::encode(Sha256::digest(&bytes)).eq_ignore_ascii_case(expected)
        {
            return Err(DatasetError::StlChanged { path: PathBuf::from(stored), manifest: manifest.to_path_buf() });
        }
        Ok(Some(bytes))
    }
}

/// Hex sha256 of a file the operator named (a regular file: [`crate::confine::open_operator_file`]),
/// read in blocks.
pub fn sha256_file(path: &Path) -> Result<String, DatasetError> {
    let mut f = crate::confine::open_operator_file(path)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf).map_err(DatasetError::io("reading", path))?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hex::encode(hasher.finalize()))
}

/// One part of the capture chain: the arm, a sensor's camera or a Modbus peripheral, with the
/// backend that drove it. Every field after `simulated` is optional: a manifest written before
/// rig recorded it still reads, and a field is absent where the backend does not know it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CapturePart {
    /// What the part is: `arm`, a sensor name (`tactip`), `modbus.<name>`.
    pub name: String,
    /// The backend: `mg400`, `magician`, `sim-mg400` for the arm; `v4l2`, `nokhwa`, `sim`,
    /// `replay` for a camera; `tcp`, `rtu`, `sim` for a Modbus peripheral.
    pub backend: String,
    /// True when the part is simulated (its frames or readings are not measured).
    pub simulated: bool,
    /// Where it was reached: the arm's address, a camera's device selector, a peripheral's
    /// address or serial port; absent for in-process simulated parts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub address: Option<String>,
    /// A camera's device node as opened (`/dev/video2`), when the backend resolves one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device_path: Option<String>,
    /// A camera's pixel format on the wire (`YUYV`, `MJPG`); absent for simulated sensors
    /// (they render RGB) and where the backend picks it unseen.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub format: Option<String>,
    /// A camera's frame size, px (width, height).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resolution_px: Option<[u32; 2]>,
    /// The frame rate asked of a camera (configured, or the simulated sensor's), Hz.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub requested_fps: Option<u32>,
    /// A V4L2 camera's exposure, gain and white-balance controls as read back from the device
    /// after rig locked them, by their V4L2 names (`exposure_time_absolute = 150`, in 100 us;
    /// `auto_exposure = 1`: manual); only the controls the device has. Absent for simulated
    /// sensors and backends that do not lock controls (nokhwa).
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub controls: std::collections::BTreeMap<String, i64>,
    /// A camera's USB serial number as the device reports it (sysfs `serial`); absent when the
    /// device has none or is not a USB device.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial: Option<String>,
    /// A camera's USB vendor and product id, `vvvv:pppp` in hex (`0c45:6366`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub usb_id: Option<String>,
    /// A camera's USB port path (`1-2.3`) when it was opened.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub usb_port: Option<String>,
    /// The rule that kept this camera's frames fresh, as the last run applied it
    /// ([`crate::camera::fresh_frame_rule`]); absent before rig recorded it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fresh_frame_rule: Option<String>,
    /// Frames the rule threw away (exposed before arrival + settle), summed over the runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stale_frames_discarded: Option<u64>,
    /// The arm's firmware version as the controller reported it (the Magician); for the
    /// simulated MG400 the version its firmware profile names, followed by `(simulated)`.
    /// Absent where the controller does not report one (the MG400: see `firmware_profile`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub firmware: Option<String>,
    /// Frames the camera's stream delivered while rig collected into this dataset, summed
    /// over every run (resumes included) that counted them; for a simulated sensor, the
    /// frames it rendered.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames_received: Option<u64>,
    /// Frames the driver captured but never delivered (gaps in its buffer sequence numbers),
    /// summed like `frames_received`; 0 for a simulated sensor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames_dropped: Option<u64>,
    /// Driver time the measured rate covers, s, summed over the runs; absent unless measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stream_s: Option<f64>,
    /// Frames delivered per second of driver time, over every run that measured it (the runs'
    /// rates weighted by their `stream_s`); absent unless measured (never for a simulated
    /// sensor, whose rate is its `requested_fps`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured_fps: Option<f64>,
}

impl CapturePart {
    /// A part named `name` driven by `backend`.
    pub fn new(name: impl Into<String>, backend: impl Into<String>, simulated: bool, address: Option<String>) -> Self {
        Self {
            name: name.into(),
            backend: backend.into(),
            simulated,
            address,
            device_path: None,
            format: None,
            resolution_px: None,
            requested_fps: None,
            controls: std::collections::BTreeMap::new(),
            serial: None,
            usb_id: None,
            usb_port: None,
            fresh_frame_rule: None,
            stale_frames_discarded: None,
            firmware: None,
            frames_received: None,
            frames_dropped: None,
            stream_s: None,
            measured_fps: None,
        }
    }

    /// This camera part with its stream: device node, pixel format, frame size and requested
    /// rate (each when known).
    pub fn with_stream(mut self, device_path: Option<String>, format: Option<String>, resolution_px: [u32; 2], requested_fps: u32) -> Self {
        self.device_path = device_path;
        self.format = format;
        self.resolution_px = Some(resolution_px);
        self.requested_fps = Some(requested_fps);
        self
    }

    /// This camera part with its controls as read back from the device.
    pub fn with_controls<'a>(mut self, controls: impl IntoIterator<Item = (&'a str, i64)>) -> Self {
        self.controls = controls.into_iter().map(|(name, value)| (name.to_string(), value)).collect();
        self
    }

    /// This camera part with its USB identity: port path, vendor and product id, serial (when
    /// the device has one).
    pub fn with_usb(mut self, port_path: &str, vendor_id: u16, product_id: u16, serial: Option<&str>) -> Self {
        self.usb_port = Some(port_path.to_string());
        self.usb_id = Some(format!("{vendor_id:04x}:{product_id:04x}"));
        self.serial = serial.map(str::to_string);
        self
    }

    /// Records the fresh-frame rule a run applied and adds the frames it discarded.
    pub fn add_stale_frames(&mut self, rule: String, discarded: u64) {
        self.fresh_frame_rule = Some(rule);
        self.stale_frames_discarded = Some(self.stale_frames_discarded.unwrap_or(0).saturating_add(discarded));
    }

    /// Adds one run's stream to this camera part: `frames_received` and `frames_dropped` are
    /// added to the totals; `timed`, for a measured stream, is the run's timed frames and the
    /// driver time between them, s, which extend `stream_s` and update `measured_fps` (total
    /// timed frames over total `stream_s`).
    pub fn add_stream_run(&mut self, frames_received: u64, frames_dropped: u64, timed: Option<(u64, f64)>) {
        self.frames_received = Some(self.frames_received.unwrap_or(0).saturating_add(frames_received));
        self.frames_dropped = Some(self.frames_dropped.unwrap_or(0).saturating_add(frames_dropped));
        let Some((frames, seconds)) = timed.filter(|&(n, s)| n > 0 && s.is_finite() && s > 0.0) else { return };
        let (before_s, before_fps) = match (self.stream_s, self.measured_fps) {
            (Some(s), Some(fps)) if s.is_finite() && s > 0.0 && fps.is_finite() && fps >= 0.0 => (s, fps),
            _ => (0.0, 0.0),
        };
        // The earlier runs' timed frames, exact up to rounding.
        let before_frames = (before_fps * before_s).round();
        let total_s = before_s + seconds;
        self.stream_s = Some(total_s);
        self.measured_fps = Some((before_frames + frames as f64) / total_s);
    }
}

/// What captured a dataset's frames (`[capture]` in the manifest). Absent in manifests
/// written before rig recorded it, and in datasets that were synthesised or imported.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CaptureChain {
    /// The arm that placed the sensor.
    pub arm: CapturePart,
    /// Every sensor of the run, this dataset's included.
    #[serde(default)]
    pub sensors: Vec<CapturePart>,
    /// The Modbus peripherals read or written around each capture.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub modbus: Vec<CapturePart>,
}

impl CaptureChain {
    /// The parts that are simulated, by name (`arm`, `tactip`, `modbus.force`).
    pub fn simulated_parts(&self) -> Vec<&str> {
        std::iter::once(&self.arm).chain(&self.sensors).chain(&self.modbus).filter(|p| p.simulated).map(|p| p.name.as_str()).collect()
    }
}

/// Contents of `manifest.toml`. Unknown keys are ignored when reading, so manifests written by
/// later rig versions stay readable.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub rig_version: String,
    /// The sensor (written `tactip`, `vitac` or `vitactip`; read in any case).
    pub sensor: SensorKind,
    /// Calibration file used, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<String>,
    /// Firmware profile name or path, if an arm was used.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub firmware_profile: Option<String>,
    /// UTC start of the first run, RFC 3339 (`2026-11-22T11:46:33Z`).
    pub started_utc: String,
    /// UTC starts of resumed runs.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub resumed_utc: Vec<String>,
    /// UTC end of the last run that finished.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ended_utc: Option<String>,
    pub object: ObjectInfo,
    /// The plan the pose ids refer to; absent for imported datasets whose ids are the source's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plan: Option<PlanSpec>,
    /// The work frame of the collection, if an arm was used.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub work_frame: Option<WorkFrame>,
    /// What captured the frames; `None` in manifests that predate the field and in datasets
    /// no rig captured (synthesised, imported).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capture: Option<CaptureChain>,
    /// The last `rig audit` of this dataset's synthetic poses (`rig dataset verify` prints it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub audit: Option<AuditSummary>,
    /// The model and the image sizes of the last synthesis into this dataset; `None` in
    /// manifests that predate the field and in datasets never synthesised into.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub synthesis: Option<SynthesisInfo>,
    /// An adaptive collection's settings (`rig collect --adaptive`); the poses it chose are
    /// in the dataset's `adaptive.csv` ([`super::choices`]). `None` for every other dataset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptive: Option<crate::plan::adaptive::AdaptiveSettings>,
}

/// What `rig synth` wrote into a dataset's manifest (`[synthesis]`): which model made its
/// synthetic images, at what resolution, and at what size they were written, so a reader (and
/// `rig audit`) knows whether they were resampled.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SynthesisInfo {
    /// The model package's name (`model.toml`) and its folder as given.
    pub model: String,
    pub model_dir: String,
    /// The model's own resolution, px (width, height).
    pub model_resolution_px: [u32; 2],
    /// The size the synthetic images were written at, px (width, height): the dataset's frames'
    /// (its `reference.png`) in a fill, the model's or the frames' in twins.
    pub image_resolution_px: [u32; 2],
}

impl SynthesisInfo {
    /// How many times larger than the model's output the written images are (the larger of
    /// the two axes' ratios; 1 when they were written at the model's size, below 1 when
    /// shrunk).
    pub fn upscale(&self) -> f64 {
        let ratio = |i: usize| self.image_resolution_px[i] as f64 / self.model_resolution_px[i].max(1) as f64;
        ratio(0).max(ratio(1))
    }

    /// True when the images are larger than the model's output.
    pub fn upscales(&self) -> bool {
        self.upscale() > 1.0 + 1e-9
    }

    /// The upscale as a factor: `4x`, `2.5x`.
    pub fn upscale_text(&self) -> String {
        let k = self.upscale();
        if (k - k.round()).abs() < 0.05 { format!("{}x", k.round()) } else { format!("{k:.1}x") }
    }

    /// The warning a synthesis prints when it upscales (`None` when it does not): by how much,
    /// what that does to the images, and what would avoid it.
    pub fn upscale_warning(&self, dataset: &Path) -> Option<String> {
        if !self.upscales() {
            return None;
        }
        let [mw, mh] = self.model_resolution_px;
        let [iw, ih] = self.image_resolution_px;
        Some(format!(
            "warning: {}: model {} works at {mw}x{mh} px and the dataset's frames are {iw}x{ih} px, so each synthetic image is \
             upscaled {} (bilinear): it holds no detail finer than {} frame pixels, and sharp features (TacTip pins, edges) come \
             out blurred and dimmer than captured ones. A model trained at {iw} px would need no upscale; `rig synth --poses-of` \
             (--twin-size model) with `rig eval` judges this model at its own {mw} px. The manifest records both sizes ([synthesis])",
            dataset.display(),
            self.model,
            self.upscale_text(),
            self.upscale_text().trim_end_matches('x'),
        ))
    }
}

/// A figure of an audit: its mean over the audited poses with a 95% bootstrap interval, over
/// the `n` poses that have it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AuditFigure {
    pub n: usize,
    pub mean: f64,
    pub interval95: [f64; 2],
}

/// What `rig audit` wrote into the audited dataset's manifest: which synthesised poses were
/// collected again on the rig (`audit/` beside the rows) and how the synthesised images compare
/// with the captured ones.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AuditSummary {
    /// UTC time the audit finished, RFC 3339.
    pub utc: String,
    /// Share of the synthetic poses drawn, and the seed of the draw.
    pub fraction: f64,
    pub seed: u64,
    /// Synthetic poses in the dataset, and how many were audited.
    pub synthetic_poses: usize,
    pub audited_poses: usize,
    /// Contact-region SSIM on raw RGB (rig's definition), the headline figure.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_ssim: Option<AuditFigure>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_psnr_db: Option<AuditFigure>,
    /// Whole-frame SSIM on grey images, each min-max scaled (MultiDiffSense's definition).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mds_ssim: Option<AuditFigure>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mds_psnr_db: Option<AuditFigure>,
    /// Contact position recovered from the synthesised image against the commanded pose, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_err_mm: Option<AuditFigure>,
    /// The `--min-ssim` bound checked against `contact_ssim`'s mean, if one was given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_ssim: Option<f64>,
}

impl AuditSummary {
    /// One line per figure, as `rig dataset verify` and `rig audit` print them.
    pub fn lines(&self) -> Vec<String> {
        let mut out = vec![format!(
            "audit {}: {} of {} synthetic poses collected again (fraction {}, seed {})",
            self.utc, self.audited_poses, self.synthetic_poses, self.fraction, self.seed
        )];
        let figures = [
            ("contact SSIM (RGB)", self.contact_ssim, 3),
            ("contact PSNR dB (RGB)", self.contact_psnr_db, 2),
            ("SSIM (grey, min-max; MultiDiffSense)", self.mds_ssim, 3),
            ("PSNR dB (grey, min-max; MultiDiffSense)", self.mds_psnr_db, 2),
            ("position error mm", self.position_err_mm, 2),
        ];
        for (name, figure, k) in figures {
            match figure {
                Some(f) => out
                    .push(format!("  {name}: {:.k$} [{:.k$}, {:.k$}] (95% interval, n {})", f.mean, f.interval95[0], f.interval95[1], f.n)),
                None => out.push(format!("  {name}: n/a")),
            }
        }
        if let (Some(bound), Some(f)) = (self.min_ssim, self.contact_ssim) {
            let verdict = if f.mean >= bound { "passed" } else { "FAILED" };
            out.push(format!("  --min-ssim {bound}: {verdict}"));
        }
        out
    }
}

impl Manifest {
    /// A manifest for a new run starting now.
    pub fn new(sensor: SensorKind, object: ObjectInfo, plan: Option<PlanSpec>) -> Self {
        Self {
            rig_version: crate::version().to_string(),
            sensor,
            calibration: None,
            firmware_profile: None,
            started_utc: utc_now(),
            resumed_utc: Vec::new(),
            ended_utc: None,
            object,
            plan,
            work_frame: None,
            capture: None,
            audit: None,
            synthesis: None,
            adaptive: None,
        }
    }

    /// Reads `dir/manifest.toml` (a regular file, not a symlink, at most
    /// [`MAX_MANIFEST_BYTES`](super::durable::MAX_MANIFEST_BYTES)) and validates its plan, so
    /// no manifest can make a reader enumerate a grid beyond [`crate::plan::MAX_GRID_POINTS`].
    pub fn load(dir: &Path) -> Result<Self, DatasetError> {
        super::require_folder(dir)?;
        let path = dir.join(super::MANIFEST_FILE);
        let bytes = super::durable::read_below(dir, Path::new(super::MANIFEST_FILE), super::durable::MAX_MANIFEST_BYTES)?;
        let text = String::from_utf8(bytes).map_err(|_| DatasetError::ManifestParse {
            path: path.clone(),
            source: crate::untrusted::SyntaxError::at(0, 0, "not UTF-8 text"),
        })?;
        let manifest: Manifest = toml::from_str(&text)
            .map_err(|e| DatasetError::ManifestParse { path: path.clone(), source: crate::untrusted::SyntaxError::from_toml(&e, &text) })?;
        if let Some(plan) = &manifest.plan {
            plan.validate().map_err(|source| DatasetError::ManifestPlan { path, source })?;
        }
        Ok(manifest)
    }

    /// Writes `dir/manifest.toml` atomically.
    pub fn store(&self, dir: &Path) -> Result<(), DatasetError> {
        self.store_in(&crate::confine::RootDir::open(dir).map_err(super::durable::dataset_error)?)
    }

    /// Writes `manifest.toml` atomically into the held dataset folder `root`.
    pub fn store_in(&self, root: &crate::confine::RootDir) -> Result<(), DatasetError> {
        let text = toml::to_string(self).map_err(|source| DatasetError::ManifestWrite { source })?;
        root.write_atomic(super::MANIFEST_FILE, text.as_bytes()).map_err(super::durable::dataset_error)
    }

    /// The first field that makes `requested` a different dataset from `self` (plan, object,
    /// sensor), as a [`DatasetError::ManifestMismatch`].
    pub fn check_same_dataset(&self, requested: &Manifest, dir: &Path) -> Result<(), DatasetError> {
        let mismatch = |field: &'static str, existing: String, requested: String| DatasetError::ManifestMismatch {
            dir: dir.to_path_buf(),
            field,
            existing,
            requested,
        };
        if self.sensor != requested.sensor {
            return Err(mismatch("sensor", self.sensor.to_string(), requested.sensor.to_string()));
        }
        if self.object.name != requested.object.name {
            return Err(mismatch("object", self.object.name.clone(), requested.object.name.clone()));
        }
        if self.object.stl_sha256 != requested.object.stl_sha256 {
            return Err(mismatch(
                "object STL (sha256)",
                format!("{:?}", self.object.stl_sha256),
                format!("{:?}", requested.object.stl_sha256),
            ));
        }
        if self.plan != requested.plan {
            let show = |p: &Option<PlanSpec>| match p {
                Some(p) => toml::to_string(p).unwrap_or_else(|_| format!("{p:?}")).replace('\n', "; "),
                None => "no plan".to_string(),
            };
            return Err(mismatch("plan", show(&self.plan), show(&requested.plan)));
        }
        // An adaptive collection resumes only as the same adaptive collection (its choices are
        // replayed), and a plain one never turns adaptive.
        let settings = |m: &Manifest| m.adaptive.clone();
        if settings(self) != settings(requested) {
            let show = |s: Option<crate::plan::adaptive::AdaptiveSettings>| match s {
                Some(s) => format!(
                    "adaptive: budget {}, {} rounds, {} seeds per pose, model {} ({})",
                    s.budget, s.rounds, s.seeds_per_pose, s.model, s.model_sha256
                ),
                None => "not adaptive".to_string(),
            };
            return Err(mismatch("adaptive collection", show(settings(self)), show(settings(requested))));
        }
        // Resuming on other hardware is allowed; resuming a simulated run on a real rig (or
        // the other way) would mix sources in one dataset.
        if let (Some(existing), Some(asked)) = (&self.capture, &requested.capture)
            && existing.simulated_parts() != asked.simulated_parts()
        {
            let show = |c: &CaptureChain| match c.simulated_parts() {
                v if v.is_empty() => "nothing simulated".to_string(),
                v => format!("simulated: {}", v.join(", ")),
            };
            return Err(mismatch("capture chain", show(existing), show(asked)));
        }
        Ok(())
    }
}

/// Where the manifest of a dataset directory lives.
pub fn manifest_path(dir: &Path) -> PathBuf {
    dir.join(super::MANIFEST_FILE)
}

/// Current UTC time as RFC 3339 with seconds (`2026-11-22T11:46:33Z`).
pub fn utc_now() -> String {
    let s = SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    utc_string(s)
}

/// Formats seconds since the Unix epoch as RFC 3339 UTC.
pub fn utc_string(unix_s: u64) -> String {
    let days = (unix_s / 86_400) as i64;
    let rem = unix_s % 86_400;
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + if m <= 2 { 1 } else { 0 };
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z", rem / 3600, rem / 60 % 60, rem % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_formatting() {
        assert_eq!(utc_string(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc_string(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(utc_string(1_795_347_993), "2026-11-22T11:46:33Z");
    }

    #[test]
    fn manifest_toml_round_trip() {
        let mut m = Manifest::new(SensorKind::TacTip, ObjectInfo::named("edge"), Some(PlanSpec::default()));
        m.work_frame = Some(WorkFrame::default());
        m.firmware_profile = Some("mg400-v1.6".into());
        let text = toml::to_string(&m).unwrap();
        let back: Manifest = toml::from_str(&text).unwrap();
        assert_eq!(back, m);
        let mut other = m.clone();
        other.plan.as_mut().unwrap().seed = 5;
        let err = m.check_same_dataset(&other, Path::new("d")).unwrap_err();
        assert!(matches!(err, DatasetError::ManifestMismatch { field: "plan", .. }), "{err}");
    }

    #[test]
    fn manifests_without_a_capture_chain_still_read_and_resuming_across_sources_is_refused() {
        let m = Manifest::new(SensorKind::ViTac, ObjectInfo::named("edge"), Some(PlanSpec::default()));
        let old = toml::to_string(&m).unwrap();
        assert!(!old.contains("capture"), "{old}");
        assert_eq!(toml::from_str::<Manifest>(&old).unwrap().capture, None);

        let chain = |simulated: bool| CaptureChain {
            arm: CapturePart::new("arm", if simulated { "sim-mg400" } else { "mg400" }, simulated, None),
            sensors: vec![CapturePart::new("vitac", if simulated { "sim" } else { "v4l2" }, simulated, None).with_stream(
                (!simulated).then(|| "/dev/video2".to_string()),
                (!simulated).then(|| "YUYV".to_string()),
                [640, 480],
                30,
            )],
            modbus: Vec::new(),
        };
        let sim = Manifest { capture: Some(chain(true)), ..m.clone() };
        let text = toml::to_string(&sim).unwrap();
        assert_eq!(toml::from_str::<Manifest>(&text).unwrap(), sim);
        assert_eq!(chain(true).simulated_parts(), ["arm", "vitac"]);
        let real = Manifest { capture: Some(chain(false)), ..m.clone() };
        let err = sim.check_same_dataset(&real, Path::new("d")).unwrap_err();
        assert!(matches!(err, DatasetError::ManifestMismatch { field: "capture chain", .. }), "{err}");
        // A dataset from before the field resumes under any chain.
        m.check_same_dataset(&sim, Path::new("d")).unwrap();
        sim.check_same_dataset(&sim.clone(), Path::new("d")).unwrap();
    }

    #[test]
    fn read_back_camera_controls_round_trip_and_older_parts_read_without_them() {
        let part = CapturePart::new("tactip", "v4l2", false, Some("usb:1-2".into()))
            .with_stream(Some("/dev/video2".into()), Some("YUYV".into()), [640, 480], 30)
            .with_controls([("auto_exposure", 1), ("exposure_time_absolute", 150), ("gain", 12)]);
        let chain = CaptureChain { arm: CapturePart::new("arm", "mg400", false, None), sensors: vec![part.clone()], modbus: Vec::new() };
        let m = Manifest { capture: Some(chain), ..Manifest::new(SensorKind::TacTip, ObjectInfo::named("edge"), None) };
        let text = toml::to_string(&m).unwrap();
        assert!(text.contains("exposure_time_absolute = 150"), "{text}");
        assert_eq!(toml::from_str::<Manifest>(&text).unwrap(), m);
        // A part written without controls (simulated, nokhwa, older rig) has none.
        let bare = toml::to_string(&CapturePart::new("vitac", "sim", true, None)).unwrap();
        assert!(!bare.contains("controls"), "{bare}");
        assert!(toml::from_str::<CapturePart>(&bare).unwrap().controls.is_empty());
    }

    /// A manifest as rig wrote it before the USB identity, firmware and stream counts.
    const MANIFEST_BEFORE_STREAM_COUNTS: &str = r#"
rig_version = "0.1.0"
sensor = "tactip"
calibration = "default"
firmware_profile = "mg400-v1.6"
started_utc = "2026-11-22T11:46:33Z"

[object]
name = "sphere"

[capture.arm]
name = "arm"
backend = "mg400"
simulated = false
address = "192.168.1.6:29999"

[[capture.sensors]]
name = "tactip"
backend = "v4l2"
simulated = false
address = "port:1-2.3"
device_path = "/dev/video2"
format = "YUYV"
resolution_px = [640, 480]
requested_fps = 30

[capture.sensors.controls]
auto_exposure = 1
"#;

    #[test]
    fn manifests_from_before_the_stream_counts_still_read() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(super::super::MANIFEST_FILE), MANIFEST_BEFORE_STREAM_COUNTS).unwrap();
        let m = Manifest::load(dir.path()).unwrap();
        let chain = m.capture.expect("the capture chain");
        assert_eq!(chain.arm.firmware, None);
        let part = &chain.sensors[0];
        assert_eq!((part.device_path.as_deref(), part.controls.get("auto_exposure")), (Some("/dev/video2"), Some(&1)));
        assert_eq!((&part.serial, &part.usb_id, &part.usb_port), (&None, &None, &None));
        assert_eq!((part.frames_received, part.frames_dropped, part.stream_s, part.measured_fps), (None, None, None, None));
    }

    #[test]
    fn identity_firmware_and_stream_counts_round_trip() {
        let mut arm = CapturePart::new("arm", "magician", false, Some("/dev/ttyUSB0".into()));
        arm.firmware = Some("3.7.0".into());
        let mut camera = CapturePart::new("tactip", "v4l2", false, Some("serial:TT-0042".into()))
            .with_stream(Some("/dev/video2".into()), Some("YUYV".into()), [640, 480], 30)
            .with_controls([("auto_exposure", 1), ("exposure_time_absolute", 156)])
            .with_usb("1-2.3", 0x0c45, 0x6366, Some("TT-0042"));
        camera.add_stream_run(301, 2, Some((299, 10.0)));
        let chain = CaptureChain { arm, sensors: vec![camera], modbus: Vec::new() };
        let m = Manifest { capture: Some(chain), ..Manifest::new(SensorKind::TacTip, ObjectInfo::named("edge"), None) };
        let text = toml::to_string(&m).unwrap();
        for line in ["serial = \"TT-0042\"", "usb_id = \"0c45:6366\"", "usb_port = \"1-2.3\"", "firmware = \"3.7.0\"", "frames_dropped = 2"]
        {
            assert!(text.contains(line), "{line} missing:\n{text}");
        }
        assert_eq!(toml::from_str::<Manifest>(&text).unwrap(), m);
    }

    #[test]
    fn stream_counts_add_up_over_runs() {
        let mut part = CapturePart::new("tactip", "v4l2", false, None);
        // First run: 300 frames delivered, 2 dropped, 299 timed over 10 s.
        part.add_stream_run(300, 2, Some((299, 10.0)));
        assert_eq!((part.frames_received, part.frames_dropped, part.stream_s), (Some(300), Some(2), Some(10.0)));
        assert!((part.measured_fps.unwrap() - 29.9).abs() < 1e-9);
        // A resumed run at a lower rate: 151 frames, 150 timed over 10 s.
        part.add_stream_run(151, 0, Some((150, 10.0)));
        assert_eq!((part.frames_received, part.frames_dropped, part.stream_s), (Some(451), Some(2), Some(20.0)));
        assert!((part.measured_fps.unwrap() - 449.0 / 20.0).abs() < 1e-9, "{:?}", part.measured_fps);
        // A run that timed nothing adds its counts and leaves the rate alone.
        part.add_stream_run(1, 0, None);
        part.add_stream_run(1, 0, Some((0, 0.0)));
        assert_eq!((part.frames_received, part.stream_s), (Some(453), Some(20.0)));
        assert!((part.measured_fps.unwrap() - 449.0 / 20.0).abs() < 1e-9);

        // A simulated sensor counts rendered frames and never gets a measured rate.
        let mut sim = CapturePart::new("vitac", "sim", true, None);
        sim.add_stream_run(5, 0, None);
        sim.add_stream_run(3, 0, None);
        assert_eq!((sim.frames_received, sim.frames_dropped, sim.stream_s, sim.measured_fps), (Some(8), Some(0), None, None));

        // A hand-edited manifest's nonsense rate is not carried into the total.
        let mut edited = CapturePart::new("tactip", "v4l2", false, None);
        (edited.stream_s, edited.measured_fps) = (Some(-1.0), Some(f64::NAN));
        edited.add_stream_run(31, 0, Some((30, 1.0)));
        assert_eq!((edited.stream_s, edited.measured_fps), (Some(1.0), Some(30.0)));
    }

    #[test]
    fn the_synthesis_record_says_how_much_a_fill_upscales_and_older_manifests_read_without_it() {
        let info = |model: u32, written: [u32; 2]| SynthesisInfo {
            model: "default".into(),
            model_dir: "models/default".into(),
            model_resolution_px: [model, model],
            image_resolution_px: written,
        };
        let tactip = info(128, [512, 512]);
        assert!(tactip.upscales());
        assert_eq!(tactip.upscale_text(), "4x");
        let warning = tactip.upscale_warning(Path::new("datasets/sphere/tactip")).expect("a 4x upscale warns");
        assert!(warning.starts_with("warning: datasets/sphere/tactip: model default works at 128x128 px"), "{warning}");
        assert!(warning.contains("frames are 512x512 px") && warning.contains("upscaled 4x"), "{warning}");
        assert!(warning.contains("A model trained at 512 px"), "{warning}");
        assert_eq!(info(128, [640, 480]).upscale_text(), "5x", "the larger axis' ratio");
        assert_eq!(info(256, [640, 480]).upscale_text(), "2.5x");
        for same_or_smaller in [info(128, [128, 128]), info(256, [128, 128])] {
            assert!(!same_or_smaller.upscales());
            assert_eq!(same_or_smaller.upscale_warning(Path::new("d")), None);
        }

        let m = Manifest::new(SensorKind::TacTip, ObjectInfo::named("sphere"), Some(PlanSpec::default()));
        let old = toml::to_string(&m).unwrap();
        assert!(!old.contains("synthesis"), "{old}");
        assert_eq!(toml::from_str::<Manifest>(&old).unwrap().synthesis, None);
        let filled = Manifest { synthesis: Some(tactip.clone()), ..m };
        let text = toml::to_string(&filled).unwrap();
        assert!(text.contains("[synthesis]") && text.contains("model_resolution_px = [128, 128]"), "{text}");
        assert_eq!(toml::from_str::<Manifest>(&text).unwrap().synthesis, Some(tactip));
    }
}
