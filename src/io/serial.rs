//! Serial helpers: finding serial ports, pseudo-terminal pairs for tests, and an async
//! serial stream for tokio (Modbus RTU).
//!
//! `serialport` is built without udev here, so [`list_serial_ports`] scans `/dev/ttyUSB*`,
//! `/dev/ttyACM*` and `/sys/class/tty` itself and reads the USB identity of each port's
//! parent device from sysfs. [`PtyPair`] wraps `openpty(3)`: the slave end has a path and
//! behaves like a serial device to the code under test, the master end is the simulated
//! device. [`open_async`] opens a port through `serialport`/`tokio-serial` at a
//! [`SerialFraming`] (baud, data bits, parity, stop bits), raw and exclusive; it is what the
//! Modbus RTU transport talks over.

use std::fs::File;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, IntoRawFd, OwnedFd};
use std::path::{Path, PathBuf};

pub use serialport::{DataBits, Parity, StopBits};

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
        let rc = unsafe { libc::openpty(&mut master, &mut slave, name.as_mut_ptr(), std::ptr::null_mut(), std::ptr::null_mut()) };
        if rc != 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: openpty succeeded, so both are fresh fds that nothing else owns.
        let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
        make_raw(slave.as_raw_fd())?;
        // SAFETY: openpty NUL-terminated the name inside the buffer.
        let path = unsafe { std::ffi::CStr::from_ptr(name.as_ptr()) }.to_string_lossy().into_owned();
        Ok(Self { master, slave, slave_path: PathBuf::from(path) })
    }

    /// A blocking file handle on the master (device) side.
    pub fn master_file(&self) -> io::Result<File> {
        Ok(File::from(self.master.try_clone()?))
    }
}

/// Raw mode (cfmakeraw), applied now: the pty's slave end carries bytes unchanged.
fn make_raw(fd: libc::c_int) -> io::Result<()> {
    // SAFETY: termios is plain data; tcgetattr fills it for a valid fd or fails.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    if unsafe { libc::tcgetattr(fd, &mut t) } != 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: t came from tcgetattr.
    unsafe { libc::cfmakeraw(&mut t) };
    t.c_cflag |= libc::CLOCAL | libc::CREAD;
    // SAFETY: valid fd and termios.
    if unsafe { libc::tcsetattr(fd, libc::TCSANOW, &t) } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// Speed and character framing of a serial line, as rig asks the driver for them.
///
/// Modbus RTU's default (Modbus over Serial Line V1.02, section 2.5.1) is even parity with one
/// stop bit, and 19200 Bd is the rate every device must offer: [`SerialFraming::MODBUS_RTU`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SerialFraming {
    pub baud: u32,
    pub data_bits: DataBits,
    pub parity: Parity,
    pub stop_bits: StopBits,
}

impl SerialFraming {
    /// 19200 Bd, 8 data bits, even parity, 1 stop bit (8E1).
    pub const MODBUS_RTU: Self = Self { baud: 19_200, data_bits: DataBits::Eight, parity: Parity::Even, stop_bits: StopBits::One };

    /// `8E1`, `8N2`: data bits, parity letter, stop bits.
    pub fn character_format(&self) -> String {
        let parity = match self.parity {
            Parity::None => 'N',
            Parity::Even => 'E',
            Parity::Odd => 'O',
        };
        format!("{}{parity}{}", u8::from(self.data_bits), u8::from(self.stop_bits))
    }
}

impl std::fmt::Display for SerialFraming {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} Bd {}", self.baud, self.character_format())
    }
}

