//! Adaptive collection (`rig collect --adaptive`): the plan's poses pressed in rounds, each
//! round choosing where the model's fill is least trustworthy, then the rest filled.
//!
//! ```text
//! AdaptiveRequest ──prepare──► AdaptiveRun ──next_round()──► CollectSetup of the round's poses
//!  (collect + budget,            plan, fence,      │  (recorded in every manifest before a
//!   rounds, seeds, model)        the record so far │   press; a resume replays the record)
//!                                                  ▼
//!                        the front end opens the rig and runs jobs::collect::run
//!                                                  │ ... every round ...
//!                                                  ▼
//!                                     fill_request(): the rest, with the same model
//! ```
//!
//! The choice itself is [`crate::plan::adaptive`]; this module measures its evidence with the
//! model (spread over seeds at the candidates, error at the poses pressed) and keeps the record.
//! Every pose pressed is a pose of the plan, checked by the fence when the plan was prepared
//! and again by [`super::collect::run`].

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use image::RgbImage;

use super::AdaptiveRequest;
use super::collect::{CollectSetup, PreparedCollect};
use super::{FillRequest, JobError};
use crate::config::RigConfig;
use crate::plan::PlannedPose;
use crate::plan::adaptive::{self, AdaptiveChoice, AdaptiveRecord, AdaptiveSettings, ChoiceReason, Scored};
use crate::sensor::SensorKind;
use crate::synth::fill::{ControlRenderer, FillOptions, read_dataset_image, read_reference, resized_to};
use crate::synth::{GenerateRequest, Pipeline, pose_seed, prompt::mds_prompt};

/// The contact region of an image: where it differs from the reference by more than this
/// (levels, 3 x 3 box mean), dilated by [`MASK_DILATE_PX`]; `rig eval`'s default.
const MASK_THRESHOLD: f64 = 10.0;
// A budget is at most the most poses a plan can have.
const _: () = assert!(super::request::MAX_BUDGET as u64 == crate::plan::MAX_GRID_POINTS);
const MASK_DILATE_PX: u32 = 1;

impl AdaptiveRequest {
    /// The model package this request uses.
    pub fn model_dir(&self) -> PathBuf {
        self.model.clone().unwrap_or_else(crate::synth::fill::default_model)
    }

    /// Checks the plan (two poses or more, to choose among) and the budget against its
    /// `plan_poses` poses, then the numbers ([`AdaptiveRequest::check`]), before any model loads.
    pub fn check_plan(&self, plan_poses: usize) -> Result<(), JobError> {
        let bad = JobError::bad_option;
        if plan_poses < 2 {
            return Err(bad(
                "plan",
                format!("an adaptive collection chooses among the plan's poses: a plan of {plan_poses} pose leaves no choice"),
            ));
        }
        if self.budget > plan_poses {
            return Err(bad("budget", format!("--budget {} is more than the plan's {plan_poses} poses", self.budget)));
        }
        Ok(self.check()?)
    }

    /// The synthesis settings of the model's images (the fill's, so a pressed pose's error is
    /// that of the image the fill would have written there).
    fn fill_request(&self, dataset: PathBuf) -> FillRequest {
        FillRequest { dataset, model: Some(self.model_dir()), steps: self.steps, ..FillRequest::default() }
    }

