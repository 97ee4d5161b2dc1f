//! The synthesis job: [`FillRequest`] (what `rig synth --fill-missing` / `--poses-of` and a
//! daemon `synth` job are asked) and [`run`], its one runner.
//!
//! Two modes share the request: **fill** (every planned pose a dataset lacks, into the dataset
//! or a shard's own `out`) and **twins** (`poses_of`: exactly the captured poses of a test set,
//! into `out`, for `rig eval`). [`FillRequest::targets`] checks the request and lists the
//! datasets before a model is loaded; [`run`] works through them with a loaded
//! [`Pipeline`], reporting each pose to the caller and stopping at the observer's cancel.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::{FillRequest, JobError, Observer};
use crate::synth::Pipeline;
use crate::synth::fill::{
    FillOptions, FillSummary, FilledPose, PosesOfSummary, Shard, fill_missing_observed, find_datasets, missing_poses, synthesise_poses_of,
};

/// One dataset of a synthesis and where its rows go.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FillTarget {
    /// The dataset whose poses are synthesised (the source of twins).
    pub dataset: PathBuf,
    /// Where the rows go; `None`: into `dataset`.
    pub out: Option<PathBuf>,
}

impl FillTarget {
    /// The dataset the rows are written to.
    pub fn written(&self) -> &Path {
        self.out.as_deref().unwrap_or(&self.dataset)
    }
}

impl FillRequest {
    /// The model package this request uses.
    pub fn model_dir(&self) -> PathBuf {
        self.model.clone().unwrap_or_else(crate::synth::fill::default_model)
    }

    /// True in twins mode (`poses_of`).
    pub fn twins(&self) -> bool {
        self.poses_of.is_some()
    }

    /// Checks the request and lists the datasets it works on, before any model is loaded.
    pub fn targets(&self) -> Result<Vec<FillTarget>, JobError> {
        self.check()?;
        let bad = |field, reason: String| JobError::bad_option(field, reason);
        let no_dataset = |root: &Path| match crate::dataset::require_folder(root) {
            Err(missing) => JobError::Dataset { dir: root.to_path_buf(), source: missing },
            Ok(()) => bad(
                "dataset",
                format!("no dataset under {} (a dataset has a manifest.toml; collect one with `rig collect`)", root.display()),
            ),
        };
        if let Some(source) = &self.poses_of {
            let Some(out) = &self.out else {
                return Err(bad("out", "twins (--poses-of) need an output folder (--out): where the synthetic twin datasets go".into()));
            };
            let datasets = find_datasets(source).map_err(|source_err| JobError::Dataset { dir: source.clone(), source: source_err })?;
            if datasets.is_empty() {
                return Err(no_dataset(source));
            }
            return Ok(datasets
                .into_iter()
                .map(|d| {
                    let rel = d.strip_prefix(source).map(Path::to_path_buf).unwrap_or_default();
                    let twin = if rel.as_os_str().is_empty() { out.clone() } else { out.join(rel) };
                    FillTarget { dataset: d, out: Some(twin) }
                })
                .collect());
        }
        if self.shard.is_some() && self.out.is_none() {
            return Err(bad("shard", "a shard needs its own output dataset (--out): shards are joined by `rig dataset merge`".into()));
        }
        let datasets = find_datasets(&self.dataset).map_err(|source| JobError::Dataset { dir: self.dataset.clone(), source })?;
        if datasets.is_empty() {
            return Err(no_dataset(&self.dataset));
        }
        if self.out.is_some() && datasets.len() > 1 {
            return Err(bad("out", "an output dataset (--out) takes one dataset: name it with --dataset .../<object>/<sensor>".into()));
        }
        Ok(datasets.into_iter().map(|d| FillTarget { dataset: d, out: self.out.clone() }).collect())
    }

