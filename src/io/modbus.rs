//! Modbus peripherals (illumination controllers, external force sensors) read or written
//! around each capture, over Modbus TCP or RTU (tokio-modbus).
//!
//! A peripheral is configured in the rig config as `[modbus.<name>]` ([`RawModbusPeripheral`],
//! resolved once into [`ModbusPeripheralConfig`]). The collection job sees them only through
//! the [`Peripherals`] trait: [`ModbusBench`] for configured devices, [`NoPeripherals`] when
//! there are none. Around every capture the job calls [`Peripherals::before_capture`] once the
//! arm has arrived (register writes such as "light on at 80%"; frames are exposed only after
//! they are done), captures, then [`Peripherals::after_capture`] while the sensor is still
//! pressed: the reads first (force, temperature, the light level), then the `after_capture`
//! writes ("light off"). The reads come back as named, scaled values ([`ModbusReading`]);
//! [`format_readings`] gives the `name=value;...` text of the dataset's `modbus` column, in
//! peripheral-name order then configured read order.
//!
//! Failure policy, per peripheral (`required`, default `true`): a required peripheral's
//! timeout, lost connection or exception is a recoverable fault like a camera timeout: the
//! pose is retried (up to `retries_per_pose`), then the run stops with exit code 3. An
//! optional one (`required = false`) never stops the run: a warning is logged and its values
//! are left empty in that row (`force.force_N=`). Either way the connection is dropped after a
//! timeout or transport error and opened again on the next use, so a device that comes back
//! is picked up.
//!
//! Register values: one 16-bit register per reading unless `words = 2` (big-endian word
//! order, as most devices use), signed or unsigned, times `scale` plus `offset`.
//!
//! RTU runs over [`open_async`](crate::io::serial::open_async) (`serialport`/`tokio-serial`),
//! so any tty works (USB-RS485 adapters, pseudo-terminals in tests). The port is opened
//! exclusively at the configured [`SerialFraming`]: `baud`, `data_bits`, `parity`, `stop_bits`,
//! with Modbus RTU's defaults (19200 Bd, 8E1) for what is left out. `transport = "sim"` names a simulated device that
//! [`crate::rigs`] starts on loopback ([`crate::sim::modbus`]); the client then talks real
//! Modbus TCP to it.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use crate::io::serial::{DataBits, Parity, SerialError, SerialFraming, StopBits};
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
    /// The RTU serial port would not open (in use by another program, missing, refused).
    #[error("modbus {peripheral}: {source}")]
    Serial {
        peripheral: String,
        #[source]
        source: SerialError,
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
    /// A fault as a recording holds it (`rig replay`), or a replay that left the recording.
    #[error("modbus (replayed): {message}")]
    Replayed { message: String, recoverable: bool },
}

impl ModbusError {
    /// True for faults that may pass (a timeout, a lost connection, a refused request); false
    /// for a configuration the device can never satisfy.
    pub fn is_recoverable(&self) -> bool {
        match self {
            ModbusError::Invalid { .. } => false,
            ModbusError::Serial { source: SerialError::PathNotUtf8 { .. } | SerialError::NotSerial { .. }, .. } => false,
            ModbusError::Replayed { recoverable, .. } => *recoverable,
            _ => true,
        }
    }

