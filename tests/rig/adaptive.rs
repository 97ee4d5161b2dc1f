//! `rig collect --adaptive` on the built-in simulated rig with the tiny test package: the
//! refusals (exit 2, nothing collected), the rounds recorded (`adaptive.csv`), and a collection SIGKILLed
//! at random moments resuming with the same choices and no lost or duplicated row.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use rand::{RngExt, SeedableRng};

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    c
}

fn tiny() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tiny-package")
}

/// A plan of the full 3 x 3 x 1 x 2 = 18-pose grid (seed 3), or of its first `n` poses.
pub(crate) fn plan(dir: &Path, full: bool) -> PathBuf {
    let path = dir.join(if full { "plan.toml" } else { "one.toml" });
    let sampling = if full { "sampling = \"full\"" } else { "sampling = \"random\"\nn_poses = 1" };
    let text = format!(
        "{sampling}\nseed = 3\norder = \"optimised\"\n[x_mm]\nmin = -2.0\nmax = 2.0\nstep = 2.0\n[y_mm]\nmin = -2.0\nmax = 2.0\nstep = 2.0\n\
         [z_mm]\nmin = 0.0\nmax = 0.0\nstep = 1.0\n[yaw_deg]\nmin = 0.0\nmax = 45.0\nstep = 45.0\n"
    );
    std::fs::write(&path, text).expect("writing the plan");
    path
}

fn adaptive_args(out: &Path, plan: &Path, model: &Path, budget: usize, sensor: &str) -> Vec<String> {
    [
        "collect",
        "--adaptive",
        "--budget",
        &budget.to_string(),
        "--rounds",
        "3",
        "--seeds-per-pose",
        "2",
        "--steps",
        "1",
        "--model",
        &model.display().to_string(),
        "--sensor",
        sensor,
        "--plan",
        &plan.display().to_string(),
        "--out",
        &out.display().to_string(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// The choices a dataset records (its `adaptive.csv`): (pose_id, round, reason) per choice,
/// after checking that its manifest names it an adaptive collection.
pub(crate) fn choices(dataset: &Path) -> Vec<(u32, usize, String)> {
    let manifest: toml::Value = toml::from_str(&std::fs::read_to_string(dataset.join("manifest.toml")).expect("manifest")).expect("toml");
    assert!(manifest["adaptive"]["budget"].as_integer().is_some(), "the manifest's [adaptive] holds the settings");
    let text = std::fs::read_to_string(dataset.join("adaptive.csv")).expect("adaptive.csv");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("pose_id,round,reason,distance,spread,error,score,distance_weight,spread_weight,error_weight"));
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[0].parse().expect("pose_id"), f[1].parse().expect("round"), f[2].to_string())
        })
        .collect()
}

/// `poses.csv` as (pose_id, source) per row.
pub(crate) fn rows(dataset: &Path) -> Vec<(u32, String)> {
    let csv = std::fs::read_to_string(dataset.join("poses.csv")).expect("poses.csv");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("column {name}"));
    let (id, source) = (col("pose_id"), col("source"));
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[id].parse().expect("pose id"), f[source].to_string())
        })
        .collect()
}

