//! The audit job: is a dataset's fill worth it? [`AuditRequest`] (what `rig audit` is asked),
//! [`PreparedAudit`] (the draw and the collection it needs, checked before anything moves),
//! [`run`] (the collection, through [`super::collect::run`]: the same job, the same fence
//! (workspace and press limit), the same crash-safe, resumable dataset writer) and [`score`] (the comparison,
//! [`crate::eval::audit`], its report and the summary in the dataset's manifest).
//!
//! ```text
//! dataset/poses.csv ──draw(fraction, seed)──► synthetic pose ids ──► CollectSetup (out: dataset/audit)
//!                                                                         │ collect::run (resumable)
//!                                                                         ▼
//!   dataset/manifest.toml [audit] ◄── score ◄── dataset/audit/<object>/<sensor>/ (source real|simulated)
//!   dataset/audit/report.md, worst-poses.png
//! ```
//!
//! The audit dataset is an ordinary dataset of its own (manifest, rows, reference frame),
//! three levels below the audited one, so nothing mixes: `rig synth --fill-missing` and `rig
//! eval` on the datasets root do not find it, and `rig eval --real dataset/audit --synthetic
//! dataset` reproduces the scoring.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use rand::SeedableRng;

use super::collect::{CollectOutcome, CollectSetup, SensorFeed, arm_part, kept_order, modbus_parts};
use super::{AuditRequest, JobError, Observer};
use crate::arm::Arm;
use crate::arm::profile::FirmwareProfile;
use crate::camera::Camera;
use crate::clock::Clock;
use crate::config::RigConfig;
use crate::dataset::{AuditSummary, DatasetError, Manifest, ObjectInfo, PoseRow, Source, read_rows};
use crate::eval::audit::{AuditScores, score_audit, verdict_line, worst_poses_panel};
use crate::fence::{Envelope, Fence, PoseSource};
use crate::geometry::objects::ObjectChoice;
use crate::io::modbus::Peripherals;
use crate::plan::{Order, PlannedPose};
use crate::pose::Pose;
use crate::sensor::SensorKind;

/// The folder, inside the audited dataset, that holds the audit (its dataset, report, panel).
pub const AUDIT_DIR: &str = "audit";
/// The report's file name, in [`AUDIT_DIR`].
pub const REPORT_FILE: &str = "report.md";
/// The worst poses side by side, in [`AUDIT_DIR`].
pub const PANEL_FILE: &str = "worst-poses.png";
/// Poses in the panel of the worst.
pub const WORST_POSES: usize = 4;

/// The synthetic pose ids of `rows` (each once, in id order), and the seeded draw of
/// `fraction` of them (at least one when there is any), in id order.
pub fn draw(rows: &[PoseRow], fraction: f64, seed: u64) -> (Vec<u32>, Vec<u32>) {
    let ids: Vec<u32> =
        rows.iter().filter(|r| r.source == Source::Synthetic).map(|r| r.pose_id).collect::<BTreeSet<u32>>().into_iter().collect();
    if ids.is_empty() {
        return (ids, Vec::new());
    }
    let k = ((ids.len() as f64 * fraction).ceil() as usize).clamp(1, ids.len());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut picked: Vec<u32> = rand::seq::index::sample(&mut rng, ids.len(), k).into_iter().map(|i| ids[i]).collect();
    picked.sort_unstable();
    (ids, picked)
}

/// An audit resolved against a rig configuration: the poses drawn, checked against the fence
/// (the workspace, the press limit of the dataset's sensor), and the collection that captures
/// them.
#[derive(Debug, Clone)]
pub struct PreparedAudit {
    pub request: AuditRequest,
    /// The collection of the drawn poses into `<dataset>/audit/<object>/<sensor>/`, resuming.
    pub setup: CollectSetup,
    /// The object's mesh, for the simulated sensors.
    pub object: ObjectChoice,
    pub sensor: SensorKind,
    /// Synthetic poses in the dataset.
    pub synthetic_poses: usize,
    /// What the drawn poses visit, as the fence found it.
    pub envelope: Envelope,
}

impl PreparedAudit {
    /// `<dataset>/audit`.
    pub fn audit_root(&self) -> PathBuf {
        self.request.dataset.join(AUDIT_DIR)
    }

    /// The audit dataset, `<dataset>/audit/<object>/<sensor>`.
    pub fn audit_dataset(&self) -> PathBuf {
        self.setup.dataset_dir(self.sensor)
    }

    /// `audit: N of M synthetic poses drawn (fraction F, seed S) into DIR`.
    pub fn plan_line(&self) -> String {
        format!(
            "audit: {} of {} synthetic poses drawn (fraction {}, seed {}) into {}",
            self.setup.poses.len(),
            self.synthetic_poses,
            self.request.fraction,
            self.request.seed,
            self.audit_dataset().display()
        )
    }
}

