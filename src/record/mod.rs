//! Recording of hardware I/O and its replay.
//!
//! Recording (`rig collect --record FILE`): a [`Recorder`] owns the file. Each MG400 socket is
//! wrapped in a [`RecordingStream`] that logs every byte the client writes or reads, with the
//! rig-clock time, and each camera in a [`RecordingCamera`] that logs every frame handed to the
//! job (its pixels as a PNG, lossless, plus its capture timestamp and sequence number). Events
//! land in the file in the order they happened; the [`RecordingHeader`] (command line, plan,
//! work frame, collect options, firmware profile, sensors, seed) comes first. The byte layout
//! is in [`mod@format`].
//!
//! A lost socket is reopened as by an unrecorded client, and the reconnection is recorded too.
//! So is each decision the client makes on the feedback, with the frame it went by (the
//! client's [`Witness`]).
//!
//! Reading: a [`RecordingFile`] opens the file through [`crate::confine`] and reads the header;
//! [`RecordReader`]s read the records on from there, one at a time, each with its own position
//! on the one handle. A recording has no length bound: what a reader holds is the record it
//! reads (at most [`format::MAX_RECORD_BYTES`], checked from the length field before the body
//! is read) and a 64 KiB buffer, so `rig replay --info` ([`RecordingFile::scan`], a
//! [`Summary`]) and a replay take the same memory for a recording of any length. Each frame
//! is checked against its camera (one the header lists, at the header's resolution) from the
//! record's fields, before its pixels are decoded ([`frame_image`]). [`Recording`] reads a
//! whole file into memory, for tests and tools on short recordings.
//!
//! Replay (`rig replay FILE`): `jobs::replay::run` runs the real [`Mg400Client`] on
//! [`replay::ReplayStream`]s (reopened where the recording reconnected) and gives the job
//! [`replay::ReplayCamera`]s,
//! all fed from one [`replay::ReplaySession`] that serves the recorded events in recorded
//! order, read from the file as they are served, checks that what the client writes is what
//! was recorded, and stops at the first divergence with both sides named. See `replay` for how
//! it stays deterministic.

pub mod format;
pub mod replay;

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

use crate::arm::ArmError;
use crate::arm::dobot::client::{ByteStream, Decision, Mg400Client, Mg400Config, Reopen, Witness, connect_tcp};
use crate::arm::dobot::proto::Port;
use crate::arm::profile::FirmwareProfile;
use crate::camera::{Camera, CameraError, Frame};
use crate::clock::Clock;
use crate::config::CollectConfig;
use crate::dataset::ObjectInfo;
use crate::io::modbus::{ModbusError, ModbusReading, Peripherals, format_readings};
use crate::plan::{PlanSpec, PlannedPose};
use crate::pose::WorkFrame;

use format::Step;
pub use format::{ConnectOutcome, Direction, Event, FormatError, FramePixels, PeripheralOutcome, PeripheralPhase, RecordedFrame, SocketId};

/// Errors reading or writing a recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("recording {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("recording {path}: {source}")]
    Format {
        path: PathBuf,
        #[source]
        source: FormatError,
    },
    #[error("recording {path}: the header is not valid: {source}")]
    Header {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("recording {path}: record {record} is a frame of camera {camera}, but the header lists {cameras} cameras")]
    UnknownCamera { path: PathBuf, record: usize, camera: u8, cameras: usize },
    /// A frame of another size than its camera's: the header's resolution, or (in recordings
    /// whose header has none) the camera's first frame. Found from the record's fields, before
    /// anything is allocated for its pixels.
    #[error(
        "recording {path}: record {record} at byte {offset} is a {}x{} frame of camera {camera}, but {expected_from} {}x{}",
        found.0, found.1, expected.0, expected.1
    )]
    FrameSize {
        path: PathBuf,
        record: usize,
        offset: u64,
        camera: String,
        found: (u32, u32),
        expected: (u32, u32),
        /// `the header's camera is`, `its first frame was`.
        expected_from: &'static str,
    },
    /// A frame whose stored pixels do not decode (a PNG whose data is damaged although its
    /// record's checksum holds).
    #[error("recording {path}: record {record} at byte {offset}: frame {seq} of camera {camera} does not decode: {reason}")]
    FrameDecode { path: PathBuf, record: usize, offset: u64, camera: String, seq: u64, reason: String },
    #[error("recording {path}: closed before its header was written")]
    NoHeader { path: PathBuf },
    /// The file is not one rig reads as a recording: a FIFO or device (which would block or
    /// never end), a symlink.
    #[error("recording: {0}")]
    Confined(#[from] crate::confine::ConfineError),
    /// The header names an object that is not a plain name: it becomes a folder name, and a
    /// path there (`/abs`, `../..`) would put the replayed dataset anywhere.
    #[error("recording {path}: the header's object.name is not a plain name (no `/`, `\\`, `..`, leading dot or control character)")]
    ObjectName { path: PathBuf },
    /// A header too long for the format's bound (a plan of millions of poses).
    #[error("recording {path}: the header is {len} bytes, more than the {max} a recording holds")]
    HeaderTooLong { path: PathBuf, len: usize, max: usize },
}

impl RecordError {
    /// Whether the recording (not the machine) is at fault: a damaged, foreign or hostile file
    /// (exit 2); else an I/O failure (exit 1).
    pub fn is_bad_input(&self) -> bool {
        match self {
            RecordError::Io { .. } => false,
            RecordError::Confined(e) => e.is_bad_input(),
            _ => true,
        }
    }
}

/// Whether `name` can be a folder name: not empty, at most 100 bytes, no leading dot, no path
/// separator or control character (the rule a job request's object name follows).
fn is_plain_name(name: &str) -> bool {
    !name.is_empty() && name.len() <= 100 && !name.starts_with('.') && !name.chars().any(|c| c == '/' || c == '\\' || c.is_control())
}

/// One camera of the recorded run, in the order of the job's sensor list.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordedSensor {
    /// The camera's name (`Camera::name`).
    pub camera: String,
    /// Dataset directory name (`tactip`, `vitac`, `vitactip`).
    pub sensor_dir: crate::sensor::SensorKind,
    /// Calibration named in the manifest.
    pub calibration: String,
    /// The camera as the manifest's capture chain names it; absent in recordings made before
    /// rig recorded it (their rows replay as `real`, as they were written then).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capture: Option<crate::dataset::CapturePart>,
}