#[test]
fn refusals_exit_2_and_collect_nothing() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let full = plan(tmp.path(), true);
    let one = plan(tmp.path(), false);
    let out = tmp.path().join("out");
    let cases: Vec<(&str, Vec<String>, &str)> = vec![
        ("a budget larger than the plan", adaptive_args(&out, &full, &tiny(), 19, "tactip"), "--budget 19"),
        ("a plan of one pose", adaptive_args(&out, &one, &tiny(), 1, "tactip"), "a plan of 1 pose"),
    ];
    // A package that makes only TacTip images, asked for ViTac.
    let tactip_only = tmp.path().join("tactip-only");
    copy_dir(&tiny(), &tactip_only);
    let toml_path = tactip_only.join("model.toml");
    let model_toml = std::fs::read_to_string(&toml_path).expect("model.toml");
    std::fs::write(&toml_path, model_toml.replace(r#"modalities = ["TacTip", "ViTac", "ViTacTip"]"#, r#"modalities = ["TacTip"]"#))
        .expect("writing model.toml");
    let mut cases = cases;
    cases.push(("a model that does not make the sensor's images", adaptive_args(&out, &full, &tactip_only, 6, "vitac"), "not of ViTac"));
    for (what, args, says) in cases {
        let o = rig().args(&args).output().expect("rig collect --adaptive");
        assert_eq!(o.status.code(), Some(2), "{what}: {}", text(&o));
        assert!(text(&o).contains(says), "{what}: the refusal should say {says:?}: {}", text(&o));
        assert!(!out.join("sphere").exists(), "{what}: nothing may be collected");
    }
    // The same model makes TacTip images: accepted (the refusal above was the sensor's).
    let o = rig().args(adaptive_args(&out, &full, &tactip_only, 3, "tactip")).output().expect("rig collect --adaptive");
    assert!(o.status.success(), "{}", text(&o));
}

#[test]
fn rounds_are_recorded_and_the_rest_is_filled() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let full = plan(tmp.path(), true);
    let out = tmp.path().join("out");
    let o = rig().args(adaptive_args(&out, &full, &tiny(), 7, "tactip,vitac")).output().expect("rig collect --adaptive");
    assert!(o.status.success(), "{}", text(&o));
    let tactip = out.join("sphere/tactip");
    let chosen = choices(&tactip);
    assert_eq!(chosen, choices(&out.join("sphere/vitac")), "every dataset records the same rounds");
    // 7 presses over 3 rounds: 3, 2, 2; round 1 space-filling, the others by acquisition.
    let per_round: Vec<usize> = (1..=3).map(|r| chosen.iter().filter(|c| c.1 == r).count()).collect();
    assert_eq!(per_round, vec![3, 2, 2], "{chosen:?}");
    assert!(chosen.iter().all(|c| (c.1 == 1) == (c.2 == "space-filling") && (c.1 > 1) == (c.2 == "acquisition")), "{chosen:?}");
    let ids = sorted_unique(chosen.iter().map(|c| c.0));
    assert_eq!(ids.len(), 7, "no pose chosen twice: {chosen:?}");
    // The pressed rows are exactly the chosen poses; the other 11 of the grid are synthetic.
    let rows = rows(&tactip);
    assert_eq!(rows.len(), 18, "{rows:?}");
    assert_eq!(pressed(&rows), ids, "{rows:?}");
    assert_eq!(rows.iter().filter(|r| r.1 == "synthetic").count(), 11);
    assert!(text(&o).contains("round 2/3: 2 poses (by acquisition,"), "{}", text(&o));
}

