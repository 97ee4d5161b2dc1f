//! Simulated Modbus TCP peripherals on loopback, for the simulated rig and tests.
//!
//! [`SimModbusServer::start`] binds `127.0.0.1:0` and serves one device with tokio-modbus's
//! real TCP server, so rig's real client ([`crate::io::modbus::ModbusPeripheral`]) is what
//! talks to it. Register map (unit id ignored):
//!
//! | device | table | address | words | type | unit | meaning |
//! |---|---|---|---|---|---|---|
//! | force sensor | input | 0..1 | 2 | i32, high word first | mN | stiffness x indentation (0 above the surface) |
//! | force sensor | input | 2 | 1 | u16, saturating | um | indentation of the arm's true pose |
//! | illumination | holding | 0 | 1 | u16, 0..=1000 | per mille | light level; writes above 1000 are refused (exception 3) |
//!
//! The force sensor reads the simulated arm's [`ArmTruth`] at the instant of the request and
//! turns it into indentation with the rig's [`WorkFrame`] (`indentation_mm`: the plan z plus
//! the contact depth, when the arm is at a contact pose). Any other address is refused with
//! exception 2 (illegal data address), any other function with exception 1.
//!
//! Fault injection: with `stop_answering_after = Some(n)` the device answers its first `n`
//! requests, then receives every later one without replying, as a device that hung or lost
//! power behind a gateway would; the client sees timeouts.

use std::future::{Ready, ready};
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU16, AtomicU64, Ordering};

use tokio::sync::watch;
use tokio_modbus::{ExceptionCode, Request, Response};

use crate::io::modbus::SimPeripheralKind;
use crate::pose::WorkFrame;
use crate::sim::ArmTruth;

/// The simulated arm a force sensor presses with.
#[derive(Debug, Clone)]
pub struct ArmContact {
    pub truth: watch::Receiver<ArmTruth>,
    pub work_frame: WorkFrame,
}

/// Shared state of one simulated device.
#[derive(Debug)]
struct DeviceState {
    kind: SimPeripheralKind,
    contact: Option<ArmContact>,
    light_permille: AtomicU16,
    requests: AtomicU64,
    stop_answering_after: Option<u64>,
}

impl DeviceState {
    /// Indentation of the arm's true pose now, mm (0 without an arm or above the surface).
    fn indentation_mm(&self) -> f64 {
        self.contact.as_ref().map_or(0.0, |c| c.work_frame.indentation_mm(&c.truth.borrow().pose).max(0.0))
    }

    fn input_register(&self, address: u16) -> Result<u16, ExceptionCode> {
        let SimPeripheralKind::ForceSensor { stiffness_n_per_mm } = self.kind else {
            return Err(ExceptionCode::IllegalDataAddress);
        };
        let indentation_mm = self.indentation_mm();
        let force_mn = (stiffness_n_per_mm * indentation_mm * 1000.0).round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
        let word = (force_mn as u32).to_be_bytes();
        match address {
            0 => Ok(u16::from_be_bytes([word[0], word[1]])),
            1 => Ok(u16::from_be_bytes([word[2], word[3]])),
            2 => Ok((indentation_mm * 1000.0).round().clamp(0.0, f64::from(u16::MAX)) as u16),
            _ => Err(ExceptionCode::IllegalDataAddress),
        }
    }

    fn holding_register(&self, address: u16) -> Result<u16, ExceptionCode> {
        match (self.kind, address) {
            (SimPeripheralKind::Illumination, 0) => Ok(self.light_permille.load(Ordering::SeqCst)),
            _ => Err(ExceptionCode::IllegalDataAddress),
        }
    }

