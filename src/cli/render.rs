//! `rig render`: one image of an object under a sensor at a pose.
//!
//! ```text
//! rig render (--object NAME | --stl PATH) --pose x,y,z,yaw \
//!     --sensor tactip|vitac|vitactip|depth|control [--calibration FILE] [--size WxH] --out PNG
//! ```
//!
//! `depth` writes the 16-bit depth PNG, `control` the MultiDiffSense control image, the
//! tactile sensors go through the sensor simulator. `--reference FRAME` (a tactile sensor
//! only) starts the simulator from a measured no-contact frame of the real sensor, of the
//! output's size: it adds only the contact to it (`SensorSim::with_reference`).
//!
//! ```text
//! rig render --controls-of DATASET [--size WxH] [--supersample N] --out DIR
//! ```
//!
//! writes, for every row of a collected dataset, the control image `rig synth --fill-missing`
//! would feed the model for that pose (`DIR/<pose_id>.png`, through
//! [`crate::synth::fill::ControlRenderer`]) and its MultiDiffSense prompt
//! (`DIR/prompts.csv`: pose_id, sensor, prompt): the training pairs of a synthesis model
//! (`tools/train/`), so training and synthesis see identical hints and prompts.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use anyhow::{Context, bail};
use clap::Args as ClapArgs;

use image::GenericImageView;
use rayon::prelude::*;

use super::sensor_bridge::{render_tactile, render_tactile_with};
use super::usage;
use crate::calibration::Calibration;
use crate::dataset::durable::MAX_IMAGE_BYTES;
use crate::dataset::{Manifest, read_rows};
use crate::geometry::control::{control_image, depth_png16};
use crate::geometry::objects::load_object;
use crate::geometry::raster::render_depth;
use crate::geometry::stl::Mesh;
use crate::pose::Pose;
use crate::sensor::SensorKind;
use crate::sim::sensor::Scene;
use crate::synth::fill::{ControlRenderer, ControlScratch};
use crate::synth::prompt::mds_prompt;

/// What `rig render` produces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum View {
    /// 16-bit depth PNG (see `geometry::control`).
    Depth,
    /// MultiDiffSense control image (viridis, RGB8).
    Control,
    /// A simulated tactile sensor image.
    Tactile(SensorKind),
}

impl FromStr for View {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "depth" => Ok(View::Depth),
            "control" => Ok(View::Control),
            other => other
                .parse::<SensorKind>()
                .map(View::Tactile)
                .map_err(|_| format!("unknown sensor {s:?}; expected tactip, vitac, vitactip, depth or control")),
        }
    }
}

/// An image size written `WxH`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageSize {
    pub width: u32,
    pub height: u32,
}

impl FromStr for ImageSize {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("size is written WxH, got {s:?}"))?;
        let parse = |v: &str| v.trim().parse::<u32>().ok().filter(|&n| (1..=8192).contains(&n));
        match (parse(w), parse(h)) {
            (Some(width), Some(height)) => Ok(ImageSize { width, height }),
            _ => Err(format!("size {s:?}: width and height must be integers in 1..=8192")),
        }
    }
}

#[derive(Debug, ClapArgs)]
#[command(group(clap::ArgGroup::new("mesh").required(true).args(["object", "stl", "controls_of"])))]
pub struct Args {
    /// Library object (`datasets/objects/NAME.stl`): edge, cuboid, sphere, pacman,
    /// hollow_cylinder, cross, cone, wedge.
    #[arg(long)]
    pub object: Option<String>,
    /// Any binary or ASCII STL file (mm).
    #[arg(long)]
    pub stl: Option<PathBuf>,
    /// A collected dataset (`.../<object>/<sensor>`): write the control image and prompt of
    /// every row into the folder --out, as `rig synth --fill-missing` renders them.
    #[arg(long, value_name = "DATASET")]
    pub controls_of: Option<PathBuf>,
    /// Sensor pose relative to the object's top centre: x,y,z,yaw (mm, mm, indentation mm, deg).
    #[arg(long, allow_hyphen_values = true, required_unless_present = "controls_of")]
    pub pose: Option<Pose>,
    /// tactip, vitac, vitactip, depth or control.
    #[arg(long, required_unless_present = "controls_of")]
    pub sensor: Option<View>,
    /// Calibration TOML (default: centred, about 8.5 px/mm at 512 px).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Image size WxH.
    #[arg(long, default_value = "512x512")]
    pub size: ImageSize,
    /// Samples per pixel along each axis for the depth render.
    #[arg(long, default_value_t = 2)]
    pub supersample: u32,
    /// Noise seed of the sensor simulator.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// A measured no-contact frame (PNG, of --size) for a tactile sensor to start from: the
    /// simulator keeps its look and adds only the contact.
    #[arg(long, value_name = "FRAME")]
    pub reference: Option<PathBuf>,
    /// Output PNG (with --controls-of: output folder).
    #[arg(long)]
    pub out: PathBuf,
}

/// Loads the mesh named by `--object` or `--stl`.
pub fn load_mesh(object: Option<&str>, stl: Option<&Path>) -> anyhow::Result<Mesh> {
    match (object, stl) {
        (Some(name), None) => load_object(name).with_context(|| format!("loading object {name:?}")),
        (None, Some(path)) => Mesh::load(path).map_err(anyhow::Error::from),
        _ => bail!("give exactly one of --object NAME or --stl PATH"),
    }
}