/// Once enough poses are pressed (8), a round weighs the distance, the spread and the error by
/// how well each predicted the errors measured at the pressed poses: round 2 (6 pressed) counts every term 1,
/// round 3 (12 pressed) records the weights it measured, measures the spread at the pressed
/// poses (2 seeds each), and at the candidates only where the spread's weight is above 0. The
/// model calls it prints are those.
#[test]
fn later_rounds_weigh_each_term_by_what_it_predicted() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let full = plan(tmp.path(), true);
    let out = tmp.path().join("out");
    // 17 of 18 poses over 3 rounds: 6, 6, 5.
    let o = rig().args(adaptive_args(&out, &full, &tiny(), 17, "tactip")).output().expect("rig collect --adaptive");
    assert!(o.status.success(), "{}", text(&o));
    let csv = std::fs::read_to_string(out.join("sphere/tactip/adaptive.csv")).expect("adaptive.csv");
    let rows: Vec<Vec<String>> = csv.lines().skip(1).map(|l| l.split(',').map(str::to_string).collect()).collect();
    let number = |v: &str| -> Option<f64> { (!v.is_empty()).then(|| v.parse().expect("a number")) };
    let weights = |r: &Vec<String>| [number(&r[7]), number(&r[8]), number(&r[9])];
    for r in rows.iter().filter(|r| r[1] == "2") {
        assert_eq!(weights(r), [Some(1.0); 3], "round 2 weighs every term 1: {r:?}");
        assert!(number(&r[4]).is_some(), "round 2 measured the spread: {r:?}");
    }
    let third: Vec<&Vec<String>> = rows.iter().filter(|r| r[1] == "3").collect();
    assert_eq!(third.len(), 5, "{csv}");
    let w = weights(third[0]).map(|v| v.expect("a weight"));
    assert!(w.iter().all(|v| (0.0..=1.0).contains(v)) && w.iter().sum::<f64>() > 0.0, "{csv}");
    assert!(w != [1.0; 3], "round 3's weights are measured, not the prior: {csv}");
    let ws = w[1];
    for r in &third {
        assert_eq!(weights(r), w.map(Some), "one set of weights a round: {csv}");
        assert_eq!(number(&r[4]).is_some(), ws > 0.0, "the spread is measured where it counts: {csv}");
    }
    // Round 3: the errors at round 2's 6 presses (round 1's were measured for round 2), the
    // spread at all 12 pressed poses with 2 seeds, and, where it counts, at the 6 candidates left.
    let calls = 6 + 12 * 2 + if ws > 0.0 { 6 * 2 } else { 0 };
    assert!(text(&o).contains(&format!("round 3/3: 5 poses (by acquisition, {calls} model calls in")), "{}", text(&o));
}