    /// True when the connection may be out of step (a reply may still arrive late, or the
    /// socket is gone): drop it and connect again.
    fn spoils_connection(&self) -> bool {
        matches!(self, ModbusError::Timeout { .. } | ModbusError::Transport { .. })
    }
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
    /// `tcp`, `rtu`, or `sim` (a simulated device on loopback; simulated rig only for `force`).
    pub transport: Option<String>,
    /// `false`: a failure leaves this peripheral's values empty in the row and the run goes
    /// on. Default `true`: a failure is a fault, retried, then the end of the run.
    pub required: Option<bool>,
    /// Transport `sim`: which device, `force` (a force sensor following the simulated arm's
    /// indentation) or `light` (an illumination controller).
    pub sim: Option<String>,
    /// Transport `sim`, device `force`: N per mm of indentation (default 2.0).
    pub sim_stiffness_n_per_mm: Option<f64>,
    /// Transport `sim`: the device answers this many requests, then goes silent (fault
    /// injection; every later request times out).
    pub sim_stop_answering_after: Option<u64>,
    /// TCP: `host:port` (port 502 if left out).
    pub address: Option<String>,
    /// RTU: serial device path.
    pub device: Option<PathBuf>,
    /// RTU: baud rate (default 19200, the Modbus default).
    pub baud: Option<u32>,
    /// RTU: data bits, 7 or 8 (default 8).
    pub data_bits: Option<u8>,
    /// RTU: `even` (default, Modbus RTU's default), `odd` or `none`.
    pub parity: Option<String>,
    /// RTU: stop bits, 1 (default) or 2 (the Modbus standard's choice with no parity).
    pub stop_bits: Option<u8>,
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
    Tcp {
        address: String,
    },
    Rtu {
        device: PathBuf,
        framing: SerialFraming,
    },
    /// A simulated device; [`crate::rigs::Rig::open`] starts it on loopback and replaces this
    /// with the [`Tcp`](Self::Tcp) address it listens on.
    Sim {
        device: SimPeripheralKind,
        stop_answering_after: Option<u64>,
    },
}

/// Which simulated Modbus device to start (see [`crate::sim::modbus`] for the register map).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SimPeripheralKind {
    /// Force = stiffness x indentation of the simulated arm, in input registers 0..1.
    ForceSensor { stiffness_n_per_mm: f64 },
    /// A dimmable light whose level (holding register 0, per mille) reads back.
    Illumination,
}

/// A validated peripheral.
#[derive(Debug, Clone, PartialEq)]
pub struct ModbusPeripheralConfig {
    pub name: String,
    pub transport: ModbusTransport,
    /// See the module docs' failure policy.
    pub required: bool,
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
                framing: rtu_framing(&raw).map_err(|(field, problem)| invalid(field, problem))?,
                device: raw.device.clone().ok_or_else(|| invalid("device", "is required for transport rtu (e.g. /dev/ttyUSB1)".into()))?,
            },
            Some("sim") => {
                let device = match raw.sim.as_deref() {
                    Some("force") => {
                        let stiffness_n_per_mm = raw.sim_stiffness_n_per_mm.unwrap_or(2.0);
                        if !(stiffness_n_per_mm.is_finite() && stiffness_n_per_mm >= 0.0) {
                            return Err(invalid("sim_stiffness_n_per_mm", format!("must be finite and >= 0, got {stiffness_n_per_mm}")));
                        }
                        SimPeripheralKind::ForceSensor { stiffness_n_per_mm }
                    }
                    Some("light") => SimPeripheralKind::Illumination,
                    other => return Err(invalid("sim", format!("must be force or light for transport sim, got {other:?}"))),
                };
                ModbusTransport::Sim { device, stop_answering_after: raw.sim_stop_answering_after }
            }
            other => return Err(invalid("transport", format!("must be tcp, rtu or sim, got {other:?}"))),
        };
        if !matches!(transport, ModbusTransport::Rtu { .. })
            && (raw.baud.is_some() || raw.data_bits.is_some() || raw.parity.is_some() || raw.stop_bits.is_some())
        {
            return Err(invalid("transport", "is not rtu, so baud, data_bits, parity and stop_bits do not apply".into()));
        }
        if !matches!(transport, ModbusTransport::Sim { .. })
            && (raw.sim.is_some() || raw.sim_stiffness_n_per_mm.is_some() || raw.sim_stop_answering_after.is_some())
        {
            return Err(invalid("sim", "options are only for transport = \"sim\"".into()));
        }
        // Bounded: the collection waits this long for each request (a cancel does not).
        let timeout_ms = crate::bounds::MODBUS_TIMEOUT.check(raw.timeout_ms.unwrap_or(500)).map_err(|p| invalid("timeout_ms", p))?;
        if let Some(stiffness) = raw.sim_stiffness_n_per_mm {
            crate::bounds::MODBUS_STIFFNESS.check(stiffness).map_err(|p| invalid("sim_stiffness_n_per_mm", p))?;
        }
        for (field, count) in
            [("read", raw.read.len()), ("before_capture", raw.before_capture.len()), ("after_capture", raw.after_capture.len())]
        {
            crate::bounds::MODBUS_OPERATIONS.check(count).map_err(|p| invalid(field, format!("{p} entries")))?;
        }
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
            required: raw.required.unwrap_or(true),
            unit: raw.unit.unwrap_or(1),
            timeout: Duration::from_millis(timeout_ms),
            before_capture: raw.before_capture,
            after_capture: raw.after_capture,
            read: raw.read,
        })
    }
}

