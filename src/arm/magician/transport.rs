//! The Magician's serial link: request/reply over any byte stream, around the sans-io codec.
//!
//! [`MagicianLink`] writes one [`Command`]'s packet, then feeds what it reads into a
//! [`PacketFramer`] until the reply with the same id arrives. Replies with another id are
//! stale answers to an earlier request that timed out; they are dropped, not matched. The
//! link is blocking (the `serialport` crate is); the [`Arm`](crate::arm::Arm) implementation
//! runs it on tokio's blocking pool.
//!
//! The Magician's USB port is a CP210x USB-UART bridge: 115200 baud, 8N1, no flow control
//! (protocol section 1).

use std::io::{ErrorKind, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::proto::{Command, PacketFramer, ProtoError, Reply};

/// Baud rate of the Magician's serial port.
pub const MAGICIAN_BAUD: u32 = 115_200;

/// A byte stream a link can talk over: a serial port, a pseudo-terminal, a test pipe.
pub trait SerialIo: Read + Write + Send {}
impl<T: Read + Write + Send> SerialIo for T {}

/// Errors of the serial link.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error("cannot open serial port {path}: {source}")]
    Open {
        path: PathBuf,
        #[source]
        source: serialport::Error,
    },
    #[error("serial i/o error: {0}")]
    Io(#[from] std::io::Error),
    #[error("no reply to command id {command_id} within {after:?}")]
    Timeout { command_id: u8, after: Duration },
    #[error("serial port closed")]
    Closed,
    #[error(transparent)]
    Proto(#[from] ProtoError),
}

/// A request/reply link to one Magician.
pub struct MagicianLink {
    io: Box<dyn SerialIo>,
    framer: PacketFramer,
    reply_timeout: Duration,
    /// Replies dropped because they answered another command.
    pub stale_replies: u64,
}

impl MagicianLink {
    /// Opens the serial device at `path` (e.g. `/dev/ttyUSB0`) at `baud`.
    pub fn open(path: &Path, baud: u32, reply_timeout: Duration) -> Result<Self, TransportError> {
        let port = serialport::new(path.to_string_lossy(), baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            // Short read timeout: the link polls its own reply deadline between reads.
            .timeout(Duration::from_millis(20))
            .open()
            .map_err(|source| TransportError::Open { path: path.to_path_buf(), source })?;
        // Bytes left in the input buffer from before are not replies to us.
        let _ = port.clear(serialport::ClearBuffer::All);
        Ok(Self::attach(Box::new(port), reply_timeout))
    }

    /// A link over any stream. Reads that time out (`TimedOut`, `WouldBlock`) are retried
    /// until the reply deadline.
    pub fn attach(io: Box<dyn SerialIo>, reply_timeout: Duration) -> Self {
        Self { io, framer: PacketFramer::new(), reply_timeout, stale_replies: 0 }
    }

    /// Sends `command` and waits for its reply.
    pub fn request(&mut self, command: &Command) -> Result<Reply, TransportError> {
        let request = command.packet();
        self.io.write_all(&command.encode())?;
        self.io.flush()?;
        let deadline = Instant::now() + self.reply_timeout;
        let mut buf = [0u8; 256];
        loop {
            while let Some(packet) = self.framer.next_packet() {
                if packet.id == request.id {
                    return Ok(command.parse_reply(&packet)?);
                }
                self.stale_replies += 1;
                tracing::debug!(got = packet.id, want = request.id, "magician: dropped a stale reply");
            }
            if Instant::now() >= deadline {
                return Err(TransportError::Timeout { command_id: request.id, after: self.reply_timeout });
            }
            match self.io.read(&mut buf) {
                Ok(0) => return Err(TransportError::Closed),
                Ok(n) => self.framer.push(&buf[..n]),
                Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted) => {
                    // Non-blocking or timed streams: avoid a hot loop while the device thinks.
                    if e.kind() == ErrorKind::WouldBlock {
                        std::thread::sleep(Duration::from_millis(1));
                    }
                }
                Err(e) => return Err(TransportError::Io(e)),
            }
        }
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;
    use crate::arm::magician::proto::{MagicianPose, PtpMode};
    use crate::io::serial::PtyPair;
    use crate::sim::magician::SimMagician;

    #[test]
    fn requests_over_a_pseudo_terminal() {
        let pty = PtyPair::open().unwrap();
        let device = SimMagician::new(MagicianPose { x_mm: 200.0, y_mm: 0.0, z_mm: 50.0, r_deg: 0.0, joints_deg: [0.0; 4] });
        let server = device.serve_in_thread(pty.master_file().unwrap());
        let mut link = MagicianLink::open(&pty.slave_path, MAGICIAN_BAUD, Duration::from_secs(2)).unwrap();
        let Reply::Pose(p) = link.request(&Command::GetPose).unwrap() else { panic!("not a pose") };
        assert_eq!((p.x_mm, p.z_mm), (200.0, 50.0));
        link.request(&Command::QueuedStartExec).unwrap();
        let r = link.request(&Command::SetPtp { mode: PtpMode::MovlXyz, x_mm: 210.0, y_mm: 5.0, z_mm: 40.0, r_deg: 10.0 });
        assert_eq!(r.unwrap(), Reply::QueuedIndex(1));
        // The simulated device runs one queued command per index poll.
        let Reply::CurrentIndex(i) = link.request(&Command::GetQueuedCurrentIndex).unwrap() else { panic!() };
        assert_eq!(i, 1);
        let Reply::Pose(p) = link.request(&Command::GetPose).unwrap() else { panic!("not a pose") };
        assert_eq!((p.x_mm, p.y_mm, p.z_mm, p.r_deg), (210.0, 5.0, 40.0, 10.0));
        drop(link);
        server.stop();
    }

    /// A stream that answers with a stale reply, noise, then the real one, a byte at a time.
    struct Scripted {
        out: std::collections::VecDeque<u8>,
        written: Vec<u8>,
    }
    impl Read for Scripted {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            match self.out.pop_front() {
                Some(b) => {
                    buf[0] = b;
                    Ok(1)
                }
                None => Err(std::io::Error::new(ErrorKind::TimedOut, "no data")),
            }
        }
    }
    impl Write for Scripted {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.written.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn stale_replies_and_noise_are_skipped_and_silence_times_out() {
        let mut out = Reply::CurrentIndex(3).packet_for(&Command::GetQueuedCurrentIndex).encode().unwrap();
        out.extend_from_slice(&[0x00, 0xAA, 0x17]);
        out.extend(Reply::Ack.packet_for(&Command::QueuedClear).encode().unwrap());
        let io = Scripted { out: out.into(), written: Vec::new() };
        let mut link = MagicianLink::attach(Box::new(io), Duration::from_millis(200));
        assert_eq!(link.request(&Command::QueuedClear).unwrap(), Reply::Ack);
        assert_eq!(link.stale_replies, 1);
        let e = link.request(&Command::GetPose).unwrap_err();
        assert!(matches!(e, TransportError::Timeout { command_id: 10, .. }), "{e}");
    }
}
