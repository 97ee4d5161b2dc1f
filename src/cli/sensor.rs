//! `rig sensor render`: render one simulated sensor frame from an analytic object, optionally
//! next to a real image for look-matching.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Subcommand, ValueEnum};

use crate::sensor::SensorKind;
use crate::sim::sensor::{MotionState, Scene, SensorSim, shapes};

/// Arguments of `rig sensor`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: SensorCommand,
}

/// `rig sensor` subcommands.
#[derive(Debug, Subcommand)]
pub enum SensorCommand {
    /// Render one frame of a simulated sensor pressed on an analytic object.
    #[command(after_help = crate::cli::examples::SENSOR_RENDER)]
    Render(RenderArgs),
}

/// The analytic object to press.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Shape {
    /// Nothing: the reference (no-contact) frame.
    None,
    /// A half-plane edge.
    Edge,
    /// A flat bar like MultiDiffSense object 1 (33 x 4 mm at the rig's scale).
    Bar,
    /// A sphere of 6 mm radius.
    Sphere,
}

/// Arguments of `rig sensor render`.
#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    /// Sensor kind: tactip, vitac or vitactip.
    #[arg(long, default_value = "tactip")]
    pub kind: SensorKind,
    /// Scene: a preset (full, fast, minimal, none) or a TOML file.
    #[arg(long, default_value = "full")]
    pub scene: String,
    #[arg(long, default_value_t = 512)]
    pub width: u32,
    #[arg(long, default_value_t = 512)]
    pub height: u32,
    /// Image scale, px per mm (the rig's calibrated TacTip scale is about 8.5 at 512x512).
    #[arg(long, default_value_t = 8.5)]
    pub px_per_mm: f32,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Object to press.
    #[arg(long, value_enum, default_value = "bar")]
    pub shape: Shape,
    /// Object offset from the sensor centre, mm (image x right).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub x_mm: f32,
    /// Object offset from the sensor centre, mm (image y down).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub y_mm: f32,
    /// Object rotation in the image, deg.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub angle_deg: f32,
    /// Indentation, mm.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    pub indent_mm: f32,
    /// Image-space speed of the contact during the exposure, px/s (motion blur).
    #[arg(long, default_value_t = 0.0)]
    pub speed_px_per_s: f32,
    /// Exposure, s.
    #[arg(long, default_value_t = 0.016)]
    pub exposure_s: f32,
    /// Noise key of the frame.
    #[arg(long, default_value_t = 1)]
    pub frame_key: u64,
    /// Output PNG.
    #[arg(long, default_value = "sensor.png")]
    pub out: PathBuf,
    /// A real image to put on the left of the render (same height), for look-matching.
    #[arg(long)]
    pub side_by_side: Option<PathBuf>,
}

/// Runs `rig sensor`.
pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        SensorCommand::Render(a) => render(a),
    }
}

fn render(a: RenderArgs) -> anyhow::Result<()> {
    let scene = Scene::preset_or_file(&a.scene).with_context(|| format!("loading scene {:?}", a.scene))?;
    let sim = SensorSim::new(a.kind, scene, a.width, a.height, a.px_per_mm, a.seed);
    let (w, h, k) = (a.width.max(1), a.height.max(1), a.px_per_mm);
    let depth = match a.shape {
        Shape::None => crate::geometry::DepthMap::empty(w, h),
        Shape::Edge => shapes::straight_edge(w, h, k, a.x_mm, a.angle_deg, a.indent_mm),
        Shape::Bar => shapes::bar(w, h, k, a.x_mm, a.y_mm, a.angle_deg, 33.0, 4.0, a.indent_mm),
        Shape::Sphere => shapes::sphere(w, h, k, a.x_mm, a.y_mm, 6.0, a.indent_mm),
    };
    let motion = MotionState { speed_px_per_s: a.speed_px_per_s, direction_rad: 0.0, exposure_s: a.exposure_s };
    let t = std::time::Instant::now();
    let img = sim.render(&depth, &motion, a.frame_key);
    let render_ms = t.elapsed().as_secs_f64() * 1e3;
    let out = match &a.side_by_side {
        None => img,
        Some(real_path) => {
            // The operator's file, bounded and decoded with limits (a FIFO or a huge "image" is
            // refused before anything is read).
            let bytes = crate::confine::read_operator_file(real_path, crate::dataset::durable::MAX_IMAGE_BYTES)?;
            let real = crate::dataset::durable::decode_image(&bytes)
                .map_err(|reason| crate::dataset::DatasetError::BadImage { path: real_path.clone(), reason })?
                .to_rgb8();
            let real = image::imageops::resize(&real, real.width() * h / real.height().max(1), h, image::imageops::FilterType::Triangle);
            let mut both = image::RgbImage::new(real.width() + img.width(), h);
            image::imageops::replace(&mut both, &real, 0, 0);
            image::imageops::replace(&mut both, &img, real.width() as i64, 0);
            both
        }
    };
    out.save(&a.out).with_context(|| format!("writing {}", a.out.display()))?;
    println!(
        "{} {}x{} scene {} -> {} ({render_ms:.1} ms); stages run: {}",
        sim.kind().label(),
        w,
        h,
        sim.scene().name,
        a.out.display(),
        sim.stage_counts()
    );
    Ok(())
}