/// The serial framing of `[modbus.<name>]`, Modbus RTU's defaults (19200 Bd, 8E1) for what is
/// left out; `Err((field, problem))` for a value no UART offers.
fn rtu_framing(raw: &RawModbusPeripheral) -> Result<SerialFraming, (&'static str, String)> {
    let default = SerialFraming::MODBUS_RTU;
    let baud = crate::bounds::MODBUS_BAUD.check(raw.baud.unwrap_or(default.baud)).map_err(|p| ("baud", p))?;
    let data_bits = match raw.data_bits {
        None => default.data_bits,
        Some(8) => DataBits::Eight,
        Some(7) => DataBits::Seven,
        Some(other) => return Err(("data_bits", format!("must be 7 or 8, got {other}"))),
    };
    let parity = match raw.parity.as_deref() {
        None => default.parity,
        Some("even") => Parity::Even,
        Some("odd") => Parity::Odd,
        Some("none") => Parity::None,
        Some(other) => return Err(("parity", format!("must be even, odd or none, got {other:?}"))),
    };
    let stop_bits = match raw.stop_bits {
        None => default.stop_bits,
        Some(1) => StopBits::One,
        Some(2) => StopBits::Two,
        Some(other) => return Err(("stop_bits", format!("must be 1 or 2, got {other}"))),
    };
    Ok(SerialFraming { baud, data_bits, parity, stop_bits })
}

