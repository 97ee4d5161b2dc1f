//! What the daemon knows, shared between the worker (which writes it) and the HTTP API
//! (which reads it and queues or cancels jobs).
//!
//! One [`DaemonState`] behind a mutex: the job list (queue, running job, history), the arm's
//! last published mode and pose, the latest frame of every sensor (JPEG bytes, encoded once
//! when captured), the latest control/synthetic pair of a synth job (PNG bytes), and the
//! recent errors. Progress of the running job is read from the job's own
//! [`indicatif::ProgressBar`] (the collect and fill jobs already report into one), so the jobs
//! need no second progress channel.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use tokio::sync::{Notify, watch};

use crate::jobs::JobRequest;
use crate::pose::Pose;

/// Finished jobs kept for `GET /api/jobs` (older ones are forgotten).
pub const KEEP_FINISHED: usize = 200;
/// Most jobs waiting in the queue; a submission past it is refused (503) until one starts.
pub const MAX_QUEUED: usize = 100;
/// Most jobs one `GET /api/jobs` page holds (the default page size too).
pub const MAX_PAGE: usize = 50;
/// Errors kept for the status and the page.
const KEEP_ERRORS: usize = 20;

/// Where a job is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    Queued,
    Running,
    Done,
    Failed,
    Cancelled,
}

impl JobState {
    /// True once the job will not change any more.
    pub fn is_final(self) -> bool {
        matches!(self, JobState::Done | JobState::Failed | JobState::Cancelled)
    }
}

/// Progress of a job in its own unit (poses for collect and synth, presses for calibrate).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    pub done: u64,
    pub total: u64,
    /// Estimated time to the end, s (from this run's rate; `None` until the rate is known).
    pub eta_s: Option<f64>,
}

/// One job as the API shows it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct JobView {
    pub id: u64,
    pub spec: JobRequest,
    pub state: JobState,
    pub progress: Progress,
    /// Unix times, s.
    pub submitted_unix_s: f64,
    pub started_unix_s: Option<f64>,
    pub finished_unix_s: Option<f64>,
    /// What a finished job did (the line the standalone command prints).
    pub message: Option<String>,
    /// Why a job failed.
    pub error: Option<String>,
    /// The exit code the standalone command would have returned (0 ok, 1 failure, 2 bad
    /// input, 3 hardware fault, 4 interrupted); `None` until final.
    pub exit_code: Option<u8>,
}

/// A job with the handles the worker and the API act through.
struct Job {
    view: JobView,
    cancel: watch::Sender<bool>,
    progress: indicatif::ProgressBar,
    /// First progress seen while running, and when: the origin of the rate behind the ETA
    /// (poses a resumed run skips at once must not count as speed).
    rate_origin: Option<(u64, Instant)>,
    /// When it started running.
    started: Option<Instant>,
}

impl Job {
    fn refresh(&mut self) {
        if self.view.state != JobState::Running {
            return;
        }
        let total = self.progress.length().unwrap_or(0);
        if self.progress.is_finished() {
            // Finishing a bar moves it to its end, also when the job stopped early: keep the
            // last position seen; the worker reports the true count when it knows it.
            self.view.progress.total = total;
            return;
        }
        let done = self.progress.position();
        let now = Instant::now();
        let (pos0, t0) = *self.rate_origin.get_or_insert((done, now));
        // The rate since the first look (which excludes poses a resumed run skipped at
        // once); until that has moved, the rate since the start.
        let origin = if done > pos0 { Some((pos0, t0)) } else { self.started.filter(|_| done > 0).map(|t| (0, t)) };
        let eta_s = origin
            .filter(|_| total >= done)
            .map(|(pos0, t0)| now.duration_since(t0).as_secs_f64() / (done - pos0) as f64 * (total - done) as f64);
        self.view.progress = Progress { done, total, eta_s };
    }
}

/// The arm as last published by the worker.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct ArmView {
    /// The controller's robot mode when it reports one (MG400 feedback), else what rig last
    /// asked of it (`enabled`, `disabled`).
    pub mode: String,
    /// Measured base-frame pose.
    pub pose: Option<Pose>,
    /// Plan pose the running job is at or moving to (`None`: the reference pose or idle).
    pub pose_id: Option<u32>,
}

