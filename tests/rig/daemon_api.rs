//! `rig daemon`'s HTTP API against the built-in simulated rig, in-process on 127.0.0.1:0:
//! a collection's progress and frames, cancel, a failing job that does not stop the queue,
//! the token rule, a synth job's control/synthetic pair, and a clean shutdown.

use std::path::Path;
use std::time::Duration;

use rig::config::RigConfig;
use rig::daemon::client::DaemonClient;
use rig::daemon::{Daemon, DaemonError, DaemonOptions, JobState, JobView, StatusView};
use serde_json::json;

/// A daemon on the built-in simulated rig whose jobs may touch `roots` only (the first is the
/// base of relative paths).
pub(crate) async fn start(token: Option<&str>, roots: &[&Path]) -> (Daemon, DaemonClient) {
    start_on(RigConfig::builtin_sim(), token, roots).await
}

/// [`start`] on the rig `config` describes.
async fn start_on(config: RigConfig, token: Option<&str>, roots: &[&Path]) -> (Daemon, DaemonClient) {
    let mut options = DaemonOptions::local(config);
    let dirs: Vec<std::path::PathBuf> = roots.iter().map(|r| r.to_path_buf()).collect();
    options.roots = Some(rig::roots::DataRoots::new(&dirs, roots[0]).expect("data roots"));
    // Frames come from the jobs only: the tests see what the jobs publish.
    options.idle_refresh = None;
    options.token = token.map(str::to_string);
    let daemon = Daemon::start(options).await.expect("daemon starts");
    let client = DaemonClient::new(&format!("http://{}", daemon.addr()), token.map(str::to_string)).expect("client");
    (daemon, client)
}

async fn submit(client: &DaemonClient, spec: serde_json::Value) -> JobView {
    let r = client.request("POST", "/api/jobs", Some(spec.to_string().as_bytes())).await.expect("POST /api/jobs");
    assert_eq!(r.status, 201, "{}", String::from_utf8_lossy(&r.body));
    serde_json::from_slice(&r.body).expect("job json")
}

async fn job(client: &DaemonClient, id: u64) -> JobView {
    client.get_json(&format!("/api/jobs/{id}")).await.expect("GET job")
}