impl ModbusPeripheralConfig {
    /// `force (sim force sensor, required)`: one line for the start-up banner.
    pub fn describe(&self) -> String {
        let transport = match &self.transport {
            ModbusTransport::Tcp { address } => format!("tcp {address}"),
            ModbusTransport::Rtu { device, framing } => format!("rtu {} {framing}", device.display()),
            ModbusTransport::Sim { device: SimPeripheralKind::ForceSensor { .. }, .. } => "sim force sensor".into(),
            ModbusTransport::Sim { device: SimPeripheralKind::Illumination, .. } => "sim light".into(),
        };
        let policy = if self.required { "required" } else { "optional" };
        format!("{} ({transport} unit {}, {policy})", self.name, self.unit)
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
    /// The scaled value; `None` when an optional peripheral did not answer.
    pub value: Option<f64>,
}

/// `name=value;name=value`, in the order given: the text of the dataset's `modbus` column.
/// A missing value is written as nothing after the `=`; values use the shortest text that
/// reads back to the same `f64`.
pub fn format_readings(readings: &[ModbusReading]) -> String {
    readings
        .iter()
        .map(|r| match r.value {
            Some(v) => format!("{}={v}", r.name),
            None => format!("{}=", r.name),
        })
        .collect::<Vec<_>>()
        .join(";")
}

/// Parses a `modbus` column back into readings (`None` for an empty value). Returns `None`
/// for text [`format_readings`] cannot have written.
pub fn parse_readings(text: &str) -> Option<Vec<ModbusReading>> {
    if text.is_empty() {
        return Some(Vec::new());
    }
    text.split(';')
        .map(|item| {
            let (name, value) = item.split_once('=')?;
            let value = if value.is_empty() { None } else { Some(value.parse::<f64>().ok()?) };
            (!name.is_empty()).then(|| ModbusReading { name: name.to_string(), value })
        })
        .collect()
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

/// A peripheral and its connection, opened on first use and again after a timeout or a lost
/// connection.
pub struct ModbusPeripheral {
    config: ModbusPeripheralConfig,
    ctx: Option<Context>,
}

impl ModbusPeripheral {
    /// A peripheral that connects on its first operation.
    pub fn new(config: ModbusPeripheralConfig) -> Self {
        Self { config, ctx: None }
    }

    /// Connects over the configured transport now.
    pub async fn connect(config: ModbusPeripheralConfig) -> Result<Self, ModbusError> {
        let mut p = Self::new(config);
        p.ensure_connected().await?;
        Ok(p)
    }

    /// A peripheral over an already connected client context (tests, custom transports).
    /// After a timeout it reconnects over `config.transport`.
    pub fn attach(config: ModbusPeripheralConfig, ctx: Context) -> Self {
        Self { config, ctx: Some(ctx) }
    }

    pub fn config(&self) -> &ModbusPeripheralConfig {
        &self.config
    }

    /// True while a connection is open.
    pub fn is_connected(&self) -> bool {
        self.ctx.is_some()
    }

    async fn ensure_connected(&mut self) -> Result<&mut Context, ModbusError> {
        if self.ctx.is_none() {
            self.ctx = Some(open_context(&self.config).await?);
        }
        self.ctx.as_mut().ok_or_else(|| ModbusError::Invalid {
            peripheral: self.config.name.clone(),
            field: "transport",
            problem: "has no connection".into(),
        })
    }

    /// One register operation with the peripheral's timeout; reads return their words.
    async fn call(&mut self, op: RegisterOp) -> Result<Vec<u16>, ModbusError> {
        let peripheral = self.config.name.clone();
        let timeout = self.config.timeout;
        let operation = op.to_string();
        let ctx = self.ensure_connected().await?;
        let result = tokio::time::timeout(timeout, async {
            match op {
                RegisterOp::Write { register, value } => ctx.write_single_register(register, value).await.map(|r| r.map(|()| Vec::new())),
                RegisterOp::Read { kind: RegisterKind::Holding, register, count } => ctx.read_holding_registers(register, count).await,
                RegisterOp::Read { kind: RegisterKind::Input, register, count } => ctx.read_input_registers(register, count).await,
            }
        })
        .await;
        let result = match result {
            Err(_) => Err(ModbusError::Timeout { peripheral, operation, after: timeout }),
            Ok(Err(source)) => Err(ModbusError::Transport { peripheral, operation, source }),
            Ok(Ok(Err(exception))) => Err(ModbusError::Exception { peripheral, operation, exception }),
            Ok(Ok(Ok(words))) => Ok(words),
        };
        if let Err(e) = &result
            && e.spoils_connection()
        {
            // A late reply would answer the next request: start over on a fresh connection.
            self.ctx = None;
        }
        result
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

    /// The reads (taken while the sensor is still pressed, the light still on), then the
    /// `after_capture` writes.
    pub async fn after_capture(&mut self) -> Result<Vec<ModbusReading>, ModbusError> {
        let readings = self.read_all().await?;
        let writes = self.config.after_capture.clone();
        self.write_all(&writes).await?;
        Ok(readings)
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
            out.push(ModbusReading { name: format!("{}.{}", self.config.name, read.name), value: Some(value) });
        }
        Ok(out)
    }

    /// One read that changes nothing, for a pre-flight: the first configured reading; without
    /// one, the holding register the first configured write goes to, read back (not written);
    /// without either, the connection alone. Returns what was read, for the report.
    pub async fn probe(&mut self) -> Result<String, ModbusError> {
        if let Some(read) = self.config.read.first().cloned() {
            let op = RegisterOp::Read { kind: read.kind, register: read.register, count: u16::from(read.words) };
            let words = self.call(op).await?;
            return Ok(match decode_reading(&read, &words) {
                Some(value) => format!("read {}.{} = {value}", self.config.name, read.name),
                None => format!("read {}.{}: {} registers, expected {}", self.config.name, read.name, words.len(), read.words),
            });
        }
        let write = self.config.before_capture.first().or_else(|| self.config.after_capture.first()).cloned();
        if let Some(w) = write {
            let words = self.call(RegisterOp::Read { kind: RegisterKind::Holding, register: w.register, count: 1 }).await?;
            return Ok(format!(
                "read holding register {} = {}",
                w.register,
                words.first().map_or_else(|| "nothing".to_string(), u16::to_string)
            ));
        }
        self.ensure_connected().await?;
        Ok("connected (nothing configured to read)".to_string())
    }

    /// Every configured reading with no value (what an optional peripheral that failed logs).
    pub fn empty_readings(&self) -> Vec<ModbusReading> {
        self.config.read.iter().map(|r| ModbusReading { name: format!("{}.{}", self.config.name, r.name), value: None }).collect()
    }
}

/// Opens a client context over `config.transport`, within `config.timeout`.
async fn open_context(config: &ModbusPeripheralConfig) -> Result<Context, ModbusError> {
    let slave = Slave(config.unit);
    let connect_err = |target: String, source| ModbusError::Connect { peripheral: config.name.clone(), target, source };
    match &config.transport {
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
            Ok(tokio_modbus::client::tcp::attach_slave(stream, slave))
        }
        ModbusTransport::Rtu { device, framing } => {
            let port = crate::io::serial::open_async(device, framing)
                .map_err(|source| ModbusError::Serial { peripheral: config.name.clone(), source })?;
            Ok(tokio_modbus::client::rtu::attach_slave(port, slave))
        }
        ModbusTransport::Sim { .. } => Err(ModbusError::Invalid {
            peripheral: config.name.clone(),
            field: "transport",
            problem: "sim: the simulated device was not started (only `rig collect` on the simulated rig starts it)".into(),
        }),
    }
}

/// What the collection job needs from the peripherals around a capture: the one seam between
/// the job and Modbus (or any other bench device), so the job never names a backend.
pub trait Peripherals: Send {
    /// True when there is nothing to do around a capture (the job then leaves its timing
    /// exactly as without peripherals).
    fn is_empty(&self) -> bool;
    /// Once the arm has arrived, before frames are exposed.
    fn before_capture(&mut self) -> impl Future<Output = Result<(), ModbusError>> + Send;
    /// After the frames, still in contact: the readings for the row, then the
    /// `after_capture` writes. An error is a fault of a required peripheral.
    fn after_capture(&mut self) -> impl Future<Output = Result<Vec<ModbusReading>, ModbusError>> + Send;
}

/// A borrowed set of peripherals: a long-lived owner (the daemon's open rig) lends them to
/// one job after another.
impl<P: Peripherals> Peripherals for &mut P {
    fn is_empty(&self) -> bool {
        (**self).is_empty()
    }
    fn before_capture(&mut self) -> impl Future<Output = Result<(), ModbusError>> + Send {
        (**self).before_capture()
    }
    fn after_capture(&mut self) -> impl Future<Output = Result<Vec<ModbusReading>, ModbusError>> + Send {
        (**self).after_capture()
    }
}

/// No peripherals configured: nothing happens around a capture and the `modbus` column stays
/// empty.
#[derive(Debug, Default, Clone, Copy)]
pub struct NoPeripherals;

impl Peripherals for NoPeripherals {
    fn is_empty(&self) -> bool {
        true
    }
    async fn before_capture(&mut self) -> Result<(), ModbusError> {
        Ok(())
    }
    async fn after_capture(&mut self) -> Result<Vec<ModbusReading>, ModbusError> {
        Ok(Vec::new())
    }
}

/// All configured peripherals, in name order, with the failure policy of the module docs.
#[derive(Default)]
pub struct ModbusBench {
    pub peripherals: Vec<ModbusPeripheral>,
    /// Per peripheral: its `before_capture` failed for this capture (optional ones only), so
    /// its reads are skipped rather than waiting out another timeout.
    failed_before: Vec<bool>,
}

impl ModbusBench {
    /// The peripherals, not yet connected (each connects on first use).
    pub fn new(configs: &BTreeMap<String, ModbusPeripheralConfig>) -> Self {
        Self::from_peripherals(configs.values().cloned().map(ModbusPeripheral::new).collect())
    }

