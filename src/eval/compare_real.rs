//! Compare-real: rendered frames against real frames of logged poses, beside the pose-blind
//! baseline. `rig compare-real` runs it on the MultiDiffSense example with the sensor
//! simulator as the renderer.
//!
//! - [`RealSample`]: one object of a MultiDiffSense-layout folder ([`RealSample::object_ids`]
//!   lists them; any number of objects and of frames): the real frames per sensor, their poses
//!   from the MDS pose log (read by
//!   [`crate::dataset::export`], whose docs fix the depth convention: indentation =
//!   [`MDS_CONTACT_DEPTH_MM`] minus the logged z) and the object's mesh.
//! - [`compare_sensor`] renders each frame's pose through a calibration with a [`Renderer`]
//!   (the caller's: compare-real itself knows no simulator) and scores it with SSIM against the
//!   real frame, over the whole frame and over the contact region, next to the pose-blind
//!   baseline (the mean of the sensor's other real frames).
//! - No-contact look: per pixel, the median of the sensor's real frames whose rendered
//!   footprint (dilated by [`FOOTPRINT_MARGIN_PX`]) does not cover that pixel (all frames where
//!   every frame covers it); the sample has no real no-contact frame.
//! - Contact region of a frame: pixels whose summed absolute RGB difference from the
//!   no-contact look exceeds [`CONTACT_THRESHOLD`]. Footprint IoU: its overlap with the rendered
//!   footprint, a check of the calibration independent of the renderer.
//! - The renderer may start from a measured no-contact look: the per-pixel median of the
//!   sensor's *other* real frames ([`simulator_reference`], leave one out).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage, imageops};

use crate::calibration::model::Calibration;
use crate::dataset::DatasetError;
use crate::dataset::export::{MDS_CONTACT_DEPTH_MM, MdsRow, import_mds};
use crate::geometry::DepthMap;
use crate::geometry::raster::render_depth;
use crate::geometry::stl::{Mesh, StlError};
use crate::imaging::{difference_mask, dilate_mask, iou, mean_image, median_image, median_image_excluding};
use crate::metrics::{MetricsError, ssim, ssim_masked};
use crate::pose::Pose;
use crate::sensor::SensorKind;

/// Margin around a rendered footprint that counts as "touched" for the no-contact estimate, px.
pub const FOOTPRINT_MARGIN_PX: u32 = 16;
/// Summed |RGB| difference from the no-contact look that makes a pixel part of the contact region.
pub const CONTACT_THRESHOLD: u32 = 60;
/// Most frames read per object and sensor (the per-pixel statistics hold them all in memory).
pub const MAX_FRAMES_PER_SENSOR: usize = 1000;
/// Frames smaller than this on a side are refused.
const MIN_SIDE_PX: u32 = 16;