#[test]
fn a_killed_adaptive_collection_resumes_with_the_same_choices() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (full, expected) = uninterrupted(tmp.path());
    let mut rng = rand::rngs::StdRng::seed_from_u64(0xada9_7173);
    let mut killed_mid_run = 0;
    for run in 0..4 {
        let out = tmp.path().join(format!("run{run}"));
        let args = adaptive_args(&out, &full, &tiny(), 6, "tactip");
        for _ in 0..2 {
            let mut child = rig().args(&args).arg("--resume").stdout(Stdio::null()).stderr(Stdio::null()).spawn().expect("spawning");
            let delay = Duration::from_millis(rng.random_range(300..6000));
            let start = Instant::now();
            let mut finished = false;
            while start.elapsed() < delay {
                if child.try_wait().expect("try_wait").is_some() {
                    finished = true;
                    break;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = child.kill(); // SIGKILL on Unix
            let _ = child.wait();
            killed_mid_run += usize::from(!finished);
        }
        let o = rig().args(&args).arg("--resume").output().expect("resuming");
        assert!(o.status.success(), "run {run}: {}", text(&o));
        let dataset = out.join("sphere/tactip");
        assert_eq!(choices(&dataset), expected, "run {run}: the resumed collection chose otherwise");
        let rows = rows(&dataset);
        let ids = sorted_unique(rows.iter().map(|r| r.0));
        assert_eq!((rows.len(), ids.len()), (18, 18), "run {run}: a row lost or duplicated: {rows:?}");
        assert_eq!(pressed(&rows), sorted_unique(expected.iter().map(|c| c.0)), "run {run}: pressed poses");
    }
    assert!(killed_mid_run > 0, "no kill landed before a run ended");
}

/// A collection's choices (`adaptive.csv`) that cannot be its own are refused by a resume
/// with exit 2, naming the file, before anything moves (its rows stay as they were); `rig
/// dataset verify` reports them and the captured rows they do not list.
#[test]
fn a_resume_refuses_choices_that_are_not_the_collections_and_verify_reports_them() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (full, expected) = uninterrupted(tmp.path());
    let clean = tmp.path().join("clean");
    let verify = |dataset: &Path| rig().args(["dataset", "verify"]).arg(dataset).output().expect("rig dataset verify");
    let o = verify(&clean.join("sphere/tactip"));
    assert!(o.status.success() && text(&o).contains("clean"), "{}", text(&o));
    let original = std::fs::read_to_string(clean.join("sphere/tactip/adaptive.csv")).expect("adaptive.csv");
    let lines: Vec<&str> = original.lines().collect();
    let first = expected[0].0;
    // A pose of the plan that no round chose (a synthetic row).
    let unchosen = (0..18).find(|id| !expected.iter().any(|c| c.0 == *id)).expect("an unchosen pose");
    let swap_first = |to: u32| original.replacen(&format!("\n{first},1,"), &format!("\n{to},1,"), 1);
    let cases: Vec<(&str, Option<String>, &str, &str)> = vec![
        ("a pose outside the plan", Some(swap_first(999)), "pose 999 (round 1) is not a pose of the plan", "outside"),
        (
            "a round cut short",
            Some(format!("{}\n", lines[..lines.len() - 1].join("\n"))),
            "round 3 records 1 poses",
            "round 3 records 1 poses",
        ),
        ("a malformed line", Some(original.replacen(&format!("\n{first},1,"), "\nfirst,1,", 1)), "line 2: pose_id `first`", "line 2"),
        ("a symlink", None, "symlink", "symlink"),
    ];
    for (what, body, resume_says, verify_says) in cases {
        let out = tmp.path().join(what.replace(' ', "-"));
        copy_dir(&clean, &out);
        let dataset = out.join("sphere/tactip");
        let file = dataset.join("adaptive.csv");
        match body {
            Some(body) => std::fs::write(&file, body).expect("tampering"),
            None => {
                let elsewhere = tmp.path().join(format!("{}.csv", what.replace(' ', "-")));
                std::fs::rename(&file, &elsewhere).expect("moving");
                std::os::unix::fs::symlink(&elsewhere, &file).expect("symlink");
            }
        }
        let before = std::fs::read(dataset.join("poses.csv")).expect("poses.csv");
        let o = rig().args(adaptive_args(&out, &full, &tiny(), 6, "tactip")).arg("--resume").output().expect("resuming");
        assert_eq!(o.status.code(), Some(2), "{what}: {}", text(&o));
        assert!(text(&o).contains("adaptive.csv") && text(&o).contains(resume_says), "{what}: {}", text(&o));
        assert_eq!(std::fs::read(dataset.join("poses.csv")).expect("poses.csv"), before, "{what}: the rows changed");
        let o = verify(&dataset);
        assert_eq!(o.status.code(), Some(1), "{what}: {}", text(&o));
        assert!(text(&o).contains("NOT clean") && text(&o).contains(verify_says), "{what}: {}", text(&o));
    }
    // Choices of the plan in the right numbers, but not the poses pressed: a resume presses
    // nothing new, and verify names the pressed row the choices do not list.
    let out = tmp.path().join("swapped");
    copy_dir(&clean, &out);
    let dataset = out.join("sphere/tactip");
    std::fs::write(dataset.join("adaptive.csv"), swap_first(unchosen)).expect("tampering");
    let o = verify(&dataset);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains(&format!("1 captured rows are not among them (first: pose_id {first})")), "{}", text(&o));
}

/// The full 18-pose plan, written into `dir`, and the choices an uninterrupted `rig collect
/// --adaptive` (budget 6 over 3 rounds, TacTip) makes on it into `dir/clean`.
fn uninterrupted(dir: &Path) -> (PathBuf, Vec<(u32, usize, String)>) {
    let full = plan(dir, true);
    let clean = dir.join("clean");
    let o = rig().args(adaptive_args(&clean, &full, &tiny(), 6, "tactip")).output().expect("rig collect --adaptive");
    assert!(o.status.success(), "{}", text(&o));
    (full, choices(&clean.join("sphere/tactip")))
}

