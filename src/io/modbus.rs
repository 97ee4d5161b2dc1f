//! Modbus peripherals (illumination controllers, external force sensors) read or written
//! around each capture, over Modbus TCP or RTU (tokio-modbus).
//!
//! A peripheral is configured in the rig config as `[modbus.<name>]` ([`RawModbusPeripheral`],
//! resolved once into [`ModbusPeripheralConfig`]). Around every capture the job calls
//! [`ModbusBench::before_capture`] (register writes such as "light on at 80%"), captures, then
//! [`ModbusBench::after_capture`] (register writes, then reads such as "force in mN"). The reads
//! come back as named, scaled values ([`ModbusReading`]) with [`format_readings`] giving the
//! `name=value;...` text logged beside the pose.
//!
//! Register values: one 16-bit register per reading unless `words = 2` (big-endian word
//! order, as most devices use), signed or unsigned, times `scale` plus `offset`.
//!
//! RTU runs over [`AsyncSerial`](crate::io::serial::AsyncSerial), so any tty works (USB-RS485
//! adapters, pseudo-terminals in tests).

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use serde::Deserialize;
use tokio_modbus::client::{Context, Reader as _, Writer as _};
use tokio_modbus::slave::Slave;

/// Errors talking to a Modbus peripheral or configuring one.
#[derive(Debug, thiserror::Error)]
pub enum ModbusError {
    #[error("modbus {peripheral}: cannot connect to {target}: {source}")]
    Connect {
        peripheral: String,
        target: String,
        #[source]
        source: std::io::Error,
    },
    #[error("modbus {peripheral}: {operation} failed: {source}")]
    Transport {
        peripheral: String,
        operation: String,
        #[source]
        source: tokio_modbus::Error,
    },
    /// The device answered with a Modbus exception (a value, not a transport fault).
    #[error("modbus {peripheral}: {operation} refused with exception {exception}")]
    Exception { peripheral: String, operation: String, exception: tokio_modbus::ExceptionCode },
    #[error("modbus {peripheral}: {operation} got no answer within {after:?}")]
    Timeout { peripheral: String, operation: String, after: Duration },
    #[error("modbus {peripheral}: {field} {problem}")]
    Invalid { peripheral: String, field: &'static str, problem: String },
}

/// Which register table a reading comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RegisterKind {
    /// Function 3, read/write.
    Holding,
    /// Function 4, read-only.
    Input,
}

/// `{ register = 10, value = 800 }`: write one holding register.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegisterWrite {
    pub register: u16,
    pub value: u16,
}

/// `{ name = "force_mN", kind = "input", register = 0, words = 2, signed = true, scale = 0.1 }`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegisterRead {
    /// Column name in the log; put the unit in it (`force_mN`, `light_pct`).
    pub name: String,
    #[serde(default = "default_kind")]
    pub kind: RegisterKind,
    pub register: u16,
    /// 1 (16-bit) or 2 (32-bit, high word first).
    #[serde(default = "one")]
    pub words: u8,
    #[serde(default)]
    pub signed: bool,
    #[serde(default = "unit_scale")]
    pub scale: f64,
    #[serde(default)]
    pub offset: f64,
}

fn default_kind() -> RegisterKind {
    RegisterKind::Holding
}
fn one() -> u8 {
    1
}
fn unit_scale() -> f64 {
    1.0
}

/// `[modbus.<name>]` as written in the rig config.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawModbusPeripheral {
    /// `tcp` or `rtu`.
    pub transport: Option<String>,
    /// TCP: `host:port` (port 502 if left out).
    pub address: Option<String>,
    /// RTU: serial device path.
    pub device: Option<PathBuf>,
    /// RTU: baud rate (default 19200, the Modbus default).
    pub baud: Option<u32>,
    /// Unit (slave) id, default 1.
    pub unit: Option<u8>,
    pub timeout_ms: Option<u64>,
    #[serde(default)]
    pub before_capture: Vec<RegisterWrite>,
    #[serde(default)]
    pub after_capture: Vec<RegisterWrite>,
    #[serde(default)]
    pub read: Vec<RegisterRead>,
}

