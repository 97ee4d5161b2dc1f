//! Peripherals besides the arm and the cameras: serial helpers ([`serial`]) and Modbus
//! devices ([`modbus`]) read or written around each capture.

pub mod inventory;
pub mod modbus;
pub mod serial;