/// Everything a replay needs besides the events: what `rig collect` was asked and resolved.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordingHeader {
    pub rig_version: String,
    /// The command line of the recorded run.
    pub command_line: Vec<String>,
    /// The rig configuration file, if one was used (for the reader; replay does not need it).
    pub config_source: Option<String>,
    pub object: ObjectInfo,
    pub sensors: Vec<RecordedSensor>,
    pub seed: u64,
    pub plan_spec: PlanSpec,
    /// The poses in the order the job ran them.
    pub plan: Vec<PlannedPose>,
    pub work_frame: WorkFrame,
    pub collect: CollectConfig,
    pub profile: FirmwareProfile,
    pub speed_factor_pct: u8,
    /// The arm and the Modbus peripherals as the manifests' capture chain names them; absent
    /// in recordings made before rig recorded them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capture_arm: Option<crate::dataset::CapturePart>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub capture_modbus: Vec<crate::dataset::CapturePart>,
}

impl RecordingHeader {
    /// Parses and checks the header text of the recording at `path` (for messages).
    fn parse(json: &str, path: &Path) -> Result<Self, RecordError> {
        let header: RecordingHeader =
            serde_json::from_str(json).map_err(|source| RecordError::Header { path: path.to_path_buf(), source })?;
        if !is_plain_name(&header.object.name) {
            return Err(RecordError::ObjectName { path: path.to_path_buf() });
        }
        Ok(header)
    }
}

/// The checks every frame record passes before it is replayed: a camera the header lists, at
/// that camera's size (the header's resolution; recordings whose header has none: the size of
/// the camera's first frame), so a replay never writes an image of another size than the
/// dataset's manifest says, nor allocates for one.
#[derive(Debug, Clone)]
struct FrameCheck {
    cameras: Vec<String>,
    /// Per camera: the size its frames must have, and whether the header said so.
    sizes: Vec<Option<((u32, u32), bool)>>,
}

impl FrameCheck {
    fn new(header: &RecordingHeader) -> Self {
        Self {
            cameras: header.sensors.iter().map(|s| s.camera.clone()).collect(),
            sizes: header.sensors.iter().map(|s| s.capture.as_ref().and_then(|c| c.resolution_px).map(|[w, h]| ((w, h), true))).collect(),
        }
    }

    fn check(&mut self, path: &Path, record: usize, offset: u64, frame: &RecordedFrame) -> Result<(), RecordError> {
        let camera = usize::from(frame.camera);
        let Some(size) = self.sizes.get_mut(camera) else {
            return Err(RecordError::UnknownCamera { path: path.to_path_buf(), record, camera: frame.camera, cameras: self.cameras.len() });
        };
        let found = (frame.width, frame.height);
        match *size {
            None => *size = Some((found, false)),
            Some((expected, from_header)) if expected != found => {
                return Err(RecordError::FrameSize {
                    path: path.to_path_buf(),
                    record,
                    offset,
                    camera: self.cameras[camera].clone(),
                    found,
                    expected,
                    expected_from: if from_header { "the header's camera is" } else { "its first frame was" },
                });
            }
            Some(_) => {}
        }
        Ok(())
    }
}

/// A decoded recording: header and every event, in memory. For tests and tools on short
/// recordings; `rig replay` streams the file instead ([`RecordingFile`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The format version it was written in.
    pub version: u16,
    pub header: RecordingHeader,
    pub events: Vec<Event>,
}

impl Recording {
    /// Reads and checks a whole recording file into memory (as [`RecordingFile`] reads it).
    pub fn read(path: &Path) -> Result<Self, RecordError> {
        let file = RecordingFile::open(path)?;
        let mut records = file.records();
        let mut events = Vec::new();
        while let Some(r) = records.next_record()? {
            events.push(r.event);
        }
        Ok(Self { version: file.version, header: file.header, events })
    }

    /// Decodes recording bytes; `path` is only used in messages. Never panics.
    pub fn decode(bytes: &[u8], path: &Path) -> Result<Self, RecordError> {
        let raw = format::decode(bytes).map_err(|source| RecordError::Format { path: path.to_path_buf(), source })?;
        let header = RecordingHeader::parse(&raw.header_json, path)?;
        let mut check = FrameCheck::new(&header);
        for (record, e) in raw.events.iter().enumerate() {
            if let Event::Frame(f) = e {
                // Offsets are not kept by a whole-slice decode.
                check.check(path, record, 0, f)?;
            }
        }
        Ok(Self { version: raw.version, header, events: raw.events })
    }

    /// Counts what the recording holds.
    pub fn summary(&self) -> Summary {
        let mut sum = Summary::new(self.version, &self.header);
        for e in &self.events {
            sum.count(e);
        }
        sum
    }
}

/// A recording file opened for reading: its preamble and header read and checked, its records
/// read from the file one at a time by [`RecordReader`]s, each with its own position on the one
/// handle opened through [`crate::confine`] (`pread`), so several can read it at once (the
/// replay's events, its peripheral calls, a look ahead) without reopening the path.
#[derive(Debug, Clone)]
pub struct RecordingFile {
    path: PathBuf,
    file: Arc<File>,
    /// The format version it was written in.
    pub version: u16,
    pub header: RecordingHeader,
    /// Byte offset of the first record.
    first_record: u64,
}

/// Bytes read from a recording at a time (records are parsed from this buffer; a longer record
/// is read whole into its own).
const READ_CHUNK_BYTES: usize = 64 << 10;

impl RecordingFile {
    /// Opens the recording at `path` (a regular file, not a symlink, FIFO or device) and reads
    /// its header.
    pub fn open(path: &Path) -> Result<Self, RecordError> {
        let (dir, name) = crate::confine::open_parent(path)?;
        let file = Arc::new(dir.open_file(&name)?);
        let mut input = BufReader::with_capacity(READ_CHUNK_BYTES, At { file: Arc::clone(&file), pos: 0 });
        let mut bytes = Vec::new();
        let mut eof = false;
        let (preamble, len) = loop {
            match format::decode_preamble(&bytes, eof).map_err(|source| RecordError::Format { path: path.to_path_buf(), source })? {
                Step::Done(preamble, len) => break (preamble, len),
                Step::Need(n) => {
                    eof = read_more(&mut input, &mut bytes, n).map_err(|source| RecordError::Io { path: path.to_path_buf(), source })?
                }
            }
        };
        let header = RecordingHeader::parse(&preamble.header_json, path)?;
        Ok(Self { path: path.to_path_buf(), file, version: preamble.version, header, first_record: len as u64 })
    }