/// Loads `--calibration` (scaled to the image size) or the default for that size.
pub fn load_calibration(path: Option<&Path>, width: u32, height: u32) -> anyhow::Result<Calibration> {
    Ok(match path {
        Some(p) => Calibration::load(p)?.scaled_to(width, height),
        None => Calibration::default_for(width, height),
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(dataset) = &args.controls_of {
        return controls_of(dataset, args.size, args.supersample, &args.out);
    }
    // clap enforces both without --controls-of; these are for a hand-built Args.
    let (Some(pose), Some(sensor)) = (args.pose, args.sensor) else {
        return Err(usage("give --pose and --sensor (or --controls-of DATASET)").into());
    };
    let ImageSize { width, height } = args.size;
    let reference = match (&args.reference, sensor) {
        (None, _) => None,
        (Some(_), View::Depth | View::Control) => {
            return Err(usage("--reference applies to a tactile sensor (tactip, vitac, vitactip), not depth or control").into());
        }
        (Some(path), View::Tactile(_)) => Some(load_reference(path, width, height)?),
    };
    let mesh = load_mesh(args.object.as_deref(), args.stl.as_deref())?;
    let calib = load_calibration(args.calibration.as_deref(), width, height)?;
    let depth = render_depth(&mesh, &pose, &calib, width, height, args.supersample);
    let out = &args.out;
    match sensor {
        View::Depth => depth_png16(&depth).save(out),
        View::Control => control_image(&depth).save(out),
        View::Tactile(sensor) => match &reference {
            Some(r) => {
                let scene = Scene::preset("full")?;
                render_tactile_with(sensor, &depth, &calib, args.seed, &scene, Some(r), None)?.save(out)
            }
            None => render_tactile(sensor, &depth, &calib, args.seed)?.save(out),
        },
    }
    .with_context(|| format!("writing {}", out.display()))?;
    println!("wrote {} ({}x{}, {:?}, max indentation {:.3} mm)", out.display(), width, height, sensor, depth.max_indentation_mm());
    Ok(())
}

/// Reads `--reference`: a PNG of `width` x `height`, at most [`MAX_IMAGE_BYTES`] bytes; any
/// other file is a usage error naming it.
fn load_reference(path: &Path, width: u32, height: u32) -> anyhow::Result<image::RgbImage> {
    let bad = |why: String| anyhow::Error::new(usage(&format!("--reference {}: {why}", path.display())));
    let bytes = crate::confine::read_operator_file(path, MAX_IMAGE_BYTES).map_err(|e| bad(e.to_string()))?;
    let image = crate::dataset::durable::decode_image(&bytes).map_err(|e| bad(format!("not a readable image ({e})")))?;
    if image.dimensions() != (width, height) {
        return Err(bad(format!(
            "{}x{} px, the output is {width}x{height} (give --size {}x{})",
            image.width(),
            image.height(),
            image.width(),
            image.height()
        )));
    }
    Ok(image.to_rgb8())
}

/// Writes `image` as a PNG with fast compression (the control maps' flat regions compress
/// well at any level; the default level costs more than rendering them).
fn write_png_fast(image: &image::RgbImage, path: &Path) -> anyhow::Result<()> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut file = std::io::BufWriter::new(std::fs::File::create(path)?);
    PngEncoder::new_with_quality(&mut file, CompressionType::Fast, FilterType::Up).write_image(
        image.as_raw(),
        image.width(),
        image.height(),
        image::ExtendedColorType::Rgb8,
    )?;
    std::io::Write::flush(&mut file)?;
    Ok(())
}

/// `--controls-of`: the control image and prompt of every row of `dataset` into `out_dir`.
fn controls_of(dataset: &Path, size: ImageSize, supersample: u32, out_dir: &Path) -> anyhow::Result<()> {
    if !dataset.join("manifest.toml").is_file() {
        return Err(usage(&format!("{} is not a dataset (no manifest.toml)", dataset.display())).into());
    }
    let manifest = Manifest::load(dataset)?;
    let kind = manifest.sensor;
    let rows = read_rows(dataset)?;
    let renderer = ControlRenderer::for_dataset(dataset, &manifest, size.width, size.height, supersample)?;
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let mut prompts = csv::Writer::from_path(out_dir.join("prompts.csv"))
        .with_context(|| format!("writing {}", out_dir.join("prompts.csv").display()))?;
    prompts.write_record(["pose_id", "sensor", "prompt"])?;
    // The maps are independent: render and write them in parallel, one scratch per thread.
    rows.par_iter().try_for_each_init(ControlScratch::default, |scratch, row| -> anyhow::Result<()> {
        let path = out_dir.join(format!("{}.png", row.pose_id));
        let image = renderer.control_image_with(&row.commanded(), scratch);
        write_png_fast(&image, &path).with_context(|| format!("writing {}", path.display()))
    })?;
    for row in &rows {
        let pose = row.commanded();
        prompts.write_record([row.pose_id.to_string(), kind.label().to_string(), mds_prompt(kind, &pose)])?;
    }
    prompts.flush()?;
    println!(
        "wrote {} control images ({}x{}) and prompts.csv of {} into {}",
        rows.len(),
        size.width,
        size.height,
        dataset.display(),
        out_dir.display()
    );
    Ok(())
}