    /// A bench of already built peripherals, kept in the given order.
    pub fn from_peripherals(peripherals: Vec<ModbusPeripheral>) -> Self {
        let failed_before = vec![false; peripherals.len()];
        Self { peripherals, failed_before }
    }

    /// Connects every peripheral now: a required one that cannot be reached is an error (a
    /// miswired bench is better found before the arm moves); an optional one is warned about
    /// and tried again at each capture.
    pub async fn connect(configs: &BTreeMap<String, ModbusPeripheralConfig>) -> Result<Self, ModbusError> {
        let mut bench = Self::new(configs);
        for p in &mut bench.peripherals {
            let required = p.config.required;
            match p.ensure_connected().await.map(|_| ()) {
                Ok(()) => {}
                Err(e) if !required => {
                    tracing::warn!(error = %e, "optional Modbus peripheral not reachable; its values stay empty until it answers")
                }
                Err(e) => return Err(e),
            }
        }
        Ok(bench)
    }
}

impl Peripherals for ModbusBench {
    fn is_empty(&self) -> bool {
        self.peripherals.is_empty()
    }

    async fn before_capture(&mut self) -> Result<(), ModbusError> {
        self.failed_before = vec![false; self.peripherals.len()];
        for (p, failed) in self.peripherals.iter_mut().zip(&mut self.failed_before) {
            match p.before_capture().await {
                Ok(()) => {}
                Err(e) if !p.config.required => {
                    tracing::warn!(error = %e, "optional Modbus peripheral failed before the capture; its values stay empty");
                    *failed = true;
                }
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    async fn after_capture(&mut self) -> Result<Vec<ModbusReading>, ModbusError> {
        let mut out = Vec::new();
        for (k, p) in self.peripherals.iter_mut().enumerate() {
            if self.failed_before.get(k).copied().unwrap_or(false) {
                out.extend(p.empty_readings());
                continue;
            }
            match p.after_capture().await {
                Ok(readings) => out.extend(readings),
                Err(e) if !p.config.required => {
                    tracing::warn!(error = %e, "optional Modbus peripheral failed after the capture; its values stay empty");
                    out.extend(p.empty_readings());
                }
                Err(e) => return Err(e),
            }
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
            required: true,
            unit: 1,
            timeout: Duration::from_secs(2),
            before_capture: vec![RegisterWrite { register: 10, value: 800 }],
            after_capture: vec![],
            read: vec![
                RegisterRead {
                    name: "light_permille".into(),
                    kind: RegisterKind::Holding,
                    register: 10,
                    words: 1,
                    signed: false,
                    scale: 1.0,
                    offset: 0.0,
                },
                RegisterRead {
                    name: "force_mN".into(),
                    kind: RegisterKind::Input,
                    register: 0,
                    words: 2,
                    signed: true,
                    scale: 0.1,
                    offset: 0.0,
                },
            ],
        }
    }

    async fn exercise(p: &mut ModbusPeripheral, bank: &RegisterBank) {
        p.before_capture().await.unwrap();
        assert_eq!(bank.holding.lock().unwrap().get(&10), Some(&800));
        let readings = p.after_capture().await.unwrap();
        let name = &p.config().name;
        assert_eq!(readings[0], ModbusReading { name: format!("{name}.light_permille"), value: Some(800.0) });
        assert!(readings[1].value.is_some_and(|v| (v - -123.4).abs() < 1e-9), "{readings:?}");
        assert_eq!(format_readings(&readings[..1]), format!("{name}.light_permille=800"));
        // A register the device does not have: an exception value, not a transport error.
        p.config.read.push(RegisterRead {
            name: "missing".into(),
            kind: RegisterKind::Holding,
            register: 99,
            words: 1,
            signed: false,
            scale: 1.0,
            offset: 0.0,
        });
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

    /// rig opens the pty's slave end as its RTU port, through the config and the real open
    /// path; tokio-modbus's RTU server answers on the master end. A pty carries bytes, not
    /// parity, so what is checked is what rig asked the driver for: the tty's termios, read
    /// back through the test's own fd on the same tty.
    #[cfg(target_os = "linux")]
    async fn rtu_round_trip_with_framing(framing_toml: &str) -> libc::termios2 {
        let pty = crate::io::serial::PtyPair::open().unwrap();
        let b = bank();
        let server = tokio_modbus::server::rtu::Server::new(pty.master_async().unwrap());
        let served = b.clone();
        let server = tokio::spawn(async move {
            let _ = server.serve_forever(served).await;
        });
        let text = format!("transport = \"rtu\"\ndevice = {:?}\n{framing_toml}", pty.slave_path.display().to_string());
        let raw: RawModbusPeripheral = toml::from_str(&text).unwrap();
        let resolved = ModbusPeripheralConfig::resolve("force", raw).unwrap();
        let cfg =
            ModbusPeripheralConfig { transport: resolved.transport, ..config("force", ModbusTransport::Tcp { address: String::new() }) };
        let mut p = ModbusPeripheral::connect(cfg.clone()).await.unwrap();
        exercise(&mut p, &b).await;
        // While rig holds the port, nobody else opens it.
        let ModbusTransport::Rtu { framing, .. } = &cfg.transport else { unreachable!() };
        let e = crate::io::serial::open_async(&pty.slave_path, framing).unwrap_err();
        assert!(matches!(e, SerialError::Busy { .. }), "{e}");
        let e = ModbusPeripheral::connect(cfg).await.err().expect("a second peripheral on the same port");
        assert!(matches!(e, ModbusError::Serial { source: SerialError::Busy { .. }, .. }) && e.is_recoverable(), "{e}");
        assert!(e.to_string().contains("in use by another program"), "{e}");
        let termios = crate::io::serial::read_termios2(&pty.slave);
        server.abort();
        termios
    }

    /// Linux's pty driver (`pty_set_termios` in drivers/tty/pty.c) forces CS8 and clears PARENB
    /// on whatever is asked of a pty, so there the parity request is read from the input
    /// flags `serialport` sets with it: INPCK (check parity) for even and odd, IGNPAR for none;
    /// PARODD, CSTOPB and the exact speed are kept as asked. On a tty that keeps PARENB (a real
    /// UART) it is checked too.
    #[cfg(target_os = "linux")]
    fn assert_framing(t: &libc::termios2, baud: u32, parity: Option<bool>, cstopb: bool) {
        let (parity_enabled, parodd) = (parity.is_some(), parity == Some(true));
        assert_eq!((t.c_ispeed, t.c_ospeed), (baud, baud), "speed");
        assert_eq!(t.c_cflag & libc::CBAUD, libc::BOTHER, "an exact rate, not a B-constant");
        assert_eq!(t.c_cflag & libc::CSIZE, libc::CS8, "8 data bits");
        assert_eq!(t.c_iflag & libc::INPCK != 0, parity_enabled, "INPCK (parity checked on input)");
        assert_eq!(t.c_iflag & libc::IGNPAR != 0, !parity_enabled, "IGNPAR");
        if t.c_cflag & libc::PARENB != 0 || !parity_enabled {
            assert_eq!(t.c_cflag & libc::PARENB != 0, parity_enabled, "PARENB");
        }
        assert_eq!(t.c_cflag & libc::PARODD != 0, parodd, "PARODD");
        assert_eq!(t.c_cflag & libc::CSTOPB != 0, cstopb, "CSTOPB");
        assert_eq!(t.c_cflag & libc::CRTSCTS, 0, "no hardware flow control");
        assert_eq!(t.c_iflag & (libc::IXON | libc::IXOFF), 0, "no software flow control");
        assert_eq!(t.c_lflag & (libc::ICANON | libc::ECHO | libc::ISIG), 0, "raw");
    }

    #[cfg(target_os = "linux")]
    #[tokio::test]
    async fn rtu_over_a_pty_defaults_to_19200_8e1() {
        let t = rtu_round_trip_with_framing("").await;
        assert_framing(&t, 19_200, Some(false), false);
    }

    #[cfg(target_os = "linux")]
    #[tokio::test]
    async fn rtu_over_a_pty_at_8o1() {
        let t = rtu_round_trip_with_framing("baud = 9600\nparity = \"odd\"\n").await;
        assert_framing(&t, 9_600, Some(true), false);
    }

    #[cfg(target_os = "linux")]
    #[tokio::test]
    async fn rtu_over_a_pty_at_8n2() {
        let t = rtu_round_trip_with_framing("baud = 38400\ndata_bits = 8\nparity = \"none\"\nstop_bits = 2\n").await;
        assert_framing(&t, 38_400, None, true);
    }

    #[test]
    fn rtu_framing_is_validated() {
        let resolve = |extra: &str| {
            let raw: RawModbusPeripheral = toml::from_str(&format!("transport = \"rtu\"\ndevice = \"/dev/ttyUSB1\"\n{extra}")).unwrap();
            ModbusPeripheralConfig::resolve("x", raw)
        };
        let c = resolve("").unwrap();
        assert_eq!(c.describe(), "x (rtu /dev/ttyUSB1 19200 Bd 8E1 unit 1, required)");
        let c = resolve("baud = 115200\ndata_bits = 7\nparity = \"odd\"\nstop_bits = 2\n").unwrap();
        assert!(matches!(c.transport, ModbusTransport::Rtu { framing, .. } if framing.to_string() == "115200 Bd 7O2"));
        for (bad, field) in
            [("parity = \"mark\"\n", "parity"), ("data_bits = 9\n", "data_bits"), ("stop_bits = 3\n", "stop_bits"), ("baud = 0\n", "baud")]
        {
            let e = resolve(bad).unwrap_err();
            assert!(matches!(e, ModbusError::Invalid { field: f, .. } if f == field), "{bad}: {e}");
        }
        let raw: RawModbusPeripheral = toml::from_str("transport = \"tcp\"\naddress = \"h\"\nparity = \"odd\"\n").unwrap();
        assert!(matches!(ModbusPeripheralConfig::resolve("x", raw), Err(ModbusError::Invalid { field: "transport", .. })));
    }

    #[test]
    fn config_resolves_and_decodes() {
        let raw: RawModbusPeripheral =
            toml::from_str("transport = \"tcp\"\naddress = \"10.0.0.5\"\nread = [{ name = \"lux\", register = 3 }]\n").unwrap();
        let c = ModbusPeripheralConfig::resolve("light", raw).unwrap();
        assert_eq!(c.transport, ModbusTransport::Tcp { address: "10.0.0.5:502".into() });
        assert_eq!(c.read[0].kind, RegisterKind::Holding);
        let raw: RawModbusPeripheral = toml::from_str("transport = \"rtu\"\n").unwrap();
        assert!(matches!(ModbusPeripheralConfig::resolve("x", raw), Err(ModbusError::Invalid { field: "device", .. })));
        let raw: RawModbusPeripheral = toml::from_str("transport = \"udp\"\n").unwrap();
        assert!(ModbusPeripheralConfig::resolve("x", raw).is_err());
        // Simulated devices, the policy flag, and sim options where they do not belong.
        let raw: RawModbusPeripheral = toml::from_str("transport = \"sim\"\nsim = \"force\"\nrequired = false\n").unwrap();
        let c = ModbusPeripheralConfig::resolve("force", raw).unwrap();
        assert!(!c.required);
        assert_eq!(
            c.transport,
            ModbusTransport::Sim { device: SimPeripheralKind::ForceSensor { stiffness_n_per_mm: 2.0 }, stop_answering_after: None }
        );
        assert_eq!(c.describe(), "force (sim force sensor unit 1, optional)");
        for bad in [
            "transport = \"sim\"\nsim = \"laser\"\n",
            "transport = \"sim\"\nsim = \"force\"\nsim_stiffness_n_per_mm = -1.0\n",
            "transport = \"tcp\"\naddress = \"h\"\nsim_stop_answering_after = 3\n",
            "transport = \"tcp\"\naddress = \"h\"\ntimeout_ms = 0\n",
        ] {
            let raw: RawModbusPeripheral = toml::from_str(bad).unwrap();
            let e = ModbusPeripheralConfig::resolve("x", raw).unwrap_err();
            assert!(matches!(e, ModbusError::Invalid { .. }) && !e.is_recoverable(), "{bad}: {e}");
        }
        let r = RegisterRead { name: "v".into(), kind: RegisterKind::Input, register: 0, words: 1, signed: true, scale: 2.0, offset: 1.0 };
        assert_eq!(decode_reading(&r, &[0xFFFF]), Some(-1.0));
        assert_eq!(decode_reading(&r, &[]), None);
    }
}
