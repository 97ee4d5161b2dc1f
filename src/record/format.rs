//! The recording file format, sans-io: [`encode_preamble`], [`encode_event`], [`encode_end`]
//! turn values into bytes; [`decode_preamble`] and a [`RecordDecoder`] turn bytes back into the
//! header and then one event at a time. The caller hands them the bytes it has read; a
//! [`Step::Need`] asks for more, so a file of any length is read holding one record at a time
//! (`record::RecordReader` is that caller, over a file). [`decode`] does a whole byte slice at
//! once. None of them panics, whatever it is given (fuzzed by
//! `fuzz/fuzz_targets/recording_decoder.rs`).
//!
//! This file depends on nothing but `std` and `thiserror`, so the fuzz target compiles it
//! alone. The header is carried as text here; `record::header` gives it its meaning. A PNG
//! frame's structure is checked here (its chunks, and that its IHDR names the record's size);
//! its pixels are inflated by `record::frame_image`, into a buffer of the size checked here.
//!
//! # Layout (format version 6; versions 1 to 5 are read too), all integers little-endian
//!
//! | offset | size | field | meaning |
//! |---|---|---|---|
//! | 0 | 8 | magic | `b"RIGREC\n\0"` |
//! | 8 | 2 | `u16` version | [`FORMAT_VERSION`] |
//! | 10 | 4 | `u32` H | header length, bytes, at most [`MAX_HEADER_BYTES`] |
//! | 14 | H | header | UTF-8 JSON (`record::header::RecordingHeader`) |
//! | 14+H | 4 | `u32` | CRC-32 (IEEE) of bytes 0..14+H |
//!
//! then records until the end record, each:
//!
//! | size | field | meaning |
//! |---|---|---|
//! | 1 | `u8` kind | 1 socket bytes, 2 camera frame, 3 interrupt, 4 peripherals (3 and 4: version 2), 5 reconnection (version 4), 6 feedback used and 7 reply timed out (version 5), 0xFF end |
//! | 4 | `u32` L | body length, bytes, at most [`MAX_RECORD_BYTES`] |
//! | L | body | per kind, below |
//! | 4 | `u32` | CRC-32 (IEEE) of kind, L and body |
//!
//! Socket body: `u8` socket (0 dashboard, 1 motion, 2 feedback), `u8` direction (0 written by
//! the client to the controller, 1 read by the client from the controller), `f64` `t_s` (rig
//! clock when the bytes passed), then the bytes themselves (L - 10 of them). None (version 3):
//! the connection was lost there. Read by the client: the read found the socket closed, or
//! failed; written by the client: the write failed. A replay gives the client the same end of
//! stream (or failed write) at the same point.
//!
//! Frame body: `u8` camera (index into the header's sensor list), `f64` `t_s` (rig clock when
//! the frame was handed to the job), `f64` `t_capture_s`, `u64` seq, `u32` width, `u32` height
//! (width x height at most [`MAX_FRAME_PIXELS`]), then from version 6 a `u8` encoding and the
//! pixels in it:
//!
//! | encoding | pixels |
//! |---|---|
//! | 0 raw | width x height x 3 bytes of RGB8, row-major (versions 1 to 5: always, with no encoding byte) |
//! | 1 PNG | a PNG of width x height 8-bit RGB pixels, not interlaced, holding the chunks IHDR, IDAT (one or more) and IEND and nothing else (what `rig collect --record` writes) |
//!
//! Interrupt body (16 bytes): `f64` `t_s` (rig clock when the run ended), `u64` poses captured
//! before the job saw the operator's interrupt (Ctrl-C). The job looks at its cancel flag only
//! before each pose, so this count is where a replay must stop. Written after the run's last
//! socket event; at most one.
//!
//! Peripherals body: `f64` `t_s`, `u8` phase (0 the writes before a capture, 1 the readings
//! after it), `u8` outcome (0 ok, 1 a recoverable fault, 2 a fault that ends the run), then
//! UTF-8 text: after an ok reading, the readings as the dataset's `modbus` column writes them
//! (`io::modbus::format_readings`); after a fault, its message; else empty.
//!
//! Connect body (10 bytes, version 4): `u8` socket, `f64` `t_s`, `u8` outcome (0 connected, 1
//! failed, 2 timed out): the client opening a socket again after losing it. The first
//! connection of each socket is not recorded (it precedes the header).
//!
//! Feedback-used body (17 bytes, version 5): `f64` `t_s`, `u8` what (0 a frame, 1 a wait that
//! timed out), `u64` the frame's number (frames count from 1 since the client started; 0: none
//! had arrived yet; 0 after a timeout): the client deciding something on the feedback (whether
//! the arm is in alarm, has arrived, is enabled), with the frame it went by. The feedback
//! reader publishes a frame only after its read was recorded, so which frame a decision saw is
//! a matter of scheduling; a replay makes the same decision on the same frame.
//!
//! Reply-timed-out body (9 bytes, version 5): `u8` socket (0 dashboard, 1 motion), `f64`
//! `t_s`: the client gave up waiting for a reply on that socket (its late reply, if it comes,
//! is read later like any bytes). A replay times out there, not on its clock.
//!
//! End body: `u64` number of records before it. A file without it was cut short (the
//! recording process was killed); bytes after it are an error.
//!
//! # Bounds
//!
//! A file has no length bound: it is read one record at a time. What a reader holds is bounded
//! by the length fields, checked before a byte of the body is read: a record body is at most
//! [`MAX_RECORD_BYTES`] (64 MiB: a raw frame of [`MAX_FRAME_PIXELS`], 16 Mpx, is 48 MiB), the
//! header at most [`MAX_HEADER_BYTES`] (256 MiB: a million planned poses), and a frame's
//! pixels, raw or inflated, at most 48 MiB.

/// First bytes of every recording.
pub const MAGIC: &[u8; 8] = b"RIGREC\n\0";
/// The format version this build writes (and the newest it reads).
pub const FORMAT_VERSION: u16 = 6;
/// The oldest version this build reads (version 1 has no interrupt records).
pub const OLDEST_READ_VERSION: u16 = 1;

const KIND_SOCKET: u8 = 1;
const KIND_FRAME: u8 = 2;
const KIND_INTERRUPT: u8 = 3;
const INTERRUPT_LEN: usize = 8 + 8;
const KIND_PERIPHERALS: u8 = 4;
const PERIPHERALS_FIXED: usize = 8 + 1 + 1;
const KIND_CONNECT: u8 = 5;
const CONNECT_LEN: usize = 1 + 8 + 1;
const KIND_FEEDBACK_USED: u8 = 6;
const FEEDBACK_USED_LEN: usize = 8 + 1 + 8;
const KIND_REPLY_TIMED_OUT: u8 = 7;
const REPLY_TIMED_OUT_LEN: usize = 1 + 8;
const KIND_END: u8 = 0xFF;
const SOCKET_FIXED: usize = 1 + 1 + 8;
const FRAME_FIXED: usize = 1 + 8 + 8 + 8 + 4 + 4;
/// A frame body's fixed fields from version 6 (the encoding byte after them).
const FRAME_FIXED_V6: usize = FRAME_FIXED + 1;
/// Kind and length before a record's body, checksum after it.
const RECORD_HEAD: usize = 1 + 4;
const RECORD_TAIL: usize = 4;
/// Magic, version and header length before the header, checksum after it.
const PREAMBLE_HEAD: usize = 8 + 2 + 4;

/// Longest record body read, bytes: a raw frame of [`MAX_FRAME_PIXELS`] with room to spare (a
/// PNG of incompressible pixels is a little longer than they are).
pub const MAX_RECORD_BYTES: usize = 64 << 20;
/// Longest header read, bytes (a million planned poses fit).
pub const MAX_HEADER_BYTES: usize = 256 << 20;
/// Most pixels in one recorded frame (4096 x 4096, as the dataset's image decoder allows).
pub const MAX_FRAME_PIXELS: u64 = 1 << 24;
/// The first bytes of a PNG file.
const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1A, b'\n'];