    /// The path it was opened at.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// A reader of its records, from the first.
    pub fn records(&self) -> RecordReader {
        RecordReader::at(self, self.first_record, format::RecordDecoder::new(self.version), FrameCheck::new(&self.header))
    }

    /// Reads every record once, in order, and counts them: the whole file is checked (checksums,
    /// frame sizes, the end record) holding one record at a time. `rig replay` does this before
    /// it writes anything, so a damaged recording is refused whole.
    pub fn scan(&self) -> Result<Summary, RecordError> {
        let mut sum = Summary::new(self.version, &self.header);
        let mut records = self.records();
        while let Some(r) = records.next_record()? {
            sum.count(&r.event);
        }
        Ok(sum)
    }
}

/// A positional reader over a shared file handle (`pread`): readers of one file keep their own
/// positions.
#[derive(Debug)]
struct At {
    file: Arc<File>,
    pos: u64,
}

impl Read for At {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.file.read_at(buf, self.pos)?;
        self.pos += n as u64;
        Ok(n)
    }
}

/// Reads from `input` until `bytes` holds `need` bytes or the input ends; returns whether it
/// ended. `need` comes from the decoder, which bounds it by the format's length bounds.
fn read_more(input: &mut impl Read, bytes: &mut Vec<u8>, need: usize) -> std::io::Result<bool> {
    let mut have = bytes.len();
    bytes.resize(need.max(have), 0);
    while have < bytes.len() {
        match input.read(&mut bytes[have..]) {
            Ok(0) => break,
            Ok(n) => have += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => {
                bytes.truncate(have);
                return Err(e);
            }
        }
    }
    let ended = have < bytes.len();
    bytes.truncate(have);
    Ok(ended)
}

/// A record read from a file, with where it is.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordAt {
    /// Its number (0 = first after the header).
    pub record: usize,
    /// Its byte offset in the file.
    pub offset: u64,
    pub event: Event,
}

/// Reads the records of a [`RecordingFile`] in order, one at a time: it holds the record being
/// read and a 64 KiB buffer, whatever the file's length. Each record is checked as it is read
/// (checksum, layout, frame camera and size); the end record ends it, and bytes after it are an
/// error. A clone reads on from the same place on its own.
pub struct RecordReader {
    path: PathBuf,
    file: Arc<File>,
    input: BufReader<At>,
    /// Byte offset of the next record.
    offset: u64,
    decoder: format::RecordDecoder,
    check: FrameCheck,
    /// The record being read (its bytes so far).
    bytes: Vec<u8>,
    ended: bool,
}

impl RecordReader {
    fn at(file: &RecordingFile, offset: u64, decoder: format::RecordDecoder, check: FrameCheck) -> Self {
        Self {
            path: file.path.clone(),
            file: Arc::clone(&file.file),
            input: BufReader::with_capacity(READ_CHUNK_BYTES, At { file: Arc::clone(&file.file), pos: offset }),
            offset,
            decoder,
            check,
            bytes: Vec::new(),
            ended: false,
        }
    }

    fn io(&self) -> impl FnOnce(std::io::Error) -> RecordError + use<> {
        let path = self.path.clone();
        move |source| RecordError::Io { path, source }
    }

    /// The next record; `None` after the end record. After an error it reads nothing more.
    pub fn next_record(&mut self) -> Result<Option<RecordAt>, RecordError> {
        let next = self.read_record();
        if next.is_err() {
            self.ended = true;
        }
        next
    }

    fn read_record(&mut self) -> Result<Option<RecordAt>, RecordError> {
        if self.ended {
            return Ok(None);
        }
        self.bytes.clear();
        // A record that was longer than the buffer: not kept once read.
        if self.bytes.capacity() > READ_CHUNK_BYTES {
            self.bytes = Vec::new();
        }
        let mut eof = false;
        let offset = self.offset;
        let at = usize::try_from(offset).unwrap_or(usize::MAX);
        loop {
            let step = self.decoder.next(&self.bytes, at, eof).map_err(|source| RecordError::Format { path: self.path.clone(), source })?;
            match step {
                Step::Need(n) => eof = read_more(&mut self.input, &mut self.bytes, n).map_err(self.io())?,
                Step::Done(event, len) => {
                    self.offset += len as u64;
                    let Some(event) = event else {
                        self.ended = true;
                        self.check_nothing_follows()?;
                        return Ok(None);
                    };
                    let record = self.decoder.records() - 1;
                    if let Event::Frame(f) = &event {
                        self.check.check(&self.path, record, offset, f)?;
                    }
                    return Ok(Some(RecordAt { record, offset, event }));
                }
            }
        }
    }

    fn check_nothing_follows(&mut self) -> Result<(), RecordError> {
        let mut one = [0u8; 1];
        if self.input.read(&mut one).map_err(self.io())? == 0 {
            return Ok(());
        }
        let len = self.file.metadata().map_err(self.io())?.len();
        let (offset, extra) = (self.offset as usize, len.saturating_sub(self.offset).max(1) as usize);
        Err(RecordError::Format { path: self.path.clone(), source: FormatError::TrailingBytes { offset, extra } })
    }

    /// The file it reads.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// A reader that goes on from here on its own (the replay's look ahead).
    pub fn fork(&self) -> RecordReader {
        Self {
            path: self.path.clone(),
            file: Arc::clone(&self.file),
            input: BufReader::with_capacity(READ_CHUNK_BYTES, At { file: Arc::clone(&self.file), pos: self.offset }),
            offset: self.offset,
            decoder: self.decoder.clone(),
            check: self.check.clone(),
            bytes: Vec::new(),
            ended: self.ended,
        }
    }
}

