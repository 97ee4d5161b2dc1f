//! Dobot Magician serial protocol, sans-io: framing, typed commands and replies.
//!
//! Sources: *Dobot Magician Communication Protocol* V1.1.5 (Shenzhen Yuejiang, 2017), sections
//! 2 (packet format) and 3 (command list), cross-checked against the command ids of the
//! official `ProtocolID.h` of the Dobot DLL and the open-source pydobot driver. No bytes here
//! were copied from those sources; the literals in the tests are computed from the rules below.
//!
//! Packet (both directions; all multi-byte values little-endian):
//!
//! | offset | size | field | meaning |
//! |---|---|---|---|
//! | 0 | 2 | header | `0xAA 0xAA` |
//! | 2 | 1 | len | payload length = 2 (id + ctrl) + params length, so 2..=255 |
//! | 3 | 1 | id | command id (table below) |
//! | 4 | 1 | ctrl | bit 0 `rw` (1 = write/set, 0 = read/get), bit 1 `isQueued` |
//! | 5 | len-2 | params | command parameters (request) or results (reply) |
//! | 3+len | 1 | checksum | two's complement of the byte sum of the payload (id, ctrl, params): `(0 - sum) mod 256` |
//!
//! The controller answers every request with a packet of the same id and ctrl. Commands used
//! by rig:
//!
//! | id | command | ctrl | request params | reply params |
//! |---|---|---|---|---|
//! | 2 | GetDeviceVersion | 0x00 | - | firmware major, minor, revision: 3 x u8 (see below) |
//! | 10 | GetPose | 0x00 | - | x, y, z, r (mm, mm, mm, deg), joint 1..4 (deg): 8 x f32 |
//! | 20 | GetAlarmsState | 0x00 | - | alarm bit field, 16 bytes (bit n = alarm n) |
//! | 21 | ClearAllAlarmsState | 0x01 | - | - |
//! | 31 | SetHOMECmd | 0x03 | reserved u32 | queued command index u64 |
//! | 83 | SetPTPCommonParams | 0x01 | velocity ratio, acceleration ratio (percent): 2 x f32 | - |
//! | 84 | SetPTPCmd | 0x03 | mode u8, x, y, z, r: 4 x f32 | queued command index u64 |
//! | 240 | SetQueuedCmdStartExec | 0x01 | - | - |
//! | 241 | SetQueuedCmdStopExec | 0x01 | - | - |
//! | 242 | SetQueuedCmdForceStopExec | 0x01 | - | - |
//! | 245 | SetQueuedCmdClear | 0x01 | - | - |
//! | 246 | GetQueuedCmdCurrentIndex | 0x00 | - | index of the queued command executing now, u64 |
//!
//! GetDeviceVersion: the protocol gives three bytes. Later versions of Dobot's DLL read a
//! fourth (a hardware version; UNCERTAIN which firmware sends it), so a longer reply is
//! accepted and only its first three bytes are read. rig does not send DeviceSN (id 0, a
//! string): the arm part of the manifest names the serial port instead.
//!
//! Note: id 31 is SetHOMECmd; the queue-control commands are the 240 block (a note handed to
//! this module said 31 was SetQueuedCmdStartExec, which the sources above contradict).
//!
//! [`decode`] works on a byte buffer and never panics: it returns [`Decoded::Incomplete`] for a
//! partial packet and [`Decoded::Junk`] (how many bytes to drop and why) for noise, so a
//! transport can resynchronise on the next header after line noise or a reset.

/// The two header bytes that open every packet.
pub const HEADER: [u8; 2] = [0xAA, 0xAA];
/// Smallest valid `len` (id + ctrl, no params).
pub const MIN_PAYLOAD_LEN: usize = 2;
/// Bytes a packet takes besides its params: header 2, len 1, id 1, ctrl 1, checksum 1.
pub const OVERHEAD: usize = 6;

