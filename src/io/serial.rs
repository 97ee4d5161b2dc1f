//! Serial helpers: finding serial ports, pseudo-terminal pairs for tests, and an async
//! serial stream for tokio (Modbus RTU).
//!
//! `serialport` is built without udev here, so [`list_serial_ports`] scans `/dev/ttyUSB*`,
//! `/dev/ttyACM*` and `/sys/class/tty` itself and reads the USB identity of each port's
//! parent device from sysfs. [`PtyPair`] wraps `openpty(3)`: the slave end has a path and
//! behaves like a serial device to the code under test, the master end is the simulated
//! device. [`AsyncSerial`] puts a tty into raw mode at a baud rate and drives it through
//! tokio's reactor; it is what the Modbus RTU transport talks over.

use std::fs::File;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::task::{Context, Poll, ready};

use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// A serial port found on this machine.
#[derive(Debug, Clone, PartialEq)]
pub struct SerialPortInfo {
    /// Device node, e.g. `/dev/ttyUSB0`.
    pub path: PathBuf,
    /// USB identity of the adapter, when the port sits on USB.
    pub usb: Option<crate::camera::usb::UsbIdentity>,
}

/// Serial ports that look like real adapters: `/dev/ttyUSB*`, `/dev/ttyACM*`, and any
/// `/sys/class/tty` entry backed by a device (which leaves out the virtual consoles).
pub fn list_serial_ports() -> Vec<SerialPortInfo> {
    list_serial_ports_in(Path::new("/dev"), Path::new("/sys/class/tty"))
}

/// [`list_serial_ports`] over other roots (tests build fake trees).
pub fn list_serial_ports_in(dev: &Path, sys_tty: &Path) -> Vec<SerialPortInfo> {
    let mut names: Vec<String> = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dev) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with("ttyUSB") || name.starts_with("ttyACM") {
                names.push(name);
            }
        }
    }
    if let Ok(entries) = std::fs::read_dir(sys_tty) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            // Only ttys with a device behind them (USB, PCI, platform UARTs that are present);
            // serial8250 placeholders have a device link but no driver bound to a real port.
            let device = e.path().join("device");
            let driver = std::fs::read_link(device.join("driver")).ok();
            // A UART whose `type` is 0 (PORT_UNKNOWN) has no hardware behind it.
            let unknown_uart = std::fs::read_to_string(e.path().join("type")).is_ok_and(|t| t.trim() == "0");
            let is_placeholder = unknown_uart || driver.as_ref().and_then(|d| d.file_name()).is_some_and(|d| d == "serial8250");
            if device.exists() && !is_placeholder && !names.contains(&name) {
                names.push(name);
            }
        }
    }
    names.sort();
    names
        .into_iter()
        .map(|name| SerialPortInfo {
            usb: crate::camera::usb::usb_identity_of_sysfs_device(&sys_tty.join(&name).join("device")),
            path: dev.join(name),
        })
        .collect()
}

/// A pseudo-terminal pair: `master` is the device side, `slave_path` the port's path.
pub struct PtyPair {
    pub master: OwnedFd,
    /// Kept open so the master does not see a hang-up when the code under test reopens it.
    pub slave: OwnedFd,
    pub slave_path: PathBuf,
}

impl PtyPair {
    /// Opens a pair in raw mode (no echo, no line editing, 8-bit clean).
    pub fn open() -> io::Result<Self> {
        let mut master: libc::c_int = -1;
        let mut slave: libc::c_int = -1;
        let mut name = [0 as libc::c_char; 256];
        // SAFETY: openpty writes two fds and a NUL-terminated name into buffers we own; the
        // name buffer is larger than any pts path. termios/winsize may be null.
        let rc = unsafe { libc::openpty(&mut master, &mut slave, name.as_mut_ptr(), std::ptr::null(), std::ptr::null()) };
        if rc != 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: openpty succeeded, so both are fresh fds that nothing else owns.
        let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
        make_raw(slave.as_raw_fd(), None)?;
        // SAFETY: openpty NUL-terminated the name inside the buffer.
        let path = unsafe { std::ffi::CStr::from_ptr(name.as_ptr()) }.to_string_lossy().into_owned();
        Ok(Self { master, slave, slave_path: PathBuf::from(path) })
    }

    /// A blocking file handle on the master (device) side.
    pub fn master_file(&self) -> io::Result<File> {
        Ok(File::from(self.master.try_clone()?))
    }
}

/// Raw mode (cfmakeraw), optionally at a baud rate, applied now.
fn make_raw(fd: libc::c_int, baud: Option<u32>) -> io::Result<()> {
    // SAFETY: termios is plain data; tcgetattr fills it for a valid fd or fails.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    if unsafe { libc::tcgetattr(fd, &mut t) } != 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: t came from tcgetattr.
    unsafe { libc::cfmakeraw(&mut t) };
    t.c_cflag |= libc::CLOCAL | libc::CREAD;
    if let Some(baud) = baud {
        let speed =
            baud_constant(baud).ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, format!("unsupported baud rate {baud}")))?;
        // SAFETY: valid termios and a speed constant.
        if unsafe { libc::cfsetspeed(&mut t, speed) } != 0 {
            return Err(io::Error::last_os_error());
        }
    }
    // SAFETY: valid fd and termios.
    if unsafe { libc::tcsetattr(fd, libc::TCSANOW, &t) } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