/// Polls the job until `done` holds, returning every view seen. Gives up after a generous
/// number of polls (a hung job fails the test instead of hanging it).
pub(crate) async fn poll_until(client: &DaemonClient, id: u64, done: impl Fn(&JobView) -> bool) -> Vec<JobView> {
    let mut seen = Vec::new();
    for _ in 0..6000 {
        let j = job(client, id).await;
        let stop = done(&j);
        seen.push(j);
        if stop {
            return seen;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    panic!("job {id} never reached the awaited state; last: {:?}", seen.last());
}

pub(crate) fn final_state(j: &JobView) -> bool {
    j.state.is_final()
}

fn rows(dir: &Path) -> usize {
    rig::dataset::read_rows(dir).expect("rows").len()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_collection_reports_progress_pose_and_frames() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (daemon, client) = start(None, &[tmp.path()]).await;
    let j =
        submit(&client, json!({"kind": "collect", "object": "edge", "sensor": "tactip,vitac", "poses": 6, "seed": 4, "out": tmp.path()}))
            .await;
    assert_eq!(j.state, JobState::Queued);

    let mut pose_ids = Vec::new();
    let mut seen = Vec::new();
    for _ in 0..6000 {
        let status: StatusView = client.get_json("/api/status").await.expect("status");
        pose_ids.extend(status.arm.pose_id);
        let view = job(&client, j.id).await;
        let end = view.state.is_final();
        seen.push(view);
        if end {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let last = seen.last().expect("polled").clone();
    assert_eq!(last.state, JobState::Done, "{last:?}");
    assert_eq!(last.exit_code, Some(0));
    assert_eq!((last.progress.done, last.progress.total), (6, 6));
    assert!(last.message.as_deref().is_some_and(|m| m.contains("collected 6 poses")), "{last:?}");
    // Progress only goes up, and was seen between the ends.
    let dones: Vec<u64> = seen.iter().filter(|v| v.state == JobState::Running).map(|v| v.progress.done).collect();
    assert!(dones.windows(2).all(|w| w[0] <= w[1]), "{dones:?}");
    assert!(dones.iter().any(|&d| d > 0 && d < 6), "no intermediate progress among {dones:?}");
    assert!(!pose_ids.is_empty(), "the status never named a plan pose");
    assert!(
        seen.iter().any(|v| v.state == JobState::Running && v.progress.done > 0 && v.progress.eta_s.is_some()),
        "no ETA while running with progress"
    );

    // The sensors of the job have frames (valid JPEGs); the one not used has none yet.
    for sensor in ["tactip", "vitac"] {
        let r = client.request("GET", &format!("/api/frames/{sensor}"), None).await.expect("frame");
        assert_eq!(r.status, 200);
        assert_eq!(r.header("content-type"), Some("image/jpeg"));
        let img = image::load_from_memory(&r.body).expect("a decodable frame");
        assert_eq!((img.width(), img.height()), (512, 512));
    }
    assert_eq!(client.request("GET", "/api/frames/vitactip", None).await.expect("frame").status, 404);
    assert_eq!(client.request("GET", "/api/frames/nosuch", None).await.expect("frame").status, 404);
    let status: StatusView = client.get_json("/api/status").await.expect("status");
    assert!(status.arm.pose.is_some());
    assert_eq!(status.sensors.len(), 2);

    assert_eq!(rows(&tmp.path().join("edge/tactip")), 6);
    assert_eq!(rows(&tmp.path().join("edge/vitac")), 6);
    daemon.shutdown().await.expect("clean shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failing_job_is_recorded_a_cancel_works_and_the_queue_goes_on() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (daemon, client) = start(None, &[tmp.path()]).await;
    let bad = submit(&client, json!({"kind": "collect", "object": "no_such_object", "poses": 2, "out": tmp.path().join("a")})).await;
    let long =
        submit(&client, json!({"kind": "collect", "object": "sphere", "sensor": "tactip", "poses": 60, "out": tmp.path().join("b")})).await;
    let after =
        submit(&client, json!({"kind": "collect", "object": "cone", "sensor": "vitac", "poses": 2, "out": tmp.path().join("c")})).await;

    let failed = poll_until(&client, bad.id, final_state).await.pop().expect("view");
    assert_eq!(failed.state, JobState::Failed);
    assert_eq!(failed.exit_code, Some(2), "an unknown object is bad input");
    assert!(failed.error.as_deref().is_some_and(|e| e.contains("no_such_object")), "{failed:?}");
    let status: StatusView = client.get_json("/api/status").await.expect("status");
    assert!(status.errors.iter().any(|e| e.job_id == Some(bad.id) && e.message.contains("no_such_object")));

    poll_until(&client, long.id, |j| j.state == JobState::Running && j.progress.done >= 1).await;
    let r = client.request("POST", &format!("/api/jobs/{}/cancel", long.id), None).await.expect("cancel");
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let cancelled = poll_until(&client, long.id, final_state).await.pop().expect("view");
    assert_eq!(cancelled.state, JobState::Cancelled, "{cancelled:?}");
    assert_eq!(cancelled.exit_code, Some(4));
    assert!(cancelled.progress.done < 60, "{cancelled:?}");
    // What was captured before the cancel is durable.
    assert_eq!(rows(&tmp.path().join("b/sphere/tactip")) as u64, cancelled.progress.done);

    let next = poll_until(&client, after.id, final_state).await.pop().expect("view");
    assert_eq!(next.state, JobState::Done, "{next:?}");
    assert_eq!(rows(&tmp.path().join("c/cone/vitac")), 2);

    // Cancelling again: the job has ended; an unknown job: not found; a bad id: bad request.
    assert_eq!(client.request("DELETE", &format!("/api/jobs/{}", long.id), None).await.expect("cancel").status, 409);
    assert_eq!(client.request("POST", "/api/jobs/999/cancel", None).await.expect("cancel").status, 404);
    assert_eq!(client.request("GET", "/api/jobs/abc", None).await.expect("job").status, 400);
    let jobs: Vec<JobView> = client.get_json("/api/jobs").await.expect("jobs");
    assert_eq!(jobs.iter().map(|j| j.id).collect::<Vec<_>>(), vec![bad.id, long.id, after.id]);
    daemon.shutdown().await.expect("clean shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_requests_get_400_with_a_message() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (daemon, client) = start(None, &[tmp.path()]).await;
    for (body, expect) in [
        ("{\"kind\": \"dance\"}", "unknown variant"),
        ("{\"kind\": \"collect\", \"objekt\": \"edge\"}", "unknown field `objekt`"),
        ("{\"kind\": \"collect\", \"poses\": \"many\"}", "invalid type"),
        ("not json", "bad job"),
    ] {
        let r = client.request("POST", "/api/jobs", Some(body.as_bytes())).await.expect("post");
        assert_eq!(r.status, 400, "{body}");
        let v: serde_json::Value = serde_json::from_slice(&r.body).expect("json error");
        let message = v["error"].as_str().expect("error message");
        assert!(message.contains(expect), "{body}: {message}");
    }
    assert_eq!(client.request("GET", "/api/synth/latest/depth", None).await.expect("get").status, 400);
    assert_eq!(client.request("GET", "/api/synth/latest/image", None).await.expect("get").status, 404);
    assert_eq!(client.request("GET", "/api/nothing", None).await.expect("get").status, 404);
    let jobs: Vec<JobView> = client.get_json("/api/jobs").await.expect("jobs");
    assert!(jobs.is_empty(), "a rejected request queued a job: {jobs:?}");
    daemon.shutdown().await.expect("clean shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_token_is_enforced_and_required_off_loopback() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (daemon, client) = start(Some("s3cret"), &[tmp.path()]).await;
    let anonymous = DaemonClient::new(&format!("http://{}", daemon.addr()), None).expect("client");
    let wrong = DaemonClient::new(&format!("http://{}", daemon.addr()), Some("guess".into())).expect("client");
    for path in ["/api/status", "/api/jobs", "/api/jobs/1", "/api/frames/tactip", "/api/synth/latest/image"] {
        assert_eq!(anonymous.request("GET", path, None).await.expect("get").status, 401, "{path}");
        assert_eq!(wrong.request("GET", path, None).await.expect("get").status, 401, "{path}");
    }
    let r = anonymous.request("POST", "/api/jobs", Some(b"{\"kind\":\"collect\"}")).await.expect("post");
    assert_eq!(r.status, 401);
    assert_eq!(client.request("GET", "/api/status", None).await.expect("get").status, 200);
    let jobs: Vec<JobView> = client.get_json("/api/jobs").await.expect("jobs");
    assert!(jobs.is_empty(), "an unauthorised POST queued a job");
    // The page itself carries no data; it is served without the token and sends it itself.
    let page = anonymous.request("GET", "/", None).await.expect("page");
    assert_eq!(page.status, 200);
    assert!(String::from_utf8_lossy(&page.body).contains("Authorization"));
    daemon.shutdown().await.expect("clean shutdown");

    let mut options = DaemonOptions::local(RigConfig::builtin_sim());
    options.listen = "0.0.0.0:0".parse().expect("addr");
    match Daemon::start(options).await {
        Err(DaemonError::TokenRequired { .. }) => {}
        Err(e) => panic!("expected TokenRequired, got {e}"),
        Ok(_) => panic!("a daemon listening on every interface started without a token"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_stops_the_running_job_and_leaves_the_arm_disabled() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (daemon, client) = start(None, &[tmp.path()]).await;
    let long = submit(&client, json!({"kind": "collect", "sensor": "tactip", "poses": 60, "out": tmp.path()})).await;
    let queued = submit(&client, json!({"kind": "collect", "sensor": "tactip", "poses": 2, "out": tmp.path().join("q")})).await;
    poll_until(&client, long.id, |j| j.state == JobState::Running && j.progress.done >= 1).await;
    let state = std::sync::Arc::clone(daemon.state());
    daemon.shutdown().await.expect("clean shutdown");
    let long = state.job(long.id).expect("job");
    assert_eq!(long.state, JobState::Cancelled, "{long:?}");
    assert!(long.progress.done < 60);
    let queued = state.job(queued.id).expect("job");
    assert_eq!(queued.state, JobState::Cancelled, "{queued:?}");
    assert_eq!(queued.started_unix_s, None);
    let status = state.status();
    assert_eq!(status.daemon, "stopping");
    assert_eq!(status.arm.mode, "disabled", "{:?}", status.arm);
    // The collection retracted above the plan origin before disabling: not in contact.
    let pose = status.arm.pose.expect("a pose");
    let above = rig::pose::WorkFrame::default().approach_pose(&rig::pose::Pose::default());
    assert!((pose.z_mm - above.z_mm).abs() < 0.5, "arm left at {pose:?}, expected above the origin at {above:?}");
    assert!(state.submit(rig::jobs::JobRequest::Collect(Default::default())).is_err(), "a stopping daemon took a job");
    assert!(!tmp.path().join("q").exists(), "the queued job ran");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[cfg_attr(not(feature = "synth"), ignore = "a synth job runs the model: needs the synth feature")]
async fn a_synth_job_publishes_the_control_and_synthetic_images() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let plan = tmp.path().join("plan.toml");
    // A 2 x 2 x 1 x 3 = 12-pose grid; collect 3, then synthesise 2 of the 9 missing.
    std::fs::write(
        &plan,
        "sampling = \"random\"\nn_poses = 3\nseed = 3\norder = \"optimised\"\n\
         [x_mm]\nmin = -2.0\nmax = 2.0\nstep = 4.0\n[y_mm]\nmin = -2.0\nmax = 2.0\nstep = 4.0\n\
         [z_mm]\nmin = 0.0\nmax = 0.0\nstep = 1.0\n[yaw_deg]\nmin = -45.0\nmax = 45.0\nstep = 45.0\n",
    )
    .expect("plan");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let (daemon, client) = start(None, &[tmp.path(), &data]).await;
    let collect = submit(&client, json!({"kind": "collect", "object": "edge", "sensor": "vitac", "plan": plan, "out": tmp.path()})).await;
    let dataset = tmp.path().join("edge/vitac");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tiny-package");
    let synth = submit(&client, json!({"kind": "synth", "dataset": dataset, "model": model, "steps": 2, "batch": 2, "limit": 2})).await;
    let c = poll_until(&client, collect.id, final_state).await.pop().expect("view");
    assert_eq!(c.state, JobState::Done, "{c:?}");
    let s = poll_until(&client, synth.id, final_state).await.pop().expect("view");
    assert_eq!(s.state, JobState::Done, "{s:?}");
    assert_eq!((s.progress.done, s.progress.total), (2, 2));
    assert_eq!(rows(&dataset), 5);

    let status: StatusView = client.get_json("/api/status").await.expect("status");
    let pair = status.synth.expect("a synth pair in the status");
    assert_eq!(pair.job_id, synth.id);
    let mut sizes = Vec::new();
    for which in ["control", "image"] {
        let r = client.request("GET", &format!("/api/synth/latest/{which}"), None).await.expect("get");
        assert_eq!(r.status, 200, "{which}");
        assert_eq!(r.header("content-type"), Some("image/png"));
        let img = image::load_from_memory_with_format(&r.body, image::ImageFormat::Png).expect("a PNG");
        sizes.push((img.width(), img.height()));
    }
    assert!(sizes.iter().all(|&(w, h)| w > 0 && h > 0), "{sizes:?}");
    daemon.shutdown().await.expect("clean shutdown");
}

/// A daemon built without the `synth` feature takes a synth job and fails it, exit 1, saying
/// how to rebuild, before it looks at the dataset; with the feature the same job gets as far as
/// the dataset (not one: exit 2). The daemon goes on either way.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_synth_job_on_a_daemon_without_the_synth_feature_fails_saying_so() {
    let tmp = tempfile::tempdir().expect("tempdir");
    std::fs::create_dir(tmp.path().join("empty")).expect("mkdir");
    let (daemon, client) = start(None, &[tmp.path()]).await;
    let synth = submit(&client, json!({"kind": "synth", "dataset": tmp.path().join("empty"), "steps": 2})).await;
    let after =
        submit(&client, json!({"kind": "collect", "object": "cone", "sensor": "vitac", "poses": 1, "out": tmp.path().join("c")})).await;
    let s = poll_until(&client, synth.id, final_state).await.pop().expect("view");
    assert_eq!(s.state, JobState::Failed, "{s:?}");
    let error = s.error.as_deref().unwrap_or_default();
    let missing = "this rig was built without the `synth` feature";
    if cfg!(feature = "synth") {
        assert_eq!(s.exit_code, Some(2), "{s:?}");
        assert!(!error.contains(missing), "{s:?}");
    } else {
        assert_eq!(s.exit_code, Some(1), "{s:?}");
        assert!(error.contains(missing) && error.contains("synth jobs"), "{s:?}");
    }
    let c = poll_until(&client, after.id, final_state).await.pop().expect("view");
    assert_eq!(c.state, JobState::Done, "the queue went on: {c:?}");
    daemon.shutdown().await.expect("clean shutdown");
}

/// `rig collect --daemon URL` (the binary) against an in-process daemon.
pub(crate) async fn rig_cli(args: Vec<String>) -> (i32, String) {
    let out = tokio::process::Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(&args)
        .env_remove("RIG_CONFIG")
        .env_remove("RIG_DAEMON_TOKEN")
        .output()
        .await
        .expect("running rig");
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.code().unwrap_or(-1), text)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_cli_submits_to_a_daemon_and_exits_as_standalone() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (daemon, client) = start(Some("cli-token"), &[tmp.path()]).await;
    let url = format!("http://{}", daemon.addr());
    let out = tmp.path().display().to_string();
    let args = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> =
            ["collect", "--daemon", &url, "--daemon-token", "cli-token", "--out", &out].iter().map(|s| s.to_string()).collect();
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let (code, text) = rig_cli(args(&["--object", "edge", "--sensor", "vitac", "--poses", "3"])).await;
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("submitted collect job 1") && text.contains("collected 3 poses"), "{text}");
    assert_eq!(rows(&tmp.path().join("edge/vitac")), 3);

    let (code, text) = rig_cli(args(&["--object", "no_such_object"])).await;
    assert_eq!(code, 2, "a bad object is bad input, as standalone: {text}");
    assert!(text.contains("no_such_object"), "{text}");

    let (code, text) = rig_cli(args(&["--object", "cone", "--sensor", "tactip", "--poses", "2", "--detach"])).await;
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("submitted collect job 3"), "{text}");
    let done = poll_until(&client, 3, final_state).await.pop().expect("view");
    assert_eq!(done.state, JobState::Done, "{done:?}");

    // Without the token the daemon refuses, and the command says why.
    let (code, text) = rig_cli(vec!["collect".into(), "--daemon".into(), url.clone(), "--poses".into(), "2".into()]).await;
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("401"), "{text}");
    daemon.shutdown().await.expect("clean shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_calibrate_job_presses_fits_and_saves() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("tactip.toml");
    let (daemon, client) = start(None, &[tmp.path()]).await;
    let j = submit(&client, json!({"kind": "calibrate", "sensor": "tactip", "grid": 3, "out": out})).await;
    let done = poll_until(&client, j.id, final_state).await.pop().expect("view");
    assert_eq!(done.state, JobState::Done, "{done:?}");
    assert_eq!(done.progress.done, done.progress.total);
    assert!(done.progress.total >= 9, "{done:?}");
    assert!(done.message.as_deref().is_some_and(|m| m.contains("residual")), "{done:?}");
    let saved = rig::calibration::Calibration::load(&out).expect("a saved calibration");
    assert!(saved.scale_px_per_mm[0] > 0.0);
    // An unknown sensor is bad input, refused when the job is submitted (the request is typed).
    let bad = client.request("POST", "/api/jobs", Some(json!({"kind": "calibrate", "sensor": "thermometer"}).to_string().as_bytes())).await;
    let bad = bad.expect("POST /api/jobs");
    let text = String::from_utf8_lossy(&bad.body);
    assert_eq!(bad.status, 400, "{text}");
    assert!(text.contains("unknown sensor") && text.contains("thermometer"), "{text}");

    // A cancel stops the pattern between presses: the arm retracts, nothing is saved.
    let other = tmp.path().join("cancelled.toml");
    let long = submit(&client, json!({"kind": "calibrate", "sensor": "tactip", "grid": 7, "out": other})).await;
    poll_until(&client, long.id, |j| j.state == JobState::Running && j.progress.done >= 1).await;
    let r = client.request("POST", &format!("/api/jobs/{}/cancel", long.id), None).await.expect("cancel");
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let cancelled = poll_until(&client, long.id, final_state).await.pop().expect("view");
    assert_eq!((cancelled.state, cancelled.exit_code), (JobState::Cancelled, Some(4)), "{cancelled:?}");
    assert!(cancelled.progress.done < cancelled.progress.total, "{cancelled:?}");
    assert!(cancelled.message.as_deref().is_some_and(|m| m.contains("no calibration saved")), "{cancelled:?}");
    assert!(!other.exists(), "a cancelled calibration saved a file");
    // Retracted to the approach pose above the pattern's centre, not left pressing.
    let status: StatusView = client.get_json("/api/status").await.expect("status");
    let at = status.arm.pose.expect("arm pose");
    let above = RigConfig::builtin_sim().work_frame.approach_pose(&rig::pose::Pose::default());
    assert!(at.distance_mm(&above) < 0.5, "arm at {at:?}, approach pose {above:?}");
    daemon.shutdown().await.expect("clean shutdown");
}

/// The daemon's jobs build the same requests and pass the same fence: on a bench whose work
/// frame touches 3 mm deep, a ViTac collection and a ViTac calibration (pressing 2 to 4 and
/// 2.5 to 3.5 mm) fail with exit 2 naming the pose and the 2.5 mm limit, before the arm moves
/// and before anything is written; a TacTip collection within its 5 mm goes on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_pressing_past_the_press_limit_fail_before_the_arm_moves() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let config = RigConfig::parse(
        "[work_frame]\norigin = { x_mm = 300.0, y_mm = 0.0, z_mm = -20.0, yaw_deg = 0.0 }\ncontact_depth_mm = 3.0\n",
        Path::new("deep.toml"),
    )
    .expect("config");
    let (daemon, client) = start_on(config, None, &[tmp.path()]).await;
    let before: StatusView = client.get_json("/api/status").await.expect("status");
    let collect =
        submit(&client, json!({"kind": "collect", "object": "edge", "sensor": "vitac", "poses": 4, "out": tmp.path().join("a")})).await;
    let calibrate = submit(&client, json!({"kind": "calibrate", "sensor": "vitac", "grid": 2, "out": tmp.path().join("vitac.toml")})).await;
    for (id, what) in [(collect.id, "plan pose"), (calibrate.id, "calibration press")] {
        let failed = poll_until(&client, id, final_state).await.pop().expect("view");
        assert_eq!((failed.state, failed.exit_code), (JobState::Failed, Some(2)), "{failed:?}");
        let error = failed.error.clone().unwrap_or_default();
        assert!(error.contains(what) && error.contains("into the skin (contact depth 3.000 mm"), "{failed:?}");
        assert!(error.contains("vitac's press limit of 2.5 mm"), "{failed:?}");
    }
    assert!(!tmp.path().join("a").exists() && !tmp.path().join("vitac.toml").exists(), "nothing may be written");
    let after: StatusView = client.get_json("/api/status").await.expect("status");
    assert_eq!(after.arm.pose, before.arm.pose, "the arm did not move");
    // Submitted only now: a job that starts reports the arm's pose, which read before the check
    // above made the refused jobs look as if they had moved the arm.
    let within =
        submit(&client, json!({"kind": "collect", "object": "edge", "sensor": "tactip", "poses": 2, "out": tmp.path().join("b")})).await;
    let next = poll_until(&client, within.id, final_state).await.pop().expect("view");
    assert_eq!(next.state, JobState::Done, "{next:?}");
    assert_eq!(rows(&tmp.path().join("b/edge/tactip")), 2);
    daemon.shutdown().await.expect("clean shutdown");
}

/// Every path a job names must lie inside the daemon's data roots, symlinks followed, and an
/// object name must be a plain name: each bad job is refused when submitted (400, the path
/// named as given), nothing is queued and nothing is written outside.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn paths_outside_the_data_roots_are_refused_at_submission() {
    let root = tempfile::tempdir().expect("tempdir");
    let outside = tempfile::tempdir().expect("tempdir");
    let sentinel = outside.path().join("sentinel.txt");
    std::fs::write(&sentinel, "untouched").expect("sentinel");
    std::os::unix::fs::symlink(outside.path(), root.path().join("escape")).expect("symlink");
    std::fs::write(outside.path().join("plan.toml"), "n_poses = 1\n").expect("plan outside");
    let (daemon, client) = start(None, &[root.path()]).await;
    let cases = [
        (json!({"kind": "collect", "object": "edge", "poses": 1, "out": outside.path()}), "outside the data roots"),
        (json!({"kind": "collect", "object": "edge", "poses": 1, "out": "escape/ds"}), "outside the data roots"),
        (json!({"kind": "collect", "object": "edge", "poses": 1, "out": "../ds"}), "outside the data roots"),
        (json!({"kind": "collect", "object": "edge", "poses": 1, "plan": outside.path().join("plan.toml")}), "outside the data roots"),
        (json!({"kind": "collect", "object": "../../x", "poses": 1}), "plain name"),
        (json!({"kind": "synth", "dataset": outside.path()}), "outside the data roots"),
        (json!({"kind": "synth", "dataset": ".", "model": outside.path()}), "outside the data roots"),
        (json!({"kind": "calibrate", "sensor": "tactip", "out": sentinel}), "outside the data roots"),
        (json!({"kind": "calibrate", "sensor": "tactip", "grid": 100000}), "grid"),
        (json!({"kind": "adaptive", "collect": {"out": outside.path()}, "budget": 4}), "outside the data roots"),
        (json!({"kind": "adaptive", "collect": {"out": "ds"}, "budget": 4, "model": outside.path()}), "outside the data roots"),
        (json!({"kind": "adaptive", "collect": {"out": "ds"}, "budget": 0}), "budget"),
        (json!({"kind": "adaptive", "collect": {"out": "ds"}, "budget": 4, "seeds_per_pose": 1000}), "seeds_per_pose"),
        (json!({"kind": "adaptive", "out": "ds", "budget": 4}), "unknown field"),
    ];
    for (job, expect) in cases {
        let r = client.request("POST", "/api/jobs", Some(job.to_string().as_bytes())).await.expect("POST");
        let body = String::from_utf8_lossy(&r.body).to_string();
        assert_eq!(r.status, 400, "{job}: {body}");
        assert!(body.contains(expect), "{job}: {body}");
        // Named as given, never as resolved (the symlink's target is not told).
        let outside_name = outside.path().display().to_string();
        assert!(!body.contains(&outside_name) || job.to_string().contains(&outside_name), "{job}: {body}");
    }
    let jobs: Vec<JobView> = client.get_json("/api/jobs").await.expect("jobs");
    assert!(jobs.is_empty(), "a refused job was queued: {jobs:?}");
    assert_eq!(std::fs::read_to_string(&sentinel).expect("sentinel"), "untouched");
    assert_eq!(std::fs::read_dir(outside.path()).expect("outside").count(), 2, "something was written outside the roots");
    // Inside the roots, through a relative path, the same job is taken and runs.
    let ok = submit(&client, json!({"kind": "collect", "object": "edge", "sensor": "tactip", "poses": 1, "out": "ds"})).await;
    let end = poll_until(&client, ok.id, final_state).await;
    assert_eq!(end.last().map(|j| j.state), Some(JobState::Done), "{:?}", end.last());
    assert_eq!(rows(&root.path().join("ds/edge/tactip")), 1);
    daemon.shutdown().await.expect("clean shutdown");
}
