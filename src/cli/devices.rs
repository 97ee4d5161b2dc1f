//! `rig devices`: list cameras (formats, USB identities), serial ports and USB devices, and
//! say which devices the rig configuration names were found here.

use std::path::PathBuf;

use clap::Args as ClapArgs;

use crate::config::{ArmBackend, RigConfig, SensorBackend};
use crate::io::inventory::DeviceReport;
use crate::io::modbus::ModbusTransport;

/// Arguments of `rig devices`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Rig configuration file whose devices to look for (default: $RIG_CONFIG, then
    /// ./rig.toml; none: only the scan).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Reads the configuration (a bad one is refused before anything is scanned), scans and
/// prints; then, for a configuration file, each device it names, found here or not, and its
/// V4L2 cameras' chosen formats against their USB buses' bandwidth. Finding nothing is a
/// normal answer (exit 0).
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = RigConfig::discover(args.config.as_deref())?;
    let report = DeviceReport::scan();
    print!("{}", report.render());
    for line in configured_lines(&config, &report) {
        println!("{line}");
    }
    let v4l2 = config.sensors.iter().filter_map(|s| match &s.backend {
        SensorBackend::V4l2 { device } => Some((s.name.as_str(), device.as_str(), &s.camera)),
        _ => None,
    });
    let streams = crate::io::inventory::configured_streams(v4l2, &report.cameras);
    for warning in crate::io::inventory::usb_bandwidth_warnings(&streams) {
        println!("{warning}");
    }
    Ok(())
}

/// `configured in FILE:` and a line per device the configuration names: each camera found
/// (at which node) or not found, each serial port (Magician, Modbus RTU) found or not among
/// the scanned ports; network devices are not contacted here. Nothing for the built-in
/// simulated rig.
pub fn configured_lines(config: &RigConfig, report: &DeviceReport) -> Vec<String> {
    let Some(source) = &config.source else {
        return vec!["rig configuration: none found (--config, $RIG_CONFIG, ./rig.toml): nothing configured to look for".to_string()];
    };
    let mut lines = vec![format!("configured in {}:", source.display())];
    let nodes: Vec<crate::camera::usb::VideoNode> = report.cameras.iter().map(|c| c.node.clone()).collect();
    let serial = |path: &std::path::Path| {
        if report.serial_ports.iter().any(|p| p.path == path) {
            "found".to_string()
        } else {
            "not found among the serial ports above".to_string()
        }
    };
    match &config.arm.backend {
        ArmBackend::Simulated { .. } => lines.push("  arm: simulated MG400 (started by rig)".to_string()),
        ArmBackend::Mg400 { host, dashboard_port, .. } => {
            lines.push(format!("  arm: MG400 at {host}:{dashboard_port}: not contacted here (rig collect --dry-run connects and reads it)"))
        }
        ArmBackend::Magician { serial_port } => {
            lines.push(format!("  arm: Magician on {}: {}", serial_port.display(), serial(serial_port)))
        }
    }
    for s in &config.sensors {
        let line = match &s.backend {
            SensorBackend::Simulated => format!("  camera {}: simulated", s.name),
            SensorBackend::V4l2 { device } => {
                let found = crate::camera::usb::DeviceSelector::parse(device)
                    .ok()
                    .and_then(|selector| crate::camera::usb::select_video_node(&nodes, &selector).ok().map(|n| n.path.clone()))
                    .or_else(|| nodes.iter().find(|n| n.path.as_os_str() == device.as_str()).map(|n| n.path.clone()));
                match found {
                    Some(path) => format!("  camera {} (v4l2 {device}): found at {}", s.name, path.display()),
                    None => format!("  camera {} (v4l2 {device}): not found (no capture node here matches {device})", s.name),
                }
            }
            SensorBackend::Nokhwa { device } => {
                format!("  camera {} (nokhwa {device}): not looked for (nokhwa numbers cameras itself)", s.name)
            }
        };
        lines.push(line);
    }
    for p in config.modbus.values() {
        let line = match &p.transport {
            ModbusTransport::Rtu { device, .. } => format!("  modbus {} (rtu {}): {}", p.name, device.display(), serial(device)),
            ModbusTransport::Tcp { address } => format!("  modbus {} (tcp {address}): not contacted here", p.name),
            ModbusTransport::Sim { .. } => format!("  modbus {}: simulated", p.name),
        };
        lines.push(line);
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::usb::{UsbIdentity, VideoNode};
    use crate::io::inventory::CameraEntry;
    use crate::io::serial::SerialPortInfo;

    /// A configuration naming two cameras, a Modbus RTU port and the Magician, against a fixed
    /// report with one of the cameras and one of the ports: each is found or not found.
    #[test]
    fn configured_devices_are_found_or_not_found() {
        let config = RigConfig::parse(
            "[arm]\nbackend = \"magician\"\nserial_port = \"/dev/ttyUSB0\"\n\
             [sensors.tactip]\nbackend = \"v4l2\"\ndevice = \"port:1-2.1\"\n\
             [sensors.vitac]\nbackend = \"v4l2\"\ndevice = \"serial:VT9\"\n\
             [modbus.force]\ntransport = \"rtu\"\ndevice = \"/dev/ttyUSB1\"\nread = [{ name = \"f\", register = 0 }]\n",
            std::path::Path::new("bench.toml"),
        )
        .expect("config");
        let usb = UsbIdentity { port_path: "1-2.1".into(), vendor_id: 0x0c45, product_id: 0x6366, ..UsbIdentity::default() };
        let report = DeviceReport {
            cameras: vec![CameraEntry {
                node: VideoNode { path: "/dev/video2".into(), name: "TacTip".into(), index: 0, usb: Some(usb) },
                offers: Vec::new(),
                error: None,
            }],
            serial_ports: vec![SerialPortInfo { path: "/dev/ttyUSB1".into(), usb: None }],
            usb_devices: Vec::new(),
        };
        let lines = configured_lines(&config, &report);
        assert_eq!(lines[0], "configured in bench.toml:");
        assert!(lines.contains(&"  arm: Magician on /dev/ttyUSB0: not found among the serial ports above".to_string()), "{lines:#?}");
        assert!(lines.contains(&"  camera tactip (v4l2 port:1-2.1): found at /dev/video2".to_string()), "{lines:#?}");
        assert!(
            lines.contains(&"  camera vitac (v4l2 serial:VT9): not found (no capture node here matches serial:VT9)".to_string()),
            "{lines:#?}"
        );
        assert!(lines.contains(&"  modbus force (rtu /dev/ttyUSB1): found".to_string()), "{lines:#?}");
        let builtin = configured_lines(&RigConfig::builtin_sim(), &report);
        assert!(builtin[0].contains("none found"), "{builtin:?}");
    }
}