    /// What would be synthesised, one line per dataset; loads no model.
    pub fn dry_run(&self) -> Result<Vec<String>, JobError> {
        let shard = self.shard.unwrap_or(Shard::ALL);
        let mut lines = Vec::new();
        for t in self.targets()? {
            if self.twins() {
                let rows = crate::dataset::read_rows(&t.dataset).map_err(|source| JobError::Dataset { dir: t.dataset.clone(), source })?;
                let captured = rows.iter().filter(|r| r.source.is_captured()).count();
                lines.push(format!("{}: {captured} captured poses to synthesise into {}", t.dataset.display(), t.written().display()));
            } else {
                let work = missing_poses(&t.dataset, t.out.as_deref(), shard).map_err(JobError::fill("reading", &t.dataset))?;
                lines.push(format!(
                    "{}: {} of {} grid poses present, {} to synthesise in shard {shard}",
                    t.dataset.display(),
                    work.present,
                    work.grid,
                    work.todo.len()
                ));
            }
        }
        Ok(lines)
    }

    /// The warning of each target whose images `pipeline` would upscale (see
    /// [`crate::dataset::SynthesisInfo::upscale_warning`]), before anything is synthesised;
    /// a dataset with nothing to fill gets none.
    pub fn upscale_warnings(&self, targets: &[FillTarget], pipeline: &Pipeline) -> Vec<String> {
        let model_px = pipeline.resolution();
        let shard = self.shard.unwrap_or(Shard::ALL);
        targets
            .iter()
            .filter_map(|t| {
                let written = match self.twin_size {
                    crate::synth::fill::TwinSize::Model if self.twins() => model_px,
                    _ if self.twins() => crate::synth::fill::fill_image_size(&t.dataset, model_px).ok()?,
                    _ => {
                        let work = missing_poses(&t.dataset, t.out.as_deref(), shard).ok()?;
                        if work.todo.is_empty() {
                            return None;
                        }
                        crate::synth::fill::fill_image_size(&t.dataset, model_px).ok()?
                    }
                };
                crate::synth::fill::synthesis_info(pipeline, written).upscale_warning(t.written())
            })
            .collect()
    }

    /// The fill options for `pipeline`: each sampling setting asked for, else the package's
    /// own, else rig's default.
    pub fn options(&self, pipeline: &Pipeline) -> FillOptions {
        let defaults = FillOptions::default();
        let sampling =
            pipeline.package().config.sampling(self.steps, self.guidance, self.sampler, self.eta, (defaults.steps, defaults.guidance));
        FillOptions {
            steps: sampling.steps,
            guidance: sampling.guidance,
            eta: sampling.eta,
            scheduler: sampling.sampler,
            conditioning_scale: self.conditioning_scale,
            shard: self.shard.unwrap_or(Shard::ALL),
            batch: self.batch,
            supersample: self.supersample,
            limit: self.limit,
            image_range: self.image_range,
        }
    }
}

/// What a synthesis did to one dataset.
#[derive(Debug, Clone, PartialEq)]
pub struct FillReport {
    pub target: FillTarget,
    pub done: FillDone,
    /// Wall time, s.
    pub elapsed_s: f64,
}

/// The counts of one dataset's synthesis, by mode.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FillDone {
    Missing(FillSummary),
    Twins(PosesOfSummary),
}

impl FillReport {
    /// The upscale warning of this dataset's synthesis, if its images were upscaled.
    pub fn warning(&self) -> Option<String> {
        let (synthesis, synthesised) = match &self.done {
            FillDone::Missing(s) => (&s.synthesis, s.synthesised),
            FillDone::Twins(s) => (&s.synthesis, s.synthesised),
        };
        synthesis.upscale_warning(self.target.written()).filter(|_| synthesised > 0)
    }

    /// The line `rig synth` prints for this dataset (and a daemon job's message holds).
    pub fn line(&self) -> String {
        let left = |n: usize| if n > 0 { format!(", {n} left to other shards or --limit") } else { String::new() };
        match &self.done {
            FillDone::Missing(s) => format!(
                "{}: synthesised {} poses in {:.1} s ({} of {} grid poses were present{})",
                self.target.written().display(),
                s.synthesised,
                self.elapsed_s,
                s.present,
                s.grid,
                left(s.left)
            ),
            FillDone::Twins(s) => format!(
                "{}: synthesised {} poses in {:.1} s ({} captured poses in {}, {} were present{})",
                self.target.written().display(),
                s.synthesised,
                self.elapsed_s,
                s.real,
                self.target.dataset.display(),
                s.present,
                left(s.left)
            ),
        }
    }
}