/// Command ids (protocol section 3).
pub mod id {
    pub const GET_DEVICE_VERSION: u8 = 2;
    pub const GET_POSE: u8 = 10;
    pub const GET_ALARMS_STATE: u8 = 20;
    pub const CLEAR_ALL_ALARMS_STATE: u8 = 21;
    pub const SET_HOME_CMD: u8 = 31;
    pub const PTP_COMMON_PARAMS: u8 = 83;
    pub const SET_PTP_CMD: u8 = 84;
    pub const QUEUED_START_EXEC: u8 = 240;
    pub const QUEUED_STOP_EXEC: u8 = 241;
    pub const QUEUED_FORCE_STOP_EXEC: u8 = 242;
    pub const QUEUED_CLEAR: u8 = 245;
    pub const GET_QUEUED_CURRENT_INDEX: u8 = 246;
}

/// The ctrl byte: bit 0 read/write, bit 1 queued; bits 2..7 are reserved and kept as sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ctrl(pub u8);

impl Ctrl {
    pub const READ: Ctrl = Ctrl(0x00);
    pub const WRITE: Ctrl = Ctrl(0x01);
    pub const WRITE_QUEUED: Ctrl = Ctrl(0x03);
    /// A set (write) command rather than a get.
    pub fn is_write(self) -> bool {
        self.0 & 0x01 != 0
    }
    /// Put in the controller's command queue (the reply carries the queue index).
    pub fn is_queued(self) -> bool {
        self.0 & 0x02 != 0
    }
}

/// One framed packet: id, ctrl and raw params.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packet {
    pub id: u8,
    pub ctrl: Ctrl,
    pub params: Vec<u8>,
}

/// Why bytes could not be framed or a packet not be understood.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProtoError {
    #[error("expected header AA AA, got {got:02X?}")]
    BadHeader { got: Vec<u8> },
    #[error("payload length {len} is below the minimum of 2")]
    BadLength { len: u8 },
    #[error("checksum {got:#04x} does not match {expected:#04x} (packet id {id})")]
    BadChecksum { id: u8, expected: u8, got: u8 },
    #[error("params of {params_len} bytes do not fit in one packet (at most 253)")]
    TooLong { params_len: usize },
    #[error("command id {id}: expected {expected} param bytes, got {got}")]
    ParamLength { id: u8, expected: usize, got: usize },
    #[error("reply id {got} does not answer command id {expected}")]
    WrongReply { expected: u8, got: u8 },
    #[error("unknown command id {id} (ctrl {ctrl:#04x})")]
    UnknownCommand { id: u8, ctrl: u8 },
    #[error("unknown PTP mode {mode}")]
    UnknownPtpMode { mode: u8 },
}

/// The sum-of-payload checksum: two's complement of the byte sum of id, ctrl and params.
pub fn checksum(id: u8, ctrl: Ctrl, params: &[u8]) -> u8 {
    let sum = params.iter().fold(id.wrapping_add(ctrl.0), |acc, b| acc.wrapping_add(*b));
    0u8.wrapping_sub(sum)
}

impl Packet {
    pub fn new(id: u8, ctrl: Ctrl, params: Vec<u8>) -> Self {
        Self { id, ctrl, params }
    }

    /// The bytes on the wire. Params longer than 253 bytes cannot be framed.
    pub fn encode(&self) -> Result<Vec<u8>, ProtoError> {
        let len = u8::try_from(self.params.len() + MIN_PAYLOAD_LEN).map_err(|_| ProtoError::TooLong { params_len: self.params.len() })?;
        let mut out = Vec::with_capacity(self.params.len() + OVERHEAD);
        out.extend_from_slice(&HEADER);
        out.push(len);
        out.push(self.id);
        out.push(self.ctrl.0);
        out.extend_from_slice(&self.params);
        out.push(checksum(self.id, self.ctrl, &self.params));
        Ok(out)
    }
}

/// What [`decode`] found at the start of a buffer.
#[derive(Debug, Clone, PartialEq)]
pub enum Decoded {
    /// Not enough bytes yet for a whole packet; keep them and read more.
    Incomplete,
    /// A packet, taking the first `used` bytes.
    Packet { packet: Packet, used: usize },
    /// The first `used` bytes are not a valid packet start; drop them and decode again.
    Junk { used: usize, error: ProtoError },
}