    fn answer(&self, req: Request<'static>) -> Result<Response, ExceptionCode> {
        let range = |address: u16, count: u16| -> Result<std::ops::Range<u16>, ExceptionCode> {
            let end = address.checked_add(count).ok_or(ExceptionCode::IllegalDataAddress)?;
            if count == 0 || count > 125 { Err(ExceptionCode::IllegalDataValue) } else { Ok(address..end) }
        };
        match req {
            Request::ReadInputRegisters(address, count) => {
                range(address, count)?.map(|a| self.input_register(a)).collect::<Result<_, _>>().map(Response::ReadInputRegisters)
            }
            Request::ReadHoldingRegisters(address, count) => {
                range(address, count)?.map(|a| self.holding_register(a)).collect::<Result<_, _>>().map(Response::ReadHoldingRegisters)
            }
            Request::WriteSingleRegister(address, value) => match (self.kind, address) {
                (SimPeripheralKind::Illumination, 0) if value <= 1000 => {
                    self.light_permille.store(value, Ordering::SeqCst);
                    Ok(Response::WriteSingleRegister(address, value))
                }
                (SimPeripheralKind::Illumination, 0) => Err(ExceptionCode::IllegalDataValue),
                _ => Err(ExceptionCode::IllegalDataAddress),
            },
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

/// The tokio-modbus service of one device (cloned per connection).
#[derive(Debug, Clone)]
struct SimModbusService {
    state: Arc<DeviceState>,
}

impl tokio_modbus::server::Service for SimModbusService {
    type Request = Request<'static>;
    /// `None`: receive the request and send nothing (the "stopped answering" fault).
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = Ready<Result<Option<Response>, ExceptionCode>>;

    fn call(&self, req: Request<'static>) -> Self::Future {
        let n = self.state.requests.fetch_add(1, Ordering::SeqCst) + 1;
        if self.state.stop_answering_after.is_some_and(|after| n > after) {
            return ready(Ok(None));
        }
        ready(self.state.answer(req).map(Some))
    }
}

/// A running simulated device. Dropping it (or [`shutdown`](Self::shutdown)) stops the
/// listener.
#[derive(Debug)]
pub struct SimModbusServer {
    addr: SocketAddr,
    state: Arc<DeviceState>,
    task: tokio::task::JoinHandle<()>,
}

impl SimModbusServer {
    /// Starts `kind` on `127.0.0.1:0`. A force sensor without `contact` always reads 0.
    pub async fn start(kind: SimPeripheralKind, contact: Option<ArmContact>, stop_answering_after: Option<u64>) -> std::io::Result<Self> {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let addr = listener.local_addr()?;
        let state =
            Arc::new(DeviceState { kind, contact, light_permille: AtomicU16::new(0), requests: AtomicU64::new(0), stop_answering_after });
        let service = SimModbusService { state: Arc::clone(&state) };
        let server = tokio_modbus::server::tcp::Server::new(listener);
        let task = tokio::spawn(async move {
            let on_connected = move |stream, _addr| {
                let service = service.clone();
                async move { Ok(Some((service, stream))) }
            };
            if let Err(e) = server.serve(&on_connected, |e| tracing::debug!(error = %e, "simulated Modbus connection")).await {
                tracing::warn!(error = %e, "simulated Modbus server stopped");
            }
        });
        Ok(Self { addr, state, task })
    }

    /// Where it listens.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Requests received so far (answered or not).
    pub fn requests(&self) -> u64 {
        self.state.requests.load(Ordering::SeqCst)
    }

    /// The illumination level last written, per mille.
    pub fn light_permille(&self) -> u16 {
        self.state.light_permille.load(Ordering::SeqCst)
    }

    /// Stops listening.
    pub fn shutdown(self) {
        self.task.abort();
    }
}

impl Drop for SimModbusServer {
    fn drop(&mut self) {
        self.task.abort();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::modbus::{
        ModbusBench, ModbusError, ModbusPeripheral, ModbusPeripheralConfig, ModbusTransport, Peripherals, RawModbusPeripheral,
        format_readings, parse_readings,
    };
    use crate::pose::Pose;

    fn config(name: &str, toml_text: &str, addr: SocketAddr) -> ModbusPeripheralConfig {
        let raw: RawModbusPeripheral = toml::from_str(toml_text).unwrap();
        let mut c = ModbusPeripheralConfig::resolve(name, raw).unwrap();
        c.transport = ModbusTransport::Tcp { address: addr.to_string() };
        c
    }

    const FORCE: &str = "transport = \"sim\"\nsim = \"force\"\nsim_stiffness_n_per_mm = 2.5\ntimeout_ms = 200\n\
        read = [{ name = \"force_N\", kind = \"input\", register = 0, words = 2, signed = true, scale = 0.001 },\
                { name = \"depth_um\", kind = \"input\", register = 2 }]\n";
    const LIGHT: &str = "transport = \"sim\"\nsim = \"light\"\ntimeout_ms = 200\n\
        before_capture = [{ register = 0, value = 800 }]\nafter_capture = [{ register = 0, value = 0 }]\n\
        read = [{ name = \"level_permille\", register = 0 }]\n";

    #[tokio::test]
    async fn force_follows_the_arm_and_the_light_reads_back() {
        let wf = WorkFrame::default();
        let (truth_tx, truth) = watch::channel(ArmTruth { t_s: 0.0, pose: wf.approach_pose(&Pose::default()), speed_mm_s: 0.0 });
        let kind = SimPeripheralKind::ForceSensor { stiffness_n_per_mm: 2.5 };
        let force = SimModbusServer::start(kind, Some(ArmContact { truth, work_frame: wf }), None).await.unwrap();
        let light = SimModbusServer::start(SimPeripheralKind::Illumination, None, None).await.unwrap();
        let configs = [("force", config("force", FORCE, force.addr())), ("light", config("light", LIGHT, light.addr()))];
        let mut bench = ModbusBench::from_peripherals(configs.into_iter().map(|(_, c)| ModbusPeripheral::new(c)).collect());

        // Above the surface: no force; the light is on during the capture and off after.
        bench.before_capture().await.unwrap();
        assert_eq!(light.light_permille(), 800);
        let text = format_readings(&bench.after_capture().await.unwrap());
        assert_eq!(text, "force.force_N=0;force.depth_um=0;light.level_permille=800");
        assert_eq!(light.light_permille(), 0);

        // Pressed 1.5 + 0.5 mm: 2.5 N/mm x 2 mm = 5 N.
        truth_tx.send_modify(|t| t.pose = wf.contact_pose(&Pose::new(1.0, -2.0, 0.5, 10.0)));
        bench.before_capture().await.unwrap();
        let readings = bench.after_capture().await.unwrap();
        assert_eq!(format_readings(&readings), "force.force_N=5;force.depth_um=2000;light.level_permille=800");
        assert_eq!(parse_readings(&format_readings(&readings)), Some(readings));
        assert_eq!(
            parse_readings("a=1;b="),
            Some(vec![
                crate::io::modbus::ModbusReading { name: "a".into(), value: Some(1.0) },
                crate::io::modbus::ModbusReading { name: "b".into(), value: None },
            ])
        );
        assert_eq!(parse_readings("a=x"), None);

        // A level the controller refuses is an exception, not a timeout.
        let mut bad = ModbusPeripheral::new(config(
            "light",
            "transport = \"tcp\"\naddress = \"x\"\nbefore_capture = [{ register = 0, value = 1001 }]\n",
            light.addr(),
        ));
        let e = bad.before_capture().await.unwrap_err();
        assert!(matches!(e, ModbusError::Exception { exception: ExceptionCode::IllegalDataValue, .. }), "{e}");
    }

    #[tokio::test]
    async fn a_silent_device_times_out_and_the_policy_decides() {
        let kind = SimPeripheralKind::ForceSensor { stiffness_n_per_mm: 1.0 };
        // Answers the first capture's two reads, then nothing.
        let force = SimModbusServer::start(kind, None, Some(2)).await.unwrap();
        let mut c = config("force", FORCE, force.addr());
        c.required = false;
        let mut bench = ModbusBench::from_peripherals(vec![ModbusPeripheral::new(c.clone())]);
        bench.before_capture().await.unwrap();
        assert_eq!(format_readings(&bench.after_capture().await.unwrap()), "force.force_N=0;force.depth_um=0");
        // Optional: empty values, no error.
        bench.before_capture().await.unwrap();
        assert_eq!(format_readings(&bench.after_capture().await.unwrap()), "force.force_N=;force.depth_um=");
        assert!(!bench.peripherals[0].is_connected(), "a timeout drops the connection");
        // Required: the timeout is the error, and a recoverable one.
        c.required = true;
        let mut bench = ModbusBench::from_peripherals(vec![ModbusPeripheral::new(c)]);
        bench.before_capture().await.unwrap();
        let e = bench.after_capture().await.unwrap_err();
        assert!(matches!(e, ModbusError::Timeout { .. }) && e.is_recoverable(), "{e}");
        assert!(force.requests() >= 4);
    }
}
