//! The fault matrix: `rig collect` (the real binary, on the built-in simulated rig) under each
//! fault a bench can throw at it, one run per row.
//!
//! Each row writes a rig config whose `[sim.faults]` switches the fault on (or SIGKILLs the
//! process at a seeded random moment), runs `rig collect`, and then:
//!
//! - the run must either complete (exit 0) or stop with a clear `error:` line, never panic,
//!   and finish well inside its time limit;
//! - a run that stopped is resumed with `--resume` and no fault, and must complete;
//! - `rig dataset verify` must find every sensor's dataset clean, and the pose ids must be
//!   exactly the plan's (nothing lost, nothing duplicated), the same as a run with no fault.
//!
//! The matrix prints as a Markdown table (run with `--nocapture` to see it; set
//! `RIG_FAULT_TABLE=<file>` to write it to a file, as the table in `docs/src/faults.md` was made). The random
//! choices (alarm moves, kill moment) come from `RIG_FAULT_SEED`, or from the time, printed.

use std::collections::BTreeSet;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use rand::{RngExt, SeedableRng};

const POSES: usize = 6;
const SENSORS: [&str; 3] = ["tactip", "vitac", "vitactip"];
/// A run that takes longer than this has hung: the test fails rather than waits.
const RUN_LIMIT: Duration = Duration::from_secs(60);

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    // Warnings (every reconnect) would drown the one line that matters.
    c.env("RIG_LOG", "error");
    c
}

fn collect(out: &Path, config: Option<&Path>, resume: bool) -> Command {
    let mut c = rig();
    c.args(["collect", "--object", "sphere", "--sensor", "all", "--seed", "7", "--poses"]).arg(POSES.to_string()).arg("--out").arg(out);
    if let Some(cfg) = config {
        c.arg("--config").arg(cfg);
    }
    if resume {
        c.arg("--resume");
    }
    c.stdout(Stdio::piped()).stderr(Stdio::piped());
    c
}

/// What one process did.
struct Finished {
    code: Option<i32>,
    stdout: String,
    stderr: String,
    killed: bool,
}

/// Waits for `child`, SIGKILLing it after `kill_after` (if given) and failing past the limit.
fn finish(mut child: Child, kill_after: Option<Duration>, what: &str) -> Finished {
    let started = Instant::now();
    let mut killed = false;
    loop {
        match child.try_wait() {
            Ok(Some(_)) => break,
            Ok(None) => {}
            Err(e) => panic!("{what}: waiting for rig: {e}"),
        }
        if kill_after.is_some_and(|k| started.elapsed() >= k) && !killed {
            let _ = child.kill(); // SIGKILL on Unix
            killed = true;
        }
        if started.elapsed() > RUN_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what}: rig collect still running after {RUN_LIMIT:?}: it hung");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let status = child.wait().unwrap_or_else(|e| panic!("{what}: {e}"));
    let mut stdout = String::new();
    let mut stderr = String::new();
    if let Some(mut o) = child.stdout.take() {
        let _ = o.read_to_string(&mut stdout);
    }
    if let Some(mut e) = child.stderr.take() {
        let _ = e.read_to_string(&mut stderr);
    }
    Finished { code: status.code(), stdout, stderr, killed }
}

fn run(mut cmd: Command, kill_after: Option<Duration>, what: &str) -> Finished {
    let child = cmd.spawn().unwrap_or_else(|e| panic!("{what}: starting rig: {e}"));
    finish(child, kill_after, what)
}

/// Pose ids of one dataset's rows.
fn pose_ids(dir: &Path) -> Vec<u32> {
    let text = std::fs::read_to_string(dir.join("poses.csv")).unwrap_or_default();
    text.lines().skip(1).filter_map(|l| l.split(',').next()?.parse().ok()).collect()
}

