//! `rig devices`: list cameras (formats, USB identities), serial ports and USB devices.

use clap::Args as ClapArgs;

/// `rig devices` takes no options yet.
#[derive(Debug, ClapArgs)]
pub struct Args {}

/// Scans and prints; finding nothing is a normal answer (exit 0).
pub fn run(_args: Args) -> anyhow::Result<()> {
    print!("{}", crate::io::inventory::DeviceReport::scan().render());
    Ok(())
}
