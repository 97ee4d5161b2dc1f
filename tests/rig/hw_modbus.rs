//! Opt-in checks against a real Modbus peripheral. Run with
//! `RIG_MODBUS_TCP=192.168.1.50:502 cargo test --test rig hw_modbus:: -- --ignored --nocapture` or
//! `RIG_MODBUS_RTU=/dev/ttyUSB1 RIG_MODBUS_BAUD=19200 ...` (8E1, Modbus RTU's default); `RIG_MODBUS_UNIT` (default 1) and
//! `RIG_MODBUS_REGISTER` (default 0, a holding register) pick what is read. Nothing is written
//! unless `RIG_MODBUS_WRITE=<register>=<value>` is set: then the capture-cycle test writes it
//! before the "capture" and writes back the value it read first afterwards (a light level,
//! for example).

use std::time::Duration;

use rig::io::modbus::{
    ModbusBench, ModbusPeripheral, ModbusPeripheralConfig, ModbusTransport, Peripherals, RegisterKind, RegisterRead, RegisterWrite,
    format_readings,
};

fn config() -> ModbusPeripheralConfig {
    let transport = if let Ok(address) = std::env::var("RIG_MODBUS_TCP") {
        ModbusTransport::Tcp { address }
    } else if let Ok(device) = std::env::var("RIG_MODBUS_RTU") {
        let baud = std::env::var("RIG_MODBUS_BAUD").map_or(19_200, |b| b.parse().expect("RIG_MODBUS_BAUD"));
        let framing = rig::io::serial::SerialFraming { baud, ..rig::io::serial::SerialFraming::MODBUS_RTU };
        ModbusTransport::Rtu { device: device.into(), framing }
    } else {
        panic!("set RIG_MODBUS_TCP=host:port or RIG_MODBUS_RTU=/dev/ttyUSBn")
    };
    let env_u16 = |name: &str, default: u16| std::env::var(name).map_or(default, |v| v.parse().expect(name));
    ModbusPeripheralConfig {
        name: "hw".into(),
        transport,
        required: true,
        unit: env_u16("RIG_MODBUS_UNIT", 1) as u8,
        timeout: Duration::from_secs(1),
        before_capture: vec![],
        after_capture: vec![],
        read: vec![RegisterRead {
            name: "value".into(),
            kind: RegisterKind::Holding,
            register: env_u16("RIG_MODBUS_REGISTER", 0),
            words: 1,
            signed: false,
            scale: 1.0,
            offset: 0.0,
        }],
    }
}

#[tokio::test]
#[ignore = "needs a Modbus device at RIG_MODBUS_TCP or RIG_MODBUS_RTU"]
async fn real_peripheral_answers_a_read() {
    let mut p = ModbusPeripheral::connect(config()).await.expect("connects");
    let readings = p.read_all().await.expect("reads the register");
    println!("{readings:?}");
    assert_eq!(readings.len(), 1);
}

#[tokio::test]
#[ignore = "needs a Modbus device at RIG_MODBUS_TCP or RIG_MODBUS_RTU (writes only with RIG_MODBUS_WRITE)"]
async fn real_peripheral_around_a_capture() {
    let mut config = config();
    if let Ok(spec) = std::env::var("RIG_MODBUS_WRITE") {
        let (register, value) = spec.split_once('=').expect("RIG_MODBUS_WRITE=<register>=<value>");
        let register: u16 = register.parse().expect("register");
        let value: u16 = value.parse().expect("value");
        // Read the register first so the test leaves the device as it found it.
        let mut probe = config.clone();
        probe.read = vec![RegisterRead {
            name: "before".into(),
            kind: RegisterKind::Holding,
            register,
            words: 1,
            signed: false,
            scale: 1.0,
            offset: 0.0,
        }];
        let mut p = ModbusPeripheral::connect(probe).await.expect("connects");
        let old = p.read_all().await.expect("reads the register to restore")[0].value.expect("a value") as u16;
        config.before_capture = vec![RegisterWrite { register, value }];
        config.after_capture = vec![RegisterWrite { register, value: old }];
    }
    let mut bench = ModbusBench::from_peripherals(vec![ModbusPeripheral::connect(config).await.expect("connects")]);
    bench.before_capture().await.expect("before-capture writes");
    let readings = bench.after_capture().await.expect("reads, then after-capture writes");
    println!("modbus column: {}", format_readings(&readings));
    assert_eq!(readings.len(), 1);
    assert!(readings[0].value.is_some());
}
