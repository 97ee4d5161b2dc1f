//! `rig objects`: the STL object library.
//!
//! ```text
//! rig objects generate [--out DIR]          # rewrite datasets/objects/*.stl from the shapes
//! rig objects contact-sheet --out PNG        # grid: objects (rows) x depth, control, sensors
//! ```

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args as ClapArgs, Subcommand};
use image::{GrayImage, Rgb, RgbImage, imageops};

use super::sensor_bridge::{render_tactile, simulator_available};
use crate::calibration::Calibration;
use crate::geometry::DepthMap;
use crate::geometry::control::control_image;
use crate::geometry::objects::{OBJECTS_DIR, generate_library, load_object, object_names};
use crate::geometry::raster::render_depth;
use crate::pose::Pose;
use crate::sensor::SensorKind;

#[derive(Debug, ClapArgs)]
pub struct Args {
    #[command(subcommand)]
    pub command: ObjectsCommand,
}

#[derive(Debug, Subcommand)]
pub enum ObjectsCommand {
    /// Write every library object as binary STL.
    #[command(after_help = crate::cli::examples::OBJECTS_GENERATE)]
    Generate {
        /// Output folder.
        #[arg(long, default_value = OBJECTS_DIR)]
        out: PathBuf,
    },
    /// One PNG grid: a row per object; columns depth, control, TacTip, ViTac, ViTacTip.
    #[command(after_help = crate::cli::examples::OBJECTS_CONTACT_SHEET)]
    ContactSheet {
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// Sensor pose for every tile: x,y,z,yaw.
        #[arg(long, default_value = "0,0,1.5,0", allow_hyphen_values = true)]
        pose: Pose,
        /// Rendered size of each image before it is shrunk into its tile, px.
        #[arg(long, default_value_t = 512)]
        render_size: u32,
        /// Tile edge length in the sheet, px.
        #[arg(long, default_value_t = 192)]
        tile: u32,
        /// Folder with `mds-example-<sensor>.toml` calibrations used for the sensor columns
        /// (the default calibration where a file is missing).
        #[arg(long, default_value = "calibration")]
        calibration_dir: PathBuf,
    },
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        ObjectsCommand::Generate { out } => {
            let written = generate_library(&out)?;
            for p in &written {
                println!("wrote {}", p.display());
            }
            Ok(())
        }
        ObjectsCommand::ContactSheet { out, pose, render_size, tile, calibration_dir } => {
            let sheet = contact_sheet(&pose, render_size, tile, &calibration_dir)?;
            sheet.save(&out).with_context(|| format!("writing {}", out.display()))?;
            println!(
                "wrote {} ({} objects x [depth, control, {}]; {}x{} px)",
                out.display(),
                object_names().len(),
                SensorKind::ALL.map(|s| s.label()).join(", "),
                sheet.width(),
                sheet.height()
            );
            if !simulator_available() {
                println!("note: sensor simulator not available in this build; the sensor columns are grey");
            }
            Ok(())
        }
    }
}

/// Depth map as 8-bit grey for viewing: the skin plane is mid-grey, +-5 mm span the range,
/// background black.
pub fn depth_preview(depth: &DepthMap) -> RgbImage {
    let g = GrayImage::from_fn(depth.width, depth.height, |x, y| {
        let h = depth.get(x, y).unwrap_or(DepthMap::BACKGROUND_MM);
        let v = if h <= DepthMap::BACKGROUND_MM { 0.0 } else { (128.0 + h * 25.0).clamp(1.0, 255.0) };
        image::Luma([v as u8])
    });
    imageops::colorops::grayscale_with_type::<Rgb<u8>, _>(&g)
}

/// Calibration for a sensor column: `<dir>/mds-example-<sensor>.toml` or the default.
fn sensor_calibration(dir: &Path, sensor: SensorKind, size: u32) -> anyhow::Result<Calibration> {
    let path = dir.join(format!("mds-example-{sensor}.toml"));
    if path.is_file() {
        let mut c = Calibration::load(&path)?.scaled_to(size, size);
        // The sheet shows objects centred; a dataset's pose correction does not apply here.
        c.pose_xy_correction = None;
        Ok(c)
    } else {
        Ok(Calibration::default_for(size, size))
    }
}

/// Renders the contact sheet (see [`ObjectsCommand::ContactSheet`]).
pub fn contact_sheet(pose: &Pose, render_size: u32, tile: u32, calibration_dir: &Path) -> anyhow::Result<RgbImage> {
    let names = object_names();
    let cols = 2 + SensorKind::ALL.len() as u32;
    let gap = 4;
    let mut sheet = RgbImage::from_pixel(cols * (tile + gap) + gap, names.len() as u32 * (tile + gap) + gap, Rgb([255, 255, 255]));
    let base_calib = Calibration::default_for(render_size, render_size);
    for (row, name) in names.iter().enumerate() {
        let mesh = load_object(name)?;
        let depth = render_depth(&mesh, pose, &base_calib, render_size, render_size, 2);
        let mut tiles = vec![depth_preview(&depth), control_image(&depth)];
        for sensor in SensorKind::ALL {
            let calib = sensor_calibration(calibration_dir, sensor, render_size)?;
            let d = render_depth(&mesh, pose, &calib, render_size, render_size, 2);
            tiles.push(
                render_tactile(sensor, &d, &calib, row as u64)
                    .unwrap_or_else(|_| RgbImage::from_pixel(render_size, render_size, Rgb([96, 96, 96]))),
            );
        }
        for (col, img) in tiles.iter().enumerate() {
            let small = imageops::resize(img, tile, tile, imageops::FilterType::Triangle);
            let x = gap + col as u32 * (tile + gap);
            let y = gap + row as u32 * (tile + gap);
            imageops::replace(&mut sheet, &small, x as i64, y as i64);
        }
    }
    Ok(sheet)
}