/// Frames the packet at the start of `buf`.
///
/// Junk before a header is reported up to the next `0xAA` candidate; a packet with a bad
/// checksum or length drops only its first header byte, so a real packet that started inside
/// the damaged one is still found.
pub fn decode(buf: &[u8]) -> Decoded {
    if buf.is_empty() {
        return Decoded::Incomplete;
    }
    if buf[0] != HEADER[0] || (buf.len() >= 2 && buf[1] != HEADER[1]) {
        // Skip to the next byte that could open a header (at least one byte).
        let skip = buf.iter().skip(1).position(|b| *b == HEADER[0]).map_or(buf.len(), |p| p + 1);
        return Decoded::Junk { used: skip, error: ProtoError::BadHeader { got: buf[..buf.len().min(2)].to_vec() } };
    }
    if buf.len() < 3 {
        return Decoded::Incomplete;
    }
    let len = buf[2];
    if usize::from(len) < MIN_PAYLOAD_LEN {
        return Decoded::Junk { used: 1, error: ProtoError::BadLength { len } };
    }
    let total = usize::from(len) + 4;
    if buf.len() < total {
        return Decoded::Incomplete;
    }
    let id = buf[3];
    let ctrl = Ctrl(buf[4]);
    let params = &buf[5..total - 1];
    let got = buf[total - 1];
    let expected = checksum(id, ctrl, params);
    if got != expected {
        return Decoded::Junk { used: 1, error: ProtoError::BadChecksum { id, expected, got } };
    }
    Decoded::Packet { packet: Packet { id, ctrl, params: params.to_vec() }, used: total }
}

/// Accumulates received bytes and hands out packets: the framer a transport feeds.
#[derive(Debug, Default)]
pub struct PacketFramer {
    buf: Vec<u8>,
    /// Bytes dropped as junk so far (line noise, partial packets after a reset).
    pub dropped_bytes: u64,
}

impl PacketFramer {
    pub fn new() -> Self {
        Self::default()
    }
    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }
    /// The next whole packet, skipping junk; `None` when more bytes are needed.
    pub fn next_packet(&mut self) -> Option<Packet> {
        loop {
            match decode(&self.buf) {
                Decoded::Incomplete => return None,
                Decoded::Packet { packet, used } => {
                    self.buf.drain(..used);
                    return Some(packet);
                }
                Decoded::Junk { used, .. } => {
                    let used = used.clamp(1, self.buf.len());
                    self.buf.drain(..used);
                    self.dropped_bytes += used as u64;
                }
            }
        }
    }
    /// Bytes waiting for the rest of a packet.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }
}

/// PTP motion modes (SetPTPCmd `ptpMode`, protocol section 3.9).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PtpMode {
    /// Lift, travel, lower (door-frame path).
    JumpXyz = 0,
    /// Joint-interpolated to a Cartesian target.
    MovjXyz = 1,
    /// Straight line to a Cartesian target.
    MovlXyz = 2,
}

impl PtpMode {
    pub fn from_u8(mode: u8) -> Result<Self, ProtoError> {
        match mode {
            0 => Ok(PtpMode::JumpXyz),
            1 => Ok(PtpMode::MovjXyz),
            2 => Ok(PtpMode::MovlXyz),
            mode => Err(ProtoError::UnknownPtpMode { mode }),
        }
    }
}

/// The commands rig sends to a Magician.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    /// The controller's firmware version.
    GetDeviceVersion,
    GetPose,
    GetAlarmsState,
    ClearAllAlarmsState,
    /// Queued homing run.
    Home,
    /// Speed and acceleration ratios of PTP moves, percent.
    SetPtpCommonParams {
        velocity_ratio_pct: f32,
        acceleration_ratio_pct: f32,
    },
    /// Queued point-to-point move to a Cartesian target (end-effector r in degrees).
    SetPtp {
        mode: PtpMode,
        x_mm: f32,
        y_mm: f32,
        z_mm: f32,
        r_deg: f32,
    },
    QueuedStartExec,
    QueuedStopExec,
    QueuedForceStopExec,
    QueuedClear,
    GetQueuedCurrentIndex,
}