/// Encodes a camera frame's pixels as a recording stores them: a PNG (lossless; the format's
/// check accepts what this writes: IHDR, IDAT and IEND), else raw.
pub fn frame_pixels(image: &image::RgbImage) -> FramePixels {
    let mut png = Vec::new();
    match image.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png) {
        Ok(()) => FramePixels::Png(png),
        // An in-memory RGB8 image always encodes; raw pixels are a valid record all the same.
        Err(_) => FramePixels::Raw(image.as_raw().clone()),
    }
}

/// The pixels of a recorded frame. A PNG is inflated into a buffer of the frame's size, which
/// the format's check bounded ([`format::MAX_FRAME_PIXELS`]) and matched with the PNG's own
/// header before a byte was inflated.
pub fn frame_image(width: u32, height: u32, pixels: FramePixels) -> Result<image::RgbImage, String> {
    use image::ImageDecoder;
    match pixels {
        FramePixels::Raw(rgb) => {
            image::RgbImage::from_raw(width, height, rgb).ok_or_else(|| format!("it does not hold {width}x{height} RGB pixels"))
        }
        FramePixels::Png(png) => {
            let mut limits = image::Limits::default();
            limits.max_image_width = Some(width);
            limits.max_image_height = Some(height);
            limits.max_alloc = Some(format::MAX_RECORD_BYTES as u64);
            let decoder = image::codecs::png::PngDecoder::with_limits(std::io::Cursor::new(&png), limits).map_err(|e| e.to_string())?;
            if decoder.dimensions() != (width, height) || decoder.color_type() != image::ColorType::Rgb8 {
                let (w, h) = decoder.dimensions();
                return Err(format!("its PNG is {w}x{h} {:?}, not {width}x{height} RGB8", decoder.color_type()));
            }
            let mut rgb = vec![0u8; decoder.total_bytes() as usize];
            decoder.read_image(&mut rgb).map_err(|e| e.to_string())?;
            image::RgbImage::from_raw(width, height, rgb).ok_or_else(|| format!("it does not hold {width}x{height} RGB pixels"))
        }
    }
}

/// What a recording holds, counted (`rig replay FILE --info`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Summary {
    pub version: u16,
    pub events: usize,
    /// Rig-clock time of the first and the last event, s.
    pub span_s: Option<(f64, f64)>,
    /// Per socket (dashboard, motion, feedback): writes and reads with bytes, and their bytes.
    pub writes: [usize; 3],
    pub reads: [usize; 3],
    pub bytes: [usize; 3],
    /// Per socket: connections lost (socket records without bytes) and reconnection attempts
    /// by outcome (connected, failed, timed out).
    pub lost: [usize; 3],
    pub reconnections: [[usize; 3]; 3],
    /// Decisions on the feedback by a frame, waits for one that timed out, replies given up
    /// on per socket.
    pub decisions: usize,
    pub waits_timed_out: usize,
    pub replies_timed_out: [usize; 3],
    /// Camera frames per sensor of the header's list (its dataset name, frames).
    pub frames: Vec<(String, usize)>,
    /// Bytes the frames' pixels take in the file (PNG or raw, as stored).
    pub frame_bytes: u64,
    /// Peripherals calls, and of those, faults.
    pub peripheral_calls: usize,
    pub peripheral_faults: usize,
    /// Poses captured before the operator's interrupt, if the run was interrupted.
    pub interrupted_after: Option<u64>,
}

impl Summary {
    /// Nothing counted yet, for a recording of `version` with `header`.
    pub fn new(version: u16, header: &RecordingHeader) -> Self {
        Self { version, frames: header.sensors.iter().map(|s| (s.sensor_dir.to_string(), 0)).collect(), ..Summary::default() }
    }

    /// Counts one more event.
    pub fn count(&mut self, e: &Event) {
        self.events += 1;
        let t_s = e.t_s();
        self.span_s = Some(self.span_s.map_or((t_s, t_s), |(first, _)| (first, t_s)));
        match e {
            Event::Socket { socket, bytes, .. } if bytes.is_empty() => self.lost[socket.index()] += 1,
            Event::Socket { socket, direction, bytes, .. } => {
                let k = socket.index();
                match direction {
                    Direction::ToController => self.writes[k] += 1,
                    Direction::FromController => self.reads[k] += 1,
                }
                self.bytes[k] += bytes.len();
            }
            Event::Connect { socket, outcome, .. } => self.reconnections[socket.index()][outcome.index()] += 1,
            Event::FeedbackUsed { seq: Some(_), .. } => self.decisions += 1,
            Event::FeedbackUsed { seq: None, .. } => self.waits_timed_out += 1,
            Event::ReplyTimedOut { socket, .. } => self.replies_timed_out[socket.index()] += 1,
            Event::Frame(f) => {
                if let Some((_, n)) = self.frames.get_mut(usize::from(f.camera)) {
                    *n += 1;
                }
                self.frame_bytes += f.pixels.bytes().len() as u64;
            }
            Event::Peripherals { outcome, .. } => {
                self.peripheral_calls += 1;
                self.peripheral_faults += usize::from(*outcome != PeripheralOutcome::Ok);
            }
            Event::Interrupt { captured, .. } => self.interrupted_after = Some(*captured),
        }
    }

    /// The events a replay serves in order: all but the interrupt and the peripheral calls
    /// (served apart, see `replay`).
    pub fn served_events(&self) -> usize {
        self.events - self.peripheral_calls - usize::from(self.interrupted_after.is_some())
    }
}

