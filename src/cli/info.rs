//! `rig info`: the version, the features of the build, and what the rig configuration names.

use std::path::PathBuf;

use clap::Args as ClapArgs;

/// Arguments of `rig info`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Rig configuration file (default: $RIG_CONFIG, then ./rig.toml, else the simulated rig).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Prints the version line, the configuration's one-line summary and what it names (arm,
/// work frame, capture settings, each sensor's camera and press limit, each Modbus
/// peripheral). Opens no device; `rig devices` says which configured devices are present and
/// `rig collect --dry-run` opens them.
pub fn run(args: Args) -> anyhow::Result<()> {
    println!("rig {} (features: {})", crate::version(), crate::features::built_list());
    let config = crate::config::RigConfig::discover(args.config.as_deref())?;
    println!("{}", config.describe());
    for line in config.listing() {
        println!("  {line}");
    }
    Ok(())
}
