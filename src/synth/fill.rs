//! Filling the poses a collection did not capture.
//!
//! The dataset's manifest names the plan (its full grid of pose ids), the object, the sensor,
//! the calibration and the work frame. Every grid pose without a row is synthesised: its
//! control image is rendered from the object's mesh at that pose through the calibration, its
//! prompt is the MultiDiffSense prompt of the sensor and pose, and its seed is
//! [`super::pose_seed`]`(plan seed, pose_id)`, so an image does not depend on
//! batching, order or sharding. A shard `i/n` takes the missing poses with
//! `pose_id % n == i - 1` and writes them to its own dataset directory, which
//! `rig dataset merge` joins later.
//!
//! The fill never orders the plan and reads no kept order (`order.csv`, see
//! [`crate::dataset::order`]): it moves no arm, so a visiting order saves nothing. It walks the
//! grid in pose-id order, which is what the shards split on, in O(grid) time and memory.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use image::RgbImage;

use super::{GenerateRequest, ImageRange, Pipeline, SchedulerKind, SynthError, pose_seed, prompt::mds_prompt};
use crate::calibration::model::Calibration;
use crate::dataset::{DatasetError, DatasetWriter, Manifest, PoseRow, SynthesisInfo, read_rows};
use crate::geometry::objects::load_object;
use crate::geometry::raster::PreparedMesh;
use crate::geometry::stl::Mesh;
use crate::plan::PlannedPose;
use crate::pose::Pose;

/// Errors of the fill job.
#[derive(Debug, thiserror::Error)]
pub enum FillError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Synth(#[from] SynthError),
    #[error("dataset {dir}: its manifest has no plan, so the missing poses are unknown")]
    NoPlan { dir: PathBuf },
    #[error("dataset {dir}: object {object}: {reason}")]
    Object { dir: PathBuf, object: String, reason: String },
    #[error("dataset {dir}: calibration {calibration}: {reason}")]
    Calibration { dir: PathBuf, calibration: String, reason: String },
}

use super::settings::defaults;
pub use super::settings::{Shard, TwinSize};

/// Sampler settings and work split of a fill.
#[derive(Debug, Clone)]
pub struct FillOptions {
    pub steps: usize,
    pub guidance: f32,
    pub eta: f32,
    pub scheduler: SchedulerKind,
    pub conditioning_scale: f32,
    pub shard: Shard,
    /// Poses per session call.
    pub batch: usize,
    /// Supersampling of the control image's depth map.
    pub supersample: u32,
    /// At most this many poses (after sharding); `None`: all.
    pub limit: Option<usize>,
    /// How the decoder's output becomes 8-bit pixels (before any resize to the frames' size).
    pub image_range: ImageRange,
}

impl Default for FillOptions {
    fn default() -> Self {
        Self {
            steps: defaults::STEPS,
            guidance: defaults::GUIDANCE,
            eta: 0.0,
            scheduler: SchedulerKind::Ddim,
            conditioning_scale: defaults::CONDITIONING_SCALE,
            shard: Shard::ALL,
            batch: defaults::BATCH,
            supersample: defaults::SUPERSAMPLE,
            limit: None,
            image_range: ImageRange::Clamp,
        }
    }
}

impl FillOptions {
    /// The model request of one image with these sampler settings: `control` and `prompt`,
    /// from noise seeded by `seed`.
    pub fn request<'a>(&self, control: &'a RgbImage, prompt: &'a str, seed: u64) -> GenerateRequest<'a> {
        let mut r = GenerateRequest::new(control, prompt);
        r.steps = self.steps;
        r.guidance = self.guidance;
        r.eta = self.eta;
        r.scheduler = self.scheduler;
        r.conditioning_scale = self.conditioning_scale;
        r.seed = seed;
        r
    }

    /// Checks every setting against [`super::limits`] (steps against the sampler's limit are
    /// checked once the package's schedule is known, before any image is made). Front ends call
    /// this before loading a model; [`fill_missing_observed`] calls it again.
    pub fn validate(&self) -> Result<(), SynthError> {
        super::limits::check_fill_settings(
            Some(self.steps),
            Some(self.guidance),
            Some(self.eta),
            self.conditioning_scale,
            self.batch,
            self.supersample,
        )?;
        Ok(())
    }
}

