//! The collection job: [`CollectRequest`] (what `rig collect` and a daemon `collect` job are
//! asked), [`PreparedCollect`] (the request resolved and checked against the rig's
//! configuration before anything moves), and [`run`], the one place a [`CollectJob`] is built.
//!
//! ```text
//! CollectRequest ──prepare(config)──► PreparedCollect ──► the front end opens (or already has)
//!   (clap / JSON)   plan, object,      .setup: CollectSetup    the arm and the cameras
//!                   fence check                             │
//!                                                           ▼
//!   recording header ──────────────────────────────► run(setup, arm, cameras, peripherals)
//!   (rig replay builds the setup it recorded)          datasets opened, CollectJob run
//! ```

use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::{CollectRequest, JobError, Observer};
use crate::arm::Arm;
use crate::arm::profile::FirmwareProfile;
use crate::camera::Camera;
use crate::clock::Clock;
use crate::collect::{CollectJob, CollectSummary, SensorStream};
use crate::config::{ArmBackend, CollectConfig, RigConfig};
use crate::dataset::{CaptureChain, CapturePart, DatasetError, DatasetWriter, Manifest, ObjectInfo, Source, choices, order};
use crate::fence::{Envelope, Fence, PoseSource};
use crate::geometry::objects::ObjectChoice;
use crate::io::modbus::{ModbusTransport, Peripherals};
use crate::plan::{Plan, PlanSpec, PlannedPose};
use crate::pose::{Pose, WorkFrame};
use crate::sensor::{SensorKind, SensorSet};

/// A collection resolved against a rig configuration: the plan built and checked against the
/// fence (nothing moves for a pose outside the workspace or past the press limit), the object
/// loaded.
#[derive(Debug, Clone)]
pub struct PreparedCollect {
    /// What the runner needs.
    pub setup: CollectSetup,
    /// The object's mesh, for the simulated sensors.
    pub object: ObjectChoice,
    /// The sensors asked for.
    pub sensors: SensorSet,
    /// The plan with its motion times (as sampled, and in the order it is visited).
    pub plan: Plan,
    /// The `order.csv` the order was read from when a dataset of the run keeps one (a resume);
    /// `None` when it was ordered now.
    pub kept_order: Option<PathBuf>,
    /// Grid points of the plan.
    pub grid_len: u64,
    /// The firmware profile the plan was checked against.
    pub profile: FirmwareProfile,
    /// What the plan visits, as the fence found it.
    pub envelope: Envelope,
}

impl CollectRequest {
    /// The plan spec this request names: the plan file (or the default plan) with `poses` and
    /// `seed` applied, validated.
    pub fn plan_spec(&self) -> Result<PlanSpec, JobError> {
        let mut spec = match &self.plan {
            Some(p) => PlanSpec::load(p)?,
            None => PlanSpec::default(),
        };
        if let Some(n) = self.poses {
            spec.n_poses = Some(n);
        }
        if let Some(s) = self.seed {
            spec.seed = s;
        }
        spec.validate()?;
        Ok(spec)
    }