/// Which MG400 connection bytes went over.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SocketId {
    Dashboard,
    Motion,
    Feedback,
}

impl SocketId {
    pub const ALL: [SocketId; 3] = [SocketId::Dashboard, SocketId::Motion, SocketId::Feedback];

    fn code(self) -> u8 {
        match self {
            SocketId::Dashboard => 0,
            SocketId::Motion => 1,
            SocketId::Feedback => 2,
        }
    }
    fn from_code(code: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.code() == code)
    }
    /// Its place in [`Self::ALL`] (for per-socket tables).
    pub fn index(self) -> usize {
        usize::from(self.code())
    }
    /// `dashboard`, `motion` or `feedback`.
    pub fn name(self) -> &'static str {
        match self {
            SocketId::Dashboard => "dashboard",
            SocketId::Motion => "motion",
            SocketId::Feedback => "feedback",
        }
    }
}

/// Which way bytes went, seen from the client.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// The client wrote them (requests).
    ToController,
    /// The client read them (replies, feedback frames).
    FromController,
}

/// One recorded event, in the order the recording saw them.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// Bytes that passed on a socket; none: the connection was lost there (version 3), see
    /// [`Event::is_connection_lost`].
    Socket {
        socket: SocketId,
        direction: Direction,
        t_s: f64,
        bytes: Vec<u8>,
    },
    Frame(RecordedFrame),
    /// The operator interrupted the run; the job stopped before pose number `captured` + 1.
    Interrupt {
        t_s: f64,
        captured: u64,
    },
    /// What the Modbus peripherals did around a capture.
    Peripherals {
        t_s: f64,
        phase: PeripheralPhase,
        outcome: PeripheralOutcome,
        text: String,
    },
    /// The client opened `socket` again after losing it (version 4).
    Connect {
        socket: SocketId,
        t_s: f64,
        outcome: ConnectOutcome,
    },
    /// The client decided something on the feedback (version 5): `Some(seq)`, by the frame
    /// numbered `seq` (from 1; 0: no frame had arrived), `None`: its wait for a frame that
    /// fits timed out.
    FeedbackUsed {
        t_s: f64,
        seq: Option<u64>,
    },
    /// The client gave up waiting for a reply on `socket` (version 5; dashboard or motion).
    ReplyTimedOut {
        socket: SocketId,
        t_s: f64,
    },
}

/// How a reconnection went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConnectOutcome {
    Connected,
    /// The connection was refused or failed.
    Failed,
    /// It did not complete within the client's connect timeout.
    TimedOut,
}

impl ConnectOutcome {
    pub const ALL: [ConnectOutcome; 3] = [ConnectOutcome::Connected, ConnectOutcome::Failed, ConnectOutcome::TimedOut];
    /// Its place in [`Self::ALL`].
    pub fn index(self) -> usize {
        usize::from(self.code())
    }
    /// `connected`, `failed` or `timed out`.
    pub fn name(self) -> &'static str {
        match self {
            ConnectOutcome::Connected => "connected",
            ConnectOutcome::Failed => "failed",
            ConnectOutcome::TimedOut => "timed out",
        }
    }
    fn code(self) -> u8 {
        match self {
            ConnectOutcome::Connected => 0,
            ConnectOutcome::Failed => 1,
            ConnectOutcome::TimedOut => 2,
        }
    }
    fn from_code(code: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|o| o.code() == code)
    }
}

impl Event {
    /// A socket event without bytes: the client's read found the connection closed (or
    /// failed), or its write failed.
    pub fn is_connection_lost(&self) -> bool {
        matches!(self, Event::Socket { bytes, .. } if bytes.is_empty())
    }
}

/// When around a capture the peripherals were used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PeripheralPhase {
    /// `before_capture`: the writes once the arm has arrived.
    Before,
    /// `after_capture`: the readings for the row (then the after-capture writes).
    After,
}

impl PeripheralPhase {
    pub const ALL: [PeripheralPhase; 2] = [PeripheralPhase::Before, PeripheralPhase::After];
    fn code(self) -> u8 {
        match self {
            PeripheralPhase::Before => 0,
            PeripheralPhase::After => 1,
        }
    }
    fn from_code(code: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.code() == code)
    }
}

/// How a peripheral call ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PeripheralOutcome {
    Ok,
    /// A fault the job clears and retries (`ModbusError::is_recoverable`).
    Recoverable,
    /// A fault that ends the run.
    Fatal,
}

impl PeripheralOutcome {
    pub const ALL: [PeripheralOutcome; 3] = [PeripheralOutcome::Ok, PeripheralOutcome::Recoverable, PeripheralOutcome::Fatal];
    fn code(self) -> u8 {
        match self {
            PeripheralOutcome::Ok => 0,
            PeripheralOutcome::Recoverable => 1,
            PeripheralOutcome::Fatal => 2,
        }
    }
    fn from_code(code: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|o| o.code() == code)
    }
}

impl Event {
    /// Rig-clock time of the event, s.
    pub fn t_s(&self) -> f64 {
        match self {
            Event::Socket { t_s, .. } => *t_s,
            Event::Frame(f) => f.t_s,
            Event::Interrupt { t_s, .. } => *t_s,
            Event::Peripherals { t_s, .. } => *t_s,
            Event::Connect { t_s, .. } => *t_s,
            Event::FeedbackUsed { t_s, .. } => *t_s,
            Event::ReplyTimedOut { t_s, .. } => *t_s,
        }
    }
}

/// A camera frame as recorded: its pixels (raw or PNG) and the frame's own timestamps.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedFrame {
    /// Index into the header's sensor list.
    pub camera: u8,
    /// Rig clock when the frame was handed to the job, s.
    pub t_s: f64,
    /// The frame's capture time (middle of the exposure) on the rig clock, s.
    pub t_capture_s: f64,
    pub seq: u64,
    pub width: u32,
    pub height: u32,
    /// The `width` x `height` RGB8 pixels, as stored.
    pub pixels: FramePixels,
}

/// How a frame's pixels are stored (the frame body's encoding byte, version 6).
#[derive(Debug, Clone, PartialEq)]
pub enum FramePixels {
    /// `width * height * 3` bytes, row-major RGB8 (every frame before version 6).
    Raw(Vec<u8>),
    /// A PNG of the 8-bit RGB pixels: IHDR, IDAT and IEND chunks only (what rig writes from
    /// version 6). Decoded lazily (`record::frame_image`): a reader that only counts frames
    /// never inflates one.
    Png(Vec<u8>),
}

impl FramePixels {
    /// The stored bytes.
    pub fn bytes(&self) -> &[u8] {
        match self {
            FramePixels::Raw(b) | FramePixels::Png(b) => b,
        }
    }
    fn code(&self) -> u8 {
        match self {
            FramePixels::Raw(_) => 0,
            FramePixels::Png(_) => 1,
        }
    }
}

/// A decoded file: the header text and every event.
#[derive(Debug, Clone, PartialEq)]
pub struct RawRecording {
    pub version: u16,
    pub header_json: String,
    pub events: Vec<Event>,
}