impl AuditRequest {
    /// Reads the dataset, draws the poses and checks every one against the fence (nothing
    /// moves for a pose outside the workspace or pressing past the sensor's limit: the rows
    /// are the dataset's, which anyone may have edited). A draw other than the one an existing audit folder holds
    /// is refused (bad input), so one audit dataset never mixes two draws.
    pub fn prepare(&self, config: &RigConfig) -> Result<PreparedAudit, JobError> {
        self.check()?;
        let dir = &self.dataset;
        let wrap = |source| JobError::Dataset { dir: dir.clone(), source };
        let manifest = Manifest::load(dir).map_err(wrap)?;
        let rows = read_rows(dir).map_err(wrap)?;
        let (synthetic, picked) = draw(&rows, self.fraction, self.seed);
        if picked.is_empty() {
            return Err(JobError::bad_option(
                "dataset",
                format!("{} has no synthetic rows to audit (fill it first: rig synth --fill-missing --dataset DIR)", dir.display()),
            ));
        }
        let synthetic_rows: std::collections::HashMap<u32, &PoseRow> =
            rows.iter().filter(|r| r.source == Source::Synthetic).map(|r| (r.pose_id, r)).collect();
        let drawn: Vec<PlannedPose> = picked
            .iter()
            .filter_map(|id| synthetic_rows.get(id))
            .map(|r| PlannedPose { pose_id: r.pose_id, pose: r.commanded() })
            .collect();
        let object = ObjectChoice::resolve(&manifest.object.name, self.stl.as_deref())?;
        super::check_plain_name("object", &object.name)?;
        if object.name != manifest.object.name {
            return Err(JobError::bad_option(
                "stl",
                format!("names object {:?}, the dataset's object is {:?}", object.name, manifest.object.name),
            ));
        }
        if let Some(sha) = &manifest.object.stl_sha256
            && !object.matches(sha)
        {
            return Err(JobError::bad_option(
                "dataset",
                format!(
                    "its object {:?} is not the one found here (sha256 {} there, {} here); name its STL file with --stl",
                    object.name, sha, object.sha256
                ),
            ));
        }
        let profile = FirmwareProfile::named(config.arm.profile.as_deref())?;
        let sensor = manifest.sensor;
        // Every drawn pose meets the fence before anything else is decided.
        let fence = Fence::for_run(profile.clone(), config, &[sensor], PoseSource::DatasetRows);
        let envelope = fence.check(&config.work_frame, &drawn)?;
        // The presses follow a travel order, computed once and kept in the audit dataset: a
        // rerun after a kill reads it back (checked to be this draw's poses).
        let audit_dataset = dir.join(AUDIT_DIR).join(&object.name).join(sensor.name());
        check_existing(&audit_dataset, &picked)?;
        let cost = |a: &Pose, b: &Pose| profile.pose_cost_s(&config.work_frame, a, b);
        let poses = match kept_order(std::slice::from_ref(&audit_dataset), |_| true)? {
            Some((path, ids)) => {
                crate::plan::in_kept_order(drawn, &ids, &cost)
                    .map_err(|mismatch| JobError::Dataset {
                        dir: audit_dataset.clone(),
                        source: DatasetError::OrderMismatch { path, mismatch },
                    })?
                    .poses
            }
            None => crate::plan::order_poses(drawn, Order::Optimised, 0, &cost).poses,
        };
        let setup = CollectSetup {
            object: ObjectInfo {
                name: object.name.clone(),
                stl_path: object.path.as_ref().map(|p| p.display().to_string()),
                stl_sha256: Some(object.sha256.clone()),
            },
            plan_spec: manifest.plan.clone().unwrap_or_default(),
            poses,
            profile_name: profile.name.clone(),
            work_frame: config.work_frame,
            options: config.collect.clone(),
            out: dir.join(AUDIT_DIR),
            // An audit always continues its own folder: a rerun after a kill resumes.
            resume: true,
            disk_budget_bytes: config.faults.disk_budget_bytes,
            arm: arm_part(config, &profile),
            modbus: modbus_parts(config),
            fence,
            adaptive: None,
        };
        Ok(PreparedAudit { request: self.clone(), setup, object, sensor, synthetic_poses: synthetic.len(), envelope })
    }
}

