//! `rig dataset verify|export|import|merge`: wiring over [`crate::dataset`].

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use crate::dataset::durable;
use crate::dataset::export::{export_mds, export_tactile_bench, import_mds, mds_rows_from, pose_row_from_mds};
#[cfg(feature = "lerobot")]
use crate::dataset::lerobot::{LerobotOptions, export_lerobot};
use crate::dataset::{DatasetWriter, Manifest, MergeOptions, ObjectInfo, merge, read_rows, verify};
use crate::sensor::SensorKind;

/// `rig dataset ...`
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: DatasetCommand,
}

/// Export dialects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// MultiDiffSense / Lepora lab: image_name,data_name,obj_id,pose_id,pose_1..6,move_1..6.
    Mds,
    /// tactile-bench: sensor_image,object_label,pose_x..pose_Rz,pose_id,source.
    TactileBench,
    /// LeRobot v3 (parquet): one frame per pose, one image key per sensor, episodes of one
    /// object's poses, files of at most --max-file-mb; --out is a new folder. DIR may be a
    /// dataset, an object folder or a folder of objects.
    Lerobot,
}

// The doc comments are `--help` text, where `<obj_id>` is a placeholder, not HTML.
#[allow(rustdoc::invalid_html_tags)]
#[derive(Debug, clap::Subcommand)]
pub enum DatasetCommand {
    /// Report missing images, orphan images, duplicated or malformed rows, leftovers of a
    /// killed run and rows that press past the sensor's press limit; exits 1 when the dataset
    /// is not clean. Changes nothing.
    #[command(after_help = crate::cli::examples::DATASET_VERIFY)]
    Verify {
        dir: PathBuf,
        /// Rig configuration whose press limit the rows are checked against (default:
        /// $RIG_CONFIG, then ./rig.toml; none: the sensor's default limit).
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Write the dataset's rows (sorted by pose_id) in another tool's CSV dialect, or the
    /// datasets under DIR as a LeRobot v3 dataset.
    #[command(after_help = crate::cli::examples::DATASET_EXPORT)]
    Export {
        dir: PathBuf,
        #[arg(long, value_enum)]
        format: Format,
        /// Output CSV (default: standard output); for lerobot, the output folder (required,
        /// absent or empty).
        #[arg(long)]
        out: Option<PathBuf>,
        /// lerobot only: meta/info.json's fps; frame i of an episode is stamped i / fps s.
        #[arg(long, default_value_t = 1)]
        fps: u32,
        /// lerobot only: the task text of every episode (default: "press the <sensors>
        /// against the <object>").
        #[arg(long)]
        task: Option<String>,
        /// lerobot only: meta/info.json's robot_type (default: from the capture chain's arm).
        #[arg(long)]
        robot_type: Option<String>,
        /// lerobot only: the bound on each parquet file, MB of 10^6 bytes (LeRobot's
        /// data_files_size_in_mb); a data file is closed before a frame would take it past the
        /// bound, and an episode ends with it.
        #[arg(long, default_value_t = crate::dataset::LEROBOT_FILE_MB, value_name = "MB",
              value_parser = clap::value_parser!(u64).range(1..=crate::dataset::LEROBOT_MAX_FILE_MB))]
        max_file_mb: u64,
        /// MDS obj_id column.
        #[arg(long, default_value = "1")]
        obj_id: String,
        /// MDS only: also copy images to DIR as <obj_id>_<sensor>_<i>.png (MultiDiffSense's
        /// tactile/<obj>/<Sensor>/target/ naming).
        #[arg(long, value_name = "DIR")]
        images_out: Option<PathBuf>,
    },
    /// Read an MDS CSV. With --out, write a rig dataset of the rows whose image is found in
    /// --images (as <image_name> or <obj_id>_<sensor>_<i>.png); the MDS pose_id becomes the
    /// dataset's pose_id. Without --out, print the poses.
    #[command(after_help = crate::cli::examples::DATASET_IMPORT)]
    Import {
        csv: PathBuf,
        #[arg(long)]
        out: Option<PathBuf>,
        /// Folder holding the images.
        #[arg(long)]
        images: Option<PathBuf>,
        /// The sensor (tactip, vitac or vitactip, any case); its images are looked for as
        /// <obj_id>_<Label>_<i>.png with Label TacTip, ViTac or ViTacTip.
        #[arg(long, default_value = "tactip")]
        sensor: SensorKind,
        /// Object name for the manifest (default: the obj_id column).
        #[arg(long)]
        object: Option<String>,
        /// STL file of the object (hashed into the manifest).
        #[arg(long)]
        stl: Option<PathBuf>,
        /// Continue an interrupted import into --out (rows already there are skipped).
        #[arg(long)]
        resume: bool,
    },
    /// Join datasets (e.g. synth shards) into OUT, refusing conflicting rows.
    #[command(after_help = crate::cli::examples::DATASET_MERGE)]
    Merge {
        /// Output dataset (created when absent).
        #[arg(long)]
        out: PathBuf,
        /// Input datasets.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Merge even when the result would hold frames of a real rig and of the simulated
        /// rig (rows of source real and simulated).
        #[arg(long)]
        allow_mixed: bool,
    },
}