/// Why bytes are not a (complete) recording. Offsets are byte offsets into the file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FormatError {
    #[error("not a rig recording (the file does not start with the RIGREC magic)")]
    BadMagic,
    #[error("recording format version {found} is not supported (this rig reads versions {oldest} to {supported})")]
    UnsupportedVersion { found: u16, oldest: u16, supported: u16 },
    #[error(
        "the recording is truncated: it ends at byte {offset} inside {what} (after {records} complete records); \
         the recording run was probably killed before it closed the file"
    )]
    Truncated { offset: usize, what: &'static str, records: usize },
    #[error(
        "the recording is truncated: {records} complete records but no end record (file ends at byte {offset}); \
         the recording run was probably killed before it closed the file"
    )]
    MissingEnd { offset: usize, records: usize },
    #[error("the recording is corrupted: checksum mismatch in {what} at byte {offset} (stored {stored:08x}, computed {computed:08x})")]
    Checksum { what: String, offset: usize, stored: u32, computed: u32 },
    #[error("the recording is corrupted: record {record} at byte {offset} has unknown kind {kind}")]
    UnknownKind { record: usize, offset: usize, kind: u8 },
    #[error("the recording is corrupted: record {record} at byte {offset}: {problem}")]
    Malformed { record: usize, offset: usize, problem: String },
    #[error("the recording header is not UTF-8 text (at byte {offset})")]
    HeaderNotText { offset: usize },
    #[error("the end record says {said} records but the file holds {found}")]
    CountMismatch { said: u64, found: usize },
    #[error("{extra} unexpected bytes after the end record at byte {offset}")]
    TrailingBytes { offset: usize, extra: usize },
    /// A length field past its bound: checked before the bytes it announces are read.
    #[error("the recording is corrupted: {what} at byte {offset} says it is {len} bytes long, more than the {max} rig reads")]
    TooLong { what: String, offset: usize, len: usize, max: usize },
}

/// CRC-32 (IEEE 802.3, reflected, as zlib) lookup table, built at compile time.
const CRC_TABLE: [u32; 256] = {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
};

/// CRC-32 of `parts` taken as one byte string.
pub fn crc32(parts: &[&[u8]]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for part in parts {
        for &b in *part {
            c = CRC_TABLE[((c ^ u32::from(b)) & 0xFF) as usize] ^ (c >> 8);
        }
    }
    c ^ 0xFFFF_FFFF
}

/// Magic, version, header and its checksum.
pub fn encode_preamble(header_json: &str) -> Vec<u8> {
    let mut out = Vec::with_capacity(18 + header_json.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(header_json.len() as u32).to_le_bytes());
    out.extend_from_slice(header_json.as_bytes());
    let crc = crc32(&[&out]);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

fn encode_record(kind: u8, body: &[u8]) -> Vec<u8> {
    let len = (body.len() as u32).to_le_bytes();
    let mut out = Vec::with_capacity(body.len() + 9);
    out.push(kind);
    out.extend_from_slice(&len);
    out.extend_from_slice(body);
    out.extend_from_slice(&crc32(&[&[kind], &len, body]).to_le_bytes());
    out
}

/// One event as a record.
pub fn encode_event(event: &Event) -> Vec<u8> {
    match event {
        Event::Socket { socket, direction, t_s, bytes } => {
            let mut body = Vec::with_capacity(SOCKET_FIXED + bytes.len());
            body.push(socket.code());
            body.push(match direction {
                Direction::ToController => 0,
                Direction::FromController => 1,
            });
            body.extend_from_slice(&t_s.to_le_bytes());
            body.extend_from_slice(bytes);
            encode_record(KIND_SOCKET, &body)
        }
        Event::Frame(f) => {
            let pixels = f.pixels.bytes();
            let mut body = Vec::with_capacity(FRAME_FIXED_V6 + pixels.len());
            body.push(f.camera);
            body.extend_from_slice(&f.t_s.to_le_bytes());
            body.extend_from_slice(&f.t_capture_s.to_le_bytes());
            body.extend_from_slice(&f.seq.to_le_bytes());
            body.extend_from_slice(&f.width.to_le_bytes());
            body.extend_from_slice(&f.height.to_le_bytes());
            body.push(f.pixels.code());
            body.extend_from_slice(pixels);
            encode_record(KIND_FRAME, &body)
        }
        Event::Interrupt { t_s, captured } => {
            let mut body = Vec::with_capacity(INTERRUPT_LEN);
            body.extend_from_slice(&t_s.to_le_bytes());
            body.extend_from_slice(&captured.to_le_bytes());
            encode_record(KIND_INTERRUPT, &body)
        }
        Event::Peripherals { t_s, phase, outcome, text } => {
            let mut body = Vec::with_capacity(PERIPHERALS_FIXED + text.len());
            body.extend_from_slice(&t_s.to_le_bytes());
            body.push(phase.code());
            body.push(outcome.code());
            body.extend_from_slice(text.as_bytes());
            encode_record(KIND_PERIPHERALS, &body)
        }
        Event::Connect { socket, t_s, outcome } => {
            let mut body = Vec::with_capacity(CONNECT_LEN);
            body.push(socket.code());
            body.extend_from_slice(&t_s.to_le_bytes());
            body.push(outcome.code());
            encode_record(KIND_CONNECT, &body)
        }
        Event::FeedbackUsed { t_s, seq } => {
            let mut body = Vec::with_capacity(FEEDBACK_USED_LEN);
            body.extend_from_slice(&t_s.to_le_bytes());
            body.push(u8::from(seq.is_none()));
            body.extend_from_slice(&seq.unwrap_or(0).to_le_bytes());
            encode_record(KIND_FEEDBACK_USED, &body)
        }
        Event::ReplyTimedOut { socket, t_s } => {
            let mut body = Vec::with_capacity(REPLY_TIMED_OUT_LEN);
            body.push(socket.code());
            body.extend_from_slice(&t_s.to_le_bytes());
            encode_record(KIND_REPLY_TIMED_OUT, &body)
        }
    }
}

/// The end record after `records` records.
pub fn encode_end(records: u64) -> Vec<u8> {
    encode_record(KIND_END, &records.to_le_bytes())
}

/// Reads fixed-size little-endian fields from a slice; `None` past its end.
struct Fields<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Fields<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.pos.checked_add(n)?;
        let s = self.bytes.get(self.pos..end)?;
        self.pos = end;
        Some(s)
    }
    fn u8(&mut self) -> Option<u8> {
        self.take(1).map(|s| s[0])
    }
    fn array<const N: usize>(&mut self) -> Option<[u8; N]> {
        self.take(N).and_then(|s| s.try_into().ok())
    }
    fn u16(&mut self) -> Option<u16> {
        self.array().map(u16::from_le_bytes)
    }
    fn u32(&mut self) -> Option<u32> {
        self.array().map(u32::from_le_bytes)
    }
    fn u64(&mut self) -> Option<u64> {
        self.array().map(u64::from_le_bytes)
    }
    fn f64(&mut self) -> Option<f64> {
        self.array().map(f64::from_le_bytes)
    }
    fn rest(&mut self) -> &'a [u8] {
        let s = self.bytes.get(self.pos..).unwrap_or_default();
        self.pos = self.bytes.len();
        s
    }
}

/// What a streaming decode step made of the bytes it was given.
#[derive(Debug, Clone, PartialEq)]
pub enum Step<T> {
    /// The item needs at least this many bytes, counted from the start of those given (never
    /// more than its length fields allow: the caller may read that many before calling again).
    Need(usize),
    /// The item, and how many of the bytes it took.
    Done(T, usize),
}

/// The magic, version and header of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Preamble {
    pub version: u16,
    pub header_json: String,
}