/// `ids` sorted, each once.
fn sorted_unique(ids: impl Iterator<Item = u32>) -> Vec<u32> {
    let mut v: Vec<u32> = ids.collect();
    v.sort();
    v.dedup();
    v
}

/// The pose ids of the rows a press made (not `synthetic`), sorted.
fn pressed(rows: &[(u32, String)]) -> Vec<u32> {
    sorted_unique(rows.iter().filter(|r| r.1 != "synthetic").map(|r| r.0))
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("read_dir") {
        let entry = entry.expect("entry");
        let target = to.join(entry.file_name());
        if entry.file_type().expect("file type").is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).expect("copy");
        }
    }
}

/// The daemon's `adaptive` job (`rig collect --adaptive --daemon URL`) presses the rounds the
/// standalone command chooses, records them, fills the rest, and exits as the command does; a
/// budget larger than the plan fails the job with exit 2 before any model loads, and the queue
/// goes on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_daemon_job_presses_the_rounds_the_command_chooses() {
    use super::daemon_api::{final_state, poll_until, rig_cli, start};
    let tmp = tempfile::tempdir().expect("tempdir");
    let (full, expected) = uninterrupted(tmp.path());
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let (daemon, client) = start(None, &[tmp.path(), &data]).await;
    let url = format!("http://{}", daemon.addr());
    let with_daemon = |out: &Path, budget: usize| {
        let mut args = adaptive_args(out, &full, &tiny(), budget, "tactip");
        args.splice(1..1, ["--daemon".to_string(), url.clone()]);
        args
    };
    let served = tmp.path().join("served");
    let (code, said) = rig_cli(with_daemon(&served, 6)).await;
    assert_eq!(code, 0, "{said}");
    assert!(said.contains("submitted adaptive job 1") && said.contains("6 poses pressed in 3 rounds"), "{said}");
    let dataset = served.join("sphere/tactip");
    assert_eq!(choices(&dataset), expected, "the daemon chose otherwise than the command");
    let rows = rows(&dataset);
    assert_eq!(rows.len(), 18, "{rows:?}");
    assert_eq!(pressed(&rows), sorted_unique(expected.iter().map(|c| c.0)));

    let refused = tmp.path().join("refused");
    let (code, said) = rig_cli(with_daemon(&refused, 19)).await;
    assert_eq!(code, 2, "{said}");
    assert!(said.contains("--budget 19"), "{said}");
    assert!(!refused.exists(), "nothing may be collected");
    let next = rig_cli(vec![
        "collect".into(),
        "--daemon".into(),
        url.clone(),
        "--sensor".into(),
        "vitac".into(),
        "--poses".into(),
        "2".into(),
        "--out".into(),
        tmp.path().join("after").display().to_string(),
    ])
    .await;
    assert_eq!(next.0, 0, "the queue went on: {}", next.1);
    let last = poll_until(&client, 3, final_state).await.pop().expect("view");
    assert!(last.state.is_final(), "{last:?}");
    daemon.shutdown().await.expect("clean shutdown");
}

/// Presses `round` on a freshly opened simulated rig of `config`, as `rig collect --adaptive`
/// does between its rounds.
async fn press_round(config: &rig::config::RigConfig, run: &rig::jobs::adaptive::AdaptiveRun, round: &rig::jobs::adaptive::Round) {
    use rig::jobs::collect::SensorFeed;
    let clock = rig::rigs::clock_for(config);
    let setup = &round.setup;
    let mut opened =
        rig::rigs::Rig::open_with(config, &run.prepared.object, &run.prepared.sensors, setup.plan_spec.seed, clock.clone(), None)
            .await
            .expect("opening the simulated rig");
    let feeds: Vec<_> = opened
        .cameras
        .drain(..)
        .map(|camera| SensorFeed { sensor: camera.kind(), calibration: camera.calibration_name(), capture: camera.capture_part(), camera })
        .collect();
    let peripherals = std::mem::take(&mut opened.peripherals);
    let outcome = rig::jobs::collect::run(setup, &mut opened.arm, feeds, peripherals, clock, rig::jobs::Observer::hidden(), None)
        .await
        .expect("pressing the round");
    assert!(!outcome.summary.interrupted, "{outcome:?}");
    opened.shutdown().await;
}