fn baud_constant(baud: u32) -> Option<libc::speed_t> {
    Some(match baud {
        1200 => libc::B1200,
        2400 => libc::B2400,
        4800 => libc::B4800,
        9600 => libc::B9600,
        19200 => libc::B19200,
        38400 => libc::B38400,
        57600 => libc::B57600,
        115200 => libc::B115200,
        230400 => libc::B230400,
        460800 => libc::B460800,
        921600 => libc::B921600,
        _ => return None,
    })
}

/// A tty in raw mode driven by tokio (non-blocking fd registered with the reactor).
pub struct AsyncSerial {
    fd: AsyncFd<OwnedFd>,
}

impl AsyncSerial {
    /// Opens `path` (e.g. `/dev/ttyUSB0` or a pty slave) raw at `baud`. Call inside a runtime.
    pub fn open(path: &Path, baud: u32) -> io::Result<Self> {
        let c_path = std::ffi::CString::new(path.as_os_str().as_encoded_bytes())
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "path contains NUL"))?;
        // SAFETY: a valid C string; the flags make the fd non-blocking and not our controlling tty.
        let raw = unsafe { libc::open(c_path.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK | libc::O_CLOEXEC) };
        if raw < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: open succeeded; we own the fd now.
        let fd = unsafe { OwnedFd::from_raw_fd(raw) };
        make_raw(fd.as_raw_fd(), Some(baud))?;
        Self::from_fd(fd)
    }

    /// Wraps an fd that is already configured; it is switched to non-blocking.
    pub fn from_fd(fd: OwnedFd) -> io::Result<Self> {
        // SAFETY: fcntl on a valid fd.
        let flags = unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_GETFL) };
        if flags < 0 || unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_SETFL, flags | libc::O_NONBLOCK) } < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: an OwnedFd stays open and keeps its number until the AsyncFd drops it.
        let fd = unsafe { AsyncFd::register(fd) }?;
        Ok(Self { fd })
    }
}

impl AsyncRead for AsyncSerial {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.fd.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            let result = guard.try_io(|fd| {
                // SAFETY: reading into an initialised buffer of the given length.
                let n = unsafe { libc::read(fd.as_raw_fd(), unfilled.as_mut_ptr().cast(), unfilled.len()) };
                if n < 0 { Err(io::Error::last_os_error()) } else { Ok(n as usize) }
            });
            match result {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                // A pty master whose slave closed reports EIO: that is end of stream.
                Ok(Err(e)) if e.raw_os_error() == Some(libc::EIO) => return Poll::Ready(Ok(())),
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for AsyncSerial {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.fd.poll_write_ready(cx))?;
            let result = guard.try_io(|fd| {
                // SAFETY: writing from a valid slice.
                let n = unsafe { libc::write(fd.as_raw_fd(), data.as_ptr().cast(), data.len()) };
                if n < 0 { Err(io::Error::last_os_error()) } else { Ok(n as usize) }
            });
            match result {
                Ok(r) => return Poll::Ready(r),
                Err(_would_block) => continue,
            }
        }
    }
    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};

    #[test]
    fn pty_pair_passes_bytes_both_ways_unchanged() {
        let pty = PtyPair::open().unwrap();
        let mut master = pty.master_file().unwrap();
        let mut slave = std::fs::OpenOptions::new().read(true).write(true).open(&pty.slave_path).unwrap();
        // Bytes a cooked tty would mangle: CR, NL, ^C, ^D, 0xFF.
        let bytes = [0xAA, 0xAA, 0x0D, 0x0A, 0x03, 0x04, 0xFF, 0x00];
        slave.write_all(&bytes).unwrap();
        let mut got = [0u8; 8];
        master.read_exact(&mut got).unwrap();
        assert_eq!(got, bytes);
        master.write_all(&bytes).unwrap();
        slave.read_exact(&mut got).unwrap();
        assert_eq!(got, bytes);
    }

    #[test]
    fn serial_scan_reads_a_fake_tree() {
        let dir = tempfile::tempdir().unwrap();
        let dev = dir.path().join("dev");
        let sys = dir.path().join("sys");
        std::fs::create_dir_all(&dev).unwrap();
        std::fs::create_dir_all(sys.join("tty0")).unwrap();
        for n in ["ttyUSB0", "ttyACM1", "tty0", "null"] {
            std::fs::write(dev.join(n), b"").unwrap();
        }
        let found: Vec<PathBuf> = list_serial_ports_in(&dev, &sys).into_iter().map(|p| p.path).collect();
        assert_eq!(found, vec![dev.join("ttyACM1"), dev.join("ttyUSB0")]);
        assert!(list_serial_ports_in(&dir.path().join("none"), &dir.path().join("none")).is_empty());
    }

    #[tokio::test]
    async fn async_serial_over_a_pty() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let pty = PtyPair::open().unwrap();
        let mut port = AsyncSerial::open(&pty.slave_path, 9600).unwrap();
        let mut device = AsyncSerial::from_fd(pty.master.try_clone().unwrap()).unwrap();
        port.write_all(b"\x01\x03\x00\x00").await.unwrap();
        let mut got = [0u8; 4];
        device.read_exact(&mut got).await.unwrap();
        assert_eq!(&got, b"\x01\x03\x00\x00");
    }
}