/// What a fill did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FillSummary {
    /// Grid poses of the plan.
    pub grid: usize,
    /// Poses the dataset already had (real or synthetic).
    pub present: usize,
    /// Poses this shard synthesised now.
    pub synthesised: usize,
    /// Missing poses left to other shards (or beyond the limit).
    pub left: usize,
    /// The model and sizes recorded in the manifest (`[synthesis]`).
    pub synthesis: SynthesisInfo,
}

/// What a dataset needs filled: its manifest and the missing grid poses of one shard.
pub struct FillWork {
    pub manifest: Manifest,
    pub todo: Vec<PlannedPose>,
    pub grid: usize,
    pub present: usize,
}

/// The default model package: `models/default` when present, else the tiny test package.
pub fn default_model() -> PathBuf {
    let roots = [PathBuf::from("."), PathBuf::from(env!("CARGO_MANIFEST_DIR"))];
    for rel in ["models/default", "tests/data/tiny-package"] {
        for root in &roots {
            let p = root.join(rel);
            if p.join("model.toml").is_file() {
                return p;
            }
        }
    }
    PathBuf::from("models/default")
}

/// Refuses a model package folder `dir` that does not exist, saying where rig looked and where
/// the default package is: a relative `--model models/default` is relative to the working
/// folder, while leaving `--model` out finds the default from anywhere ([`default_model`]).
pub fn check_model_dir(dir: &Path) -> Result<(), SynthError> {
    if std::fs::symlink_metadata(dir).is_ok() {
        return Ok(());
    }
    let cwd = std::env::current_dir().map(|d| format!(" (relative to the working folder {})", d.display())).unwrap_or_default();
    let default = default_model();
    let hint = if default.join("model.toml").is_file() {
        format!("leave out --model to use the default package, found at {}", default.display())
    } else {
        "no default package is installed either (models/default)".to_string()
    };
    Err(SynthError::BadRequest {
        field: "model",
        value: dir.display().to_string(),
        reason: format!("folder {} does not exist{}; {hint}", dir.display(), if dir.is_relative() { cwd } else { String::new() }),
    })
}

/// Dataset directories under `root` (itself, or up to two levels below).
pub fn find_datasets(root: &Path) -> Result<Vec<PathBuf>, DatasetError> {
    crate::dataset::find_datasets(root)
}

/// Lists the grid poses of `dataset` (and of `out`, when a shard writes elsewhere) that have
/// no row yet and belong to `shard`.
pub fn missing_poses(dataset: &Path, out: Option<&Path>, shard: Shard) -> Result<FillWork, FillError> {
    let manifest = Manifest::load(dataset)?;
    let spec = manifest.plan.clone().ok_or_else(|| FillError::NoPlan { dir: dataset.to_path_buf() })?;
    let grid = spec.grid();
    let mut present: std::collections::BTreeSet<u32> = read_rows(dataset)?.iter().map(|r| r.pose_id).collect();
    if let Some(out) = out.filter(|o| o.join("poses.csv").is_file()) {
        present.extend(read_rows(out)?.iter().map(|r| r.pose_id));
    }
    let todo: Vec<PlannedPose> = grid.iter().filter(|p| !present.contains(&p.pose_id) && shard.owns(p.pose_id)).copied().collect();
    let present = grid.iter().filter(|p| present.contains(&p.pose_id)).count();
    Ok(FillWork { manifest, todo, grid: grid.len(), present })
}

/// Fills the missing poses of `dataset` with `pipeline`; rows go into `out` (a shard's own
/// dataset) or, when `out` is `None`, into `dataset` itself. `progress` is told after each
/// batch. Resumable: poses already written are not redone.
pub fn fill_missing(
    dataset: &Path,
    out: Option<&Path>,
    pipeline: &mut Pipeline,
    options: &FillOptions,
    progress: &indicatif::ProgressBar,
) -> Result<FillSummary, FillError> {
    fill_missing_observed(dataset, out, pipeline, options, progress, &mut |_| ControlFlow::Continue(()))
}

/// One synthesised pose, shown to the observer of [`fill_missing_observed`].
#[derive(Debug)]
pub struct FilledPose<'a> {
    pub pose_id: u32,
    /// The control image (depth map) the model was conditioned on.
    pub control: &'a RgbImage,
    /// The synthetic image as written to the dataset.
    pub image: &'a RgbImage,
}