    /// Resolves the collection, checks the numbers, the model against the sensors, and reads
    /// the record a resumed collection has; nothing moves.
    pub fn prepare(&self, config: &RigConfig, pipeline: &Pipeline) -> Result<AdaptiveRun, JobError> {
        let prepared = self.collect.prepare(config)?;
        self.check_plan(prepared.plan.poses.len())?;
        check_model(pipeline, &self.collect.sensor.0, &self.model_dir())?;
        let options = self.fill_request(PathBuf::new()).options(pipeline);
        let package = pipeline.package();
        let settings = AdaptiveSettings {
            budget: self.budget,
            rounds: self.rounds,
            seeds_per_pose: self.seeds_per_pose,
            model: package.config.name.clone(),
            model_sha256: pipeline.package_hash().to_string(),
            steps: options.steps,
        };
        let mut record = AdaptiveRecord { settings, choices: Vec::new() };
        let ids: Vec<u32> = prepared.plan.poses.iter().map(|p| p.pose_id).collect();
        if self.collect.resume {
            let in_plan: std::collections::HashSet<u32> = ids.iter().copied().collect();
            // The longest record of this collection among its datasets (a kill between two
            // datasets' records leaves one a round ahead); another collection's is left to
            // the writer, which refuses it by name.
            for sensor in self.collect.sensor.iter() {
                let dir = prepared.setup.dataset_dir(sensor);
                let same = crate::dataset::Manifest::load(&dir).is_ok_and(|m| m.adaptive.as_ref() == Some(&record.settings));
                if !same {
                    continue;
                }
                let dataset = |source| JobError::Dataset { dir: dir.clone(), source };
                let choices = crate::dataset::choices::read_choices(&dir).map_err(dataset)?.unwrap_or_default();
                let kept = AdaptiveRecord { settings: record.settings.clone(), choices };
                kept.check_choices("the plan", |id| in_plan.contains(&id)).map_err(|reason| {
                    dataset(crate::dataset::DatasetError::ChoicesMismatch { path: dir.join(crate::dataset::choices::CHOICES_FILE), reason })
                })?;
                if kept.choices.len() > record.choices.len() {
                    record = kept;
                }
            }
        }
        let points = adaptive::normalised(&prepared.setup.plan_spec, &prepared.plan.poses);
        Ok(AdaptiveRun {
            request: self.clone(),
            prepared,
            record,
            ids,
            points,
            options,
            errors: HashMap::new(),
            spreads: HashMap::new(),
            round: 0,
        })
    }
}

/// Refuses a model that cannot make images of every sensor asked for (its `modalities`).
pub fn check_model(pipeline: &Pipeline, sensors: &[SensorKind], model: &std::path::Path) -> Result<(), JobError> {
    let modalities = &pipeline.package().config.modalities;
    if let Some(missing) = sensors.iter().find(|s| !modalities.iter().any(|m| m.eq_ignore_ascii_case(s.label()))) {
        return Err(JobError::bad_option(
            "model",
            format!(
                "model {} makes images of {} (model.toml modalities), not of {}: choose a model of every sensor collected, or --sensor",
                model.display(),
                modalities.join(", "),
                missing.label()
            ),
        ));
    }
    Ok(())
}

/// One round as chosen: its setup for [`super::collect::run`] and what choosing it cost.
#[derive(Debug, Clone)]
pub struct Round {
    pub number: usize,
    pub setup: CollectSetup,
    /// The choices of this round, in the order chosen.
    pub choices: Vec<AdaptiveChoice>,
    /// Model calls (images) spent choosing it: 0 when replayed from the record or in round 1.
    pub model_calls: usize,
    /// Wall time of choosing it, s.
    pub choose_s: f64,
    /// True when read back from the manifest (a resume) instead of chosen now.
    pub replayed: bool,
}

impl Round {
    /// The line `rig collect --adaptive` prints before pressing the round.
    pub fn line(&self, rounds: usize) -> String {
        let how = if self.replayed {
            "as recorded".to_string()
        } else if self.number == 1 {
            "space-filling".to_string()
        } else {
            format!("by acquisition, {} model calls in {:.1} s", self.model_calls, self.choose_s)
        };
        let ids: Vec<String> = self.choices.iter().map(|c| c.pose_id.to_string()).collect();
        format!("round {}/{rounds}: {} poses ({how}): {}", self.number, self.choices.len(), ids.join(" "))
    }
}

/// An adaptive collection under way: the prepared plan, the record, and the errors measured so
/// far (one per pressed pose and sensor, each measured once per process).
pub struct AdaptiveRun {
    request: AdaptiveRequest,
    pub prepared: PreparedCollect,
    pub record: AdaptiveRecord,
    ids: Vec<u32>,
    points: Vec<[f64; 4]>,
    options: FillOptions,
    errors: HashMap<(SensorKind, u32), f64>,
    /// The spread over seeds measured at pressed poses, per sensor and pose.
    spreads: HashMap<(SensorKind, u32), f64>,
    round: usize,
}