    /// Resolves and checks the request against `config`: plan, object, firmware profile, and
    /// every pose through the fence (contact, approach, the reference above the origin inside
    /// the workspace; every press within the press limit of the sensors asked for).
    pub fn prepare(&self, config: &RigConfig) -> Result<PreparedCollect, JobError> {
        self.check()?;
        let spec = self.plan_spec()?;
        let object = ObjectChoice::resolve(&self.object, self.stl.as_deref())?;
        super::check_plain_name("object", &object.name)?;
        let profile = FirmwareProfile::named(config.arm.profile.as_deref())?;
        let cost = |a: &Pose, b: &Pose| profile.pose_cost_s(&config.work_frame, a, b);
        let sampled = spec.sample()?;
        // A resume visits the poses in the order its datasets keep (checked to be this plan's
        // poses), without ordering again; a dataset that keeps none is ordered as a new run is.
        let datasets: Vec<PathBuf> = self.sensor.iter().map(|s| self.out.join(&object.name).join(s.name())).collect();
        let kept = if self.resume { kept_order(&datasets, |m| m.plan.as_ref() == Some(&spec))? } else { None };
        let (plan, kept_order) = match kept {
            Some((path, ids)) => {
                let plan = crate::plan::in_kept_order(sampled, &ids, &cost)
                    .map_err(|mismatch| dataset_error(&path, DatasetError::OrderMismatch { path: path.clone(), mismatch }))?;
                (plan, Some(path))
            }
            None => (spec.order_sampled(sampled, &cost), None),
        };
        let fence = Fence::for_run(profile.clone(), config, &self.sensor.0, PoseSource::Plan);
        let envelope = fence.check(&config.work_frame, &plan.poses)?;
        let mut setup = CollectSetup {
            object: ObjectInfo {
                name: object.name.clone(),
                stl_path: object.path.as_ref().map(|p| p.display().to_string()),
                stl_sha256: Some(object.sha256.clone()),
            },
            plan_spec: spec.clone(),
            poses: plan.poses.clone(),
            profile_name: profile.name.clone(),
            work_frame: config.work_frame,
            options: config.collect.clone(),
            out: self.out.clone(),
            resume: self.resume,
            disk_budget_bytes: config.faults.disk_budget_bytes,
            arm: arm_part(config, &profile),
            modbus: modbus_parts(config),
            fence,
            adaptive: None,
        };
        if self.resume {
            // A dataset an earlier rig build collected on a built-in object recorded another hash of the same
            // mesh ([`ObjectChoice::legacy_sha256`]): it resumes under the hash it has.
            let legacy = object.legacy_sha256();
            let has_legacy = |sensor| {
                crate::dataset::Manifest::load(&setup.dataset_dir(sensor))
                    .is_ok_and(|m| m.object.stl_sha256.is_some_and(|h| h.eq_ignore_ascii_case(&legacy)))
            };
            if self.sensor.iter().any(has_legacy) {
                setup.object.stl_sha256 = Some(legacy);
            }
        }
        Ok(PreparedCollect { setup, object, sensors: self.sensor.clone(), plan, kept_order, grid_len: spec.grid_len(), profile, envelope })
    }
}

impl PreparedCollect {
    /// `plan: N poses of a M-point grid; motion time ...`, as `rig collect` prints it.
    pub fn plan_line(&self) -> String {
        let order = match &self.kept_order {
            Some(path) => format!("in the order kept in {}", relative_to_working_folder(path).display()),
            None => "in rig's order".to_string(),
        };
        format!(
            "plan: {} poses of a {}-point grid; motion time {:.1} s as sampled, {:.1} s {order}",
            self.plan.poses.len(),
            self.grid_len,
            self.plan.motion_time_before_s,
            self.plan.motion_time_after_s
        )
    }
}

/// The first order kept by one of `datasets` (in the order given) whose manifest `belongs`
/// (a dataset of another plan is left to the writer, which refuses it by name), as the path
/// of its `order.csv` and the ids it lists. Every such order is read, so a malformed one is
/// refused before anything moves.
pub(crate) fn kept_order(datasets: &[PathBuf], belongs: impl Fn(&Manifest) -> bool) -> Result<Option<(PathBuf, Vec<u32>)>, JobError> {
    let mut first = None;
    for dir in datasets {
        let has_manifest =
            crate::dataset::durable::entry_exists(&dir.join(crate::dataset::MANIFEST_FILE), crate::dataset::durable::Kind::File)
                .map_err(|source| JobError::Dataset { dir: dir.clone(), source })?;
        if !has_manifest || !Manifest::load(dir).is_ok_and(|m| belongs(&m)) {
            continue;
        }
        if let Some(ids) = order::read_order(dir).map_err(|source| JobError::Dataset { dir: dir.clone(), source })? {
            first.get_or_insert((dir.join(order::ORDER_FILE), ids));
        }
    }
    Ok(first)
}

/// `source` as the job error of the dataset holding `file`.
fn dataset_error(file: &Path, source: DatasetError) -> JobError {
    JobError::Dataset { dir: file.parent().map(Path::to_path_buf).unwrap_or_default(), source }
}

/// Everything a collection run needs besides the hardware: what its manifests say, the poses,
/// where the datasets go. [`CollectRequest::prepare`] makes one; `rig replay` rebuilds the one
/// it recorded.
#[derive(Debug, Clone)]
pub struct CollectSetup {
    pub object: ObjectInfo,
    pub plan_spec: PlanSpec,
    /// The poses, in the order they are visited.
    pub poses: Vec<PlannedPose>,
    pub profile_name: String,
    pub work_frame: WorkFrame,
    pub options: CollectConfig,
    /// Output root; datasets go to `<out>/<object>/<sensor>/`.
    pub out: PathBuf,
    pub resume: bool,
    /// Injected disk-full fault (`[sim.faults] disk_budget_bytes`).
    pub disk_budget_bytes: Option<u64>,
    /// The arm, as the manifests' capture chain names it ([`run`] adds the firmware version
    /// the controller reports, if it reports one).
    pub arm: CapturePart,
    /// The Modbus peripherals, as the manifests' capture chain names them.
    pub modbus: Vec<CapturePart>,
    /// The workspace and press limit every pose keeps to, checked again by [`run`] before the
    /// arm moves.
    pub fence: Fence,
    /// An adaptive collection's record: its settings go into each dataset's manifest, its
    /// choices into `adaptive.csv` (its rounds are the visiting order, so no `order.csv` is
    /// kept); `None` for a plain collection.
    pub adaptive: Option<crate::plan::adaptive::AdaptiveRecord>,
}