/// [`fill_missing`], telling `observe` about every pose once it is written. `observe` returning
/// `Break` stops the fill after that batch: what was written stays (durable and resumable), the
/// dataset is not finished, and the summary counts the poses not done as `left`.
pub fn fill_missing_observed(
    dataset: &Path,
    out: Option<&Path>,
    pipeline: &mut Pipeline,
    options: &FillOptions,
    progress: &indicatif::ProgressBar,
    observe: &mut dyn FnMut(&FilledPose<'_>) -> ControlFlow<()>,
) -> Result<FillSummary, FillError> {
    options.validate()?;
    let work = missing_poses(dataset, out, options.shard)?;
    let manifest = work.manifest.clone();
    let dir = dataset.to_path_buf();
    let spec_seed = manifest.plan.as_ref().map(|p| p.seed).unwrap_or(0);
    let kind = manifest.sensor;
    let (width, height) = pipeline.resolution();
    let renderer = ControlRenderer::for_dataset(&dir, &manifest, width, height, options.supersample)?;
    let output_size = reference_size(dataset)?;

    let mut todo = work.todo;
    let total_missing = todo.len();
    if let Some(limit) = options.limit {
        todo.truncate(limit);
    }
    let mut writer = match out {
        Some(out) => DatasetWriter::resume(out, manifest.clone())?,
        None => DatasetWriter::resume(dataset, manifest.clone())?,
    };
    // A shard's own dataset gets the collection's reference frame (decoded only when missing).
    if let Some(out) = out
        && !out.join("reference.png").is_file()
        && let Some(reference) = read_reference(dataset)?
    {
        writer.write_reference(&reference)?;
    }
    let synthesis = synthesis_info(pipeline, output_size.unwrap_or((width, height)));
    // Recorded only by a run that synthesises: a dataset with nothing missing keeps what it had.
    if !todo.is_empty() {
        writer.update_manifest(|m| m.synthesis = Some(synthesis.clone()))?;
    }
    let model = pipeline.package_hash().to_string();
    progress.set_length(todo.len() as u64);
    let mut synthesised = 0usize;
    for chunk in todo.chunks(options.batch.max(1)) {
        let controls: Vec<RgbImage> = chunk.iter().map(|p| renderer.control_image(&p.pose)).collect();
        let prompts: Vec<String> = chunk.iter().map(|p| mds_prompt(kind, &p.pose)).collect();
        let requests: Vec<GenerateRequest> = chunk
            .iter()
            .zip(controls.iter().zip(&prompts))
            .map(|(p, (control, prompt))| options.request(control, prompt, pose_seed(spec_seed, p.pose_id)))
            .collect();
        let outputs = pipeline.generate_batch(&requests)?;
        let mut stop = false;
        for (((p, request), output), control) in chunk.iter().zip(&requests).zip(outputs).zip(&controls) {
            let image = resized_to(output.to_rgb8(options.image_range), output_size);
            let row = PoseRow::synthetic(p.pose_id, p.pose, &model, request.seed, options.steps as u32, options.guidance as f64);
            writer.append(row, &image)?;
            synthesised += 1;
            stop |= observe(&FilledPose { pose_id: p.pose_id, control, image: &image }).is_break();
        }
        progress.inc(chunk.len() as u64);
        if stop {
            // Stopped early: the rows written are durable; an unfinished dataset resumes.
            return Ok(FillSummary { grid: work.grid, present: work.present, synthesised, left: total_missing - synthesised, synthesis });
        }
    }
    writer.finish()?;
    Ok(FillSummary { grid: work.grid, present: work.present, synthesised: todo.len(), left: total_missing - todo.len(), synthesis })
}

/// What `rig synth --poses-of` did for one dataset.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PosesOfSummary {
    /// Captured rows of the source (`source=real` or `simulated`): the poses to twin.
    pub real: usize,
    /// Of those, poses the output already had (a resumed run).
    pub present: usize,
    /// Poses synthesised now.
    pub synthesised: usize,
    /// Poses left to other shards or beyond the limit.
    pub left: usize,
    /// The model and sizes recorded in the twins' manifest (`[synthesis]`).
    pub synthesis: SynthesisInfo,
}