impl AdaptiveRun {
    /// The next round to press, chosen now or replayed from the record (and recorded in every
    /// dataset before it is returned); `None` after the last.
    ///
    /// `cancelled` is asked before choosing and between the model's calls: when it says yes,
    /// nothing of the round is recorded and `None` comes back (a resume chooses the round
    /// again, the same way); the caller tells the two `None`s apart by its own flag.
    pub fn next_round(&mut self, pipeline: &mut Pipeline, cancelled: &dyn Fn() -> bool) -> Result<Option<Round>, JobError> {
        if cancelled() {
            return Ok(None);
        }
        self.round += 1;
        let number = self.round;
        let settings = self.record.settings.clone();
        if number > settings.rounds {
            return Ok(None);
        }
        let t0 = Instant::now();
        let mut model_calls = 0;
        let replayed = number <= self.record.rounds_recorded();
        if !replayed {
            let pressed: Vec<usize> = self.indices_of(|c| c.round < number);
            let count = adaptive::round_size(settings.budget, settings.rounds, number);
            let choices = if number == 1 {
                adaptive::farthest_points(&self.points, &self.ids, &pressed, count, self.prepared.setup.plan_spec.seed)
                    .into_iter()
                    .map(|(i, distance)| AdaptiveChoice {
                        pose_id: self.ids[i],
                        round: 1,
                        reason: ChoiceReason::SpaceFilling,
                        distance,
                        spread: None,
                        error: None,
                        score: None,
                        distance_weight: None,
                        spread_weight: None,
                        error_weight: None,
                    })
                    .collect()
            } else {
                let Some((scored, weights, calls)) = self.evidence(pipeline, &pressed, count, cancelled)? else {
                    self.round -= 1;
                    return Ok(None);
                };
                model_calls = calls;
                adaptive::acquisition_batch(&self.points, &self.ids, &pressed, &scored, weights, count, number)
            };
            // Recorded in every dataset by the round's collection, before its first press
            // (`adaptive.csv`), so a resume presses these.
            self.record.choices.extend(choices);
        }
        let chosen: Vec<AdaptiveChoice> = self.record.choices.iter().filter(|c| c.round == number).cloned().collect();
        let ids: std::collections::HashSet<u32> = chosen.iter().map(|c| c.pose_id).collect();
        let mut setup = self.prepared.setup.clone();
        // The plan's visiting order, kept within the round.
        setup.poses = self.prepared.plan.poses.iter().filter(|p| ids.contains(&p.pose_id)).copied().collect();
        setup.adaptive = Some(self.record.clone());
        setup.resume = self.request.collect.resume || number > 1;
        Ok(Some(Round { number, setup, choices: chosen, model_calls, choose_s: t0.elapsed().as_secs_f64(), replayed }))
    }

    /// The fill of every dataset of the collection with the same model, after the last round.
    pub fn fill_requests(&self) -> Vec<FillRequest> {
        self.request.collect.sensor.iter().map(|s| self.request.fill_request(self.prepared.setup.dataset_dir(s))).collect()
    }

    /// Indices (into the plan) of the recorded choices that `keep`.
    fn indices_of(&self, keep: impl Fn(&AdaptiveChoice) -> bool) -> Vec<usize> {
        let at: HashMap<u32, usize> = self.ids.iter().enumerate().map(|(i, &id)| (id, i)).collect();
        self.record.choices.iter().filter(|c| keep(c)).filter_map(|c| at.get(&c.pose_id).copied()).collect()
    }