/// How to reach a peripheral.
#[derive(Debug, Clone, PartialEq)]
pub enum ModbusTransport {
    Tcp { address: String },
    Rtu { device: PathBuf, baud: u32 },
}

/// A validated peripheral.
#[derive(Debug, Clone, PartialEq)]
pub struct ModbusPeripheralConfig {
    pub name: String,
    pub transport: ModbusTransport,
    pub unit: u8,
    pub timeout: Duration,
    pub before_capture: Vec<RegisterWrite>,
    pub after_capture: Vec<RegisterWrite>,
    pub read: Vec<RegisterRead>,
}

impl ModbusPeripheralConfig {
    /// Validates `[modbus.<name>]`.
    pub fn resolve(name: &str, raw: RawModbusPeripheral) -> Result<Self, ModbusError> {
        let invalid = |field, problem: String| ModbusError::Invalid { peripheral: name.to_string(), field, problem };
        let transport = match raw.transport.as_deref() {
            Some("tcp") => {
                let address = raw.address.ok_or_else(|| invalid("address", "is required for transport tcp (host:port)".into()))?;
                let address = if address.contains(':') { address } else { format!("{address}:502") };
                ModbusTransport::Tcp { address }
            }
            Some("rtu") => ModbusTransport::Rtu {
                device: raw.device.ok_or_else(|| invalid("device", "is required for transport rtu (e.g. /dev/ttyUSB1)".into()))?,
                baud: raw.baud.unwrap_or(19_200),
            },
            other => return Err(invalid("transport", format!("must be tcp or rtu, got {other:?}"))),
        };
        for r in &raw.read {
            if !(r.words == 1 || r.words == 2) {
                return Err(invalid("read.words", format!("{}: must be 1 or 2, got {}", r.name, r.words)));
            }
            if r.name.is_empty() || r.name.contains([';', '=', ',']) {
                return Err(invalid("read.name", format!("{:?} must be non-empty without ; = ,", r.name)));
            }
            if !r.scale.is_finite() || !r.offset.is_finite() {
                return Err(invalid("read.scale", format!("{}: scale and offset must be finite", r.name)));
            }
        }
        Ok(Self {
            name: name.to_string(),
            transport,
            unit: raw.unit.unwrap_or(1),
            timeout: Duration::from_millis(raw.timeout_ms.unwrap_or(500)),
            before_capture: raw.before_capture,
            after_capture: raw.after_capture,
            read: raw.read,
        })
    }
}

/// Decodes a reading's registers into its scaled value.
pub fn decode_reading(read: &RegisterRead, words: &[u16]) -> Option<f64> {
    let raw = match (read.words, read.signed, words) {
        (1, false, [w, ..]) => f64::from(*w),
        (1, true, [w, ..]) => f64::from(*w as i16),
        (2, false, [hi, lo, ..]) => f64::from((u32::from(*hi) << 16) | u32::from(*lo)),
        (2, true, [hi, lo, ..]) => f64::from(((u32::from(*hi) << 16) | u32::from(*lo)) as i32),
        _ => return None,
    };
    Some(raw * read.scale + read.offset)
}

/// One named value read from a peripheral.
#[derive(Debug, Clone, PartialEq)]
pub struct ModbusReading {
    /// `<peripheral>.<name>`.
    pub name: String,
    pub value: f64,
}

/// `name=value;name=value`, in the order given: the text logged beside a pose.
pub fn format_readings(readings: &[ModbusReading]) -> String {
    readings.iter().map(|r| format!("{}={}", r.name, r.value)).collect::<Vec<_>>().join(";")
}

/// One Modbus register operation (for messages and [`ModbusPeripheral`]'s dispatch).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RegisterOp {
    Write { register: u16, value: u16 },
    Read { kind: RegisterKind, register: u16, count: u16 },
}