impl CollectSetup {
    /// The dataset folder of `sensor`.
    pub fn dataset_dir(&self, sensor: SensorKind) -> PathBuf {
        self.out.join(&self.object.name).join(sensor.name())
    }

    /// The manifest a new dataset of `sensor` starts with; `arm` and `sensors` are the capture
    /// parts of the run's arm and of every sensor of the run.
    fn manifest(&self, sensor: SensorKind, calibration: &str, arm: &CapturePart, sensors: &[CapturePart]) -> Manifest {
        // The STL as the dataset names it: relative to its folder when inside, else absolute.
        let object = ObjectInfo {
            stl_path: self.object.stl_path.as_deref().map(|p| ObjectInfo::stored_stl_path(Path::new(p), &self.dataset_dir(sensor))),
            ..self.object.clone()
        };
        let mut manifest = Manifest::new(sensor, object, Some(self.plan_spec.clone()));
        manifest.calibration = Some(calibration.to_string());
        manifest.firmware_profile = Some(self.profile_name.clone());
        manifest.work_frame = Some(self.work_frame);
        manifest.capture = Some(CaptureChain { arm: arm.clone(), sensors: sensors.to_vec(), modbus: self.modbus.clone() });
        manifest.adaptive = self.adaptive.as_ref().map(|a| a.settings.clone());
        manifest
    }
}

/// The arm of `config` as a capture part (`arm`: `sim-mg400`, `mg400` at its host, `magician`
/// on its serial port). The simulated MG400 runs `profile`, so its firmware is the profile's
/// version marked `(simulated)`; a real controller's firmware is what it reports when the run
/// starts ([`Arm::firmware_version`]), and the MG400 reports none.
pub fn arm_part(config: &RigConfig, profile: &FirmwareProfile) -> CapturePart {
    match &config.arm.backend {
        ArmBackend::Simulated { .. } => {
            let mut part = CapturePart::new("arm", "sim-mg400", true, None);
            part.firmware = Some(format!("{} (simulated)", profile.firmware));
            part
        }
        ArmBackend::Mg400 { host, dashboard_port, .. } => CapturePart::new("arm", "mg400", false, Some(format!("{host}:{dashboard_port}"))),
        ArmBackend::Magician { serial_port } => CapturePart::new("arm", "magician", false, Some(serial_port.display().to_string())),
    }
}

/// The Modbus peripherals of `config` as capture parts (`modbus.<name>`), in name order.
pub fn modbus_parts(config: &RigConfig) -> Vec<CapturePart> {
    config
        .modbus
        .iter()
        .map(|(name, p)| {
            let name = format!("modbus.{name}");
            match &p.transport {
                ModbusTransport::Tcp { address } => CapturePart::new(name, "tcp", false, Some(address.clone())),
                ModbusTransport::Rtu { device, .. } => CapturePart::new(name, "rtu", false, Some(device.display().to_string())),
                ModbusTransport::Sim { .. } => CapturePart::new(name, "sim", true, None),
            }
        })
        .collect()
}

/// One camera of a collection and the sensor whose dataset it fills.
pub struct SensorFeed<C> {
    pub camera: C,
    pub sensor: SensorKind,
    /// The calibration it renders or was fitted with (named in the manifest).
    pub calibration: String,
    /// The camera as the manifest's capture chain names it; its `simulated` flag decides the
    /// rows' source (`simulated` or `real`).
    pub capture: CapturePart,
}

/// How a collection ended when it did not fail.
#[derive(Debug, Clone, PartialEq)]
pub struct CollectOutcome {
    pub summary: CollectSummary,
    /// Where the datasets are (`<out>/<object>`).
    pub root: PathBuf,
    /// One dataset per sensor.
    pub datasets: Vec<PathBuf>,
}