fn f32s(params: &[u8], id: u8, n: usize) -> Result<Vec<f32>, ProtoError> {
    if params.len() != 4 * n {
        return Err(ProtoError::ParamLength { id, expected: 4 * n, got: params.len() });
    }
    Ok(params.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
}

fn u64_param(params: &[u8], id: u8) -> Result<u64, ProtoError> {
    let bytes: [u8; 8] = params.try_into().map_err(|_| ProtoError::ParamLength { id, expected: 8, got: params.len() })?;
    Ok(u64::from_le_bytes(bytes))
}

impl Command {
    /// The request packet.
    pub fn packet(&self) -> Packet {
        let put = |values: &[f32]| values.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>();
        match *self {
            Command::GetDeviceVersion => Packet::new(id::GET_DEVICE_VERSION, Ctrl::READ, vec![]),
            Command::GetPose => Packet::new(id::GET_POSE, Ctrl::READ, vec![]),
            Command::GetAlarmsState => Packet::new(id::GET_ALARMS_STATE, Ctrl::READ, vec![]),
            Command::ClearAllAlarmsState => Packet::new(id::CLEAR_ALL_ALARMS_STATE, Ctrl::WRITE, vec![]),
            Command::Home => Packet::new(id::SET_HOME_CMD, Ctrl::WRITE_QUEUED, vec![0; 4]),
            Command::SetPtpCommonParams { velocity_ratio_pct, acceleration_ratio_pct } => {
                Packet::new(id::PTP_COMMON_PARAMS, Ctrl::WRITE, put(&[velocity_ratio_pct, acceleration_ratio_pct]))
            }
            Command::SetPtp { mode, x_mm, y_mm, z_mm, r_deg } => {
                let mut params = vec![mode as u8];
                params.extend(put(&[x_mm, y_mm, z_mm, r_deg]));
                Packet::new(id::SET_PTP_CMD, Ctrl::WRITE_QUEUED, params)
            }
            Command::QueuedStartExec => Packet::new(id::QUEUED_START_EXEC, Ctrl::WRITE, vec![]),
            Command::QueuedStopExec => Packet::new(id::QUEUED_STOP_EXEC, Ctrl::WRITE, vec![]),
            Command::QueuedForceStopExec => Packet::new(id::QUEUED_FORCE_STOP_EXEC, Ctrl::WRITE, vec![]),
            Command::QueuedClear => Packet::new(id::QUEUED_CLEAR, Ctrl::WRITE, vec![]),
            Command::GetQueuedCurrentIndex => Packet::new(id::GET_QUEUED_CURRENT_INDEX, Ctrl::READ, vec![]),
        }
    }

    /// The request bytes (every rig command fits in one packet).
    pub fn encode(&self) -> Vec<u8> {
        // The largest request (SetPtp) has 17 param bytes, far below the 253-byte limit.
        self.packet().encode().unwrap_or_default()
    }

    /// Parses a request packet (the device side: the fake Magician in tests, the fuzzer).
    pub fn from_packet(p: &Packet) -> Result<Command, ProtoError> {
        let none = |c: Command| {
            if p.params.is_empty() { Ok(c) } else { Err(ProtoError::ParamLength { id: p.id, expected: 0, got: p.params.len() }) }
        };
        match (p.id, p.ctrl.is_write()) {
            (id::GET_DEVICE_VERSION, false) => none(Command::GetDeviceVersion),
            (id::GET_POSE, false) => none(Command::GetPose),
            (id::GET_ALARMS_STATE, false) => none(Command::GetAlarmsState),
            // The protocol shares id 20 between get and clear in some firmware; 21 is the clear.
            (id::CLEAR_ALL_ALARMS_STATE, true) | (id::GET_ALARMS_STATE, true) => none(Command::ClearAllAlarmsState),
            (id::SET_HOME_CMD, true) => {
                if p.params.len() == 4 || p.params.is_empty() {
                    Ok(Command::Home)
                } else {
                    Err(ProtoError::ParamLength { id: p.id, expected: 4, got: p.params.len() })
                }
            }
            (id::PTP_COMMON_PARAMS, true) => {
                let v = f32s(&p.params, p.id, 2)?;
                Ok(Command::SetPtpCommonParams { velocity_ratio_pct: v[0], acceleration_ratio_pct: v[1] })
            }
            (id::SET_PTP_CMD, true) => {
                let Some((&mode, rest)) = p.params.split_first() else {
                    return Err(ProtoError::ParamLength { id: p.id, expected: 17, got: 0 });
                };
                let mode = PtpMode::from_u8(mode)?;
                let v = f32s(rest, p.id, 4).map_err(|_| ProtoError::ParamLength { id: p.id, expected: 17, got: p.params.len() })?;
                Ok(Command::SetPtp { mode, x_mm: v[0], y_mm: v[1], z_mm: v[2], r_deg: v[3] })
            }
            (id::QUEUED_START_EXEC, true) => none(Command::QueuedStartExec),
            (id::QUEUED_STOP_EXEC, true) => none(Command::QueuedStopExec),
            (id::QUEUED_FORCE_STOP_EXEC, true) => none(Command::QueuedForceStopExec),
            (id::QUEUED_CLEAR, true) => none(Command::QueuedClear),
            (id::GET_QUEUED_CURRENT_INDEX, false) => none(Command::GetQueuedCurrentIndex),
            _ => Err(ProtoError::UnknownCommand { id: p.id, ctrl: p.ctrl.0 }),
        }
    }

    /// Checks that `reply` answers this command and decodes its params.
    pub fn parse_reply(&self, reply: &Packet) -> Result<Reply, ProtoError> {
        let request = self.packet();
        if reply.id != request.id {
            return Err(ProtoError::WrongReply { expected: request.id, got: reply.id });
        }
        match self {
            Command::GetDeviceVersion => match reply.params[..] {
                [major, minor, revision, ..] => Ok(Reply::DeviceVersion(DeviceVersion { major, minor, revision })),
                _ => Err(ProtoError::ParamLength { id: reply.id, expected: 3, got: reply.params.len() }),
            },
            Command::GetPose => {
                let v = f32s(&reply.params, reply.id, 8)?;
                Ok(Reply::Pose(MagicianPose { x_mm: v[0], y_mm: v[1], z_mm: v[2], r_deg: v[3], joints_deg: [v[4], v[5], v[6], v[7]] }))
            }
            Command::GetAlarmsState => Ok(Reply::Alarms(alarm_bits(&reply.params))),
            Command::Home | Command::SetPtp { .. } => Ok(Reply::QueuedIndex(u64_param(&reply.params, reply.id)?)),
            Command::GetQueuedCurrentIndex => Ok(Reply::CurrentIndex(u64_param(&reply.params, reply.id)?)),
            _ => Ok(Reply::Ack),
        }
    }
}

/// Indices of the set bits of an alarm bit field (byte 0 bit 0 is alarm 0x00).
pub fn alarm_bits(field: &[u8]) -> Vec<u16> {
    let mut out = Vec::new();
    for (byte_index, byte) in field.iter().enumerate() {
        for bit in 0..8u16 {
            if byte & (1 << bit) != 0 {
                out.push(byte_index as u16 * 8 + bit);
            }
        }
    }
    out
}

/// The alarm bit field with these alarms set (`bytes` long; alarms beyond it are left out).
pub fn alarm_field(alarms: &[u16], bytes: usize) -> Vec<u8> {
    let mut field = vec![0u8; bytes];
    for &a in alarms {
        if let Some(byte) = field.get_mut(usize::from(a / 8)) {
            *byte |= 1 << (a % 8);
        }
    }
    field
}

/// GetPose result: Cartesian pose of the end effector and the four joint angles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MagicianPose {
    pub x_mm: f32,
    pub y_mm: f32,
    pub z_mm: f32,
    /// End-effector rotation (base + servo), degrees.
    pub r_deg: f32,
    pub joints_deg: [f32; 4],
}