    /// The evidence of a later round, each figure averaged over the sensors:
    ///
    /// 1. the error measured at every pressed pose (synthesised with the fill's seed, compared
    ///    with its frame in the contact region), and, from [`adaptive::MIN_EVIDENCE`] presses
    ///    on, the spread over seeds there too;
    /// 2. the weights: how well the distance to the nearest other pressed pose, the regressed
    ///    error (each pressed pose left out) and the spread predicted those errors
    ///    ([`adaptive::Weights::PRIOR`] with fewer presses);
    /// 3. the candidates, the unpressed poses best by the weighted distance and regressed
    ///    error, and the spread at each where its weight is above 0 (none measured otherwise).
    ///
    /// Returns the scored candidates, the weights and the model calls made; `None` when
    /// `cancelled` said yes between two calls (what was measured so far is kept).
    fn evidence(
        &mut self,
        pipeline: &mut Pipeline,
        pressed: &[usize],
        count: usize,
        cancelled: &dyn Fn() -> bool,
    ) -> Result<Option<(Vec<Scored>, adaptive::Weights, usize)>, JobError> {
        let sensors: Vec<SensorKind> = self.request.collect.sensor.iter().collect();
        let seed = self.prepared.setup.plan_spec.seed;
        let k = self.record.settings.seeds_per_pose as u64;
        let weigh = pressed.len() >= adaptive::MIN_EVIDENCE;
        let mut calls = 0;
        let mut sources = Vec::with_capacity(sensors.len());
        let mut measured: Vec<([f64; 4], f64)> = pressed.iter().map(|&i| (self.points[i], 0.0)).collect();
        let mut pressed_spread = vec![0.0; pressed.len()];
        for &sensor in &sensors {
            let source = SensorSource::open(&self.prepared.setup.dataset_dir(sensor), sensor, pipeline, &self.options)?;
            for (j, &i) in pressed.iter().enumerate() {
                let id = self.ids[i];
                let pose = self.prepared.plan.poses[i];
                let error = match self.errors.get(&(sensor, id)) {
                    Some(&e) => e,
                    None if cancelled() => return Ok(None),
                    None => {
                        let image = source.generate(pipeline, &self.options, &[(pose, pose_seed(seed, id))])?.remove(0);
                        calls += 1;
                        let e = source.error_at(&pose, &image)?;
                        self.errors.insert((sensor, id), e);
                        e
                    }
                };
                measured[j].1 += error / sensors.len() as f64;
                if weigh {
                    let spread = match self.spreads.get(&(sensor, id)) {
                        Some(&s) => s,
                        None if cancelled() => return Ok(None),
                        None => {
                            let images = source.generate(pipeline, &self.options, &spread_seeds(pose, seed, k))?;
                            calls += images.len();
                            let s = source.spread(&images);
                            self.spreads.insert((sensor, id), s);
                            s
                        }
                    };
                    pressed_spread[j] += spread / sensors.len() as f64;
                }
            }
            sources.push(source);
        }
        let errors = adaptive::ErrorModel::new(&measured);
        let weights = if weigh {
            let measured_errors: Vec<f64> = measured.iter().map(|m| m.1).collect();
            adaptive::Weights::measured(errors.distance_weight(), adaptive::term_weight(&pressed_spread, &measured_errors), errors.weight())
        } else {
            adaptive::Weights::PRIOR
        };
        let free = self.points.len() - pressed.len();
        let candidates =
            adaptive::candidates_to_score(&self.points, &self.ids, pressed, Some((&errors, weights)), adaptive::scored_count(count, free));
        let measure_spread = weights.spread > 0.0;
        let mut spread = vec![0.0; candidates.len()];
        for source in sources.iter().filter(|_| measure_spread) {
            for (j, &i) in candidates.iter().enumerate() {
                if cancelled() {
                    return Ok(None);
                }
                let images = source.generate(pipeline, &self.options, &spread_seeds(self.prepared.plan.poses[i], seed, k))?;
                calls += images.len();
                spread[j] += source.spread(&images) / sensors.len() as f64;
            }
        }
        let scored = candidates
            .iter()
            .zip(spread)
            .map(|(&index, spread)| Scored {
                index,
                spread: measure_spread.then_some(spread),
                error: errors.at(&self.points[index]).unwrap_or(0.0),
            })
            .collect();
        Ok(Some((scored, weights, calls)))
    }
}

/// The `k` seeds of a pose's spread, other than its fill's: `pose_seed(plan seed + s, pose_id)`,
/// s = 1..=k.
fn spread_seeds(pose: PlannedPose, seed: u64, k: u64) -> Vec<(PlannedPose, u64)> {
    (0..k).map(|s| (pose, pose_seed(seed.wrapping_add(s + 1), pose.pose_id))).collect()
}

/// One sensor's dataset as the evidence needs it: its control renderer and its reference
/// frame at the model's size.
struct SensorSource {
    dir: PathBuf,
    sensor: SensorKind,
    renderer: ControlRenderer,
    reference: Option<RgbImage>,
    size: (u32, u32),
}