/// Errors opening a serial port.
#[derive(Debug, thiserror::Error)]
pub enum SerialError {
    /// Another process (or another part of rig) holds the port: rig opens ports exclusively
    /// (`TIOCEXCL` and an exclusive `flock`), so two programs never interleave frames.
    #[error("serial port {path} is in use by another program (rig opens serial ports exclusively): {source}")]
    Busy {
        path: PathBuf,
        #[source]
        source: serialport::Error,
    },
    #[error("cannot open serial port {path} at {framing}: {source}")]
    Open {
        path: PathBuf,
        framing: SerialFraming,
        #[source]
        source: serialport::Error,
    },
    #[error("serial port path {path:?} is not valid UTF-8")]
    PathNotUtf8 { path: PathBuf },
    /// The configured path is not a serial device (a regular file, a FIFO, `/dev/null`, a
    /// device that is not a terminal): the configuration's mistake, never opened as a port.
    #[error("{path} is not a serial port (it is {found}); name the port's device, e.g. /dev/ttyUSB0 or /dev/serial/by-id/...")]
    NotSerial { path: PathBuf, found: &'static str },
}

/// Checks that `path` (its symlinks followed, as `/dev/serial/by-id/...` are) names a
/// character device that can be a serial port, without opening it: a regular file, a folder,
/// a FIFO, a socket or a block device is refused, and so is a memory device (`/dev/null`,
/// `/dev/zero`: Linux's character major 1). A path that does not exist passes (the port may be
/// unplugged: opening it then fails as a missing device, a hardware fault).
pub fn check_serial_device(path: &Path) -> Result<(), SerialError> {
    use rustix::fs::FileType;
    let not_serial = |found| Err(SerialError::NotSerial { path: path.to_path_buf(), found });
    let stat = match rustix::fs::stat(path) {
        Ok(stat) => stat,
        Err(_) => return Ok(()),
    };
    match FileType::from_raw_mode(stat.st_mode) {
        FileType::CharacterDevice if cfg!(target_os = "linux") && rustix::fs::major(stat.st_rdev) == LINUX_MEMORY_DEVICES_MAJOR => {
            not_serial("a memory device such as /dev/null or /dev/zero")
        }
        FileType::CharacterDevice => Ok(()),
        FileType::RegularFile => not_serial("a regular file"),
        FileType::Directory => not_serial("a folder"),
        FileType::Fifo => not_serial("a FIFO"),
        FileType::Socket => not_serial("a socket"),
        FileType::BlockDevice => not_serial("a block device"),
        _ => not_serial("not a device"),
    }
}

/// Linux's character major of `/dev/null`, `/dev/zero`, `/dev/random` and the other memory
/// devices (Documentation/admin-guide/devices.txt).
const LINUX_MEMORY_DEVICES_MAJOR: u32 = 1;

/// Whether `serialport` failed because the device is not a terminal (`ENOTTY` from its
/// terminal set-up; `serialport` keeps only the message, "Not a typewriter" or "Inappropriate
/// ioctl for device" as the C library words it).
pub fn is_not_a_tty(e: &serialport::Error) -> bool {
    let text = e.description.to_ascii_lowercase();
    text.contains("not a typewriter") || text.contains("inappropriate ioctl")
}

/// Opens `path` (e.g. `/dev/ttyUSB0`) raw at `framing`, exclusively, with no flow control, as
/// a tokio stream (the Modbus RTU transport). Call inside a runtime. A second open of the
/// same port, by rig or by any program that honours `TIOCEXCL` or `flock`, fails with
/// [`SerialError::Busy`].
pub fn open_async(path: &Path, framing: &SerialFraming) -> Result<tokio_serial::SerialStream, SerialError> {
    let name = path.to_str().ok_or_else(|| SerialError::PathNotUtf8 { path: path.to_path_buf() })?;
    check_serial_device(path)?;
    let builder = serialport::new(name, framing.baud)
        .data_bits(framing.data_bits)
        .parity(framing.parity)
        .stop_bits(framing.stop_bits)
        .flow_control(serialport::FlowControl::None)
        .exclusive(true);
    tokio_serial::SerialStream::open(&builder).map_err(|source| match source.kind {
        _ if is_not_a_tty(&source) => SerialError::NotSerial { path: path.to_path_buf(), found: "a device that is not a terminal" },
        // serialport reports EBUSY from open(2) under TIOCEXCL, and a held flock, as NoDevice.
        serialport::ErrorKind::NoDevice => SerialError::Busy { path: path.to_path_buf(), source },
        _ => SerialError::Open { path: path.to_path_buf(), framing: *framing, source },
    })
}

impl PtyPair {
    /// The master (device) side as a tokio stream, for a simulated device such as
    /// tokio-modbus's RTU server. Call inside a runtime.
    pub fn master_async(&self) -> io::Result<tokio_serial::SerialStream> {
        let fd = self.master.try_clone()?;
        // SAFETY: `fd` is a fresh duplicate that nothing else owns; TTYPort takes it over and
        // closes it on drop.
        let port = unsafe { serialport::TTYPort::from_raw_fd(fd.into_raw_fd()) };
        tokio_serial::SerialStream::try_from(port).map_err(io::Error::from)
    }
}

/// Test support: what the driver holds for a tty, read back through `TCGETS2` (the call
/// `serialport` sets speeds with on Linux, so `c_ospeed` is the rate in Bd).
#[cfg(all(test, target_os = "linux"))]
pub(crate) fn read_termios2(fd: &impl AsRawFd) -> libc::termios2 {
    // SAFETY: termios2 is plain data; TCGETS2 fills it for a valid tty fd or fails.
    let mut t: libc::termios2 = unsafe { std::mem::zeroed() };
    let rc = unsafe { libc::ioctl(fd.as_raw_fd(), libc::TCGETS2, &mut t) };
    assert_eq!(rc, 0, "TCGETS2: {}", io::Error::last_os_error());
    t
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
    async fn open_async_carries_bytes_over_a_pty() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let pty = PtyPair::open().unwrap();
        let mut port = open_async(&pty.slave_path, &SerialFraming::MODBUS_RTU).unwrap();
        let mut device = pty.master_async().unwrap();
        AsyncWriteExt::write_all(&mut port, b"\x01\x03\x00\x00").await.unwrap();
        let mut got = [0u8; 4];
        AsyncReadExt::read_exact(&mut device, &mut got).await.unwrap();
        assert_eq!(&got, b"\x01\x03\x00\x00");
        AsyncWriteExt::write_all(&mut device, b"\x0D\x0A\xFF").await.unwrap();
        let mut got = [0u8; 3];
        AsyncReadExt::read_exact(&mut port, &mut got).await.unwrap();
        assert_eq!(&got, b"\x0D\x0A\xFF");
    }