/// GetDeviceVersion result: the controller's firmware version.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceVersion {
    pub major: u8,
    pub minor: u8,
    pub revision: u8,
}

impl std::fmt::Display for DeviceVersion {
    /// `3.7.0`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.revision)
    }
}

/// A decoded reply.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// A set command was accepted; no result.
    Ack,
    DeviceVersion(DeviceVersion),
    Pose(MagicianPose),
    /// Active alarm codes.
    Alarms(Vec<u16>),
    /// The queue index given to a queued command.
    QueuedIndex(u64),
    /// The queue index executing now.
    CurrentIndex(u64),
}

impl Reply {
    /// The reply packet for `command` (the device side).
    pub fn packet_for(&self, command: &Command) -> Packet {
        let request = command.packet();
        let params = match self {
            Reply::Ack => vec![],
            Reply::DeviceVersion(v) => vec![v.major, v.minor, v.revision],
            Reply::Pose(p) => [p.x_mm, p.y_mm, p.z_mm, p.r_deg, p.joints_deg[0], p.joints_deg[1], p.joints_deg[2], p.joints_deg[3]]
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect(),
            Reply::Alarms(a) => alarm_field(a, 16),
            Reply::QueuedIndex(i) | Reply::CurrentIndex(i) => i.to_le_bytes().to_vec(),
        };
        Packet::new(request.id, request.ctrl, params)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn literal_requests() {
        // GetPose: AA AA 02 0A 00, checksum = -(0x0A + 0x00) = 0xF6.
        assert_eq!(Command::GetPose.encode(), [0xAA, 0xAA, 0x02, 0x0A, 0x00, 0xF6]);
        // SetQueuedCmdStartExec: id 240 (0xF0), ctrl 1 -> -(0xF1) = 0x0F.
        assert_eq!(Command::QueuedStartExec.encode(), [0xAA, 0xAA, 0x02, 0xF0, 0x01, 0x0F]);
        // GetQueuedCmdCurrentIndex: id 246 (0xF6), ctrl 0 -> 0x0A.
        assert_eq!(Command::GetQueuedCurrentIndex.encode(), [0xAA, 0xAA, 0x02, 0xF6, 0x00, 0x0A]);
        // GetDeviceVersion: id 2, ctrl 0 -> -(0x02) = 0xFE.
        assert_eq!(Command::GetDeviceVersion.encode(), [0xAA, 0xAA, 0x02, 0x02, 0x00, 0xFE]);
        // ClearAllAlarmsState: id 21 (0x15), ctrl 1 -> -(0x16) = 0xEA.
        assert_eq!(Command::ClearAllAlarmsState.encode(), [0xAA, 0xAA, 0x02, 0x15, 0x01, 0xEA]);
        // SetPTPCmd MOVL to (200, 0, 50, 0): 200.0f32 = 00 00 48 43, 50.0f32 = 00 00 48 42.
        let ptp = Command::SetPtp { mode: PtpMode::MovlXyz, x_mm: 200.0, y_mm: 0.0, z_mm: 50.0, r_deg: 0.0 };
        let expected_sum: u32 = 0x54 + 0x03 + 0x02 + 0x48 + 0x43 + 0x48 + 0x42;
        let check = (0x100 - (expected_sum % 0x100)) as u8;
        assert_eq!(
            ptp.encode(),
            [
                0xAA, 0xAA, 0x13, 0x54, 0x03, 0x02, 0x00, 0x00, 0x48, 0x43, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x48, 0x42, 0x00, 0x00,
                0x00, 0x00, check
            ]
        );
    }

    #[test]
    fn literal_replies() {
        // A queued-index reply to SetPTPCmd: index 7 as u64 LE.
        let bytes = [0xAA, 0xAA, 0x0A, 0x54, 0x03, 7, 0, 0, 0, 0, 0, 0, 0, 0u8.wrapping_sub(0x54 + 0x03 + 7)];
        let Decoded::Packet { packet, used } = decode(&bytes) else { panic!("not framed: {:?}", decode(&bytes)) };
        assert_eq!(used, bytes.len());
        let ptp = Command::SetPtp { mode: PtpMode::MovjXyz, x_mm: 0.0, y_mm: 0.0, z_mm: 0.0, r_deg: 0.0 };
        assert_eq!(ptp.parse_reply(&packet), Ok(Reply::QueuedIndex(7)));
        // The same reply answers GetPose with an error, not a panic.
        assert_eq!(Command::GetPose.parse_reply(&packet), Err(ProtoError::WrongReply { expected: 10, got: 84 }));
        // Alarms: byte 0 = 0x01 (alarm 0x00, reset), byte 2 = 0x10 (alarm 0x14).
        let mut field = vec![0u8; 16];
        field[0] = 0x01;
        field[2] = 0x10;
        let packet = Packet::new(20, Ctrl::READ, field);
        assert_eq!(Command::GetAlarmsState.parse_reply(&packet), Ok(Reply::Alarms(vec![0x00, 0x14])));
    }

    #[test]
    fn device_version_replies() {
        // Firmware 3.7.0: AA AA 05 02 00 03 07 00, checksum -(0x02 + 0x03 + 0x07) = 0xF4.
        let bytes = [0xAA, 0xAA, 0x05, 0x02, 0x00, 0x03, 0x07, 0x00, 0xF4];
        let Decoded::Packet { packet, used } = decode(&bytes) else { panic!("not framed: {:?}", decode(&bytes)) };
        assert_eq!(used, bytes.len());
        let version = DeviceVersion { major: 3, minor: 7, revision: 0 };
        assert_eq!(Command::GetDeviceVersion.parse_reply(&packet), Ok(Reply::DeviceVersion(version)));
        assert_eq!(version.to_string(), "3.7.0");
        assert_eq!(Reply::DeviceVersion(version).packet_for(&Command::GetDeviceVersion).encode(), Ok(bytes.to_vec()));
        // A fourth byte (a hardware version, in later DLLs) is ignored.
        let longer = Packet::new(2, Ctrl::READ, vec![3, 9, 2, 1]);
        assert_eq!(
            Command::GetDeviceVersion.parse_reply(&longer),
            Ok(Reply::DeviceVersion(DeviceVersion { major: 3, minor: 9, revision: 2 }))
        );
        // Too short is an error, not a panic; another command's reply is refused.
        let short = Packet::new(2, Ctrl::READ, vec![3, 7]);
        assert_eq!(Command::GetDeviceVersion.parse_reply(&short), Err(ProtoError::ParamLength { id: 2, expected: 3, got: 2 }));
        assert_eq!(Command::GetDeviceVersion.parse_reply(&Command::GetPose.packet()), Err(ProtoError::WrongReply { expected: 2, got: 10 }));
    }

    #[test]
    fn framing_partial_junk_and_checksum() {
        let bytes = Command::GetPose.encode();
        for cut in 0..bytes.len() {
            assert_eq!(decode(&bytes[..cut]), Decoded::Incomplete, "cut {cut}");
        }
        assert!(matches!(decode(&[0x00, 0x13, 0xAA]), Decoded::Junk { used: 2, .. }));
        assert!(matches!(decode(&[0xAA, 0x01]), Decoded::Junk { used: 2, .. }));
        assert!(matches!(decode(&[0xAA, 0xAA, 0x01]), Decoded::Junk { used: 1, error: ProtoError::BadLength { len: 1 } }));
        let mut bad = bytes.clone();
        *bad.last_mut().unwrap() ^= 0xFF;
        assert!(matches!(decode(&bad), Decoded::Junk { used: 1, error: ProtoError::BadChecksum { id: 10, .. } }));
        // The framer skips noise and a damaged packet and finds the good one after them.
        let mut framer = PacketFramer::new();
        framer.push(&[0x55, 0x00]);
        framer.push(&bad);
        framer.push(&bytes[..3]);
        assert_eq!(framer.next_packet(), None);
        framer.push(&bytes[3..]);
        assert_eq!(framer.next_packet(), Some(Command::GetPose.packet()));
        assert_eq!(framer.pending(), 0);
        assert_eq!(framer.dropped_bytes, 2 + bad.len() as u64);
    }

    #[test]
    fn oversized_params_are_refused() {
        assert_eq!(Packet::new(1, Ctrl::WRITE, vec![0; 254]).encode(), Err(ProtoError::TooLong { params_len: 254 }));
        assert_eq!(Packet::new(1, Ctrl::WRITE, vec![0; 253]).encode().map(|b| b.len()), Ok(253 + OVERHEAD));
    }

    fn any_command() -> impl Strategy<Value = Command> {
        let f = -1000.0f32..1000.0;
        prop_oneof![
            Just(Command::GetDeviceVersion),
            Just(Command::GetPose),
            Just(Command::GetAlarmsState),
            Just(Command::ClearAllAlarmsState),
            Just(Command::Home),
            Just(Command::QueuedStartExec),
            Just(Command::QueuedStopExec),
            Just(Command::QueuedForceStopExec),
            Just(Command::QueuedClear),
            Just(Command::GetQueuedCurrentIndex),
            (0.0f32..100.0, 0.0f32..100.0)
                .prop_map(|(v, a)| Command::SetPtpCommonParams { velocity_ratio_pct: v, acceleration_ratio_pct: a }),
            (0u8..3, f.clone(), f.clone(), f.clone(), f).prop_map(|(m, x, y, z, r)| Command::SetPtp {
                mode: PtpMode::from_u8(m).unwrap(),
                x_mm: x,
                y_mm: y,
                z_mm: z,
                r_deg: r
            }),
        ]
    }

    proptest! {
        #[test]
        fn commands_round_trip(cmd in any_command()) {
            let bytes = cmd.encode();
            let Decoded::Packet { packet, used } = decode(&bytes) else { panic!("not framed") };
            prop_assert_eq!(used, bytes.len());
            prop_assert_eq!(Command::from_packet(&packet), Ok(cmd));
        }

        #[test]
        fn replies_round_trip(x in -500.0f32..500.0, idx in any::<u64>(), alarms in proptest::collection::btree_set(0u16..128, 0..6)) {
            let pose = MagicianPose { x_mm: x, y_mm: -x, z_mm: 1.5, r_deg: 30.0, joints_deg: [1.0, 2.0, 3.0, 4.0] };
            let alarms: Vec<u16> = alarms.into_iter().collect();
            for (cmd, reply) in [
                (Command::GetPose, Reply::Pose(pose)),
                (Command::GetQueuedCurrentIndex, Reply::CurrentIndex(idx)),
                (Command::Home, Reply::QueuedIndex(idx)),
                (Command::GetAlarmsState, Reply::Alarms(alarms.clone())),
                (Command::QueuedClear, Reply::Ack),
                (Command::GetDeviceVersion, Reply::DeviceVersion(DeviceVersion { major: idx as u8, minor: (idx >> 8) as u8, revision: (idx >> 16) as u8 })),
            ] {
                let bytes = reply.packet_for(&cmd).encode().unwrap();
                let Decoded::Packet { packet, .. } = decode(&bytes) else { panic!("not framed") };
                prop_assert_eq!(cmd.parse_reply(&packet), Ok(reply));
            }
        }

        /// Fallback for the cargo-fuzz target `magician_decoder`: no input panics.
        #[test]
        fn decoder_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
            let mut framer = PacketFramer::new();
            framer.push(&bytes);
            let mut n = 0;
            while let Some(p) = framer.next_packet() {
                let _ = Command::from_packet(&p);
                let _ = Command::GetPose.parse_reply(&p);
                let _ = Command::GetDeviceVersion.parse_reply(&p);
                n += 1;
                prop_assert!(n <= bytes.len());
            }
            prop_assert!(framer.pending() <= bytes.len());
        }
    }
}