/// What a synthesis by `pipeline` records when it writes images of `written` px (width,
/// height): the model, its resolution and the images' size.
pub fn synthesis_info(pipeline: &Pipeline, written: (u32, u32)) -> SynthesisInfo {
    let package = pipeline.package();
    let (width, height) = pipeline.resolution();
    SynthesisInfo {
        model: package.config.name.clone(),
        model_dir: package.dir.display().to_string(),
        model_resolution_px: [width, height],
        image_resolution_px: [written.0, written.1],
    }
}

/// The size a fill of `dataset` writes its images at: its frames' (`reference.png`'s), else the
/// model's `model_px`.
pub fn fill_image_size(dataset: &Path, model_px: (u32, u32)) -> Result<(u32, u32), FillError> {
    Ok(reference_size(dataset)?.unwrap_or(model_px))
}

/// Synthesises exactly the poses of `source`'s captured rows (real or simulated) into the dataset `out` (created with
/// `source`'s manifest: object, sensor, calibration, plan, work frame; its `reference.png` is
/// copied, at `size`), keeping each pose's `pose_id`. This is how a test set gets its synthetic twin for
/// `rig eval`. Seeds are [`pose_seed`]`(plan seed, pose_id)` as in [`fill_missing`], so a pose
/// gets the same image either way. Resumable: poses `out` already has are not redone.
/// `options.shard` and `options.limit` apply as in a fill.
pub fn synthesise_poses_of(
    source: &Path,
    out: &Path,
    pipeline: &mut Pipeline,
    options: &FillOptions,
    size: TwinSize,
    progress: &indicatif::ProgressBar,
) -> Result<PosesOfSummary, FillError> {
    options.validate()?;
    let source_manifest = Manifest::load(source)?;
    let (width, height) = pipeline.resolution();
    let output_size = match size {
        TwinSize::Model => Some((width, height)),
        TwinSize::Source => reference_size(source)?,
    };
    let dir = source.to_path_buf();
    let real: Vec<PlannedPose> = read_rows(source)?
        .iter()
        .filter(|r| r.source.is_captured())
        .map(|r| PlannedPose { pose_id: r.pose_id, pose: r.commanded() })
        .collect();
    let manifest = Manifest {
        started_utc: crate::dataset::manifest::utc_now(),
        resumed_utc: Vec::new(),
        ended_utc: None,
        rig_version: crate::version().to_string(),
        // The twins are synthesised: no sensor captured them, and no audit has judged them.
        capture: None,
        audit: None,
        ..source_manifest.clone()
    };
    let mut writer = DatasetWriter::resume(out, manifest)?;
    let synthesis = synthesis_info(pipeline, output_size.unwrap_or((width, height)));
    let present: std::collections::BTreeSet<u32> = writer.done_ids().clone();
    let mut todo: Vec<PlannedPose> =
        real.iter().filter(|p| !present.contains(&p.pose_id) && options.shard.owns(p.pose_id)).copied().collect();
    let waiting = real.iter().filter(|p| !present.contains(&p.pose_id)).count();
    if let Some(limit) = options.limit {
        todo.truncate(limit);
    }
    if !todo.is_empty() {
        writer.update_manifest(|m| m.synthesis = Some(synthesis.clone()))?;
    }
    if !out.join(crate::dataset::REFERENCE_FILE).is_file()
        && let Some(reference) = read_reference(source)?
    {
        writer.write_reference(&resized_to(reference, output_size))?;
    }
    let kind = source_manifest.sensor;
    let renderer = ControlRenderer::for_dataset(&dir, &source_manifest, width, height, options.supersample)?;
    let spec_seed = source_manifest.plan.as_ref().map(|p| p.seed).unwrap_or(0);
    let model = pipeline.package_hash().to_string();
    progress.set_length(todo.len() as u64);
    for chunk in todo.chunks(options.batch.max(1)) {
        let controls: Vec<RgbImage> = chunk.iter().map(|p| renderer.control_image(&p.pose)).collect();
        let prompts: Vec<String> = chunk.iter().map(|p| mds_prompt(kind, &p.pose)).collect();
        let requests: Vec<GenerateRequest> = chunk
            .iter()
            .zip(controls.iter().zip(&prompts))
            .map(|(p, (control, prompt))| GenerateRequest {
                steps: options.steps,
                guidance: options.guidance,
                eta: options.eta,
                scheduler: options.scheduler,
                conditioning_scale: options.conditioning_scale,
                seed: pose_seed(spec_seed, p.pose_id),
                ..GenerateRequest::new(control, prompt)
            })
            .collect();
        let outputs = pipeline.generate_batch(&requests)?;
        for ((p, request), output) in chunk.iter().zip(&requests).zip(outputs) {
            let image = resized_to(output.to_rgb8(options.image_range), output_size);
            let row = PoseRow::synthetic(p.pose_id, p.pose, &model, request.seed, options.steps as u32, options.guidance as f64);
            writer.append(row, &image)?;
        }
        progress.inc(chunk.len() as u64);
    }
    writer.finish()?;
    Ok(PosesOfSummary { real: real.len(), present: real.len() - waiting, synthesised: todo.len(), left: waiting - todo.len(), synthesis })
}