/// A cancel that lands while a round is chosen (between two of the model's calls) stops at once:
/// nothing of the round is recorded or pressed, and both the same run asked again and a
/// `--resume` of the command choose the round the uninterrupted command chose.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancel_while_a_round_is_chosen_records_nothing_and_the_round_is_chosen_again() {
    use std::cell::Cell;

    let tmp = tempfile::tempdir().expect("tempdir");
    let (full, expected) = uninterrupted(tmp.path());
    let round = |r: usize| -> Vec<(u32, usize, String)> { expected.iter().filter(|c| c.1 == r).cloned().collect() };

    let config = rig::config::RigConfig::builtin_sim();
    let runtime = rig::synth::RuntimeOptions::default();
    let mut pipeline = rig::synth::Pipeline::load(&tiny(), &runtime).expect("the tiny package");
    // Cancelled at the k-th question: 1 asks before choosing; 2 and 3 before measuring the
    // error at round 1's two pressed poses; 4 and later before each scored pose's images.
    for cancel_at in [1, 3, 4, 6] {
        let out = tmp.path().join(format!("cut{cancel_at}"));
        let request = rig::jobs::AdaptiveRequest {
            collect: rig::jobs::CollectRequest {
                sensor: "tactip".parse().expect("sensor"),
                plan: Some(full.clone()),
                out: out.clone(),
                ..Default::default()
            },
            budget: 6,
            rounds: 3,
            seeds_per_pose: 2,
            model: Some(tiny()),
            steps: Some(1),
        };
        let mut run = request.prepare(&config, &pipeline).expect("prepared");
        let first = run.next_round(&mut pipeline, &|| false).expect("round 1").expect("a round 1");
        press_round(&config, &run, &first).await;
        let dataset = out.join("sphere/tactip");
        assert_eq!(choices(&dataset), round(1), "round 1 as the command chose it");

        let asked = Cell::new(0);
        let cancelled = || {
            asked.set(asked.get() + 1);
            asked.get() >= cancel_at
        };
        let stopped = run.next_round(&mut pipeline, &cancelled).expect("no error");
        assert!(stopped.is_none(), "cancelled at question {cancel_at}, a round came back");
        assert_eq!(asked.get(), cancel_at, "the choice went on after the cancel");
        assert_eq!(choices(&dataset), round(1), "cancelled at question {cancel_at}: something of round 2 was recorded");
        assert_eq!(pressed(&rows(&dataset)), sorted_unique(round(1).iter().map(|c| c.0)), "only round 1 is pressed");

        if cancel_at % 2 == 0 {
            // Asked again, the same run chooses round 2 as the command did.
            let second = run.next_round(&mut pipeline, &|| false).expect("round 2").expect("a round 2");
            let ids: Vec<u32> = second.choices.iter().map(|c| c.pose_id).collect();
            assert_eq!(ids, round(2).iter().map(|c| c.0).collect::<Vec<_>>(), "cancelled at question {cancel_at}");
        } else {
            // A new process resumes: the same rounds, every pose once.
            drop(run);
            let o = rig().args(adaptive_args(&out, &full, &tiny(), 6, "tactip")).arg("--resume").output().expect("resuming");
            assert!(o.status.success(), "{}", text(&o));
            assert_eq!(choices(&dataset), expected, "cancelled at question {cancel_at}, resumed");
            let rows = rows(&dataset);
            assert_eq!((rows.len(), sorted_unique(rows.iter().map(|r| r.0)).len()), (18, 18), "{rows:?}");
        }
    }
}