/// Why a comparison cannot run.
#[derive(Debug, thiserror::Error)]
pub enum CompareRealError {
    #[error(transparent)]
    Mesh(#[from] StlError),
    #[error(transparent)]
    PoseLog(#[from] DatasetError),
    #[error("{path}: image_name {name:?} is not frame_<i>_0.png")]
    FrameName { path: PathBuf, name: String },
    #[error("reading {path}: {source}")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("{path}: {width}x{height} differs from the sensor's other frames ({expected_width}x{expected_height})")]
    FrameSize { path: PathBuf, width: u32, height: u32, expected_width: u32, expected_height: u32 },
    #[error("{path}: {width}x{height} is too small to compare")]
    TooSmall { path: PathBuf, width: u32, height: u32 },
    #[error("no pose row for frame {index} (its image is there, the pose log has no frame_{index}_0.png)")]
    NoPose { index: usize },
    #[error("{dir}: no object found (a MultiDiffSense-layout folder has csv/<id>.csv and stl/<id>.stl for each object)")]
    NoObjects { dir: PathBuf },
    #[error("{dir}: more than {max} frames; compare fewer at a time")]
    TooManyFrames { dir: PathBuf, max: usize },
    #[error("listing {path}: {source}")]
    ReadDir {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{sensor}: need at least two real frames, have {frames}")]
    TooFewFrames { sensor: &'static str, frames: usize },
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    #[error("creating {path}: {source}")]
    CreateDir {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("writing {path}: {source}")]
    Write {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

/// One object of a real sample: the object, the pose log and the frames (MultiDiffSense's
/// layout: `stl/<id>.stl`, `csv/<id>.csv`, `tactile/<id>/<Sensor>/target/<id>_<Sensor>_<i>.png`
/// for any frame indices `i`).
pub struct RealSample {
    /// The object id (`1`): the stem of its CSV and STL files.
    pub object: String,
    pub mesh: Mesh,
    /// The pose log's rows by image index.
    pub rows: BTreeMap<usize, MdsRow>,
    /// Frames per sensor, (image index, image), in index order; all of one size per sensor.
    pub frames: BTreeMap<SensorKind, Vec<(usize, RgbImage)>>,
}

impl RealSample {
    /// The object ids of a MultiDiffSense-layout folder: the stems of `csv/<id>.csv` that have
    /// an `stl/<id>.stl`, in order (numerically when both are numbers).
    pub fn object_ids(dir: &Path) -> Result<Vec<String>, CompareRealError> {
        let csv_dir = dir.join("csv");
        let mut ids: Vec<String> = list_dir(&csv_dir)?
            .into_iter()
            .filter_map(|name| name.strip_suffix(".csv").map(str::to_string))
            .filter(|id| !id.is_empty() && !id.starts_with('.') && dir.join("stl").join(format!("{id}.stl")).is_file())
            .collect();
        ids.sort_by(|a, b| match (a.parse::<u64>(), b.parse::<u64>()) {
            (Ok(x), Ok(y)) => x.cmp(&y),
            _ => a.cmp(b),
        });
        Ok(ids)
    }

    /// Loads the first object of the folder ([`Self::object_ids`]).
    pub fn load(dir: &Path) -> Result<Self, CompareRealError> {
        let ids = Self::object_ids(dir)?;
        let id = ids.first().ok_or_else(|| CompareRealError::NoObjects { dir: dir.to_path_buf() })?;
        Self::load_object(dir, id)
    }

    /// Loads object `id` of the folder: every frame `tactile/<id>/<Sensor>/target/<id>_<Sensor>_<i>.png`
    /// there is, for each sensor (a sensor without a folder has no frames).
    pub fn load_object(dir: &Path, id: &str) -> Result<Self, CompareRealError> {
        let mesh = Mesh::load(dir.join(format!("stl/{id}.stl")))?;
        let csv = dir.join(format!("csv/{id}.csv"));
        let mut rows = BTreeMap::new();
        for row in import_mds(&csv)? {
            let index = row.frame_index().ok_or_else(|| CompareRealError::FrameName { path: csv.clone(), name: row.image_name.clone() })?;
            rows.insert(index as usize, row);
        }
        let mut frames = BTreeMap::new();
        for sensor in SensorKind::ALL {
            let name = sensor.label();
            let target = dir.join(format!("tactile/{id}/{name}/target"));
            let prefix = format!("{id}_{name}_");
            let mut indices: Vec<usize> = if target.is_dir() {
                list_dir(&target)?.iter().filter_map(|f| f.strip_prefix(&prefix)?.strip_suffix(".png")?.parse::<usize>().ok()).collect()
            } else {
                Vec::new()
            };
            indices.sort_unstable();
            indices.dedup();
            if indices.len() > MAX_FRAMES_PER_SENSOR {
                return Err(CompareRealError::TooManyFrames { dir: target, max: MAX_FRAMES_PER_SENSOR });
            }
            let mut list: Vec<(usize, RgbImage)> = Vec::new();
            for i in indices {
                let path = target.join(format!("{prefix}{i}.png"));
                // Below the sample folder with no symlink, bounded, pixel count checked first.
                let rel = format!("tactile/{id}/{name}/target/{prefix}{i}.png");
                let bytes = crate::dataset::durable::read_below(dir, Path::new(&rel), crate::dataset::durable::MAX_IMAGE_BYTES)?;
                let img = crate::dataset::durable::decode_image(&bytes)
                    .map_err(|reason| crate::dataset::DatasetError::BadImage { path: path.clone(), reason })?
                    .to_rgb8();
                // The per-pixel statistics need one size per sensor.
                if let Some((_, first)) = list.first()
                    && first.dimensions() != img.dimensions()
                {
                    return Err(CompareRealError::FrameSize {
                        path,
                        width: img.width(),
                        height: img.height(),
                        expected_width: first.width(),
                        expected_height: first.height(),
                    });
                }
                if img.width() < MIN_SIDE_PX || img.height() < MIN_SIDE_PX {
                    return Err(CompareRealError::TooSmall { path, width: img.width(), height: img.height() });
                }
                list.push((i, img));
            }
            frames.insert(sensor, list);
        }
        Ok(Self { object: id.to_string(), mesh, rows, frames })
    }

    /// The frames of `sensor` (image index, image), in index order.
    pub fn frames_of(&self, sensor: SensorKind) -> &[(usize, RgbImage)] {
        self.frames.get(&sensor).map(Vec::as_slice).unwrap_or(&[])
    }

    /// The work-frame pose of frame `index` in rig's convention (z = the indentation beyond
    /// the contact depth, [`MdsRow::work_pose`]).
    pub fn work_pose(&self, index: usize) -> Result<Pose, CompareRealError> {
        self.rows.get(&index).map(MdsRow::work_pose).ok_or(CompareRealError::NoPose { index })
    }

    /// The render pose of frame `index` (z = the skin indentation, [`MdsRow::render_pose`] at
    /// [`MDS_CONTACT_DEPTH_MM`]).
    pub fn render_pose(&self, index: usize) -> Result<Pose, CompareRealError> {
        self.rows.get(&index).map(|r| r.render_pose(MDS_CONTACT_DEPTH_MM)).ok_or(CompareRealError::NoPose { index })
    }

    /// The frames of `sensor` named as on disk (`<id>_<Sensor>_<i>.png`) with their pose:
    /// `pose_of` is [`Self::work_pose`] or [`Self::render_pose`].
    pub fn posed_frames(
        &self,
        sensor: SensorKind,
        pose_of: impl Fn(&Self, usize) -> Result<Pose, CompareRealError>,
    ) -> Result<Vec<(String, Pose, RgbImage)>, CompareRealError> {
        self.frames_of(sensor)
            .iter()
            .map(|(i, img)| Ok((format!("{}_{}_{i}.png", self.object, sensor.label()), pose_of(self, *i)?, img.clone())))
            .collect()
    }
}

/// What is compared with the real frames: renders what `sensor` shows for a depth map through
/// a calibration, with a noise seed, starting from a measured no-contact look when one is
/// given; `None` when it cannot render.
pub type Renderer<'a> = dyn Fn(&DepthMap, &Calibration, u64, Option<&RgbImage>) -> Option<RgbImage> + 'a;

/// Scores of one frame. The renderer's columns are `None` when it could not render.
#[derive(Debug, Clone, Copy)]
pub struct FrameScores {
    pub index: usize,
    /// Share of the frame in the contact region.
    pub contact_fraction: f64,
    /// Overlap of the contact region with the rendered footprint.
    pub footprint_iou: f64,
    pub baseline_whole: f64,
    pub baseline_contact: f64,
    pub sim_whole: Option<f64>,
    pub sim_contact: Option<f64>,
}

/// How [`compare_sensor`] runs.
#[derive(Debug, Clone, Default)]
pub struct CompareOptions {
    /// Start the renderer from the measured no-contact look of the other frames
    /// ([`simulator_reference`]); otherwise it renders its own modelled look.
    pub measured_reference: bool,
    /// Write side-by-side panels (real | baseline | footprint | contact region | rendered) and
    /// the no-contact look into this folder.
    pub panels: Option<PathBuf>,
}

/// The measured no-contact look the renderer starts from: the per-pixel median of the *other*
/// real frames of the sensor only (leave one out: the renderer never sees the frame it is
/// scored on, and has the same information as the baseline). One median over the same frames
/// everywhere keeps the pins whole (they shift a little between frames; switching frame sets
/// per pixel, as the footprint-aware no-contact look does, tears them).
pub fn simulator_reference(others: &[&RgbImage]) -> RgbImage {
    median_image(others)
}

/// Compares one sensor's frames with what `render` makes of their poses through `calib`.
pub fn compare_sensor(
    sample: &RealSample,
    sensor: SensorKind,
    calib: &Calibration,
    render: &Renderer,
    options: &CompareOptions,
) -> Result<Vec<FrameScores>, CompareRealError> {
    let list = sample.frames_of(sensor);
    if list.len() < 2 {
        return Err(CompareRealError::TooFewFrames { sensor: sensor.label(), frames: list.len() });
    }
    let (w, h) = list[0].1.dimensions();
    let calib = calib.scaled_to(w, h);
    let mut depths = Vec::new();
    let mut footprints = Vec::new();
    for (i, _) in list {
        let d = render_depth(&sample.mesh, &sample.render_pose(*i)?, &calib, w, h, 2);
        footprints.push(d.height_mm.iter().map(|&v| v > 0.0).collect::<Vec<bool>>());
        depths.push(d);
    }
    let covered: Vec<Vec<bool>> = footprints.iter().map(|f| dilate_mask(f, w as usize, h as usize, FOOTPRINT_MARGIN_PX as usize)).collect();
    let all: Vec<&RgbImage> = list.iter().map(|(_, img)| img).collect();
    let no_contact = median_image_excluding(&all, &covered);
    if let Some(dir) = &options.panels {
        std::fs::create_dir_all(dir).map_err(|source| CompareRealError::CreateDir { path: dir.clone(), source })?;
    }
    let mut scores = Vec::new();
    for (k, (index, real)) in list.iter().enumerate() {
        let others: Vec<&RgbImage> = all.iter().enumerate().filter(|(j, _)| *j != k).map(|(_, f)| *f).collect();
        let baseline = mean_image(&others);
        let mask = difference_mask(real, &no_contact, CONTACT_THRESHOLD);
        let contact_fraction = mask.iter().filter(|&&m| m).count() as f64 / mask.len() as f64;
        let reference = options.measured_reference.then(|| simulator_reference(&others));
        let sim = render(&depths[k], &calib, *index as u64, reference.as_ref());
        let masked = |img: &RgbImage| ssim_masked(real, img, &mask).ok();
        scores.push(FrameScores {
            index: *index,
            contact_fraction,
            footprint_iou: iou(&footprints[k], &mask),
            baseline_whole: ssim(real, &baseline)?,
            baseline_contact: masked(&baseline).unwrap_or(f64::NAN),
            sim_whole: sim.as_ref().map(|s| ssim(real, s)).transpose()?,
            sim_contact: sim.as_ref().and_then(masked),
        });
        if let Some(dir) = &options.panels {
            let name = format!("{}_{sensor}_{index}.png", sample.object);
            save(&panel(real, &baseline, &footprints[k], &mask, sim.as_ref()), &dir.join(name))?;
        }
    }
    if let Some(dir) = &options.panels {
        save(&no_contact, &dir.join(format!("{}_{sensor}_no_contact.png", sample.object)))?;
    }
    Ok(scores)
}

/// The names of the entries of `dir`, sorted (names that are not UTF-8 are left out).
fn list_dir(dir: &Path) -> Result<Vec<String>, CompareRealError> {
    let err = |source| CompareRealError::ReadDir { path: dir.to_path_buf(), source };
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(err)? {
        if let Ok(name) = entry.map_err(err)?.file_name().into_string() {
            names.push(name);
        }
    }
    names.sort();
    Ok(names)
}

fn save(image: &RgbImage, path: &Path) -> Result<(), CompareRealError> {
    image.save(path).map_err(|source| CompareRealError::Write { path: path.to_path_buf(), source })
}

/// real | baseline | real with footprint outline | contact region | rendered (if any).
fn panel(real: &RgbImage, baseline: &RgbImage, footprint: &[bool], mask: &[bool], sim: Option<&RgbImage>) -> RgbImage {
    let (w, h) = real.dimensions();
    let mut overlay = real.clone();
    for (i, px) in overlay.pixels_mut().enumerate() {
        if footprint[i] {
            px.0 = [px.0[0] / 2 + 127, px.0[1] / 2, px.0[2] / 2];
        }
    }
    let region = RgbImage::from_fn(w, h, |x, y| {
        let i = (y * w + x) as usize;
        match (mask[i], footprint[i]) {
            (true, true) => Rgb([255, 255, 255]),
            (true, false) => Rgb([0, 160, 255]),
            (false, true) => Rgb([255, 60, 0]),
            (false, false) => Rgb([0, 0, 0]),
        }
    });
    let mut tiles = vec![real.clone(), baseline.clone(), overlay, region];
    if let Some(s) = sim {
        tiles.push(s.clone());
    }
    let mut out = RgbImage::new(w * tiles.len() as u32, h);
    for (k, t) in tiles.iter().enumerate() {
        imageops::replace(&mut out, t, (k as u32 * w) as i64, 0);
    }
    out
}