/// Decodes the preamble from the first bytes of a file. `eof`: no bytes follow `bytes` (a
/// shortfall is then a truncation, else a [`Step::Need`]).
pub fn decode_preamble(bytes: &[u8], eof: bool) -> Result<Step<Preamble>, FormatError> {
    let have = bytes.len();
    let short = |need: usize, what: &'static str| {
        if eof { Err(FormatError::Truncated { offset: have, what, records: 0 }) } else { Ok(Step::Need(need)) }
    };
    let mut f = Fields { bytes, pos: 0 };
    match f.take(MAGIC.len()) {
        Some(m) if m == MAGIC => {}
        Some(_) => return Err(FormatError::BadMagic),
        None if !MAGIC.starts_with(bytes) || (eof && bytes.is_empty()) => return Err(FormatError::BadMagic),
        // The whole fixed part at once: the caller reads it in one go.
        None => return short(PREAMBLE_HEAD, "the magic"),
    }
    let Some(version) = f.u16() else { return short(MAGIC.len() + 2, "the format version") };
    if !(OLDEST_READ_VERSION..=FORMAT_VERSION).contains(&version) {
        return Err(FormatError::UnsupportedVersion { found: version, oldest: OLDEST_READ_VERSION, supported: FORMAT_VERSION });
    }
    let Some(header_len) = f.u32() else { return short(PREAMBLE_HEAD, "the header length") };
    let header_len = header_len as usize;
    if header_len > MAX_HEADER_BYTES {
        return Err(FormatError::TooLong { what: "the header".into(), offset: PREAMBLE_HEAD, len: header_len, max: MAX_HEADER_BYTES });
    }
    let total = PREAMBLE_HEAD + header_len + 4;
    let Some(header) = f.take(header_len) else { return short(total, "the header") };
    let Some(stored) = f.u32() else { return short(total, "the header checksum") };
    let computed = crc32(&[&bytes[..PREAMBLE_HEAD + header_len]]);
    if stored != computed {
        return Err(FormatError::Checksum { what: "the header".into(), offset: 0, stored, computed });
    }
    let header_json =
        std::str::from_utf8(header).map_err(|e| FormatError::HeaderNotText { offset: PREAMBLE_HEAD + e.valid_up_to() })?.to_string();
    Ok(Step::Done(Preamble { version, header_json }, total))
}

/// Decodes the records after the preamble, one at a time, keeping what spans records (their
/// count, whether an interrupt was seen).
#[derive(Debug, Clone)]
pub struct RecordDecoder {
    version: u16,
    records: usize,
    interrupted: bool,
}

impl RecordDecoder {
    /// A decoder for the records of a file of format `version` (from its [`Preamble`]).
    pub fn new(version: u16) -> Self {
        Self { version, records: 0, interrupted: false }
    }

    /// Complete records decoded so far (the end record not counted): the number of the next.
    pub fn records(&self) -> usize {
        self.records
    }

    /// Decodes the record at the start of `bytes`, which start at byte `offset` of the file;
    /// `eof`: nothing follows `bytes`. `Done(None, n)` is the end record: the caller checks
    /// that nothing follows it ([`FormatError::TrailingBytes`]).
    pub fn next(&mut self, bytes: &[u8], offset: usize, eof: bool) -> Result<Step<Option<Event>>, FormatError> {
        let record = self.records;
        let end = offset.saturating_add(bytes.len());
        let short = |need: usize, what: &'static str| {
            if eof { Err(FormatError::Truncated { offset: end, what, records: record }) } else { Ok(Step::Need(need)) }
        };
        let mut f = Fields { bytes, pos: 0 };
        let Some(kind) = f.u8() else {
            // Kind and length at once: the caller reads them in one go.
            return if eof { Err(FormatError::MissingEnd { offset, records: record }) } else { Ok(Step::Need(RECORD_HEAD)) };
        };
        let Some(len_bytes) = f.array::<4>() else { return short(RECORD_HEAD, "a record length") };
        let len = u32::from_le_bytes(len_bytes) as usize;
        if len > MAX_RECORD_BYTES {
            return Err(FormatError::TooLong { what: format!("record {record}"), offset, len, max: MAX_RECORD_BYTES });
        }
        let total = RECORD_HEAD + len + RECORD_TAIL;
        let Some(body) = f.take(len) else { return short(total, "a record body") };
        let Some(stored) = f.u32() else { return short(total, "a record checksum") };
        let computed = crc32(&[&[kind], &len_bytes, body]);
        if stored != computed {
            return Err(FormatError::Checksum { what: format!("record {record}"), offset, stored, computed });
        }
        let malformed = |problem: String| FormatError::Malformed { record, offset, problem };
        if kind == KIND_END {
            let said = Fields { bytes: body, pos: 0 }
                .u64()
                .filter(|_| len == 8)
                .ok_or_else(|| malformed(format!("end record body of {len} bytes, not 8")))?;
            if said != record as u64 {
                return Err(FormatError::CountMismatch { said, found: record });
            }
            return Ok(Step::Done(None, total));
        }
        let event = self.decode_body(kind, body).map_err(|e| match e {
            BodyError::Malformed(problem) => malformed(problem),
            BodyError::UnknownKind => FormatError::UnknownKind { record, offset, kind },
        })?;
        if matches!(event, Event::Interrupt { .. }) {
            self.interrupted = true;
        }
        self.records += 1;
        Ok(Step::Done(Some(event), total))
    }

    /// The event a record body of `kind` holds.
    fn decode_body(&self, kind: u8, body: &[u8]) -> Result<Event, BodyError> {
        let version = self.version;
        let len = body.len();
        let malformed = |problem: String| BodyError::Malformed(problem);
        let mut b = Fields { bytes: body, pos: 0 };
        match kind {
            KIND_SOCKET => {
                let (Some(socket), Some(direction), Some(t_s)) = (b.u8(), b.u8(), b.f64()) else {
                    return Err(malformed(format!("socket record body of {len} bytes is shorter than {SOCKET_FIXED}")));
                };
                let socket = SocketId::from_code(socket).ok_or_else(|| malformed(format!("unknown socket {socket}")))?;
                let direction = match direction {
                    0 => Direction::ToController,
                    1 => Direction::FromController,
                    d => return Err(malformed(format!("unknown direction {d}"))),
                };
                if !t_s.is_finite() {
                    return Err(malformed(format!("time {t_s} is not finite")));
                }
                let data = b.rest();
                if data.is_empty() && version < 3 {
                    return Err(malformed("socket record without bytes".into()));
                }
                Ok(Event::Socket { socket, direction, t_s, bytes: data.to_vec() })
            }
            KIND_FRAME => {
                let fixed = if version >= 6 { FRAME_FIXED_V6 } else { FRAME_FIXED };
                let (Some(camera), Some(t_s), Some(t_capture_s), Some(seq), Some(width), Some(height)) =
                    (b.u8(), b.f64(), b.f64(), b.u64(), b.u32(), b.u32())
                else {
                    return Err(malformed(format!("frame record body of {len} bytes is shorter than {fixed}")));
                };
                // Before version 6 every frame is raw, with no encoding byte.
                let encoding = if version >= 6 {
                    b.u8().ok_or_else(|| malformed(format!("frame record body of {len} bytes is shorter than {fixed}")))?
                } else {
                    0
                };
                if !(t_s.is_finite() && t_capture_s.is_finite()) {
                    return Err(malformed(format!("frame times {t_s}, {t_capture_s} are not finite")));
                }
                let pixels = u64::from(width) * u64::from(height);
                if pixels > MAX_FRAME_PIXELS {
                    return Err(malformed(format!("a frame of {width}x{height} pixels is more than the {MAX_FRAME_PIXELS} rig reads")));
                }
                let data = b.rest();
                let pixels = match encoding {
                    0 => {
                        let expected = pixels * 3;
                        if data.len() as u64 != expected {
                            return Err(malformed(format!(
                                "frame of {width}x{height} pixels needs {expected} RGB bytes, the record holds {}",
                                data.len()
                            )));
                        }
                        FramePixels::Raw(data.to_vec())
                    }
                    1 => {
                        check_png(data, width, height).map_err(|problem| malformed(format!("frame PNG: {problem}")))?;
                        FramePixels::Png(data.to_vec())
                    }
                    e => return Err(malformed(format!("unknown frame encoding {e}"))),
                };
                Ok(Event::Frame(RecordedFrame { camera, t_s, t_capture_s, seq, width, height, pixels }))
            }
            KIND_INTERRUPT if version >= 2 => {
                let (Some(t_s), Some(captured)) = (b.f64(), b.u64()) else {
                    return Err(malformed(format!("interrupt record body of {len} bytes, not {INTERRUPT_LEN}")));
                };
                if len != INTERRUPT_LEN {
                    return Err(malformed(format!("interrupt record body of {len} bytes, not {INTERRUPT_LEN}")));
                }
                if !t_s.is_finite() {
                    return Err(malformed(format!("time {t_s} is not finite")));
                }
                if self.interrupted {
                    return Err(malformed("a second interrupt record".into()));
                }
                Ok(Event::Interrupt { t_s, captured })
            }
            KIND_PERIPHERALS if version >= 2 => {
                let (Some(t_s), Some(phase), Some(outcome)) = (b.f64(), b.u8(), b.u8()) else {
                    return Err(malformed(format!("peripherals record body of {len} bytes is shorter than {PERIPHERALS_FIXED}")));
                };
                if !t_s.is_finite() {
                    return Err(malformed(format!("time {t_s} is not finite")));
                }
                let phase = PeripheralPhase::from_code(phase).ok_or_else(|| malformed(format!("unknown peripherals phase {phase}")))?;
                let outcome =
                    PeripheralOutcome::from_code(outcome).ok_or_else(|| malformed(format!("unknown peripherals outcome {outcome}")))?;
                let text = std::str::from_utf8(b.rest()).map_err(|e| malformed(format!("peripherals text is not UTF-8: {e}")))?;
                Ok(Event::Peripherals { t_s, phase, outcome, text: text.to_string() })
            }
            KIND_CONNECT if version >= 4 => {
                let (Some(socket), Some(t_s), Some(outcome)) = (b.u8(), b.f64(), b.u8()) else {
                    return Err(malformed(format!("connect record body of {len} bytes, not {CONNECT_LEN}")));
                };
                if len != CONNECT_LEN {
                    return Err(malformed(format!("connect record body of {len} bytes, not {CONNECT_LEN}")));
                }
                let socket = SocketId::from_code(socket).ok_or_else(|| malformed(format!("unknown socket {socket}")))?;
                if !t_s.is_finite() {
                    return Err(malformed(format!("time {t_s} is not finite")));
                }
                let outcome = ConnectOutcome::from_code(outcome).ok_or_else(|| malformed(format!("unknown connect outcome {outcome}")))?;
                Ok(Event::Connect { socket, t_s, outcome })
            }
            KIND_FEEDBACK_USED if version >= 5 => {
                let (Some(t_s), Some(what), Some(seq)) = (b.f64(), b.u8(), b.u64()) else {
                    return Err(malformed(format!("feedback-used record body of {len} bytes, not {FEEDBACK_USED_LEN}")));
                };
                if len != FEEDBACK_USED_LEN {
                    return Err(malformed(format!("feedback-used record body of {len} bytes, not {FEEDBACK_USED_LEN}")));
                }
                if !t_s.is_finite() {
                    return Err(malformed(format!("time {t_s} is not finite")));
                }
                let seq = match (what, seq) {
                    (0, seq) => Some(seq),
                    (1, 0) => None,
                    (1, seq) => return Err(malformed(format!("a timed-out wait names frame {seq}"))),
                    (w, _) => return Err(malformed(format!("unknown feedback use {w}"))),
                };
                Ok(Event::FeedbackUsed { t_s, seq })
            }
            KIND_REPLY_TIMED_OUT if version >= 5 => {
                let (Some(socket), Some(t_s)) = (b.u8(), b.f64()) else {
                    return Err(malformed(format!("reply-timed-out record body of {len} bytes, not {REPLY_TIMED_OUT_LEN}")));
                };
                if len != REPLY_TIMED_OUT_LEN {
                    return Err(malformed(format!("reply-timed-out record body of {len} bytes, not {REPLY_TIMED_OUT_LEN}")));
                }
                let socket = match SocketId::from_code(socket) {
                    Some(s @ (SocketId::Dashboard | SocketId::Motion)) => s,
                    _ => return Err(malformed(format!("socket {socket} has no replies"))),
                };
                if !t_s.is_finite() {
                    return Err(malformed(format!("time {t_s} is not finite")));
                }
                Ok(Event::ReplyTimedOut { socket, t_s })
            }
            _ => Err(BodyError::UnknownKind),
        }
    }
}