/// The rows of the dataset at `dir` that press past the press limit of its sensor: the limit
/// `config` sets (`[sensors.<name>] max_indentation_mm`), else the sensor's default, in the
/// work frame its manifest recorded (else `config`'s). Nothing when the manifest is unreadable
/// (verify reports that).
fn rows_past_press_limit(dir: &Path, config: &crate::config::RigConfig) -> anyhow::Result<Vec<crate::dataset::VerifyIssue>> {
    let Ok(manifest) = Manifest::load(dir) else { return Ok(Vec::new()) };
    let limit = config.press_limit(manifest.sensor);
    let work_frame = manifest.work_frame.unwrap_or(config.work_frame);
    let rows = crate::dataset::press_limit::rows_past_press_limit(dir, &work_frame, limit.max_indentation_mm, &limit.to_string())
        .with_context(|| format!("verifying {}", dir.display()))?;
    Ok(rows)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        DatasetCommand::Verify { dir, config } => {
            let config = crate::config::RigConfig::discover(config.as_deref())?;
            let mut report = verify(&dir).with_context(|| format!("verifying {}", dir.display()))?;
            report.issues.extend(rows_past_press_limit(&dir, &config)?);
            // The details, the audit's summary, then the verdict naming the dataset last.
            let text = report.to_string();
            let details = text.strip_suffix(report.verdict()).unwrap_or(&text);
            print!("{}: {details}", dir.display());
            if let Ok(Manifest { audit: Some(audit), .. }) = Manifest::load(&dir) {
                for line in audit.lines() {
                    println!("{line}");
                }
            }
            println!("{}: {}", dir.display(), report.verdict());
            if !report.is_clean() {
                bail!("{} is not clean ({} issues)", dir.display(), report.issues.len());
            }
            Ok(())
        }
        #[cfg(not(feature = "lerobot"))]
        DatasetCommand::Export { format: Format::Lerobot, .. } => {
            use crate::features::{Feature, FeatureMissing};
            Err(FeatureMissing { feature: Feature::Lerobot, needed_by: "`rig dataset export --format lerobot`" }.into())
        }
        #[cfg(feature = "lerobot")]
        DatasetCommand::Export { dir, format: Format::Lerobot, out, fps, task, robot_type, max_file_mb, .. } => {
            let Some(out) = out else { bail!(crate::cli::usage("--format lerobot needs --out DIR (a new folder)")) };
            let options = LerobotOptions { fps, task, robot_type, max_file_mb };
            let s = export_lerobot(&dir, &out, &options).with_context(|| format!("exporting {} as LeRobot", dir.display()))?;
            let sensors: Vec<&str> = s.sensors.iter().map(|k| k.name()).collect();
            let largest_mb = s.data_files.iter().map(|f| f.bytes).max().unwrap_or(0) as f64 / 1e6;
            println!(
                "wrote a LeRobot v3 dataset to {}: {} episode{}, {} frames, image keys for {}{}",
                out.display(),
                s.episodes,
                if s.episodes == 1 { "" } else { "s" },
                s.frames,
                sensors.join(", "),
                if s.reencoded > 0 { format!(" ({} images re-encoded as 8-bit RGB)", s.reencoded) } else { String::new() }
            );
            println!(
                "{} data file{}, the largest {largest_mb:.1} MB (at most {max_file_mb} MB each)",
                s.data_files.len(),
                if s.data_files.len() == 1 { "" } else { "s" }
            );
            Ok(())
        }
        DatasetCommand::Export { dir, format, out, obj_id, images_out, .. } => {
            export(&dir, format, out.as_deref(), &obj_id, images_out.as_deref())
        }
        DatasetCommand::Import { csv, out, images, sensor, object, stl, resume } => {
            let target = ImportTarget { out, images, sensor, object, stl, resume };
            import(&csv, &target)
        }
        DatasetCommand::Merge { out, inputs, allow_mixed } => {
            let report = merge(&inputs, &out, MergeOptions { allow_mixed }).with_context(|| format!("merging into {}", out.display()))?;
            println!(
                "merged {} datasets into {}: {} rows appended, {} already present",
                report.inputs,
                out.display(),
                report.appended,
                report.already_present
            );
            Ok(())
        }
    }
}