/// Runs `rig dataset verify` on every sensor's dataset; the summary, or a failure.
fn verify_all(root: &Path) -> Result<String, String> {
    let mut rows = Vec::new();
    for sensor in SENSORS {
        let dir = root.join("sphere").join(sensor);
        let o = rig().args(["dataset", "verify"]).arg(&dir).output().map_err(|e| e.to_string())?;
        let text = String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
        if !o.status.success() || !text.lines().any(|l| l.trim() == format!("{}: clean", dir.display())) {
            return Err(format!("{sensor}: {}", text.trim().replace('\n', "; ")));
        }
        rows.push(pose_ids(&dir).len());
    }
    Ok(format!("clean, rows {}", rows.iter().map(usize::to_string).collect::<Vec<_>>().join("/")))
}

/// The line a reader should see: the `error:` line of a stopped run, the summary of a
/// finished one.
fn message(f: &Finished) -> String {
    let error = f.stderr.lines().rev().find(|l| l.starts_with("error: ")).map(str::to_string);
    let summary = || {
        f.stdout
            .lines()
            .rev()
            .find(|l| l.starts_with("collected ") || l.starts_with("interrupted:"))
            .map(|l| l.split(" into ").next().unwrap_or(l).to_string())
    };
    error.or_else(summary).unwrap_or_default()
}

/// A row of the matrix.
struct Case {
    fault: String,
    /// `[sim.faults]` body; `None` for no config.
    faults: Option<String>,
    kill_after: Option<Duration>,
    /// The exit code a stop must have (any when `None`); 0 means it must complete.
    expect_code: Option<i32>,
}

fn case(fault: &str, faults: &str, expect_code: Option<i32>) -> Case {
    Case { fault: fault.to_string(), faults: Some(faults.to_string()), kill_after: None, expect_code }
}

/// Table cells may not hold `|` or newlines.
fn cell(text: &str) -> String {
    text.replace('|', "\\|").replace('\n', " ")
}