/// Why a record body does not decode (placed in the file by [`RecordDecoder::next`]).
enum BodyError {
    Malformed(String),
    UnknownKind,
}

/// Checks that `png` is a PNG of `width` x `height` 8-bit RGB pixels, not interlaced, with the
/// chunks IHDR, IDAT (one or more) and IEND and nothing else, without inflating anything: no
/// ancillary chunk (a compressed ICC profile or text) is ever decoded, and the pixels inflate
/// into a buffer of the size checked here.
fn check_png(png: &[u8], width: u32, height: u32) -> Result<(), String> {
    if png.get(..PNG_SIGNATURE.len()) != Some(&PNG_SIGNATURE[..]) {
        return Err("not a PNG (no PNG signature)".into());
    }
    let mut at = PNG_SIGNATURE.len();
    let mut idat = 0usize;
    loop {
        let head = png.get(at..at + 8).ok_or("a chunk is cut short")?;
        let len = u32::from_be_bytes([head[0], head[1], head[2], head[3]]) as usize;
        let kind = [head[4], head[5], head[6], head[7]];
        // Length, type, data, CRC.
        let next = (at + 8).checked_add(len).and_then(|n| n.checked_add(4)).filter(|n| *n <= png.len()).ok_or("a chunk is cut short")?;
        let data = &png[at + 8..at + 8 + len];
        match (at == PNG_SIGNATURE.len(), &kind) {
            (true, b"IHDR") => {
                let [w0, w1, w2, w3, h0, h1, h2, h3, depth, colour, compression, filter, interlace] =
                    <[u8; 13]>::try_from(data).map_err(|_| format!("an IHDR chunk of {len} bytes, not 13"))?;
                let (w, h) = (u32::from_be_bytes([w0, w1, w2, w3]), u32::from_be_bytes([h0, h1, h2, h3]));
                if (w, h) != (width, height) {
                    return Err(format!("the PNG is {w}x{h} pixels, the record says {width}x{height}"));
                }
                if (depth, colour, compression, filter, interlace) != (8, 2, 0, 0, 0) {
                    return Err(format!(
                        "not 8-bit RGB without interlacing (bit depth {depth}, colour type {colour}, compression {compression}, filter {filter}, interlace {interlace})"
                    ));
                }
            }
            (true, _) => return Err("the PNG does not start with its IHDR chunk".into()),
            (false, b"IDAT") => idat += 1,
            (false, b"IEND") => {
                if idat == 0 {
                    return Err("no IDAT chunk".into());
                }
                if len != 0 || next != png.len() {
                    return Err("bytes after the IEND chunk".into());
                }
                return Ok(());
            }
            (false, other) => {
                return Err(format!(
                    "a {} chunk (rig records IHDR, IDAT and IEND only)",
                    other.iter().map(|&c| char::from(c)).collect::<String>().escape_debug()
                ));
            }
        }
        at = next;
    }
}