fn export(dir: &Path, format: Format, out: Option<&Path>, obj_id: &str, images_out: Option<&Path>) -> anyhow::Result<()> {
    let manifest = Manifest::load(dir)?;
    let mut rows = read_rows(dir)?;
    rows.sort_by_key(|r| r.pose_id);
    let mut buf = Vec::new();
    match format {
        Format::Mds => {
            export_mds(&mds_rows_from(&rows, obj_id), &mut buf)?;
            if let Some(img_dir) = images_out {
                if !durable::is_plain_file_name(obj_id) {
                    bail!(crate::cli::usage(&format!(
                        "--obj-id {obj_id:?} becomes part of file names: give a plain name (no `/`, no `..`)"
                    )));
                }
                std::fs::create_dir_all(img_dir).with_context(|| format!("creating {}", img_dir.display()))?;
                // Images are read as regular files inside the dataset (never through a symlink)
                // and written atomically, so a symlink in --images-out is replaced, not followed.
                durable::entry_exists(&dir.join(crate::dataset::IMAGES_DIR), durable::Kind::Folder)?;
                let root = crate::confine::RootDir::open(dir)?;
                for (i, r) in rows.iter().enumerate() {
                    let name = format!("{obj_id}_{}_{i}.png", manifest.sensor.label());
                    let bytes = root.read(&r.image, durable::MAX_IMAGE_BYTES)?;
                    durable::write_atomic(img_dir, &name, &bytes)
                        .with_context(|| format!("copying to {}", img_dir.join(&name).display()))?;
                }
            }
        }
        Format::TactileBench => export_tactile_bench(&rows, &manifest.object.name, &mut buf)?,
        Format::Lerobot => bail!("the LeRobot export writes a folder, not a CSV"),
    }
    match out {
        Some(path) => {
            // Replaced whole or not at all (a symlink there is replaced, not written through).
            let (folder, name) = crate::confine::open_parent(path)?;
            folder.write_atomic(&name, &buf).with_context(|| format!("writing {}", path.display()))?;
            eprintln!("wrote {} rows to {}", rows.len(), path.display());
        }
        None => std::io::stdout().write_all(&buf)?,
    }
    Ok(())
}

/// Where and how `rig dataset import` writes.
struct ImportTarget {
    out: Option<PathBuf>,
    images: Option<PathBuf>,
    sensor: SensorKind,
    object: Option<String>,
    stl: Option<PathBuf>,
    resume: bool,
}

fn import(csv: &Path, target: &ImportTarget) -> anyhow::Result<()> {
    let rows = import_mds(csv)?;
    println!("{}: {} filled rows", csv.display(), rows.len());
    let Some(out) = target.out.as_deref() else {
        println!("{:>8} {:>12} {:>12} {:>12} {:>12}  image_name", "pose_id", "x_mm", "y_mm", "z_mm", "yaw_deg");
        for r in &rows {
            let p = r.work_pose();
            println!("{:>8} {:>12.6} {:>12.6} {:>12.6} {:>12.6}  {}", r.pose_id, p.x_mm, p.y_mm, p.z_mm, p.yaw_deg, r.image_name);
        }
        return Ok(());
    };
    let Some(images) = target.images.as_deref() else { bail!("--out needs --images: a dataset row needs its image") };
    let sensor = target.sensor;
    let obj_name = target.object.clone().or_else(|| rows.first().map(|r| r.obj_id.clone())).unwrap_or_default();
    let object = match &target.stl {
        Some(stl) => ObjectInfo::with_stl(&obj_name, stl, out)?,
        None => ObjectInfo::named(&obj_name),
    };
    let manifest = Manifest::new(sensor, object, None);
    let mut writer = DatasetWriter::start(out, manifest, target.resume)?;
    let (mut written, mut skipped) = (0, Vec::new());
    // The operator's --images folder; every image below it through the opener (no symlink,
    // a regular file, bounded), decoded with limits. The names are the CSV's plain file names.
    let images_root = crate::confine::RootDir::open(images)?;
    for r in rows.iter().filter(|r| !writer.done_ids().contains(&r.pose_id)).collect::<Vec<_>>() {
        let mut candidates = vec![r.image_name.clone()];
        if let Some(i) = r.frame_index() {
            candidates.push(format!("{}_{}_{i}.png", r.obj_id, sensor.label()));
        }
        let mut found = None;
        for name in candidates {
            if images_root.stat(&name)?.is_some() {
                found = Some(name);
                break;
            }
        }
        let Some(name) = found else {
            skipped.push(r.image_name.clone());
            continue;
        };
        let path = images.join(&name);
        let bytes = images_root.read(&name, durable::MAX_IMAGE_BYTES)?;
        let image = durable::decode_image(&bytes).map_err(|reason| crate::dataset::DatasetError::BadImage { path, reason })?.to_rgb8();
        writer.append(pose_row_from_mds(r), &image)?;
        written += 1;
    }
    writer.finish()?;
    println!("wrote {written} rows to {}", out.display());
    if !skipped.is_empty() {
        println!("{} rows without an image were left out: {}", skipped.len(), skipped.join(", "));
    }
    Ok(())
}