/// Renders the control images (ControlNet hints) of one dataset's poses, exactly as
/// [`fill_missing`] feeds them to the model: the dataset's object mesh, pressed in by the work
/// frame's contact depth, seen through its calibration at the model's resolution. Training
/// tools (`rig render --controls-of`) use it too, so training and synthesis see the same hints.
pub struct ControlRenderer {
    /// The dataset's object mesh, ready for rendering (walls dropped, sorted top down; built
    /// once).
    prepared: PreparedMesh,
    pub calibration: Calibration,
    /// Added to a pose's z (indentation) to place the object: the work frame's contact depth.
    pub contact_depth_mm: f64,
    pub width: u32,
    pub height: u32,
    /// Samples per pixel along each axis of the depth render.
    pub supersample: u32,
}

impl ControlRenderer {
    /// The renderer of the dataset at `dir` (whose manifest is `manifest`) for `width` x
    /// `height` hints.
    pub fn for_dataset(dir: &Path, manifest: &Manifest, width: u32, height: u32, supersample: u32) -> Result<Self, FillError> {
        let mesh = object_mesh(dir, manifest)?;
        Ok(Self {
            prepared: PreparedMesh::for_many_renders(&mesh),
            calibration: calibration_of(dir, manifest, width, height)?,
            contact_depth_mm: manifest.work_frame.map(|w| w.contact_depth_mm).unwrap_or(1.5),
            width,
            height,
            supersample,
        })
    }

    /// The control image of the work-frame `pose`.
    pub fn control_image(&self, pose: &Pose) -> RgbImage {
        self.control_image_with(pose, &mut ControlScratch::default())
    }

    /// [`ControlRenderer::control_image`] with the buffers of `scratch`: a loop over many
    /// poses (one scratch per thread) allocates only the images it returns.
    pub fn control_image_with(&self, pose: &Pose, scratch: &mut ControlScratch) -> RgbImage {
        let object_pose = Pose { z_mm: pose.z_mm + self.contact_depth_mm, ..*pose };
        crate::geometry::raster::render_depth_into(
            &self.prepared,
            &object_pose,
            &self.calibration,
            self.width,
            self.height,
            self.supersample,
            &mut scratch.raster,
            &mut scratch.depth,
        );
        crate::geometry::control::control_image(&scratch.depth)
    }
}

/// The buffers [`ControlRenderer::control_image_with`] reuses from pose to pose.
#[derive(Debug)]
pub struct ControlScratch {
    raster: crate::geometry::raster::RasterScratch,
    depth: crate::geometry::DepthMap,
}

impl Default for ControlScratch {
    fn default() -> Self {
        Self { raster: Default::default(), depth: crate::geometry::DepthMap::empty(0, 0) }
    }
}

/// The object mesh the dataset was collected on: the STL its manifest names (read by the rules
/// of [`crate::dataset::named`], checked against its sha256, [`crate::dataset::ObjectInfo::stl_bytes`]);
/// else the library object of that name. A named STL that is gone is an error naming it, unless
/// the library holds the same file (the manifest's sha256 is the library object's): a library
/// object named relative to where it was collected.
fn object_mesh(dir: &Path, manifest: &Manifest) -> Result<Mesh, FillError> {
    let name = manifest.object.name.clone();
    let err = |reason: String| FillError::Object { dir: dir.to_path_buf(), object: name.clone(), reason };
    let manifest_file = dir.join(crate::dataset::MANIFEST_FILE);
    match manifest.object.stl_bytes(dir, &manifest_file, crate::geometry::stl::MAX_STL_BYTES) {
        Ok(Some(bytes)) => Mesh::from_bytes(&bytes).map_err(|e| err(e.to_string())),
        Ok(None) => load_object(&name).map_err(|e| err(e.to_string())),
        Err(missing @ (DatasetError::StlMissing { .. } | DatasetError::StlUnusable { .. })) => {
            match crate::geometry::objects::ObjectChoice::resolve(&name, None) {
                Ok(library) if manifest.object.stl_sha256.as_ref().is_some_and(|h| library.matches(h)) => Ok((*library.mesh).clone()),
                _ => Err(missing.into()),
            }
        }
        Err(e) => Err(e.into()),
    }
}