    #[tokio::test]
    async fn a_second_open_of_a_port_is_refused_until_the_first_closes() {
        let pty = PtyPair::open().unwrap();
        let first = open_async(&pty.slave_path, &SerialFraming::MODBUS_RTU).unwrap();
        let e = open_async(&pty.slave_path, &SerialFraming::MODBUS_RTU).unwrap_err();
        assert!(matches!(&e, SerialError::Busy { path, .. } if *path == pty.slave_path), "{e}");
        assert!(e.to_string().contains("in use by another program"), "{e}");
        drop(first);
        open_async(&pty.slave_path, &SerialFraming::MODBUS_RTU).unwrap();
    }

    #[tokio::test]
    async fn paths_that_are_not_serial_devices_are_refused_unopened() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("not-a-port");
        std::fs::write(&file, b"").unwrap();
        let fifo = dir.path().join("fifo");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: mkfifo on a NUL-terminated path we own.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        // /dev/null is only named: refused from its kind, before any open.
        for (path, found) in [
            (file.as_path(), "a regular file"),
            (fifo.as_path(), "a FIFO"),
            (dir.path(), "a folder"),
            (Path::new("/dev/null"), "memory device"),
        ] {
            let e = check_serial_device(path).unwrap_err();
            assert!(matches!(&e, SerialError::NotSerial { .. }) && e.to_string().contains(found), "{e}");
            // Opening a FIFO for reading would block: the check comes first.
            let e = open_async(path, &SerialFraming::MODBUS_RTU).unwrap_err();
            assert!(matches!(e, SerialError::NotSerial { .. }), "{e}");
        }
        let pty = PtyPair::open().unwrap();
        check_serial_device(&pty.slave_path).expect("a pseudo-terminal is a serial device");
        check_serial_device(&dir.path().join("unplugged")).expect("a missing port is for the open to report");
        let enotty = serialport::Error::new(serialport::ErrorKind::Unknown, "Not a typewriter");
        assert!(is_not_a_tty(&enotty) && !is_not_a_tty(&serialport::Error::new(serialport::ErrorKind::NoDevice, "busy")));
    }

    #[test]
    fn framing_names_itself_like_a_datasheet() {
        assert_eq!(SerialFraming::MODBUS_RTU.to_string(), "19200 Bd 8E1");
        let f = SerialFraming { baud: 9600, data_bits: DataBits::Seven, parity: Parity::Odd, stop_bits: StopBits::Two };
        assert_eq!(f.character_format(), "7O2");
    }

    #[test]
    fn opening_a_missing_port_names_it_and_the_framing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ttyUSB9");
        let e = open_async(&path, &SerialFraming::MODBUS_RTU).unwrap_err();
        assert!(matches!(e, SerialError::Open { .. }), "{e}");
        assert!(e.to_string().contains("ttyUSB9") && e.to_string().contains("19200 Bd 8E1"), "{e}");
    }
}