/// Refuses an audit dataset `dir` that holds poses outside this draw.
fn check_existing(dir: &Path, picked: &[u32]) -> Result<(), JobError> {
    if !dir.join(crate::dataset::POSES_FILE).is_file() {
        return Ok(());
    }
    let rows = read_rows(dir).map_err(|source| JobError::Dataset { dir: dir.to_path_buf(), source })?;
    if let Some(r) = rows.iter().find(|r| picked.binary_search(&r.pose_id).is_err()) {
        return Err(JobError::bad_option(
            "fraction",
            format!(
                "{} holds pose {} of another draw; rerun with that audit's --fraction and --seed, or move the folder away",
                dir.display(),
                r.pose_id
            ),
        ));
    }
    Ok(())
}

/// How an audit ended when it did not fail.
#[derive(Debug, Clone)]
pub struct AuditOutcome {
    pub collected: CollectOutcome,
    /// `None` when the collection was interrupted (nothing scored; rerun to continue).
    pub scored: Option<ScoredAudit>,
}

/// The scoring of a finished audit.
#[derive(Debug, Clone)]
pub struct ScoredAudit {
    pub scores: AuditScores,
    /// What went into the dataset's manifest.
    pub summary: AuditSummary,
    pub report: PathBuf,
    pub panel: Option<PathBuf>,
    /// `Some(false)` when the mean contact-region SSIM is below `--min-ssim` (or there is none).
    pub passed: Option<bool>,
    /// The one-line verdict against the two baselines, with the likely cause
    /// ([`crate::eval::audit::verdict_line`]).
    pub verdict: String,
}

/// Runs an audit: collects the drawn poses (resuming what an earlier, killed run left) through
/// [`super::collect::run`], then, unless interrupted, [`score`]s them.
pub async fn run<A: Arm, C: Camera, P: Peripherals>(
    prepared: &PreparedAudit,
    arm: &mut A,
    cameras: Vec<SensorFeed<C>>,
    peripherals: P,
    clock: Arc<dyn Clock>,
    observer: Observer,
) -> Result<AuditOutcome, JobError> {
    if let Some(feed) = cameras.iter().find(|f| f.sensor != prepared.sensor) {
        return Err(JobError::SensorNotOpen { sensor: prepared.sensor, opened: feed.sensor.to_string() });
    }
    let collected = super::collect::run(&prepared.setup, arm, cameras, peripherals, clock, observer, None).await?;
    if collected.summary.interrupted {
        return Ok(AuditOutcome { collected, scored: None });
    }
    let scored = score(prepared)?;
    Ok(AuditOutcome { collected, scored: Some(scored) })
}