impl SensorSource {
    fn open(dir: &std::path::Path, sensor: SensorKind, pipeline: &Pipeline, options: &FillOptions) -> Result<Self, JobError> {
        let fill = JobError::fill("reading", dir);
        let manifest = crate::dataset::Manifest::load(dir).map_err(|source| JobError::Dataset { dir: dir.to_path_buf(), source })?;
        let size = pipeline.resolution();
        let renderer =
            ControlRenderer::for_dataset(dir, &manifest, size.0, size.1, options.supersample).map_err(JobError::fill("reading", dir))?;
        let reference = read_reference(dir).map_err(fill)?.map(|r| resized_to(r, Some(size)));
        Ok(Self { dir: dir.to_path_buf(), sensor, renderer, reference, size })
    }

    /// The model's images at `poses` (each with its seed), at the model's size.
    fn generate(&self, pipeline: &mut Pipeline, options: &FillOptions, poses: &[(PlannedPose, u64)]) -> Result<Vec<RgbImage>, JobError> {
        let controls: Vec<RgbImage> = poses.iter().map(|(p, _)| self.renderer.control_image(&p.pose)).collect();
        let prompts: Vec<String> = poses.iter().map(|(p, _)| mds_prompt(self.sensor, &p.pose)).collect();
        let requests: Vec<GenerateRequest> = poses
            .iter()
            .zip(controls.iter().zip(&prompts))
            .map(|((_, seed), (control, prompt))| options.request(control, prompt, *seed))
            .collect();
        let model = |source| JobError::Model { model: self.dir.clone(), source };
        Ok(pipeline.generate_batch(&requests).map_err(model)?.into_iter().map(|o| o.to_rgb8(options.image_range)).collect())
    }

    /// 1 - contact SSIM of the model's `image` against the frame pressed at `pose`
    /// ([`error_of`]), both at the model's size.
    fn error_at(&self, pose: &PlannedPose, image: &RgbImage) -> Result<f64, JobError> {
        let real =
            read_dataset_image(&self.dir, &crate::dataset::image_rel_path(pose.pose_id)).map_err(JobError::fill("reading", &self.dir))?;
        Ok(error_of(&resized_to(real, Some(self.size)), image, self.reference.as_ref()))
    }

    /// The spread of the model's `images` of one pose ([`spread_of`]).
    fn spread(&self, images: &[RgbImage]) -> f64 {
        spread_of(images, self.reference.as_ref())
    }
}

/// The contact region of `image`: where it differs from `reference`, as `rig eval` finds it;
/// `None` when nothing does (no contact: `rig eval` and `rig audit` give such a pose no contact
/// figure). The whole frame when the dataset has no reference frame.
fn contact_region(image: &RgbImage, reference: Option<&RgbImage>) -> Option<Vec<bool>> {
    let Some(reference) = reference else { return Some(vec![true; (image.width() * image.height()) as usize]) };
    let mask = crate::eval::contact_mask(image, reference, MASK_THRESHOLD, MASK_DILATE_PX);
    mask.iter().any(|&m| m).then_some(mask)
}

/// 1 - contact SSIM of the model's `image` against the `real` frame in the real frame's
/// contact region: the figure `rig audit` reports. 0 when the real frame shows no contact (the
/// figure judges nothing there, so there is nothing the model got wrong).
fn error_of(real: &RgbImage, image: &RgbImage, reference: Option<&RgbImage>) -> f64 {
    let Some(mask) = contact_region(real, reference) else { return 0.0 };
    crate::metrics::ssim_masked(real, image, &mask).map(|s| (1.0 - s).clamp(0.0, 2.0)).unwrap_or(1.0)
}