/// Decodes a whole recording held in memory ([`decode_preamble`], then a [`RecordDecoder`]
/// over the rest). Never panics; every failure says where and why.
pub fn decode(bytes: &[u8]) -> Result<RawRecording, FormatError> {
    let (Preamble { version, header_json }, mut at) = match decode_preamble(bytes, true)? {
        Step::Done(preamble, n) => (preamble, n),
        // `eof` makes every shortfall an error; this cannot happen.
        Step::Need(_) => return Err(FormatError::Truncated { offset: bytes.len(), what: "the header", records: 0 }),
    };
    let mut decoder = RecordDecoder::new(version);
    let mut events = Vec::new();
    loop {
        match decoder.next(bytes.get(at..).unwrap_or_default(), at, true)? {
            Step::Done(Some(event), n) => {
                events.push(event);
                at += n;
            }
            Step::Done(None, n) => {
                at += n;
                if at < bytes.len() {
                    return Err(FormatError::TrailingBytes { offset: at, extra: bytes.len() - at });
                }
                return Ok(RawRecording { version, header_json, events });
            }
            Step::Need(_) => return Err(FormatError::MissingEnd { offset: at, records: decoder.records() }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_events() -> [Event; 4] {
        [
            Event::Socket { socket: SocketId::Motion, direction: Direction::ToController, t_s: 0.5, bytes: b"Sync()".to_vec() },
            Event::Frame(RecordedFrame {
                camera: 1,
                t_s: 1.0,
                t_capture_s: 0.9,
                seq: 7,
                width: 2,
                height: 1,
                pixels: FramePixels::Raw(vec![1, 2, 3, 4, 5, 6]),
            }),
            Event::Interrupt { t_s: 1.5, captured: 3 },
            Event::Peripherals {
                t_s: 1.6,
                phase: PeripheralPhase::After,
                outcome: PeripheralOutcome::Ok,
                text: "lamp.current=0.25;scale.force=".into(),
            },
        ]
    }

    fn sample() -> Vec<u8> {
        let mut out = encode_preamble("{\"a\":1}");
        for e in &sample_events() {
            out.extend(encode_event(e));
        }
        out.extend(encode_end(4));
        out
    }

    /// A record as a writer before version 6 wrote it: a frame's raw pixels with no encoding
    /// byte before them.
    fn encode_event_before_v6(event: &Event) -> Vec<u8> {
        match event {
            Event::Frame(RecordedFrame { pixels: FramePixels::Raw(rgb), .. }) => {
                let record = encode_event(event);
                let mut body = record[RECORD_HEAD..record.len() - RECORD_TAIL].to_vec();
                body.remove(FRAME_FIXED);
                assert_eq!(body.len(), FRAME_FIXED + rgb.len());
                encode_record(KIND_FRAME, &body)
            }
            other => encode_event(other),
        }
    }

    /// `sample()` as a writer of `version` wrote it (frames without the encoding byte before
    /// version 6).
    fn with_version(version: u16) -> Vec<u8> {
        let mut bytes = encode_preamble("{\"a\":1}");
        for e in &sample_events() {
            bytes.extend(if version < 6 { encode_event_before_v6(e) } else { encode_event(e) });
        }
        bytes.extend(encode_end(4));
        set_version(&mut bytes, version);
        bytes
    }

    /// Rewrites a recording's version number and redoes its header checksum.
    fn set_version(bytes: &mut [u8], version: u16) {
        bytes[8..10].copy_from_slice(&version.to_le_bytes());
        let header_len = u32::from_le_bytes([bytes[10], bytes[11], bytes[12], bytes[13]]) as usize;
        let crc = crc32(&[&bytes[..14 + header_len]]);
        bytes[14 + header_len..18 + header_len].copy_from_slice(&crc.to_le_bytes());
    }

    #[test]
    fn interrupt_records_need_version_2_and_come_once() {
        let r = decode(&sample()).unwrap();
        assert_eq!(r.events[2], Event::Interrupt { t_s: 1.5, captured: 3 });
        // Version 1 has no interrupt kind: such a file is corrupt, not silently misread.
        assert!(matches!(decode(&with_version(1)), Err(FormatError::UnknownKind { record: 2, kind: 3, .. })));
        assert!(matches!(decode(&with_version(7)), Err(FormatError::UnsupportedVersion { found: 7, oldest: 1, supported: 6 })));
        // Two interrupts.
        let mut two = encode_preamble("{}");
        for _ in 0..2 {
            two.extend(encode_event(&Event::Interrupt { t_s: 0.0, captured: 1 }));
        }
        two.extend(encode_end(2));
        assert!(matches!(decode(&two), Err(FormatError::Malformed { record: 1, .. })), "{:?}", decode(&two));
        // A body of the wrong length.
        let mut short = encode_preamble("{}");
        short.extend(encode_record(KIND_INTERRUPT, &[0u8; 15]));
        short.extend(encode_end(1));
        assert!(matches!(decode(&short), Err(FormatError::Malformed { record: 0, .. })));
        let mut long = encode_preamble("{}");
        long.extend(encode_record(KIND_INTERRUPT, &[0u8; 17]));
        long.extend(encode_end(1));
        assert!(matches!(decode(&long), Err(FormatError::Malformed { record: 0, .. })));
        // Peripherals: an unknown phase, an unknown outcome, text that is not UTF-8.
        for body in [[0u8, 0, 0, 0, 0, 0, 0, 0, 2, 0, b'x'], [0, 0, 0, 0, 0, 0, 0, 0, 1, 3, b'x'], [0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0xFF]] {
            let mut bad = encode_preamble("{}");
            bad.extend(encode_record(KIND_PERIPHERALS, &body));
            bad.extend(encode_end(1));
            assert!(matches!(decode(&bad), Err(FormatError::Malformed { record: 0, .. })), "{body:?}: {:?}", decode(&bad));
        }
    }

    #[test]
    fn crc_matches_the_zlib_check_value() {
        assert_eq!(crc32(&[b"123456789"]), 0xCBF4_3926);
        assert_eq!(crc32(&[b"1234", b"56789"]), 0xCBF4_3926);
    }

    #[test]
    fn literal_socket_record_bytes() {
        let e = Event::Socket { socket: SocketId::Dashboard, direction: Direction::FromController, t_s: 0.0, bytes: b"ok".to_vec() };
        let bytes = encode_event(&e);
        assert_eq!(&bytes[..5], &[1, 12, 0, 0, 0]);
        assert_eq!(&bytes[5..7], &[0, 1]);
        assert_eq!(&bytes[15..17], b"ok");
        assert_eq!(bytes.len(), 5 + 12 + 4);
    }

    #[test]
    fn round_trip() {
        let r = decode(&sample()).unwrap();
        assert_eq!(r.header_json, "{\"a\":1}");
        assert_eq!(r.events.len(), 4);
        assert!(
            matches!(&r.events[3], Event::Peripherals { phase: PeripheralPhase::After, text, .. } if text == "lamp.current=0.25;scale.force=")
        );
        assert!(matches!(&r.events[0], Event::Socket { socket: SocketId::Motion, bytes, .. } if bytes == b"Sync()"));
    }

    #[test]
    fn every_cut_is_a_truncation_error() {
        let full = sample();
        for cut in 0..full.len() {
            let e = decode(&full[..cut]).unwrap_err();
            assert!(
                matches!(e, FormatError::Truncated { .. } | FormatError::MissingEnd { .. } | FormatError::BadMagic),
                "cut at {cut}: {e:?}"
            );
        }
    }

    #[test]
    fn every_flipped_bit_is_caught() {
        let full = sample();
        for i in 0..full.len() {
            for bit in 0..8 {
                let mut bad = full.clone();
                bad[i] ^= 1 << bit;
                assert!(decode(&bad).is_err(), "flip of bit {bit} of byte {i} went unnoticed");
            }
        }
    }

    fn re_encode(r: &RawRecording) -> Vec<u8> {
        let mut out = encode_preamble(&r.header_json);
        for e in &r.events {
            out.extend(encode_event(e));
        }
        out.extend(encode_end(r.events.len() as u64));
        out
    }

    fn any_event() -> impl proptest::strategy::Strategy<Value = Event> {
        use proptest::prelude::*;
        let socket =
            (0u8..3, any::<bool>(), -1e6f64..1e6, proptest::collection::vec(any::<u8>(), 0..64)).prop_map(|(s, to, t_s, bytes)| {
                Event::Socket {
                    socket: SocketId::ALL[usize::from(s)],
                    direction: if to { Direction::ToController } else { Direction::FromController },
                    t_s,
                    bytes,
                }
            });
        let frame = (any::<u8>(), -1e6f64..1e6, -1e6f64..1e6, any::<u64>(), 0u32..5, 0u32..5, any::<u8>(), any::<bool>()).prop_map(
            |(camera, t_s, t_capture_s, seq, width, height, v, png)| {
                let pixels = if png && width * height > 0 {
                    FramePixels::Png(png_container(width, height, &[v; 7]))
                } else {
                    FramePixels::Raw(vec![v; (width * height * 3) as usize])
                };
                Event::Frame(RecordedFrame { camera, t_s, t_capture_s, seq, width, height, pixels })
            },
        );
        let peripherals = (-1e6f64..1e6, any::<bool>(), 0u8..3, ".{0,40}").prop_map(|(t_s, before, outcome, text)| Event::Peripherals {
            t_s,
            phase: if before { PeripheralPhase::Before } else { PeripheralPhase::After },
            outcome: PeripheralOutcome::ALL[usize::from(outcome)],
            text,
        });
        let connect = (0u8..3, -1e6f64..1e6, 0u8..3).prop_map(|(s, t_s, o)| Event::Connect {
            socket: SocketId::ALL[usize::from(s)],
            t_s,
            outcome: ConnectOutcome::ALL[usize::from(o)],
        });
        let used = (-1e6f64..1e6, proptest::option::of(any::<u64>())).prop_map(|(t_s, seq)| Event::FeedbackUsed { t_s, seq });
        let timed_out = (0u8..2, -1e6f64..1e6).prop_map(|(s, t_s)| Event::ReplyTimedOut { socket: SocketId::ALL[usize::from(s)], t_s });
        prop_oneof![socket, frame, peripherals, connect, used, timed_out]
    }

    proptest::proptest! {
        #[test]
        fn decode_never_panics(data in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..2048)) {
            let _ = decode(&data);
            // Behind a valid preamble the record decoder is reached; what decodes re-encodes
            // to the same bytes.
            let mut framed = encode_preamble("{}");
            framed.extend_from_slice(&data);
            if let Ok(r) = decode(&framed) {
                proptest::prop_assert_eq!(re_encode(&r), framed);
            }
        }

        #[test]
        fn events_round_trip(events in proptest::collection::vec(any_event(), 0..8), header in ".{0,40}") {
            let r = RawRecording { version: FORMAT_VERSION, header_json: header, events };
            let bytes = re_encode(&r);
            proptest::prop_assert_eq!(decode(&bytes), Ok(r));
        }

        #[test]
        fn mutated_recordings_never_panic(
            events in proptest::collection::vec(any_event(), 1..6),
            edits in proptest::collection::vec((proptest::prelude::any::<usize>(), proptest::prelude::any::<u8>()), 1..4),
            cut in proptest::prelude::any::<usize>(),
        ) {
            let r = RawRecording { version: FORMAT_VERSION, header_json: "{}".into(), events };
            let mut bytes = re_encode(&r);
            let len = bytes.len();
            for (at, v) in edits {
                bytes[at % len] = v;
            }
            bytes.truncate(cut % (len + 1));
            let _ = decode(&bytes);
        }
    }

    #[test]
    fn a_lost_connection_is_a_socket_record_without_bytes_from_version_3() {
        let lost = Event::Socket { socket: SocketId::Dashboard, direction: Direction::FromController, t_s: 2.0, bytes: Vec::new() };
        assert!(lost.is_connection_lost());
        let mut bytes = encode_preamble("{}");
        bytes.extend(encode_event(&lost));
        bytes.extend(encode_end(1));
        assert_eq!(decode(&bytes).map(|r| r.events), Ok(vec![lost]));
        // Before version 3 an empty socket record is damage, not a lost connection.
        set_version(&mut bytes, 2);
        assert!(matches!(decode(&bytes), Err(FormatError::Malformed { record: 0, .. })), "{:?}", decode(&bytes));
    }

    #[test]
    fn a_reconnection_is_a_connect_record_from_version_4() {
        let again = Event::Connect { socket: SocketId::Feedback, t_s: 2.5, outcome: ConnectOutcome::TimedOut };
        let mut bytes = encode_preamble("{}");
        bytes.extend(encode_event(&again));
        bytes.extend(encode_end(1));
        assert_eq!(decode(&bytes).map(|r| r.events), Ok(vec![again]));
        set_version(&mut bytes, 3);
        assert!(matches!(decode(&bytes), Err(FormatError::UnknownKind { record: 0, kind: 5, .. })), "{:?}", decode(&bytes));
    }

    #[test]
    fn decisions_are_feedback_used_and_reply_timed_out_records_from_version_5() {
        let used = [
            Event::FeedbackUsed { t_s: 3.0, seq: Some(41) },
            Event::FeedbackUsed { t_s: 3.5, seq: None },
            Event::ReplyTimedOut { socket: SocketId::Motion, t_s: 4.0 },
        ];
        let mut bytes = encode_preamble("{}");
        for e in &used {
            bytes.extend(encode_event(e));
        }
        bytes.extend(encode_end(3));
        assert_eq!(&encode_event(&used[0])[..5], &[6, 17, 0, 0, 0]);
        assert_eq!(&encode_event(&used[2])[..6], &[7, 9, 0, 0, 0, 1]);
        assert_eq!(decode(&bytes).map(|r| r.events), Ok(used.to_vec()));
        set_version(&mut bytes, 4);
        assert!(matches!(decode(&bytes), Err(FormatError::UnknownKind { record: 0, kind: 6, .. })), "{:?}", decode(&bytes));
        // A timed-out wait has no frame; an unknown use is damage; the feedback socket has no replies.
        let t = 1.0f64.to_le_bytes();
        let bad_bodies = [
            (KIND_FEEDBACK_USED, [&t[..], &[1], &7u64.to_le_bytes()].concat()),
            (KIND_FEEDBACK_USED, [&t[..], &[2], &0u64.to_le_bytes()].concat()),
            (KIND_REPLY_TIMED_OUT, [&[2], &t[..]].concat()),
            (KIND_REPLY_TIMED_OUT, [&[0], &t[..], &[0]].concat()),
        ];
        for (kind, body) in bad_bodies {
            let mut bad = encode_preamble("{}");
            bad.extend(encode_record(kind, &body));
            bad.extend(encode_end(1));
            assert!(matches!(decode(&bad), Err(FormatError::Malformed { record: 0, .. })), "{kind} {body:?}: {:?}", decode(&bad));
        }
    }

    #[test]
    fn trailing_bytes_and_wrong_counts_are_errors() {
        let mut more = sample();
        more.push(0);
        assert!(matches!(decode(&more), Err(FormatError::TrailingBytes { extra: 1, .. })));
        let mut wrong = sample();
        let end = encode_end(4);
        wrong.truncate(wrong.len() - end.len());
        wrong.extend(encode_end(5));
        assert!(matches!(decode(&wrong), Err(FormatError::CountMismatch { said: 5, found: 4 })));
    }

    /// A PNG container of `width` x `height` 8-bit RGB with `idat` as its one IDAT chunk's
    /// data (not inflated by the format's check, so any bytes do) and checksummed chunks.
    fn png_container(width: u32, height: u32, idat: &[u8]) -> Vec<u8> {
        let mut ihdr = Vec::new();
        ihdr.extend_from_slice(&width.to_be_bytes());
        ihdr.extend_from_slice(&height.to_be_bytes());
        ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
        png_with_chunks(&[(*b"IHDR", ihdr), (*b"IDAT", idat.to_vec()), (*b"IEND", Vec::new())])
    }

    fn png_with_chunks(chunks: &[([u8; 4], Vec<u8>)]) -> Vec<u8> {
        let mut png = PNG_SIGNATURE.to_vec();
        for (kind, data) in chunks {
            png.extend_from_slice(&(data.len() as u32).to_be_bytes());
            png.extend_from_slice(kind);
            png.extend_from_slice(data);
            png.extend_from_slice(&crc32(&[kind, data]).to_be_bytes());
        }
        png
    }

    /// A recording of one frame record with `body` (after the fixed fields of a 2 x 1 frame).
    fn one_frame(encoding: u8, pixels: &[u8]) -> Vec<u8> {
        let frame =
            RecordedFrame { camera: 0, t_s: 1.0, t_capture_s: 1.0, seq: 1, width: 2, height: 1, pixels: FramePixels::Raw(vec![0; 6]) };
        let record = encode_event(&Event::Frame(frame));
        let mut body = record[RECORD_HEAD..RECORD_HEAD + FRAME_FIXED].to_vec();
        body.push(encoding);
        body.extend_from_slice(pixels);
        let mut bytes = encode_preamble("{}");
        bytes.extend(encode_record(KIND_FRAME, &body));
        bytes.extend(encode_end(1));
        bytes
    }

    #[test]
    fn frames_are_raw_or_png_from_version_6_and_raw_without_an_encoding_byte_before() {
        let png = png_container(2, 1, b"not inflated here");
        let r = decode(&one_frame(1, &png)).expect("a PNG frame");
        assert!(matches!(&r.events[0], Event::Frame(f) if f.pixels == FramePixels::Png(png.clone())));
        assert_eq!(&encode_event(&r.events[0])[RECORD_HEAD + FRAME_FIXED..][..1], &[1], "the encoding byte");
        let r = decode(&one_frame(0, &[9; 6])).expect("a raw frame");
        assert!(matches!(&r.events[0], Event::Frame(f) if f.pixels == FramePixels::Raw(vec![9; 6])));
        // A version-5 writer wrote the raw pixels right after the height; they still read, and
        // the same bytes read as version 6 are damage, not other pixels.
        let v5 = with_version(5);
        let r = decode(&v5).expect("a version-5 recording");
        assert_eq!((r.version, &r.events[..]), (5, &sample_events()[..]));
        let mut as_v6 = v5.clone();
        set_version(&mut as_v6, 6);
        assert!(matches!(decode(&as_v6), Err(FormatError::Malformed { record: 1, .. })), "{:?}", decode(&as_v6));
        assert_eq!(decode(&with_version(6)).map(|r| r.events), Ok(sample_events().to_vec()));
        // An unknown encoding.
        assert!(matches!(decode(&one_frame(2, &[9; 6])), Err(FormatError::Malformed { record: 0, .. })));
    }

    #[test]
    fn a_png_frame_must_be_the_records_size_in_rgb8_with_pixel_chunks_only() {
        let ihdr = |w: u32, h: u32, tail: [u8; 5]| [&w.to_be_bytes()[..], &h.to_be_bytes(), &tail].concat();
        let rgb8 = [8, 2, 0, 0, 0];
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b"GIF89a".to_vec(), "no PNG signature"),
            (png_container(200, 100, b"x"), "the PNG is 200x100 pixels, the record says 2x1"),
            (png_with_chunks(&[(*b"IHDR", ihdr(2, 1, [16, 2, 0, 0, 0])), (*b"IDAT", vec![1]), (*b"IEND", vec![])]), "bit depth 16"),
            (png_with_chunks(&[(*b"IHDR", ihdr(2, 1, [8, 2, 0, 0, 1])), (*b"IDAT", vec![1]), (*b"IEND", vec![])]), "interlace 1"),
            (png_with_chunks(&[(*b"IDAT", vec![1]), (*b"IHDR", ihdr(2, 1, rgb8)), (*b"IEND", vec![])]), "does not start with its IHDR"),
            // An ICC profile (compressed, so a bomb) and text are never decoded: refused here.
            (png_with_chunks(&[(*b"IHDR", ihdr(2, 1, rgb8)), (*b"iCCP", vec![0; 40]), (*b"IDAT", vec![1]), (*b"IEND", vec![])]), "iCCP"),
            (png_with_chunks(&[(*b"IHDR", ihdr(2, 1, rgb8)), (*b"IDAT", vec![1]), (*b"zTXt", vec![0; 4]), (*b"IEND", vec![])]), "zTXt"),
            (png_with_chunks(&[(*b"IHDR", ihdr(2, 1, rgb8)), (*b"IEND", vec![])]), "no IDAT"),
            ([png_container(2, 1, b"x"), vec![0]].concat(), "after the IEND"),
            (png_container(2, 1, b"x")[..30].to_vec(), "cut short"),
        ];
        for (png, why) in cases {
            match decode(&one_frame(1, &png)) {
                Err(FormatError::Malformed { record: 0, problem, .. }) => assert!(problem.contains(why), "{why:?} not in {problem:?}"),
                other => panic!("{why}: {other:?}"),
            }
        }
    }

    #[test]
    fn lengths_past_their_bounds_are_refused_before_reading_what_they_announce() {
        // A header length of 4 GiB, in a file of 14 bytes: refused without asking for more.
        let mut head = encode_preamble("{}")[..PREAMBLE_HEAD].to_vec();
        head[10..14].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(decode_preamble(&head, false), Err(FormatError::TooLong { len, .. }) if len == u32::MAX as usize));
        // A record body of MAX_RECORD_BYTES + 1: refused from its 5 first bytes.
        let mut decoder = RecordDecoder::new(FORMAT_VERSION);
        let mut record = vec![KIND_SOCKET];
        record.extend_from_slice(&(MAX_RECORD_BYTES as u32 + 1).to_le_bytes());
        assert!(matches!(decoder.next(&record, 18, false), Err(FormatError::TooLong { offset: 18, .. })));
        // At the bound it asks for the whole record, no more.
        record[1..5].copy_from_slice(&(MAX_RECORD_BYTES as u32).to_le_bytes());
        assert_eq!(decoder.next(&record, 18, false), Ok(Step::Need(RECORD_HEAD + MAX_RECORD_BYTES + RECORD_TAIL)));
        // A frame of more pixels than rig reads, whatever it holds.
        let frame = RecordedFrame {
            camera: 0,
            t_s: 0.0,
            t_capture_s: 0.0,
            seq: 0,
            width: 4097,
            height: 4096,
            pixels: FramePixels::Png(png_container(4097, 4096, b"x")),
        };
        let mut bytes = encode_preamble("{}");
        bytes.extend(encode_event(&Event::Frame(frame)));
        bytes.extend(encode_end(1));
        assert!(matches!(decode(&bytes), Err(FormatError::Malformed { problem, .. }) if problem.contains("4097x4096")));
    }

    #[test]
    fn fed_a_byte_at_a_time_the_decoder_asks_for_what_it_needs_and_reads_the_same() {
        let bytes = sample();
        let mut at = 0;
        let preamble = loop {
            match decode_preamble(&bytes[..at], false).expect("a preamble") {
                Step::Need(n) => {
                    assert!(n > at && n <= bytes.len(), "asked for {n} with {at}");
                    at += 1;
                }
                Step::Done(p, n) => break (p, n),
            }
        };
        let (mut start, mut end, mut events) = (preamble.1, preamble.1, Vec::new());
        let mut decoder = RecordDecoder::new(preamble.0.version);
        loop {
            match decoder.next(&bytes[start..end], start, false).expect("a record") {
                Step::Need(n) => {
                    assert!(start + n > end, "asked for {n} it has");
                    end += 1;
                }
                Step::Done(Some(e), n) => {
                    events.push(e);
                    start += n;
                }
                Step::Done(None, n) => {
                    assert_eq!(start + n, bytes.len());
                    break;
                }
            }
        }
        assert_eq!(events, sample_events().to_vec());
    }
}
