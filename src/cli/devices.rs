//! `rig devices`: list cameras (formats, USB identities), serial ports and USB devices.

use clap::Args as ClapArgs;

/// `rig devices` takes no options yet.
#[derive(Debug, ClapArgs)]
pub struct Args {}

/// Scans and prints; finding nothing is a normal answer (exit 0). When a rig configuration
/// is found, its V4L2 cameras' chosen formats are checked against their USB buses' bandwidth.
pub fn run(_args: Args) -> anyhow::Result<()> {
    let report = crate::io::inventory::DeviceReport::scan();
    print!("{}", report.render());
    if let Ok(config) = crate::config::RigConfig::discover(None) {
        let v4l2 = config.sensors.iter().filter_map(|s| match &s.backend {
            crate::config::SensorBackend::V4l2 { device } => Some((s.name.as_str(), device.as_str(), &s.camera)),
            _ => None,
        });
        let streams = crate::io::inventory::configured_streams(v4l2, &report.cameras);
        for warning in crate::io::inventory::usb_bandwidth_warnings(&streams) {
            println!("{warning}");
        }
    }
    Ok(())
}
