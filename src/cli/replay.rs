//! `rig replay FILE [--out DIR]`: re-runs a recorded collection against its recording, with
//! no hardware, and writes the dataset again.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, bail};

use crate::record::Recording;
use crate::record::replay::{ReplayError, replay_collection};

/// Arguments of `rig replay`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The recording (`rig collect --record FILE`).
    pub file: PathBuf,
    /// Output root; datasets go to `<out>/<object>/<sensor>/` (must not hold them yet).
    #[arg(long, default_value = "datasets-replay")]
    pub out: PathBuf,
    /// Seconds without progress after which the replay is declared stuck.
    #[arg(long, default_value_t = 10.0)]
    pub stall_s: f64,
}

/// Runs `rig replay`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let recording = match Recording::read(&args.file) {
        Ok(r) => r,
        // A file that is not a whole recording is bad input (exit 2).
        Err(e) => bail!(crate::cli::UsageError(e.to_string())),
    };
    let h = &recording.header;
    println!(
        "replaying {} ({} events, rig {}): {}",
        args.file.display(),
        recording.events.len(),
        h.rig_version,
        h.command_line.join(" ")
    );
    if !(args.stall_s.is_finite() && args.stall_s > 0.0) {
        bail!(crate::cli::usage("--stall-s must be a positive number of seconds"));
    }
    // One thread: the client's feedback reader and the job interleave only where the
    // recording says (see `record::replay`).
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let outcome = runtime.block_on(replay_collection(&recording, &args.out, Duration::from_secs_f64(args.stall_s)));
    match outcome {
        Ok(o) => {
            println!(
                "replayed {} of {} recorded events: {} poses captured into {}",
                o.replayed,
                o.recorded,
                o.summary.captured,
                args.out.join(&h.object.name).display()
            );
            Ok(())
        }
        Err(e @ ReplayError::Diverged(_)) => {
            eprintln!("error: {e}");
            bail!(crate::cli::ExitStatus(3))
        }
        Err(e) => Err(e).context("replaying the collection"),
    }
}