/// Scores the collected audit against the dataset's synthesised rows, writes
/// `audit/report.md` and `audit/worst-poses.png`, and the summary into the dataset's manifest.
pub fn score(prepared: &PreparedAudit) -> Result<ScoredAudit, JobError> {
    let request = &prepared.request;
    let dataset = &request.dataset;
    let audit_dataset = prepared.audit_dataset();
    let root = prepared.audit_root();
    let scoring = |source| JobError::Audit { dataset: dataset.clone(), source };
    let scores = score_audit(dataset, &audit_dataset, request.size_px).map_err(scoring)?;
    let contact_ssim = scores.contact_ssim();
    let totals = scores.totals();
    let find = |name: &str| totals.iter().find(|(n, _, _)| *n == name).and_then(|(_, f, _)| *f);
    let summary = AuditSummary {
        utc: crate::dataset::manifest::utc_now(),
        fraction: request.fraction,
        seed: request.seed,
        synthetic_poses: prepared.synthetic_poses,
        audited_poses: scores.poses.len(),
        contact_ssim,
        contact_psnr_db: find("contact PSNR dB (RGB)"),
        mds_ssim: find("SSIM (grey, min-max; MultiDiffSense)"),
        mds_psnr_db: find("PSNR dB (grey, min-max; MultiDiffSense)"),
        position_err_mm: find("position error mm"),
        min_ssim: request.min_ssim,
    };
    let passed = request.min_ssim.map(|bound| contact_ssim.is_some_and(|f| f.mean >= bound));

    let worst = scores.worst(WORST_POSES);
    let panel = worst_poses_panel(dataset, &audit_dataset, &worst, request.size_px).map_err(scoring)?;
    let panel_path = match panel {
        Some(image) => {
            let mut png = std::io::Cursor::new(Vec::new());
            let path = root.join(PANEL_FILE);
            image
                .write_to(&mut png, image::ImageFormat::Png)
                .map_err(|e| JobError::AuditWrite { path: path.clone(), reason: e.to_string() })?;
            write(&root, PANEL_FILE, png.get_ref())?;
            Some(path)
        }
        None => None,
    };
    let mut manifest = Manifest::load(dataset).map_err(|source| JobError::Dataset { dir: dataset.clone(), source })?;
    let verdict = verdict_line(&scores.eval.comparisons, manifest.synthesis.as_ref());
    let report = report_markdown(prepared, &scores, &summary, &worst, panel_path.is_some(), passed, &verdict);
    write(&root, REPORT_FILE, report.as_bytes())?;

    manifest.audit = Some(summary.clone());
    manifest.store(dataset).map_err(|source| JobError::Dataset { dir: dataset.clone(), source })?;
    Ok(ScoredAudit { scores, summary, report: root.join(REPORT_FILE), panel: panel_path, passed, verdict })
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> Result<(), JobError> {
    crate::dataset::durable::write_atomic(dir, name, bytes)
        .map_err(|e| JobError::AuditWrite { path: dir.join(name), reason: e.to_string() })
}

/// `report.md`: the draw, the totals with their intervals, the verdict against the baselines,
/// the verdict of `--min-ssim`, the worst poses, every pose, then `rig eval`'s table with the baselines.
fn report_markdown(
    prepared: &PreparedAudit,
    scores: &AuditScores,
    summary: &AuditSummary,
    worst: &[&crate::eval::audit::AuditPose],
    panel: bool,
    passed: Option<bool>,
    verdict: &str,
) -> String {
    let r = &prepared.request;
    let mut s = format!("# rig audit: {}\n\n", r.dataset.display());
    s += &format!(
        "{} of the dataset's {} synthesised poses (fraction {}, seed {}) collected again on the rig into `{}/{}/{}`, \
         each synthesised image judged against the captured one at {} px. Intervals: 95% bootstrap of the mean over the poses \
         that have the figure. MultiDiffSense's definition: both images grey (Rec. 601 luma) and each min-max scaled onto 0..255.\n\n",
        summary.audited_poses, summary.synthetic_poses, r.fraction, r.seed, AUDIT_DIR, prepared.object.name, prepared.sensor, r.size_px,
    );
    s += &scores.totals_markdown();
    s += &format!("\n{}\n", verdict.replacen("verdict:", "**Verdict:**", 1));
    if let (Some(bound), Some(ok)) = (r.min_ssim, passed) {
        s += &format!("\n--min-ssim {bound}: {} (mean contact SSIM).\n", if ok { "passed" } else { "FAILED" });
    }
    if panel {
        let ids: Vec<String> = worst.iter().map(|p| p.pose_id.to_string()).collect();
        s += &format!(
            "\n## Worst poses\n\nLowest contact SSIM first (pose ids {}): synthesised on the left, captured on the right.\n\n![worst poses]({PANEL_FILE})\n",
            ids.join(", ")
        );
    }
    s += "\n## Every audited pose\n\n";
    s += &scores.poses_markdown();
    s += "\n## Against the baselines (rig eval)\n\n";
    s += &scores.eval.to_markdown();
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(pose_id: u32, source: Source) -> PoseRow {
        PoseRow::commanded_only(pose_id, crate::pose::Pose { x_mm: pose_id as f64, ..Default::default() }, source)
    }

    #[test]
    fn draw_takes_a_seeded_share_of_the_synthetic_poses_only() {
        let mut rows: Vec<PoseRow> = (0..50).map(|i| row(i, Source::Simulated)).collect();
        rows.extend((50..135).map(|i| row(i, Source::Synthetic)));
        let (all, picked) = draw(&rows, 0.1, 7);
        assert_eq!(all.len(), 85);
        assert_eq!(picked.len(), 9, "ceil(8.5)");
        assert!(picked.iter().all(|id| (50..135).contains(id)), "{picked:?}");
        assert!(picked.windows(2).all(|w| w[0] < w[1]), "sorted, unique: {picked:?}");
        assert_eq!(draw(&rows, 0.1, 7).1, picked, "same seed, same draw");
        assert_ne!(draw(&rows, 0.1, 8).1, picked, "another seed, another draw");
        assert_eq!(draw(&rows, 1e-6, 7).1.len(), 1, "at least one pose");
        assert_eq!(draw(&rows, 1.0, 7).1, all);
        assert!(draw(&rows[..50], 0.5, 7).1.is_empty(), "no synthetic rows, nothing drawn");
    }

    #[test]
    fn request_bounds_are_checked() {
        let ok = AuditRequest::default();
        assert!(ok.check().is_ok());
        for bad in [
            AuditRequest { fraction: 0.0, ..ok.clone() },
            AuditRequest { fraction: 1.5, ..ok.clone() },
            AuditRequest { fraction: f64::NAN, ..ok.clone() },
            AuditRequest { min_ssim: Some(2.0), ..ok.clone() },
            AuditRequest { size_px: 4, ..ok.clone() },
            AuditRequest { size_px: 100_000, ..ok.clone() },
        ] {
            assert!(bad.check().is_err(), "{bad:?}");
        }
    }
}