impl CollectOutcome {
    /// The last line `rig collect` prints (and a daemon job's message); `resume` is how the
    /// front end spells the option that continues an interrupted run.
    pub fn line(&self, resume: &str) -> String {
        let s = &self.summary;
        if s.interrupted {
            format!("interrupted: {} poses captured, {} left; continue with {resume}", s.captured, s.remaining)
        } else {
            format!(
                "collected {} poses ({} already present, {} arm or camera faults recovered) into {}",
                s.captured,
                s.skipped,
                s.recovered_faults,
                relative_to_working_folder(&self.root).display()
            )
        }
    }
}

/// Creates `<out>/<object>/<sensor>/` (or finds it) with no symlink below `<out>`: the object
/// and sensor folders come from the request, and a symlink planted there (`<out>/sphere ->
/// /elsewhere`) would put the dataset outside what was approved. `<out>` itself is the
/// operator's path (or a request's, confined to the data roots).
fn confine_dataset_dir(setup: &CollectSetup, sensor: SensorKind) -> Result<(), crate::dataset::DatasetError> {
    std::fs::create_dir_all(&setup.out).map_err(|e| crate::dataset::DatasetError::Io {
        op: "creating",
        path: setup.out.clone(),
        source: e,
    })?;
    let out = crate::confine::RootDir::open(&setup.out)?;
    out.create_dir_all(std::path::Path::new(&setup.object.name).join(sensor.name()))?;
    Ok(())
}

/// `path` relative to the working folder when it lies inside it, else as it is: a daemon job,
/// whose paths were resolved against the daemon's working folder, reports `out/tour/edge` as the
/// standalone command does.
fn relative_to_working_folder(path: &Path) -> PathBuf {
    match std::env::current_dir() {
        Ok(cwd) if path.is_absolute() => match path.strip_prefix(&cwd) {
            Ok(inside) if !inside.as_os_str().is_empty() => inside.to_path_buf(),
            _ => path.to_path_buf(),
        },
        _ => path.to_path_buf(),
    }
}

/// Runs a collection: checks `setup.poses` against `setup.fence`, opens (or resumes) one
/// dataset per camera and drives the arm through the poses. The one place a [`CollectJob`] is
/// built: `rig collect`, `rig audit`, the daemon, `rig replay` and `rig bench` all come here,
/// so no pose reaches the arm without passing the fence. `stop_after` stops as if cancelled
/// after that many poses (a replay stops where its recording was interrupted).
pub async fn run<A: Arm, C: Camera, P: Peripherals>(
    setup: &CollectSetup,
    arm: &mut A,
    cameras: Vec<SensorFeed<C>>,
    peripherals: P,
    clock: Arc<dyn Clock>,
    observer: Observer,
    stop_after: Option<usize>,
) -> Result<CollectOutcome, JobError> {
    setup.fence.check(&setup.work_frame, &setup.poses)?;
    let mut sensors = Vec::new();
    let mut datasets = Vec::new();
    let order_ids: Vec<u32> = setup.poses.iter().map(|p| p.pose_id).collect();
    let parts: Vec<CapturePart> = cameras.iter().map(|f| f.capture.clone()).collect();
    let mut arm_part = setup.arm.clone();
    if let Some(version) = arm.firmware_version().await {
        arm_part.firmware = Some(version);
    }
    for feed in cameras {
        let dir = setup.dataset_dir(feed.sensor);
        confine_dataset_dir(setup, feed.sensor).map_err(|source| JobError::Dataset { dir: dir.clone(), source })?;
        let manifest = setup.manifest(feed.sensor, &feed.calibration, &arm_part, &parts);
        let writer = DatasetWriter::start(&dir, manifest, setup.resume)
            .map_err(|source| JobError::Dataset { dir: dir.clone(), source })?
            .with_byte_budget(setup.disk_budget_bytes);
        // The order, kept before the first pose (under the writer's lock); a dataset that
        // keeps one already keeps it. An adaptive collection's order is its rounds, recorded
        // here up to this one (`adaptive.csv`) before the round's first press.
        match &setup.adaptive {
            None => order::keep_order(&dir, &order_ids).map(drop),
            Some(record) => choices::keep_choices(&dir, &record.choices).map(drop),
        }
        .map_err(|source| JobError::Dataset { dir: dir.clone(), source })?;
        let source = Source::captured(feed.capture.simulated);
        sensors.push(SensorStream { camera: feed.camera, writer, source });
        datasets.push(dir);
    }
    let job = CollectJob {
        arm,
        sensors,
        work_frame: setup.work_frame,
        options: setup.options.clone(),
        clock,
        cancel: observer.cancel,
        stop_after,
        progress: observer.progress,
        peripherals,
    };
    let summary = job.run(&setup.poses).await?;
    Ok(CollectOutcome { summary, root: setup.out.join(&setup.object.name), datasets })
}