#[test]
fn every_fault_completes_or_stops_clearly_and_the_dataset_verifies() {
    let seed: u64 = std::env::var("RIG_FAULT_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(1));
    println!("fault matrix seed {seed} (set RIG_FAULT_SEED={seed} to repeat it)");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);

    // A collection makes 1 reference move plus 3 per pose (approach, descend, retract).
    let moves = 1 + 3 * POSES as u64;
    let mut alarm_moves: BTreeSet<u64> = BTreeSet::new();
    while alarm_moves.len() < 3 {
        alarm_moves.insert(rng.random_range(1..=moves));
    }
    let alarm_moves: Vec<u64> = alarm_moves.into_iter().collect();
    // Frames: 1 reference + 1 per pose, per camera.
    let stall_frame = rng.random_range(1..=1 + POSES as u64);
    let kill_ms = rng.random_range(150..1500u64);

    // One pose is about 200 kB per sensor (512x512 PNG); leave room for the reference and
    // about two poses.
    let disk_budget = 700_000u64;
    let cases = vec![
        Case { fault: "none (baseline)".into(), faults: None, kill_after: None, expect_code: Some(0) },
        case("controller replies delayed 30 ms", "reply_delay_ms = 30", Some(0)),
        case("controller replies split across writes", "split_replies = true", Some(0)),
        case("garbage before every 3rd feedback frame", "feedback_garbage_every = 3", Some(0)),
        case("feedback stream starts mid-frame", "feedback_start_mid_frame = true", Some(0)),
        case("dashboard socket dropped after 5 commands", "drop_dashboard_after = 5", Some(0)),
        case("all sockets dropped every 1.5 s (rig clock)", "drop_sockets_every_s = 1.5", Some(0)),
        case(&format!("collision alarms at random moves {alarm_moves:?}"), &format!("collision_at_moves = {alarm_moves:?}"), Some(0)),
        case("collision alarm on every retry of a pose", "collision_at_moves = [5, 6, 7, 8, 9, 10]", Some(3)),
        case(
            &format!("camera timeout at frame {stall_frame}"),
            &format!("camera_timeout_at_frames = [{stall_frame}]\ncamera_timeout_ms = 200"),
            Some(0),
        ),
        case(
            "camera dead from frame 3",
            &format!("camera_timeout_at_frames = {:?}\ncamera_timeout_ms = 50", (3..40).collect::<Vec<u64>>()),
            Some(3),
        ),
        case(&format!("disk full after {disk_budget} bytes"), &format!("disk_budget_bytes = {disk_budget}"), Some(1)),
        Case {
            fault: format!("SIGKILL after {kill_ms} ms"),
            faults: None,
            kill_after: Some(Duration::from_millis(kill_ms)),
            expect_code: None,
        },
    ];

    let tmp = tempfile::tempdir().expect("temp dir");
    let mut table = vec!["| fault | outcome | message | after resume | verify |".to_string(), "|---|---|---|---|---|".to_string()];
    let mut failures = Vec::new();
    let mut baseline: Option<Vec<u32>> = None;
    for (i, c) in cases.iter().enumerate() {
        let out = tmp.path().join(format!("run{i}"));
        let config: Option<PathBuf> = c.faults.as_ref().map(|body| {
            let p = tmp.path().join(format!("rig{i}.toml"));
            std::fs::write(&p, format!("[sim.faults]\n{body}\n")).expect("writing the rig config");
            p
        });
        let what = format!("row {:?}", c.fault);
        let first = run(collect(&out, config.as_deref(), false), c.kill_after, &what);
        let msg = message(&first);
        let outcome = match (first.killed, first.code) {
            (true, _) => "killed".to_string(),
            (false, Some(0)) => "completed".to_string(),
            (false, Some(code)) => format!("stopped, exit {code}"),
            (false, None) => "ended by a signal".to_string(),
        };
        let mut problems = Vec::new();
        if first.stderr.contains("panicked") {
            problems.push(format!("panicked: {}", first.stderr));
        }
        if !first.killed {
            if let Some(want) = c.expect_code
                && first.code != Some(want)
            {
                problems.push(format!("exit {:?}, expected {want}; stderr: {}", first.code, first.stderr.trim()));
            }
            if first.code != Some(0) && !msg.starts_with("error: ") {
                problems.push(format!("stopped without a clear error line; stderr: {}", first.stderr.trim()));
            }
        }
        let resumed = if first.code == Some(0) && !first.killed {
            "not needed".to_string()
        } else {
            let again = run(collect(&out, None, true), None, &format!("{what} resume"));
            if again.code != Some(0) {
                problems.push(format!("resume failed, exit {:?}: {}", again.code, again.stderr.trim()));
            }
            message(&again)
        };
        let verified = match verify_all(&out) {
            Ok(v) => v,
            Err(e) => {
                problems.push(format!("verify: {e}"));
                format!("NOT clean: {e}")
            }
        };
        for sensor in SENSORS {
            let mut ids = pose_ids(&out.join("sphere").join(sensor));
            let n = ids.len();
            ids.sort_unstable();
            ids.dedup();
            if ids.len() != n || n != POSES {
                problems.push(format!("{sensor}: {n} rows, {} distinct, expected {POSES}", ids.len()));
            }
            match &baseline {
                None => baseline = Some(ids),
                Some(b) if *b != ids => problems.push(format!("{sensor}: pose ids {ids:?} differ from the baseline's {b:?}")),
                Some(_) => {}
            }
        }
        table.push(format!(
            "| {} | {} | {} | {} | {} |",
            cell(&c.fault),
            cell(&outcome),
            cell(if msg.is_empty() { "(none)" } else { &msg }),
            cell(&resumed),
            cell(&verified)
        ));
        if !problems.is_empty() {
            failures.push(format!("{}: {}", c.fault, problems.join("; ")));
        }
    }
    let table = table.join("\n");
    println!("\n{table}\n");
    if let Ok(path) = std::env::var("RIG_FAULT_TABLE") {
        std::fs::write(&path, format!("{table}\n")).unwrap_or_else(|e| panic!("writing {path}: {e}"));
    }
    assert!(failures.is_empty(), "fault matrix (seed {seed}) failed:\n{}\n\n{table}", failures.join("\n"));
}