/// An error worth showing: a failed job, or a fault the worker met.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ErrorEntry {
    pub unix_s: f64,
    pub job_id: Option<u64>,
    pub message: String,
}

/// A sensor's latest frame, encoded.
#[derive(Debug, Clone)]
pub struct EncodedFrame {
    /// Counts frames published for this sensor (changes whenever the image does).
    pub seq: u64,
    pub width: u32,
    pub height: u32,
    /// Capture time on the rig clock, s.
    pub t_capture_s: f64,
    pub content_type: &'static str,
    pub bytes: Arc<Vec<u8>>,
}

/// The latest control image and synthetic image of a synth job, PNG.
#[derive(Debug, Clone)]
pub struct SynthPair {
    pub seq: u64,
    pub job_id: u64,
    pub pose_id: u32,
    pub control_png: Arc<Vec<u8>>,
    pub image_png: Arc<Vec<u8>>,
}

/// `GET /api/status`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StatusView {
    pub version: String,
    /// `running` or `stopping`.
    pub daemon: String,
    pub rig: String,
    pub uptime_s: f64,
    pub arm: ArmView,
    /// The running job, if any.
    pub current: Option<JobView>,
    pub queued: usize,
    /// Sensor name, frame counter and size of each sensor that has a frame.
    pub sensors: Vec<SensorView>,
    pub synth: Option<SynthView>,
    pub errors: Vec<ErrorEntry>,
}

/// A sensor in the status.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SensorView {
    pub name: String,
    pub seq: u64,
    pub width: u32,
    pub height: u32,
    pub t_capture_s: f64,
}

/// The synth pair in the status.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SynthView {
    pub seq: u64,
    pub job_id: u64,
    pub pose_id: u32,
}

struct Inner {
    next_id: u64,
    jobs: Vec<Job>,
    accepting: bool,
    arm: ArmView,
    frames: BTreeMap<String, EncodedFrame>,
    synth: Option<SynthPair>,
    errors: VecDeque<ErrorEntry>,
}

/// The daemon's shared state; cheap to share as `Arc<DaemonState>`.
pub struct DaemonState {
    inner: Mutex<Inner>,
    /// Wakes the worker when a job is queued or the daemon stops.
    pub(crate) wake: Notify,
    started: Instant,
    rig: String,
}

/// A job handed to the worker.
pub struct StartedJob {
    pub id: u64,
    pub spec: JobRequest,
    pub cancel: watch::Receiver<bool>,
    pub progress: indicatif::ProgressBar,
}

/// How a job ended, as the worker reports it.
#[derive(Debug, Clone)]
pub enum JobOutcome {
    Done { message: String },
    Cancelled { message: String },
    Failed { error: String, exit_code: u8 },
}

/// Why a submission was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SubmitError {
    #[error("the daemon is shutting down; no new jobs")]
    ShuttingDown,
    #[error("the queue already holds {max} jobs; wait for some to run, or cancel some")]
    QueueFull { max: usize },
}

/// One page of the job list: `jobs` oldest first, the newest ones older than the cursor.
#[derive(Debug, Clone)]
pub struct JobsPage {
    pub jobs: Vec<JobView>,
    /// Jobs the daemon holds (queued, running and the finished ones kept).
    pub total: usize,
    /// The cursor of the next (older) page, when there are older jobs.
    pub next_before: Option<u64>,
}

/// Why a cancel was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CancelError {
    #[error("no job {id}")]
    NoSuchJob { id: u64 },
    #[error("job {id} has already ended ({state:?})")]
    AlreadyFinal { id: u64, state: JobState },
}

pub(crate) fn unix_now_s() -> f64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0)
}