/// How a synthesis ended when it did not fail.
#[derive(Debug, Clone, PartialEq)]
pub struct FillOutcome {
    /// One report per dataset done (or begun, when cancelled).
    pub reports: Vec<FillReport>,
    pub cancelled: bool,
}

/// Runs the synthesis `request` describes on `targets` (from [`FillRequest::targets`]) with a
/// loaded `pipeline`. `on_pose` sees every pose as it is written (fill mode); `on_dataset` each
/// dataset's report as it ends. The observer's progress bar counts poses per dataset; its
/// cancel stops after the current batch (fill) or dataset (twins): what was written stays and
/// resumes.
pub fn run(
    request: &FillRequest,
    targets: &[FillTarget],
    pipeline: &mut Pipeline,
    observer: &Observer,
    on_pose: &mut dyn FnMut(&FilledPose<'_>),
    on_dataset: &mut dyn FnMut(&FillReport),
) -> Result<FillOutcome, JobError> {
    // The sampling loop checks the cancel before every step, so a long sampling (up to
    // limits::MAX_STEPS steps an image) stops within one step of a cancel request.
    let cancel = observer.cancel.clone();
    pipeline.set_cancel(Some(std::sync::Arc::new(move || *cancel.borrow())));
    let outcome = run_targets(request, targets, pipeline, observer, on_pose, on_dataset);
    pipeline.set_cancel(None);
    outcome
}

/// True when a synthesis error is the sampling loop stopping at a cancel request.
fn is_cancel(e: &crate::synth::fill::FillError) -> bool {
    matches!(e, crate::synth::fill::FillError::Synth(crate::synth::SynthError::Cancelled))
}

fn run_targets(
    request: &FillRequest,
    targets: &[FillTarget],
    pipeline: &mut Pipeline,
    observer: &Observer,
    on_pose: &mut dyn FnMut(&FilledPose<'_>),
    on_dataset: &mut dyn FnMut(&FillReport),
) -> Result<FillOutcome, JobError> {
    let options = request.options(pipeline);
    let mut reports = Vec::new();
    for target in targets {
        if observer.cancelled() {
            return Ok(FillOutcome { reports, cancelled: true });
        }
        observer.progress.reset();
        observer.progress.set_length(0);
        observer.progress.set_prefix(crate::progress::dataset_name(target.written()));
        let t0 = Instant::now();
        let done = match &target.out {
            Some(out) if request.twins() => {
                match synthesise_poses_of(&target.dataset, out, pipeline, &options, request.twin_size, &observer.progress) {
                    Ok(summary) => FillDone::Twins(summary),
                    Err(e) if is_cancel(&e) => return Ok(FillOutcome { reports, cancelled: true }),
                    Err(e) => return Err(JobError::fill("synthesising the poses of", &target.dataset)(e)),
                }
            }
            _ => {
                let mut observe = |filled: &FilledPose<'_>| {
                    on_pose(filled);
                    if observer.cancelled() { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
                };
                match fill_missing_observed(&target.dataset, target.out.as_deref(), pipeline, &options, &observer.progress, &mut observe) {
                    Ok(summary) => FillDone::Missing(summary),
                    // What was written stays (each pose is durable) and resumes.
                    Err(e) if is_cancel(&e) => return Ok(FillOutcome { reports, cancelled: true }),
                    Err(e) => return Err(JobError::fill("filling", &target.dataset)(e)),
                }
            }
        };
        let report = FillReport { target: target.clone(), done, elapsed_s: t0.elapsed().as_secs_f64() };
        on_dataset(&report);
        reports.push(report);
    }
    Ok(FillOutcome { cancelled: observer.cancelled(), reports })
}