/// `name n` pairs joined, the zero counts left out; "none" when all are.
fn counted(pairs: &[(&str, usize)]) -> String {
    let parts: Vec<String> = pairs.iter().filter(|(_, n)| *n > 0).map(|(name, n)| format!("{name} {n}")).collect();
    if parts.is_empty() { "none".to_string() } else { parts.join(", ") }
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names = SocketId::ALL.map(SocketId::name);
        match self.span_s {
            Some((a, b)) => {
                writeln!(f, "format version {}, {} events from t = {a:.3} s to {b:.3} s of rig time", self.version, self.events)?
            }
            None => writeln!(f, "format version {}, no events", self.version)?,
        }
        for (k, name) in names.iter().enumerate() {
            writeln!(f, "{name} socket: {} writes, {} reads, {} bytes", self.writes[k], self.reads[k], self.bytes[k])?;
        }
        let lost: Vec<(&str, usize)> = names.iter().copied().zip(self.lost).collect();
        writeln!(f, "connections lost: {}", counted(&lost))?;
        let by_outcome: Vec<String> = ConnectOutcome::ALL
            .iter()
            .filter_map(|outcome| {
                let pairs: Vec<(&str, usize)> = names.iter().copied().zip(self.reconnections.map(|r| r[outcome.index()])).collect();
                pairs.iter().any(|(_, n)| *n > 0).then(|| format!("{} {}", outcome.name(), counted(&pairs)))
            })
            .collect();
        writeln!(f, "reconnections: {}", if by_outcome.is_empty() { "none".to_string() } else { by_outcome.join("; ") })?;
        if self.version >= 5 {
            writeln!(
                f,
                "decisions on the feedback: {} by a frame, {} waits timed out; replies given up on: {}",
                self.decisions,
                self.waits_timed_out,
                counted(&names.iter().copied().zip(self.replies_timed_out).collect::<Vec<_>>())
            )?;
        } else {
            writeln!(f, "decisions on the feedback: not recorded before format version 5")?;
        }
        let frames: Vec<(&str, usize)> = self.frames.iter().map(|(name, n)| (name.as_str(), *n)).collect();
        let total: usize = self.frames.iter().map(|(_, n)| n).sum();
        match self.frame_bytes.checked_div(total as u64) {
            Some(per_frame) => {
                writeln!(f, "camera frames: {} ({} bytes of pixels, {per_frame} a frame)", counted(&frames), self.frame_bytes)?
            }
            None => writeln!(f, "camera frames: {}", counted(&frames))?,
        }
        writeln!(f, "peripherals calls: {} ({} faults)", self.peripheral_calls, self.peripheral_faults)?;
        match self.interrupted_after {
            Some(n) => write!(f, "interrupted by the operator after {n} poses"),
            None => write!(f, "not interrupted"),
        }
    }
}

/// What the recorder holds behind its lock.
struct RecorderState {
    path: PathBuf,
    out: BufWriter<File>,
    /// Events logged before the header was known (the connection's first feedback frames).
    pending: Option<Vec<Event>>,
    records: u64,
    /// The first write error; reported by [`Recorder::finish`] (sockets keep working).
    error: Option<std::io::Error>,
    finished: bool,
}

impl RecorderState {
    fn write_event(&mut self, event: &Event) {
        if self.error.is_some() || self.finished {
            return;
        }
        match self.out.write_all(&format::encode_event(event)) {
            Ok(()) => self.records += 1,
            Err(e) => self.error = Some(e),
        }
    }
}

/// Writes a recording. Cloning shares the file; events are written in the order they arrive.
#[derive(Clone)]
pub struct Recorder {
    state: Arc<Mutex<RecorderState>>,
    clock: Arc<dyn Clock>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder").finish_non_exhaustive()
    }
}