/// The spread of `images` (one pose, several seeds): the per-pixel standard deviation over the
/// seeds, averaged over the channels and the contact region of their mean, in [0, 1]; 0 when
/// their mean shows no contact (no contact for the model to be unsure about).
fn spread_of(images: &[RgbImage], reference: Option<&RgbImage>) -> f64 {
    let Some(first) = images.first() else { return 0.0 };
    let n = images.len() as f64;
    let len = first.as_raw().len();
    let mut mean = vec![0.0f64; len];
    let mut sq = vec![0.0f64; len];
    for image in images.iter().filter(|i| i.as_raw().len() == len) {
        for (k, &v) in image.as_raw().iter().enumerate() {
            mean[k] += v as f64 / n;
            sq[k] += (v as f64) * (v as f64) / n;
        }
    }
    let mean_image = RgbImage::from_raw(first.width(), first.height(), mean.iter().map(|&m| m.round().clamp(0.0, 255.0) as u8).collect());
    let Some(mask) = mean_image.as_ref().and_then(|m| contact_region(m, reference)) else { return 0.0 };
    let (mut sum, mut count) = (0.0, 0usize);
    for (px, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        for c in 0..3 {
            let k = px * 3 + c;
            sum += (sq[k] - mean[k] * mean[k]).max(0.0).sqrt();
            count += 1;
        }
    }
    if count == 0 { 0.0 } else { sum / count as f64 / 255.0 }
}
#[cfg(test)]
mod tests {
    use super::*;

    /// A 32 x 32 grey frame with, when `blob` is given, a 10 x 10 square of that level: a press.
    fn frame(blob: Option<u8>) -> RgbImage {
        RgbImage::from_fn(32, 32, |x, y| {
            let inside = (10..20).contains(&x) && (10..20).contains(&y);
            image::Rgb([blob.filter(|_| inside).unwrap_or(100); 3])
        })
    }

    #[test]
    fn spread_and_error_are_judged_in_the_contact_region_and_are_0_without_contact() {
        let reference = frame(None);
        let r = Some(&reference);
        // Seeds that agree on no contact (noise under the contact threshold): nothing to judge.
        let quiet: Vec<RgbImage> = [100u8, 103, 97].iter().map(|&v| RgbImage::from_pixel(32, 32, image::Rgb([v; 3]))).collect();
        assert_eq!(spread_of(&quiet, r), 0.0);
        assert_eq!(error_of(&reference, &quiet[1], r), 0.0, "a real frame without contact: nothing to get wrong");
        // Seeds that disagree about the press, and a model image unlike the pressed frame.
        let unsure = [frame(Some(200)), frame(Some(160))];
        let spread = spread_of(&unsure, r);
        assert!(spread > 0.02, "{spread}");
        assert!(spread_of(&[frame(Some(200)), frame(Some(200))], r) == 0.0, "seeds that agree");
        let wrong = error_of(&frame(Some(200)), &frame(Some(130)), r);
        assert!(wrong > 0.0, "{wrong}");
        assert_eq!(error_of(&frame(Some(200)), &frame(Some(200)), r), 0.0);
        // Without a reference frame the whole frame is judged.
        assert!(spread_of(&quiet, None) > 0.0);
        assert!(error_of(&reference, &quiet[1], None) > 0.0);
    }

    fn request(budget: usize, rounds: usize, seeds_per_pose: usize) -> AdaptiveRequest {
        AdaptiveRequest { budget, rounds, seeds_per_pose, ..AdaptiveRequest::default() }
    }

    #[test]
    fn numbers_are_checked_against_the_plan() {
        assert!(request(10, 3, 2).check_plan(100).is_ok());
        assert!(request(100, 3, 2).check_plan(100).is_ok(), "the whole plan may be pressed");
        let refused = |r: AdaptiveRequest, poses: usize, field: &str| {
            let e = r.check_plan(poses).expect_err("refused");
            assert!(matches!(&e, JobError::Request(crate::jobs::RequestError::BadOption { field: f, .. }) if *f == field), "{e}");
        };
        refused(request(101, 3, 2), 100, "budget");
        refused(request(0, 1, 2), 100, "budget");
        refused(request(crate::jobs::request::MAX_BUDGET + 1, 3, 2), crate::jobs::request::MAX_BUDGET + 10, "budget");
        refused(request(1, 1, 2), 1, "plan");
        refused(request(3, 4, 2), 100, "rounds");
        refused(request(3, 0, 2), 100, "rounds");
        refused(request(3, 1, 1), 100, "seeds_per_pose");
        refused(request(3, 1, crate::jobs::request::MAX_SEEDS_PER_POSE + 1), 100, "seeds_per_pose");
    }
}
