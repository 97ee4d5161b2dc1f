//! Opt-in checks against a real Modbus peripheral. Run with
//! `RIG_MODBUS_TCP=192.168.1.50:502 cargo test --test hw_modbus -- --ignored --nocapture` or
//! `RIG_MODBUS_RTU=/dev/ttyUSB1 RIG_MODBUS_BAUD=19200 ...`; `RIG_MODBUS_UNIT` (default 1) and
//! `RIG_MODBUS_REGISTER` (default 0, a holding register) pick what is read. Nothing is written.

use std::time::Duration;

use rig::io::modbus::{ModbusPeripheral, ModbusPeripheralConfig, ModbusTransport, RegisterKind, RegisterRead};

fn config() -> ModbusPeripheralConfig {
    let transport = if let Ok(address) = std::env::var("RIG_MODBUS_TCP") {
        ModbusTransport::Tcp { address }
    } else if let Ok(device) = std::env::var("RIG_MODBUS_RTU") {
        let baud = std::env::var("RIG_MODBUS_BAUD").map_or(19_200, |b| b.parse().expect("RIG_MODBUS_BAUD"));
        ModbusTransport::Rtu { device: device.into(), baud }
    } else {
        panic!("set RIG_MODBUS_TCP=host:port or RIG_MODBUS_RTU=/dev/ttyUSBn")
    };
    let env_u16 = |name: &str, default: u16| std::env::var(name).map_or(default, |v| v.parse().expect(name));
    ModbusPeripheralConfig {
        name: "hw".into(),
        transport,
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