impl Recorder {
    /// Creates `path`. Events are stamped with `clock`; until [`begin`](Self::begin) writes the
    /// header they are held in memory.
    pub fn create(path: &Path, clock: Arc<dyn Clock>) -> Result<Self, RecordError> {
        let file = File::create(path).map_err(|source| RecordError::Io { path: path.to_path_buf(), source })?;
        let state = RecorderState {
            path: path.to_path_buf(),
            out: BufWriter::with_capacity(1 << 20, file),
            pending: Some(Vec::new()),
            records: 0,
            error: None,
            finished: false,
        };
        Ok(Self { state: Arc::new(Mutex::new(state)), clock })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, RecorderState> {
        // A panic elsewhere while holding the lock leaves consistent state (one whole write).
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Writes the header, then the events held so far.
    pub fn begin(&self, header: &RecordingHeader) -> Result<(), RecordError> {
        let mut st = self.lock();
        let path = st.path.clone();
        let json = serde_json::to_string_pretty(header).map_err(|source| RecordError::Header { path: path.clone(), source })?;
        if json.len() > format::MAX_HEADER_BYTES {
            return Err(RecordError::HeaderTooLong { path, len: json.len(), max: format::MAX_HEADER_BYTES });
        }
        st.out.write_all(&format::encode_preamble(&json)).map_err(|source| RecordError::Io { path, source })?;
        for event in st.pending.take().unwrap_or_default() {
            st.write_event(&event);
        }
        Ok(())
    }

    fn log(&self, make: impl FnOnce(f64) -> Event) {
        let mut st = self.lock();
        // Stamped under the lock, so times in the file never go backwards.
        let event = make(self.clock.now_s());
        match st.pending.as_mut() {
            Some(pending) => pending.push(event),
            None => st.write_event(&event),
        }
    }

    /// Logs bytes that passed on `socket`.
    pub fn log_socket(&self, socket: SocketId, direction: Direction, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        self.log(|t_s| Event::Socket { socket, direction, t_s, bytes: bytes.to_vec() });
    }

    /// Logs that the client's read (`FromController`) found `socket` closed or failed, or
    /// that its write (`ToController`) failed: a socket record without bytes.
    pub fn log_connection_lost(&self, socket: SocketId, direction: Direction) {
        self.log(|t_s| Event::Socket { socket, direction, t_s, bytes: Vec::new() });
    }

    /// Logs how the client's reconnection of `socket` went.
    pub fn log_connect(&self, socket: SocketId, outcome: ConnectOutcome) {
        self.log(|t_s| Event::Connect { socket, t_s, outcome });
    }

    /// Logs a decision of the client that timing settled: a feedback-used or a
    /// reply-timed-out record.
    pub fn log_decision(&self, decision: Decision) {
        self.log(|t_s| decision_event(decision, t_s));
    }

    /// Logs a frame handed to the job by camera number `camera`, its pixels as a PNG.
    pub fn log_frame(&self, camera: u8, frame: &Frame) {
        // Compressed before the lock is taken: the sockets' records are not held up meanwhile.
        let pixels = frame_pixels(&frame.image);
        self.log(|t_s| {
            Event::Frame(RecordedFrame {
                camera,
                t_s,
                t_capture_s: frame.t_capture_s,
                seq: frame.seq,
                width: frame.image.width(),
                height: frame.image.height(),
                pixels,
            })
        });
    }

    /// Logs that the operator interrupted the run and the job stopped with `captured` poses
    /// captured (call after the job returned, before [`Self::finish`]).
    pub fn log_interrupt(&self, captured: u64) {
        self.log(|t_s| Event::Interrupt { t_s, captured });
    }

    /// Writes the end record and flushes; later events are dropped. Returns the record count.
    pub fn finish(&self) -> Result<u64, RecordError> {
        let mut st = self.lock();
        let path = st.path.clone();
        if st.pending.is_some() {
            return Err(RecordError::NoHeader { path });
        }
        if let Some(source) = st.error.take() {
            return Err(RecordError::Io { path, source });
        }
        if !st.finished {
            st.finished = true;
            let end = format::encode_end(st.records);
            let written = st.out.write_all(&end).and_then(|()| st.out.flush()).and_then(|()| st.out.get_ref().sync_all());
            written.map_err(|source| RecordError::Io { path, source })?;
        }
        Ok(st.records)
    }
}

/// A byte stream that logs everything read from and written to it.
pub struct RecordingStream<S> {
    inner: S,
    socket: SocketId,
    recorder: Recorder,
}

impl<S> RecordingStream<S> {
    pub fn new(inner: S, socket: SocketId, recorder: Recorder) -> Self {
        Self { inner, socket, recorder }
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for RecordingStream<S> {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let room = buf.remaining() > 0;
        let this = &mut *self;
        let polled = Pin::new(&mut this.inner).poll_read(cx, buf);
        match &polled {
            // Nothing read into a buffer with room: the end of the stream.
            Poll::Ready(Ok(())) if room && buf.filled().len() == before => {
                this.recorder.log_connection_lost(this.socket, Direction::FromController)
            }
            Poll::Ready(Ok(())) => this.recorder.log_socket(this.socket, Direction::FromController, &buf.filled()[before..]),
            Poll::Ready(Err(_)) => this.recorder.log_connection_lost(this.socket, Direction::FromController),
            Poll::Pending => {}
        }
        polled
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for RecordingStream<S> {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        let this = &mut *self;
        let polled = Pin::new(&mut this.inner).poll_write(cx, buf);
        match &polled {
            Poll::Ready(Ok(0)) | Poll::Ready(Err(_)) if !buf.is_empty() => {
                this.recorder.log_connection_lost(this.socket, Direction::ToController)
            }
            Poll::Ready(Ok(n)) => this.recorder.log_socket(this.socket, Direction::ToController, buf.get(..*n).unwrap_or_default()),
            _ => {}
        }
        polled
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// Peripherals that log what each call around a capture gave (the readings, or the fault);
/// a plain pass-through without a recorder.
pub struct RecordingPeripherals<P> {
    inner: P,
    recorder: Option<Recorder>,
}

impl<P: Peripherals> RecordingPeripherals<P> {
    pub fn new(inner: P, recorder: Option<Recorder>) -> Self {
        Self { inner, recorder }
    }

    fn log<T>(&self, phase: PeripheralPhase, result: &Result<T, ModbusError>, ok_text: impl FnOnce(&T) -> String) {
        // No peripherals configured: nothing to record (the replay then has none either).
        let Some(r) = self.recorder.as_ref().filter(|_| !self.inner.is_empty()) else { return };
        let (outcome, text) = match result {
            Ok(v) => (PeripheralOutcome::Ok, ok_text(v)),
            Err(e) if e.is_recoverable() => (PeripheralOutcome::Recoverable, e.to_string()),
            Err(e) => (PeripheralOutcome::Fatal, e.to_string()),
        };
        r.log(|t_s| Event::Peripherals { t_s, phase, outcome, text });
    }
}

impl<P: Peripherals> Peripherals for RecordingPeripherals<P> {
    fn is_empty(&self) -> bool {
        self.inner.is_empty()
    }
    async fn before_capture(&mut self) -> Result<(), ModbusError> {
        let result = self.inner.before_capture().await;
        self.log(PeripheralPhase::Before, &result, |_| String::new());
        result
    }
    async fn after_capture(&mut self) -> Result<Vec<ModbusReading>, ModbusError> {
        let result = self.inner.after_capture().await;
        self.log(PeripheralPhase::After, &result, |readings| format_readings(readings));
        result
    }
}

/// A camera that logs every frame it hands out; a plain pass-through without a recorder.
pub struct RecordingCamera<C> {
    inner: C,
    index: u8,
    recorder: Option<Recorder>,
}

impl<C: Camera> RecordingCamera<C> {
    /// Wraps camera number `index` (its place in the header's sensor list).
    pub fn new(inner: C, index: u8, recorder: Option<Recorder>) -> Self {
        Self { inner, index, recorder }
    }
    pub fn inner(&self) -> &C {
        &self.inner
    }
}

impl<C: Camera> Camera for RecordingCamera<C> {
    fn name(&self) -> &str {
        self.inner.name()
    }
    async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
        let frame = self.inner.frame_after(not_before_s).await?;
        if let Some(r) = &self.recorder {
            r.log_frame(self.index, &frame);
        }
        Ok(frame)
    }
    fn stream_stats(&self) -> Option<crate::camera::StreamStats> {
        self.inner.stream_stats()
    }
}

/// Connects the MG400 client like [`Mg400Client::connect`], with every socket recorded.
/// A lost socket is reconnected as by an unrecorded client: the loss (a socket record without
/// bytes), each reconnection attempt and the new connection's bytes are recorded, so the
/// replay loses and reopens it at the same points.
pub async fn connect_recorded(cfg: Mg400Config, clock: Arc<dyn Clock>, recorder: Recorder) -> Result<Mg400Client, ArmError> {
    let open = |socket: SocketId, port: u16| {
        let (cfg, recorder) = (cfg.clone(), recorder.clone());
        async move {
            let first = connect_tcp(&cfg.host, port, cfg.connect_timeout, socket.name()).await?;
            let stream: Box<dyn ByteStream> = Box::new(RecordingStream::new(first, socket, recorder.clone()));
            Ok::<_, ArmError>((stream, recorded_reopen(&cfg, port, socket, recorder)))
        }
    };
    let dashboard = open(SocketId::Dashboard, cfg.dashboard_port).await?;
    let motion = open(SocketId::Motion, cfg.motion_port).await?;
    let feedback = open(SocketId::Feedback, cfg.feedback_port).await?;
    let mut client = Mg400Client::with_reopen(cfg, clock, [dashboard, motion, feedback]);
    client.set_witness(Witness::Report(Arc::new(move |decision| recorder.log_decision(decision))));
    client.wait_first_feedback().await?;
    Ok(client)
}

/// The record of a client decision made at `t_s`; [`decision_of`] reads it back.
pub fn decision_event(decision: Decision, t_s: f64) -> Event {
    match decision {
        Decision::Feedback(seq) => Event::FeedbackUsed { t_s, seq: Some(seq) },
        Decision::FeedbackTimedOut => Event::FeedbackUsed { t_s, seq: None },
        Decision::ReplyTimedOut(Port::Dashboard) => Event::ReplyTimedOut { socket: SocketId::Dashboard, t_s },
        Decision::ReplyTimedOut(Port::Motion) => Event::ReplyTimedOut { socket: SocketId::Motion, t_s },
    }
}

/// The client decision an event records, if it records one (the inverse of [`decision_event`]).
pub fn decision_of(event: &Event) -> Option<Decision> {
    match event {
        Event::FeedbackUsed { seq: Some(seq), .. } => Some(Decision::Feedback(*seq)),
        Event::FeedbackUsed { seq: None, .. } => Some(Decision::FeedbackTimedOut),
        Event::ReplyTimedOut { socket: SocketId::Dashboard, .. } => Some(Decision::ReplyTimedOut(Port::Dashboard)),
        Event::ReplyTimedOut { socket: SocketId::Motion, .. } => Some(Decision::ReplyTimedOut(Port::Motion)),
        _ => None,
    }
}

/// Reconnects `socket` over TCP, recording the attempt and then the new connection's bytes.
fn recorded_reopen(cfg: &Mg400Config, port: u16, socket: SocketId, recorder: Recorder) -> Reopen {
    let cfg = cfg.clone();
    Arc::new(move || {
        let (cfg, recorder) = (cfg.clone(), recorder.clone());
        Box::pin(async move {
            let opened = connect_tcp(&cfg.host, port, cfg.connect_timeout, socket.name()).await;
            recorder.log_connect(
                socket,
                match &opened {
                    Ok(_) => ConnectOutcome::Connected,
                    Err(ArmError::Timeout { .. }) => ConnectOutcome::TimedOut,
                    Err(_) => ConnectOutcome::Failed,
                },
            );
            opened.map(|s| Box::new(RecordingStream::new(s, socket, recorder)) as Box<dyn ByteStream>)
        })
    })
}

/// Timeouts of a replayed client: long, so that a stalled replay is reported by the replay's
/// own watchdog (which names the record it waits for) rather than by a client timeout.
pub(crate) const REPLAY_CLIENT_TIMEOUT: Duration = Duration::from_secs(600);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::MockClock;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    fn header() -> RecordingHeader {
        RecordingHeader {
            rig_version: crate::version().into(),
            command_line: vec!["rig".into(), "collect".into()],
            config_source: None,
            object: ObjectInfo { name: "sphere".into(), stl_path: None, stl_sha256: None },
            sensors: vec![RecordedSensor {
                camera: "tactip".into(),
                sensor_dir: crate::sensor::SensorKind::TacTip,
                calibration: "default".into(),
                capture: None,
            }],
            seed: 1,
            plan_spec: PlanSpec::default(),
            plan: vec![PlannedPose { pose_id: 4, pose: crate::pose::Pose::new(1.0, 2.0, 0.5, 15.0) }],
            work_frame: WorkFrame::default(),
            collect: CollectConfig::default(),
            profile: FirmwareProfile::default_mg400(),
            speed_factor_pct: 100,
            capture_arm: None,
            capture_modbus: Vec::new(),
        }
    }

    struct OneFrame;
    impl Camera for OneFrame {
        fn name(&self) -> &str {
            "tactip"
        }
        async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
            Ok(Frame { image: image::RgbImage::from_pixel(2, 3, image::Rgb([9, 8, 7])), t_capture_s: not_before_s + 0.1, seq: 42 })
        }
    }

    #[tokio::test]
    async fn wrappers_log_both_directions_and_frames_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.rec");
        let clock = MockClock::new();
        let recorder = Recorder::create(&path, Arc::new(clock.clone())).unwrap();
        let (client, mut controller) = tokio::io::duplex(256);
        let mut stream = RecordingStream::new(client, SocketId::Dashboard, recorder.clone());
        // Logged before the header is known, written after it.
        stream.write_all(b"RobotMode()").await.unwrap();
        recorder.begin(&header()).unwrap();
        clock.set_s(2.5);
        controller.write_all(b"0,{5},RobotMode();").await.unwrap();
        let mut buf = [0u8; 64];
        let n = stream.read(&mut buf).await.unwrap();
        assert_eq!(&buf[..n], b"0,{5},RobotMode();");
        let mut camera = RecordingCamera::new(OneFrame, 0, Some(recorder.clone()));
        let frame = camera.frame_after(3.0).await.unwrap();
        assert_eq!(recorder.finish().unwrap(), 3);

        let r = Recording::read(&path).unwrap();
        assert_eq!(r.header, header());
        assert_eq!(
            r.events[0],
            Event::Socket { socket: SocketId::Dashboard, direction: Direction::ToController, t_s: 0.0, bytes: b"RobotMode()".to_vec() }
        );
        assert!(matches!(&r.events[1], Event::Socket { direction: Direction::FromController, t_s, .. } if *t_s == 2.5));
        let Event::Frame(f) = &r.events[2] else { panic!("a frame: {:?}", r.events[2]) };
        assert_eq!((f.width, f.height, f.seq, f.t_capture_s), (2, 3, 42, frame.t_capture_s));
        assert!(matches!(f.pixels, FramePixels::Png(_)), "frames are recorded as PNG");
        assert_eq!(frame_image(f.width, f.height, f.pixels.clone()), Ok(frame.image.clone()), "losslessly");
    }

    #[test]
    fn a_summary_counts_every_kind_of_event() {
        let mut h = header();
        h.sensors = vec![RecordedSensor {
            camera: "cam".into(),
            sensor_dir: crate::sensor::SensorKind::TacTip,
            calibration: "default".into(),
            capture: None,
        }];
        let socket = |socket, direction, bytes: &[u8]| Event::Socket { socket, direction, t_s: 1.0, bytes: bytes.to_vec() };
        let frame =
            RecordedFrame { camera: 0, t_s: 2.0, t_capture_s: 1.9, seq: 1, width: 1, height: 1, pixels: FramePixels::Raw(vec![0; 3]) };
        let events = vec![
            socket(SocketId::Motion, Direction::ToController, b"Sync()"),
            socket(SocketId::Motion, Direction::FromController, b""),
            Event::Connect { socket: SocketId::Motion, t_s: 1.1, outcome: ConnectOutcome::Failed },
            Event::Connect { socket: SocketId::Motion, t_s: 1.2, outcome: ConnectOutcome::Connected },
            socket(SocketId::Feedback, Direction::FromController, &[0; 1440]),
            Event::FeedbackUsed { t_s: 1.3, seq: Some(1) },
            Event::FeedbackUsed { t_s: 1.4, seq: None },
            Event::ReplyTimedOut { socket: SocketId::Dashboard, t_s: 1.5 },
            Event::Frame(frame),
            Event::Peripherals { t_s: 2.1, phase: PeripheralPhase::After, outcome: PeripheralOutcome::Recoverable, text: "x".into() },
            Event::Interrupt { t_s: 3.0, captured: 2 },
        ];
        let s = Recording { version: 5, header: h, events }.summary();
        assert_eq!((s.events, s.span_s), (11, Some((1.0, 3.0))));
        assert_eq!((s.writes, s.reads, s.bytes, s.lost), ([0, 1, 0], [0, 0, 1], [0, 6, 1440], [0, 1, 0]));
        assert_eq!(s.reconnections, [[0, 0, 0], [1, 1, 0], [0, 0, 0]]);
        assert_eq!((s.decisions, s.waits_timed_out, s.replies_timed_out), (1, 1, [1, 0, 0]));
        assert_eq!(s.frames, vec![("tactip".to_string(), 1)]);
        assert_eq!((s.peripheral_calls, s.peripheral_faults, s.interrupted_after), (1, 1, Some(2)));
        let text = s.to_string();
        for line in [
            "format version 5, 11 events from t = 1.000 s to 3.000 s of rig time",
            "motion socket: 1 writes, 0 reads, 6 bytes",
            "connections lost: motion 1",
            "reconnections: connected motion 1; failed motion 1",
            "decisions on the feedback: 1 by a frame, 1 waits timed out; replies given up on: dashboard 1",
            "camera frames: tactip 1 (3 bytes of pixels, 3 a frame)",
            "peripherals calls: 1 (1 faults)",
            "interrupted by the operator after 2 poses",
        ] {
            assert!(text.lines().any(|l| l == line), "{line:?} not in:\n{text}");
        }
        let old = Recording { version: 4, header: header(), events: Vec::new() }.summary().to_string();
        assert!(
            old.contains("no events") && old.contains("not recorded before format version 5") && old.contains("reconnections: none"),
            "{old}"
        );
    }

    #[test]
    fn closing_without_a_header_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let recorder = Recorder::create(&dir.path().join("r.rec"), Arc::new(MockClock::new())).unwrap();
        assert!(matches!(recorder.finish(), Err(RecordError::NoHeader { .. })));
    }

    /// A recorded 24 x 16 PNG frame of smooth pixels and noise.
    fn png_frame() -> Vec<u8> {
        let image = image::RgbImage::from_fn(24, 16, |x, y| image::Rgb([x as u8 * 10, y as u8 * 15, ((x * 7 + y * 13) % 5) as u8]));
        let FramePixels::Png(png) = frame_pixels(&image) else { panic!("an RGB8 image encodes as PNG") };
        assert_eq!(frame_image(24, 16, FramePixels::Png(png.clone())), Ok(image));
        png
    }

    proptest::proptest! {
        /// What the format's check lets through (a PNG container of the record's size whose
        /// chunks are IHDR, IDAT and IEND) decodes or fails, never panics, and never yields
        /// another size than the record's.
        #[test]
        fn a_damaged_png_frame_fails_to_decode_without_panicking(
            edits in proptest::collection::vec((proptest::prelude::any::<usize>(), proptest::prelude::any::<u8>()), 1..6),
        ) {
            let mut png = png_frame();
            // The IDAT chunk's data (after the signature, IHDR, and the IDAT's length and type).
            let idat = 8 + 25 + 8;
            let idat_len = png.len() - idat - 4 - 12;
            for (at, v) in edits {
                png[idat + at % idat_len] = v;
            }
            if let Ok(image) = frame_image(24, 16, FramePixels::Png(png)) {
                proptest::prop_assert_eq!(image.dimensions(), (24, 16));
            }
        }
    }

    #[test]
    fn a_png_frame_of_another_size_or_colour_than_its_record_does_not_decode() {
        let png = png_frame();
        assert!(frame_image(24, 17, FramePixels::Png(png.clone())).is_err());
        let grey = image::GrayImage::from_pixel(24, 16, image::Luma([9]));
        let mut grey_png = Vec::new();
        grey.write_to(&mut std::io::Cursor::new(&mut grey_png), image::ImageFormat::Png).unwrap();
        assert!(frame_image(24, 16, FramePixels::Png(grey_png)).is_err());
        assert!(frame_image(2, 2, FramePixels::Raw(vec![0; 11])).is_err());
    }

    #[test]
    fn a_frame_of_an_unlisted_camera_is_refused() {
        let mut bytes = format::encode_preamble(&serde_json::to_string(&header()).unwrap());
        let frame = RecordedFrame { camera: 1, t_s: 0.0, t_capture_s: 0.0, seq: 0, width: 0, height: 0, pixels: FramePixels::Raw(vec![]) };
        bytes.extend(format::encode_event(&Event::Frame(frame)));
        bytes.extend(format::encode_end(1));
        let e = Recording::decode(&bytes, Path::new("x.rec")).unwrap_err();
        assert!(matches!(e, RecordError::UnknownCamera { camera: 1, cameras: 1, .. }), "{e}");
    }
}