impl DaemonState {
    /// Empty state of a daemon driving `rig` (its one-line description).
    pub fn new(rig: String) -> Self {
        Self {
            inner: Mutex::new(Inner {
                next_id: 1,
                jobs: Vec::new(),
                accepting: true,
                arm: ArmView { mode: "unknown".into(), ..ArmView::default() },
                frames: BTreeMap::new(),
                synth: None,
                errors: VecDeque::new(),
            }),
            wake: Notify::new(),
            started: Instant::now(),
            rig,
        }
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        // A panic while holding the lock leaves plain data behind; keep serving it.
        self.inner.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Queues a job; refused once the daemon is stopping or [`MAX_QUEUED`] jobs wait.
    pub fn submit(&self, spec: JobRequest) -> Result<JobView, SubmitError> {
        let mut inner = self.lock();
        if !inner.accepting {
            return Err(SubmitError::ShuttingDown);
        }
        if inner.jobs.iter().filter(|j| j.view.state == JobState::Queued).count() >= MAX_QUEUED {
            return Err(SubmitError::QueueFull { max: MAX_QUEUED });
        }
        let id = inner.next_id;
        inner.next_id += 1;
        let (cancel, _) = watch::channel(false);
        let view = JobView {
            id,
            spec,
            state: JobState::Queued,
            progress: Progress { done: 0, total: 0, eta_s: None },
            submitted_unix_s: unix_now_s(),
            started_unix_s: None,
            finished_unix_s: None,
            message: None,
            error: None,
            exit_code: None,
        };
        inner.jobs.push(Job { view: view.clone(), cancel, progress: indicatif::ProgressBar::hidden(), rate_origin: None, started: None });
        drop(inner);
        self.wake.notify_one();
        Ok(view)
    }

    /// Every job, oldest first.
    pub fn jobs(&self) -> Vec<JobView> {
        let mut inner = self.lock();
        inner
            .jobs
            .iter_mut()
            .map(|j| {
                j.refresh();
                j.view.clone()
            })
            .collect()
    }

    /// Up to `limit` (at most [`MAX_PAGE`]) of the newest jobs with an id below `before` (all,
    /// when `None`), oldest first: `GET /api/jobs?limit=N&before=ID`.
    pub fn jobs_page(&self, before: Option<u64>, limit: usize) -> JobsPage {
        let limit = limit.clamp(1, MAX_PAGE);
        let mut inner = self.lock();
        let total = inner.jobs.len();
        // Ids grow with the list, so the jobs below the cursor are a prefix of it.
        let end = before.map_or(total, |b| inner.jobs.partition_point(|j| j.view.id < b));
        let start = end.saturating_sub(limit);
        let jobs: Vec<JobView> = inner.jobs[start..end]
            .iter_mut()
            .map(|j| {
                j.refresh();
                j.view.clone()
            })
            .collect();
        let next_before = (start > 0).then(|| jobs.first().map(|j| j.id)).flatten();
        JobsPage { jobs, total, next_before }
    }

    /// One job.
    pub fn job(&self, id: u64) -> Option<JobView> {
        let mut inner = self.lock();
        inner.jobs.iter_mut().find(|j| j.view.id == id).map(|j| {
            j.refresh();
            j.view.clone()
        })
    }

    /// Cancels a queued job at once, or asks the running one to stop at its next safe point.
    pub fn cancel(&self, id: u64) -> Result<JobView, CancelError> {
        let mut inner = self.lock();
        let job = inner.jobs.iter_mut().find(|j| j.view.id == id).ok_or(CancelError::NoSuchJob { id })?;
        match job.view.state {
            JobState::Queued => {
                job.view.state = JobState::Cancelled;
                job.view.finished_unix_s = Some(unix_now_s());
                job.view.message = Some("cancelled before it started".into());
                job.view.exit_code = Some(4);
                let view = job.view.clone();
                forget_old_jobs(&mut inner);
                return Ok(view);
            }
            JobState::Running => {
                let _ = job.cancel.send(true);
                job.refresh();
            }
            state => return Err(CancelError::AlreadyFinal { id, state }),
        }
        Ok(job.view.clone())
    }

    /// Takes the oldest queued job and marks it running.
    pub fn start_next(&self) -> Option<StartedJob> {
        let mut inner = self.lock();
        let job = inner.jobs.iter_mut().find(|j| j.view.state == JobState::Queued)?;
        job.view.state = JobState::Running;
        job.view.started_unix_s = Some(unix_now_s());
        job.started = Some(Instant::now());
        Some(StartedJob { id: job.view.id, spec: job.view.spec.clone(), cancel: job.cancel.subscribe(), progress: job.progress.clone() })
    }

    /// Records how the running job `id` ended.
    /// `done`, when known, is the job's true final progress count.
    pub fn finish(&self, id: u64, outcome: JobOutcome, done: Option<u64>) {
        let mut inner = self.lock();
        let Some(job) = inner.jobs.iter_mut().find(|j| j.view.id == id) else { return };
        job.refresh();
        job.view.progress.eta_s = None;
        if let Some(done) = done {
            job.view.progress.done = done;
        }
        job.view.finished_unix_s = Some(unix_now_s());
        let mut error = None;
        match outcome {
            JobOutcome::Done { message } => {
                job.view.state = JobState::Done;
                job.view.message = Some(message);
                job.view.exit_code = Some(0);
            }
            JobOutcome::Cancelled { message } => {
                job.view.state = JobState::Cancelled;
                job.view.message = Some(message);
                job.view.exit_code = Some(4);
            }
            JobOutcome::Failed { error: e, exit_code } => {
                job.view.state = JobState::Failed;
                job.view.error = Some(e.clone());
                job.view.exit_code = Some(exit_code);
                error = Some(e);
            }
        }
        if let Some(message) = error {
            push_error(&mut inner, Some(id), message);
        }
        inner.arm.pose_id = None;
        forget_old_jobs(&mut inner);
    }

    /// Stops accepting jobs, cancels the queued ones and asks the running one to stop.
    ///
    /// Returns a line for each running job it cancels, saying where that job stood, for the
    /// daemon's log.
    pub fn begin_shutdown(&self) -> Vec<String> {
        let mut inner = self.lock();
        inner.accepting = false;
        let mut cancelled_running = Vec::new();
        for job in &mut inner.jobs {
            match job.view.state {
                JobState::Queued => {
                    job.view.state = JobState::Cancelled;
                    job.view.finished_unix_s = Some(unix_now_s());
                    job.view.message = Some("cancelled: the daemon is shutting down".into());
                    job.view.exit_code = Some(4);
                }
                JobState::Running => {
                    let _ = job.cancel.send(true);
                    let (done, total) = (job.progress.position(), job.progress.length().unwrap_or(0));
                    cancelled_running.push(format!(
                        "shutdown: cancelling running {} job {} at {done}/{total} (what it wrote stays; the same job resumes it)",
                        job.view.spec.kind(),
                        job.view.id
                    ));
                }
                _ => {}
            }
        }
        forget_old_jobs(&mut inner);
        drop(inner);
        self.wake.notify_one();
        cancelled_running
    }

    /// True until [`begin_shutdown`](Self::begin_shutdown).
    pub fn accepting(&self) -> bool {
        self.lock().accepting
    }

    /// Records an error that is not a job's own failure (e.g. a fault while idle).
    pub fn record_error(&self, job_id: Option<u64>, message: String) {
        push_error(&mut self.lock(), job_id, message);
    }

    /// Publishes the arm's mode and pose (fields left `None` keep their value).
    pub fn set_arm(&self, mode: Option<String>, pose: Option<Pose>) {
        let mut inner = self.lock();
        if let Some(mode) = mode {
            inner.arm.mode = mode;
        }
        if pose.is_some() {
            inner.arm.pose = pose;
        }
    }

    /// Publishes the plan pose the running job is at (`None`: the reference pose).
    pub fn set_pose_id(&self, pose_id: Option<u32>) {
        self.lock().arm.pose_id = pose_id;
    }

    /// Publishes a sensor's latest frame (the sequence number is assigned here).
    pub fn set_frame(&self, sensor: &str, mut frame: EncodedFrame) {
        let mut inner = self.lock();
        frame.seq = inner.frames.get(sensor).map_or(1, |f| f.seq + 1);
        inner.frames.insert(sensor.to_string(), frame);
    }

    /// A sensor's latest frame.
    pub fn frame(&self, sensor: &str) -> Option<EncodedFrame> {
        self.lock().frames.get(sensor).cloned()
    }

    /// Publishes a synth job's latest control/synthetic pair.
    pub fn set_synth(&self, job_id: u64, pose_id: u32, control_png: Vec<u8>, image_png: Vec<u8>) {
        let mut inner = self.lock();
        let seq = inner.synth.as_ref().map_or(1, |s| s.seq + 1);
        inner.synth = Some(SynthPair { seq, job_id, pose_id, control_png: Arc::new(control_png), image_png: Arc::new(image_png) });
    }

    /// The latest control/synthetic pair.
    pub fn synth(&self) -> Option<SynthPair> {
        self.lock().synth.clone()
    }

    /// `GET /api/status`.
    pub fn status(&self) -> StatusView {
        let mut inner = self.lock();
        let mut current = None;
        let mut queued = 0;
        for job in &mut inner.jobs {
            match job.view.state {
                JobState::Running => {
                    job.refresh();
                    current = Some(job.view.clone());
                }
                JobState::Queued => queued += 1,
                _ => {}
            }
        }
        StatusView {
            version: crate::version().to_string(),
            daemon: if inner.accepting { "running" } else { "stopping" }.to_string(),
            rig: self.rig.clone(),
            uptime_s: self.started.elapsed().as_secs_f64(),
            arm: inner.arm.clone(),
            current,
            queued,
            sensors: inner
                .frames
                .iter()
                .map(|(name, f)| SensorView {
                    name: name.clone(),
                    seq: f.seq,
                    width: f.width,
                    height: f.height,
                    t_capture_s: f.t_capture_s,
                })
                .collect(),
            synth: inner.synth.as_ref().map(|s| SynthView { seq: s.seq, job_id: s.job_id, pose_id: s.pose_id }),
            errors: inner.errors.iter().cloned().collect(),
        }
    }
}

/// Forgets the oldest finished jobs beyond [`KEEP_FINISHED`].
fn forget_old_jobs(inner: &mut Inner) {
    let finished = inner.jobs.iter().filter(|j| j.view.state.is_final()).count();
    if finished > KEEP_FINISHED {
        let mut drop_n = finished - KEEP_FINISHED;
        inner.jobs.retain(|j| {
            if drop_n > 0 && j.view.state.is_final() {
                drop_n -= 1;
                false
            } else {
                true
            }
        });
    }
}

fn push_error(inner: &mut Inner, job_id: Option<u64>, message: String) {
    inner.errors.push_back(ErrorEntry { unix_s: unix_now_s(), job_id, message });
    while inner.errors.len() > KEEP_ERRORS {
        inner.errors.pop_front();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> JobRequest {
        JobRequest::Collect(Default::default())
    }

    #[test]
    fn jobs_run_in_order_and_a_queued_cancel_is_final_at_once() {
        let state = DaemonState::new("test rig".into());
        let a = state.submit(spec()).expect("accepting");
        let b = state.submit(spec()).expect("accepting");
        let c = state.submit(spec()).expect("accepting");
        assert_eq!(state.cancel(b.id).expect("cancel").state, JobState::Cancelled);
        assert_eq!(state.start_next().map(|j| j.id), Some(a.id));
        assert_eq!(state.status().current.map(|j| j.id), Some(a.id));
        state.finish(a.id, JobOutcome::Failed { error: "boom".into(), exit_code: 3 }, None);
        // The cancelled job is skipped.
        assert_eq!(state.start_next().map(|j| j.id), Some(c.id));
        let status = state.status();
        assert_eq!(status.errors.len(), 1);
        assert_eq!((status.errors[0].job_id, status.errors[0].message.as_str()), (Some(a.id), "boom"));
        assert_eq!(state.job(a.id).map(|j| (j.state, j.exit_code)), Some((JobState::Failed, Some(3))));
        assert_eq!(state.cancel(a.id).map(|j| j.id), Err(CancelError::AlreadyFinal { id: a.id, state: JobState::Failed }));
        assert_eq!(state.cancel(99).map(|j| j.id), Err(CancelError::NoSuchJob { id: 99 }));
    }

    #[test]
    fn a_running_cancel_signals_the_job_and_shutdown_cancels_the_queue() {
        let state = DaemonState::new("test rig".into());
        let a = state.submit(spec()).expect("accepting");
        let b = state.submit(spec()).expect("accepting");
        let running = state.start_next().expect("a job");
        assert!(!*running.cancel.borrow());
        assert_eq!(state.cancel(a.id).expect("cancel").state, JobState::Running, "stops at its next safe point");
        assert!(*running.cancel.borrow());
        running.progress.set_length(200);
        running.progress.set_position(77);
        let lines = state.begin_shutdown();
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(lines[0].starts_with(&format!("shutdown: cancelling running collect job {} at 77/200", a.id)), "{lines:?}");
        assert_eq!(state.submit(spec()).map(|j| j.id), Err(SubmitError::ShuttingDown));
        assert_eq!(state.job(b.id).map(|j| j.state), Some(JobState::Cancelled));
        assert!(state.start_next().is_none());
        assert_eq!(state.status().daemon, "stopping");
    }

    #[test]
    fn errors_and_finished_jobs_are_bounded() {
        let state = DaemonState::new("test rig".into());
        for k in 0..(KEEP_FINISHED + 5) {
            let j = state.submit(spec()).expect("accepting");
            state.start_next();
            state.finish(j.id, JobOutcome::Failed { error: format!("e{k}"), exit_code: 1 }, None);
        }
        assert_eq!(state.jobs().len(), KEEP_FINISHED);
        // Jobs cancelled in the queue count as finished too.
        for _ in 0..5 {
            let j = state.submit(spec()).expect("accepting");
            state.cancel(j.id).expect("cancel");
        }
        assert_eq!(state.jobs().len(), KEEP_FINISHED);
        let errors = state.status().errors;
        assert_eq!(errors.len(), KEEP_ERRORS);
        assert_eq!(errors.last().map(|e| e.message.clone()), Some(format!("e{}", KEEP_FINISHED + 4)));
    }
}

#[cfg(test)]
mod paging_tests {
    use super::*;

    #[test]
    fn the_queue_is_bounded_and_the_list_comes_in_pages() {
        let state = DaemonState::new("test rig".into());
        let ids: Vec<u64> = (0..MAX_QUEUED).map(|_| state.submit(JobRequest::Collect(Default::default())).expect("room").id).collect();
        let full = state.submit(JobRequest::Collect(Default::default())).map(|j| j.id);
        assert_eq!(full, Err(SubmitError::QueueFull { max: MAX_QUEUED }));
        // The newest page first, oldest first within it; a cursor walks back to the oldest.
        let page = state.jobs_page(None, 1000);
        assert_eq!(page.total, MAX_QUEUED);
        assert_eq!(page.jobs.len(), MAX_PAGE, "a page is capped");
        assert_eq!(page.jobs.iter().map(|j| j.id).collect::<Vec<_>>(), ids[MAX_QUEUED - MAX_PAGE..]);
        let mut seen = page.jobs.iter().map(|j| j.id).collect::<Vec<_>>();
        let mut cursor = page.next_before;
        while let Some(before) = cursor {
            let page = state.jobs_page(Some(before), 30);
            assert!(page.jobs.len() <= 30 && page.jobs.iter().all(|j| j.id < before));
            seen.splice(0..0, page.jobs.iter().map(|j| j.id));
            cursor = page.next_before;
        }
        assert_eq!(seen, ids, "every job once, in order");
        assert!(state.jobs_page(Some(1), 10).jobs.is_empty());
        // A job that starts frees a place in the queue.
        state.start_next().expect("a job");
        assert!(state.submit(JobRequest::Collect(Default::default())).is_ok());
    }
}