impl std::fmt::Display for RegisterOp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RegisterOp::Write { register, value } => write!(f, "writing {value} to holding register {register}"),
            RegisterOp::Read { kind, register, count } => write!(f, "reading {count} {kind:?} register(s) at {register}"),
        }
    }
}

/// A connected peripheral.
pub struct ModbusPeripheral {
    config: ModbusPeripheralConfig,
    ctx: Context,
}

impl ModbusPeripheral {
    /// Connects over the configured transport.
    pub async fn connect(config: ModbusPeripheralConfig) -> Result<Self, ModbusError> {
        let slave = Slave(config.unit);
        let connect_err = |target: String, source| ModbusError::Connect { peripheral: config.name.clone(), target, source };
        let ctx = match &config.transport {
            ModbusTransport::Tcp { address } => {
                let addr: SocketAddr = tokio::net::lookup_host(address.as_str())
                    .await
                    .map_err(|e| connect_err(address.clone(), e))?
                    .next()
                    .ok_or_else(|| connect_err(address.clone(), std::io::Error::other("no address")))?;
                let stream = tokio::time::timeout(config.timeout, tokio::net::TcpStream::connect(addr))
                    .await
                    .map_err(|_| connect_err(address.clone(), std::io::Error::from(std::io::ErrorKind::TimedOut)))?
                    .map_err(|e| connect_err(address.clone(), e))?;
                tokio_modbus::client::tcp::attach_slave(stream, slave)
            }
            ModbusTransport::Rtu { device, baud } => {
                let port = crate::io::serial::AsyncSerial::open(device, *baud)
                    .map_err(|e| connect_err(device.display().to_string(), e))?;
                tokio_modbus::client::rtu::attach_slave(port, slave)
            }
        };
        Ok(Self { config, ctx })
    }

    /// A peripheral over an already connected client context (tests, custom transports).
    pub fn attach(config: ModbusPeripheralConfig, ctx: Context) -> Self {
        Self { config, ctx }
    }

    pub fn config(&self) -> &ModbusPeripheralConfig {
        &self.config
    }

    /// One register operation with the peripheral's timeout; reads return their words.
    async fn call(&mut self, op: RegisterOp) -> Result<Vec<u16>, ModbusError> {
        let peripheral = self.config.name.clone();
        let timeout = self.config.timeout;
        let operation = op.to_string();
        let result = tokio::time::timeout(timeout, async {
            match op {
                RegisterOp::Write { register, value } => self.ctx.write_single_register(register, value).await.map(|r| r.map(|()| Vec::new())),
                RegisterOp::Read { kind: RegisterKind::Holding, register, count } => self.ctx.read_holding_registers(register, count).await,
                RegisterOp::Read { kind: RegisterKind::Input, register, count } => self.ctx.read_input_registers(register, count).await,
            }
        })
        .await;
        match result {
            Err(_) => Err(ModbusError::Timeout { peripheral, operation, after: timeout }),
            Ok(Err(source)) => Err(ModbusError::Transport { peripheral, operation, source }),
            Ok(Ok(Err(exception))) => Err(ModbusError::Exception { peripheral, operation, exception }),
            Ok(Ok(Ok(words))) => Ok(words),
        }
    }

    async fn write_all(&mut self, writes: &[RegisterWrite]) -> Result<(), ModbusError> {
        for w in writes {
            self.call(RegisterOp::Write { register: w.register, value: w.value }).await?;
        }
        Ok(())
    }

    /// The `before_capture` writes.
    pub async fn before_capture(&mut self) -> Result<(), ModbusError> {
        let writes = self.config.before_capture.clone();
        self.write_all(&writes).await
    }

    /// The `after_capture` writes, then the reads.
    pub async fn after_capture(&mut self) -> Result<Vec<ModbusReading>, ModbusError> {
        let writes = self.config.after_capture.clone();
        self.write_all(&writes).await?;
        self.read_all().await
    }