/// The calibration named in the manifest ("default": the default for the image size).
fn calibration_of(dir: &Path, manifest: &Manifest, width: u32, height: u32) -> Result<Calibration, FillError> {
    let failed =
        |calibration: &str, reason: String| FillError::Calibration { dir: dir.to_path_buf(), calibration: calibration.to_string(), reason };
    match manifest.calibration.as_deref() {
        // An uncalibrated collection: the calibration `rig calibrate` saved since, if any (rig's
        // own file, not one the manifest names).
        None | Some("default") => {
            let saved = manifest.sensor.calibration_path();
            if saved.is_file() {
                let shown = saved.display().to_string();
                return Calibration::load(&saved).map(|c| c.scaled_to(width, height)).map_err(|e| failed(&shown, e.to_string()));
            }
            Ok(Calibration::default_for(width, height))
        }
        // A fitted calibration belongs to the frames' size; the hint is rendered at the model's.
        Some(named) => {
            let bytes = crate::dataset::named::read_named(dir, "calibration", named, None, crate::untrusted::MAX_CONFIG_BYTES)
                .map_err(|e| failed(named, e.to_string()))?
                .ok_or_else(|| failed(named, "no such file below the dataset folder or the working folder".into()))?;
            let text = String::from_utf8(bytes).map_err(|_| failed(named, "not UTF-8 text".into()))?;
            Calibration::from_toml(&text, named).map(|c| c.scaled_to(width, height)).map_err(|e| failed(named, e.to_string()))
        }
    }
}

/// `image` at `size` (bilinear) when one is given and it differs; else as it is.
pub(crate) fn resized_to(image: RgbImage, size: Option<(u32, u32)>) -> RgbImage {
    match size {
        Some((w, h)) if (w, h) != image.dimensions() => image::imageops::resize(&image, w, h, image::imageops::FilterType::Triangle),
        _ => image,
    }
}

/// The dataset's reference frame, if it has one: a regular file (a symlink is an error, as
/// everywhere in a dataset), decoded with bounds.
pub fn read_reference(dataset: &Path) -> Result<Option<RgbImage>, FillError> {
    use crate::dataset::durable;
    let path = dataset.join(crate::dataset::REFERENCE_FILE);
    if !durable::entry_exists(&path, durable::Kind::File)? {
        return Ok(None);
    }
    read_dataset_image(dataset, crate::dataset::REFERENCE_FILE).map(Some)
}

/// The image `rel` (a row's `image`, or `reference.png`) of the dataset at `dataset`, read
/// through the dataset opener (no symlink, a regular file) and decoded with bounds.
pub fn read_dataset_image(dataset: &Path, rel: &str) -> Result<RgbImage, FillError> {
    use crate::dataset::durable;
    let bytes = durable::read_below(dataset, Path::new(rel), durable::MAX_IMAGE_BYTES)?;
    let image =
        durable::decode_image(&bytes).map_err(|reason| crate::dataset::DatasetError::BadImage { path: dataset.join(rel), reason })?;
    Ok(image.to_rgb8())
}

/// Size of the dataset's reference frame, so synthetic images match the captured ones.
fn reference_size(dataset: &Path) -> Result<Option<(u32, u32)>, FillError> {
    Ok(read_reference(dataset)?.map(|r| r.dimensions()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_partition_the_ids() {
        let shards: Vec<Shard> = (1..=3).map(|i| format!("{i}/3").parse().unwrap()).collect();
        for id in 0..100u32 {
            assert_eq!(shards.iter().filter(|s| s.owns(id)).count(), 1, "id {id}");
        }
        for bad in ["0/2", "3/2", "1/0", "x/2", "2", ""] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }
}