    /// Reads every configured value.
    pub async fn read_all(&mut self) -> Result<Vec<ModbusReading>, ModbusError> {
        let mut out = Vec::new();
        for read in self.config.read.clone() {
            let op = RegisterOp::Read { kind: read.kind, register: read.register, count: u16::from(read.words) };
            let words = self.call(op).await?;
            let value = decode_reading(&read, &words).ok_or_else(|| ModbusError::Invalid {
                peripheral: self.config.name.clone(),
                field: "read",
                problem: format!("{}: device returned {} registers, expected {}", read.name, words.len(), read.words),
            })?;
            out.push(ModbusReading { name: format!("{}.{}", self.config.name, read.name), value });
        }
        Ok(out)
    }
}

/// All configured peripherals, in name order.
#[derive(Default)]
pub struct ModbusBench {
    pub peripherals: Vec<ModbusPeripheral>,
}

impl ModbusBench {
    /// Connects every peripheral.
    pub async fn connect(configs: &BTreeMap<String, ModbusPeripheralConfig>) -> Result<Self, ModbusError> {
        let mut peripherals = Vec::new();
        for config in configs.values() {
            peripherals.push(ModbusPeripheral::connect(config.clone()).await?);
        }
        Ok(Self { peripherals })
    }

    pub async fn before_capture(&mut self) -> Result<(), ModbusError> {
        for p in &mut self.peripherals {
            p.before_capture().await?;
        }
        Ok(())
    }

    pub async fn after_capture(&mut self) -> Result<Vec<ModbusReading>, ModbusError> {
        let mut out = Vec::new();
        for p in &mut self.peripherals {
            out.extend(p.after_capture().await?);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::future::{Ready, ready};
    use std::sync::{Arc, Mutex};
    use tokio_modbus::{ExceptionCode, Request, Response};

    /// A register bank standing in for an illumination controller and a force sensor.
    #[derive(Clone, Default)]
    struct RegisterBank {
        holding: Arc<Mutex<BTreeMap<u16, u16>>>,
        input: Arc<Mutex<BTreeMap<u16, u16>>>,
    }

    impl tokio_modbus::server::Service for RegisterBank {
        type Request = Request<'static>;
        type Response = Response;
        type Exception = ExceptionCode;
        type Future = Ready<Result<Response, ExceptionCode>>;

        fn call(&self, req: Request<'static>) -> Self::Future {
            let read = |table: &Mutex<BTreeMap<u16, u16>>, addr: u16, n: u16| -> Result<Vec<u16>, ExceptionCode> {
                let t = table.lock().unwrap();
                (addr..addr.saturating_add(n)).map(|a| t.get(&a).copied().ok_or(ExceptionCode::IllegalDataAddress)).collect()
            };
            ready(match req {
                Request::ReadHoldingRegisters(a, n) => read(&self.holding, a, n).map(Response::ReadHoldingRegisters),
                Request::ReadInputRegisters(a, n) => read(&self.input, a, n).map(Response::ReadInputRegisters),
                Request::WriteSingleRegister(a, v) => {
                    self.holding.lock().unwrap().insert(a, v);
                    Ok(Response::WriteSingleRegister(a, v))
                }
                _ => Err(ExceptionCode::IllegalFunction),
            })
        }
    }

    fn bank() -> RegisterBank {
        let b = RegisterBank::default();
        b.holding.lock().unwrap().insert(10, 0);
        // Force: -1234 (0.1 mN units) as a signed 32-bit value over registers 0..1.
        let force = (-1234i32) as u32;
        b.input.lock().unwrap().insert(0, (force >> 16) as u16);
        b.input.lock().unwrap().insert(1, force as u16);
        b
    }

    fn config(name: &str, transport: ModbusTransport) -> ModbusPeripheralConfig {
        ModbusPeripheralConfig {
            name: name.into(),
            transport,
            unit: 1,
            timeout: Duration::from_secs(2),
            before_capture: vec![RegisterWrite { register: 10, value: 800 }],
            after_capture: vec![],
            read: vec![
                RegisterRead { name: "light_permille".into(), kind: RegisterKind::Holding, register: 10, words: 1, signed: false, scale: 1.0, offset: 0.0 },
                RegisterRead { name: "force_mN".into(), kind: RegisterKind::Input, register: 0, words: 2, signed: true, scale: 0.1, offset: 0.0 },
            ],
        }
    }

    async fn exercise(p: &mut ModbusPeripheral, bank: &RegisterBank) {
        p.before_capture().await.unwrap();
        assert_eq!(bank.holding.lock().unwrap().get(&10), Some(&800));
        let readings = p.after_capture().await.unwrap();
        let name = &p.config().name;
        assert_eq!(readings[0], ModbusReading { name: format!("{name}.light_permille"), value: 800.0 });
        assert!((readings[1].value - -123.4).abs() < 1e-9, "{readings:?}");
        assert_eq!(format_readings(&readings[..1]), format!("{name}.light_permille=800"));
        // A register the device does not have: an exception value, not a transport error.
        p.config.read.push(RegisterRead { name: "missing".into(), kind: RegisterKind::Holding, register: 99, words: 1, signed: false, scale: 1.0, offset: 0.0 });
        let e = p.read_all().await.unwrap_err();
        assert!(matches!(e, ModbusError::Exception { exception: ExceptionCode::IllegalDataAddress, .. }), "{e}");
    }

    #[tokio::test]
    async fn tcp_peripheral_against_a_loopback_server() {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let b = bank();
        let served = b.clone();
        let server = tokio_modbus::server::tcp::Server::new(listener);
        tokio::spawn(async move {
            let on_connected = move |stream, _addr| {
                let service = served.clone();
                async move { Ok(Some((service, stream))) }
            };
            let _ = server.serve(&on_connected, |_e| {}).await;
        });
        let mut p = ModbusPeripheral::connect(config("light", ModbusTransport::Tcp { address: addr.to_string() })).await.unwrap();
        exercise(&mut p, &b).await;
    }

    #[cfg(unix)]
    #[tokio::test]
    async fn rtu_peripheral_over_a_pseudo_terminal() {
        let pty = crate::io::serial::PtyPair::open().unwrap();
        let b = bank();
        // The device opens the slave end as its serial port; rig talks through the master.
        let server = tokio_modbus::server::rtu::Server::new_from_path(&pty.slave_path, 19_200).unwrap();
        let served = b.clone();
        tokio::spawn(async move {
            let _ = server.serve_forever(served).await;
        });
        let port = crate::io::serial::AsyncSerial::from_fd(pty.master.try_clone().unwrap()).unwrap();
        let cfg = config("force", ModbusTransport::Rtu { device: pty.slave_path.clone(), baud: 19_200 });
        let ctx = tokio_modbus::client::rtu::attach_slave(port, Slave(cfg.unit));
        let mut p = ModbusPeripheral::attach(cfg, ctx);
        exercise(&mut p, &b).await;
    }

    #[test]
    fn config_resolves_and_decodes() {
        let raw: RawModbusPeripheral = toml::from_str(
            "transport = \"tcp\"\naddress = \"10.0.0.5\"\nread = [{ name = \"lux\", register = 3 }]\n",
        )
        .unwrap();
        let c = ModbusPeripheralConfig::resolve("light", raw).unwrap();
        assert_eq!(c.transport, ModbusTransport::Tcp { address: "10.0.0.5:502".into() });
        assert_eq!(c.read[0].kind, RegisterKind::Holding);
        let raw: RawModbusPeripheral = toml::from_str("transport = \"rtu\"\n").unwrap();
        assert!(matches!(ModbusPeripheralConfig::resolve("x", raw), Err(ModbusError::Invalid { field: "device", .. })));
        let raw: RawModbusPeripheral = toml::from_str("transport = \"udp\"\n").unwrap();
        assert!(ModbusPeripheralConfig::resolve("x", raw).is_err());
        let r = RegisterRead { name: "v".into(), kind: RegisterKind::Input, register: 0, words: 1, signed: true, scale: 2.0, offset: 1.0 };
        assert_eq!(decode_reading(&r, &[0xFFFF]), Some(-1.0));
        assert_eq!(decode_reading(&r, &[]), None);
    }
}
