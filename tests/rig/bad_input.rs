//! The bad-input table: each bad input a user can give rig, what rig says and its exit code.
//!
//! Runs the real binary on each bad input and checks the exit code and a key phrase of the
//! message (2 = bad input, 1 = general; see `rig::report::Exit`). Nothing may panic, and nothing
//! may move: every case fails before the arm is driven. The table prints as Markdown (run with
//! `--nocapture`; `RIG_BAD_INPUT_TABLE=<file>` writes it, as the table in
//! `docs/src/faults.md` was made).

use std::path::Path;
use std::process::Command;

fn rig(cwd: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(cwd);
    c.env_remove("RIG_CONFIG");
    c.env("RIG_LOG", "error");
    c
}

struct Case {
    input: &'static str,
    args: Vec<String>,
    code: i32,
    phrase: &'static str,
}

fn case(input: &'static str, args: &[&str], code: i32, phrase: &'static str) -> Case {
    Case { input, args: args.iter().map(|s| s.to_string()).collect(), code, phrase }
}

/// `rig synth one` on the tiny test package with an 8-bit control image and a prompt, then
/// `extra`: a bad input that must exit 2 saying `phrase`.
fn one_on_the_tiny_package(input: &'static str, extra: &[&str], phrase: &'static str) -> Case {
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/tiny-package");
    let args: Vec<&str> =
        ["synth", "one", "--model", model, "--control", "control.png", "--prompt", "p"].into_iter().chain(extra.iter().copied()).collect();
    case(input, &args, 2, phrase)
}

/// The message a reader sees: from the `error:` line (clap's too) on, on one line, without
/// the source excerpts TOML errors draw (`2 | speed = 3`, `  | ^^^`) and clap's usage hints,
/// with the temp dir shortened.
fn message(stderr: &str, tmp: &Path) -> String {
    let mut lines = stderr.lines().skip_while(|l| !l.starts_with("error:"));
    let mut parts: Vec<String> = Vec::new();
    for l in lines.by_ref() {
        let t = l.trim();
        let excerpt = t.starts_with('|') || t.split_once(" |").is_some_and(|(n, _)| n.chars().all(|c| c.is_ascii_digit()));
        if t.starts_with("Usage:") || t.starts_with("For more information") {
            break;
        }
        if !t.is_empty() && !excerpt {
            parts.push(t.to_string());
        }
    }
    parts.join(" ").replace(&tmp.display().to_string(), "<dir>")
}

#[test]
#[cfg_attr(
    not(all(feature = "synth", feature = "lerobot")),
    ignore = "the table has synth and LeRobot cases: it needs the default features"
)]
fn every_bad_input_gets_a_clear_message_and_its_exit_code() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let dir = tmp.path();
    let write = |name: &str, text: &[u8]| std::fs::write(dir.join(name), text).expect("writing a fixture");
    write(
        "garbage.stl",
        b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 nan\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid x\n",
    );
    write("truncated.stl", &[0u8; 90]);
    write("syntax.toml", b"[arm\nbackend = sim\n");
    write("unknown-field.toml", b"[arm]\nspeed = 3\n");
    write("zero-frames.toml", b"[collect]\nframes_per_pose = 0\n");
    write("faults-on-real-arm.toml", b"[arm]\nbackend = \"mg400\"\nhost = \"192.0.2.1\"\n[sim.faults]\nsplit_replies = true\n");
    write("no-host.toml", b"[arm]\nbackend = \"mg400\"\n");
    write("no-profile.toml", b"[arm]\nprofile = \"mg999\"\n");
    write("bad-calibration.toml", b"scale_px_per_mm = \"wide\"\n");
    write("uses-bad-calibration.toml", b"[sensors.tactip]\ncalibration = \"bad-calibration.toml\"\n");
    write("far.toml", b"[work_frame]\norigin = { x_mm = 500.0, y_mm = 0.0, z_mm = 0.0, yaw_deg = 0.0 }\n");
    write(
        "deep-plan.toml",
        b"sampling = \"full\"\norder = \"optimised\"\nx_mm = { min = 0.0, max = 0.0, step = 1.0 }\ny_mm = { min = 0.0, max = 0.0, step = 1.0 }\nz_mm = { min = 20.0, max = 30.0, step = 5.0 }\nyaw_deg = { min = 0.0, max = 0.0, step = 1.0 }\n",
    );
    write("zero-limit.toml", b"[sensors.vitac]\nmax_indentation_mm = 0.0\n");
    write(
        "negative-step.toml",
        b"sampling = \"lhs\"\nn_poses = 1\nseed = 1\norder = \"optimised\"\nx_mm = { min = -5.0, max = 5.0, step = -1.0 }\ny_mm = { min = -5.0, max = 5.0, step = 1.0 }\nz_mm = { min = 0.0, max = 1.0, step = 0.5 }\nyaw_deg = { min = 0.0, max = 0.0, step = 1.0 }\n",
    );
    write("plan-syntax.toml", b"x_mm = { min = 1.0, max = \n");
    write(
        "plan-typo.toml",
        b"samplng = \"full\"\norder = \"optimised\"\nx_mm = { min = 0.0, max = 1.0, step = 1.0 }\ny_mm = { min = 0.0, max = 1.0, step = 1.0 }\nz_mm = { min = 0.0, max = 1.0, step = 1.0 }\nyaw_deg = { min = 0.0, max = 0.0, step = 1.0 }\n",
    );
    // What `rig render --sensor depth` writes: a 16-bit grey PNG, not a control image.
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(16, 16, |x, y| image::Luma([(x * 1000 + y) as u16]))
        .save(dir.join("depth.png"))
        .expect("writing depth.png");
    // An 8-bit RGB control image of the tiny package's size.
    image::RgbImage::from_fn(64, 64, |x, y| image::Rgb([(x * 4) as u8, (y * 4) as u8, 128]))
        .save(dir.join("control.png"))
        .expect("writing control.png");
    write("bad.csv", b"a,b\n1,2\n");
    write("bad-row.csv", b"image_name,data_name,obj_id,pose_id,pose_1,pose_2,pose_3,pose_4,pose_5,pose_6,move_1,move_2,move_3,move_4,move_5,move_6\nf.png,d,1,x,1,2,3,4,5,6,0,0,0,0,0,0\n");
    std::fs::create_dir_all(dir.join("not-a-dataset")).expect("mkdir");
    std::fs::create_dir_all(dir.join("not-a-dataset-either")).expect("mkdir");
    write("not-a-dataset-either/notes.txt", b"a user's file\n");

    // A real small dataset, for the "already exists" and "different plan" cases.
    let made = rig(dir)
        .args(["collect", "--poses", "2", "--seed", "1", "--sensor", "tactip", "--out", "ds"])
        .output()
        .expect("running rig collect");
    assert!(made.status.success(), "setup collect failed: {}", String::from_utf8_lossy(&made.stderr));

    // A dataset whose images/ is a symlink, and a recording "file" that is a FIFO.
    let made = rig(dir).args(["collect", "--poses", "1", "--sensor", "tactip", "--out", "linked"]).output().expect("running rig collect");
    assert!(made.status.success(), "setup collect failed: {}", String::from_utf8_lossy(&made.stderr));
    std::fs::rename(dir.join("linked/sphere/tactip/images"), dir.join("elsewhere")).expect("mv");
    std::os::unix::fs::symlink(dir.join("elsewhere"), dir.join("linked/sphere/tactip/images")).expect("symlink");
    let fifo = std::ffi::CString::new(dir.join("fifo.rec").to_str().expect("utf-8")).expect("c string");
    // SAFETY: mkfifo on a NUL-terminated path in the test's temp folder.
    assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o600) }, 0);

    write("nokhwa.toml", b"[sensors.tactip]\nbackend = \"nokhwa\"\ndevice = \"index:0\"\n");
    write("modbus-forever.toml", b"[modbus.force]\ntransport = \"tcp\"\naddress = \"127.0.0.1:502\"\ntimeout_ms = 18446744073709551615\n");
    write("not-a-port", b"");
    write("magician-file.toml", b"[arm]\nbackend = \"magician\"\nserial_port = \"not-a-port\"\n");

    let mut cases = vec![
        case("unknown subcommand", &["frobnicate"], 2, "unrecognized subcommand"),
        case("a number flag given a word", &["collect", "--poses", "many"], 2, "invalid value"),
        case("unknown sensor name", &["collect", "--sensor", "gelsight", "--dry-run"], 2, "unknown sensor"),
        case("a bad name in a sensor list", &["collect", "--sensor", "all,gelsight", "--dry-run"], 2, "unknown sensor \"gelsight\""),
        case("unknown object name", &["collect", "--object", "teapot", "--dry-run"], 2, "unknown object"),
        case("missing STL file", &["collect", "--stl", "nope.stl", "--dry-run"], 2, "cannot read"),
        case("STL with a NaN vertex", &["collect", "--stl", "garbage.stl", "--dry-run"], 2, "STL"),
        case("truncated binary STL", &["collect", "--stl", "truncated.stl", "--dry-run"], 2, "truncated"),
        case("missing rig config", &["collect", "--config", "nope.toml", "--dry-run"], 2, "cannot read rig config"),
        case("rig config TOML syntax error", &["collect", "--config", "syntax.toml", "--dry-run"], 2, "is not valid"),
        case("unknown rig config field", &["collect", "--config", "unknown-field.toml", "--dry-run"], 2, "unknown field"),
        case("rig config value out of range", &["collect", "--config", "zero-frames.toml", "--dry-run"], 2, "frames_per_pose"),
        case("real arm without a host", &["collect", "--config", "no-host.toml", "--dry-run"], 2, "arm.host"),
        case("fault injection on the real arm", &["collect", "--config", "faults-on-real-arm.toml", "--dry-run"], 2, "simulated arm"),
        case("unknown firmware profile", &["collect", "--config", "no-profile.toml", "--dry-run"], 2, "mg999"),
        case(
            "malformed calibration file",
            &["collect", "--config", "uses-bad-calibration.toml", "--sensor", "tactip", "--poses", "1", "--out", "cal"],
            2,
            "calibration",
        ),
        case("plan file missing", &["collect", "--plan", "nope.toml", "--dry-run"], 2, "cannot read plan"),
        case("plan TOML syntax error", &["collect", "--plan", "plan-syntax.toml", "--dry-run"], 2, "not a valid plan"),
        case("plan with a negative step", &["collect", "--plan", "negative-step.toml", "--dry-run"], 2, "step must be positive"),
        case("plan with a mistyped key", &["collect", "--plan", "plan-typo.toml", "--dry-run"], 2, "(key `samplng`)"),
        case("zero poses asked for", &["collect", "--poses", "0", "--dry-run"], 2, "0 poses"),
        case("more poses than the grid has", &["collect", "--poses", "100000000", "--dry-run"], 2, "only"),
        case("plan outside the arm's workspace", &["collect", "--config", "far.toml", "--dry-run"], 2, "outside the arm's workspace"),
        case("a Modbus timeout no device takes", &["collect", "--config", "modbus-forever.toml", "--dry-run"], 2, "1 to 60000 ms"),
        case(
            "an arm serial port that is a regular file",
            &["collect", "--config", "magician-file.toml", "--sensor", "tactip", "--poses", "1", "--out", "mag"],
            2,
            "is not a serial port",
        ),
        case(
            "plan pressing past the sensor's press limit",
            &["collect", "--plan", "deep-plan.toml", "--sensor", "tactip", "--dry-run"],
            2,
            "beyond tactip's press limit of 5 mm",
        ),
        case(
            "press limit out of range in the rig config",
            &["collect", "--config", "zero-limit.toml", "--dry-run"],
            2,
            "max_indentation_mm",
        ),
        case(
            "collecting into an existing dataset without --resume",
            &["collect", "--poses", "2", "--seed", "1", "--sensor", "tactip", "--out", "ds"],
            2,
            "--resume",
        ),
        case(
            "--resume with a different plan",
            &["collect", "--poses", "3", "--seed", "9", "--sensor", "tactip", "--out", "ds", "--resume"],
            2,
            "different",
        ),
        case("verify a folder that is not a dataset", &["dataset", "verify", "not-a-dataset"], 2, "is not a dataset"),
        case("verify a folder that does not exist", &["dataset", "verify", "no-such-folder"], 2, "folder no-such-folder does not exist"),
        case(
            "fill a folder that does not exist",
            &["synth", "--fill-missing", "--dataset", "no-such-folder", "--dry-run"],
            2,
            "folder no-such-folder does not exist",
        ),
        case("import a CSV that is not MDS", &["dataset", "import", "bad.csv"], 2, "missing column"),
        case("import an MDS row with a bad number", &["dataset", "import", "bad-row.csv"], 2, "malformed MDS row"),
        case("LeRobot export without --out", &["dataset", "export", "ds", "--format", "lerobot"], 2, "needs --out"),
        case(
            "LeRobot export into a folder in use",
            &["dataset", "export", "ds", "--format", "lerobot", "--out", "not-a-dataset-either"],
            2,
            "refusing to overwrite",
        ),
        case("synth with a missing model package", &["synth", "info", "--model", "no-model"], 2, "folder no-model does not exist"),
        case(
            "a depth map as the control image",
            &[
                "synth",
                "one",
                "--model",
                concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/tiny-package"),
                "--control",
                "depth.png",
                "--sensor",
                "vitac",
                "--pose",
                "0,0,1,0",
                "--out",
                "o.png",
            ],
            2,
            "make it with `rig render --sensor control",
        ),
        case(
            "a dataset whose images/ is a symlink",
            &["dataset", "export", "linked/sphere/tactip", "--format", "lerobot", "--out", "lr"],
            2,
            "symlink",
        ),
        case("a recording that is a FIFO", &["replay", "fifo.rec", "--info"], 2, "not a regular file"),
        case(
            "a real image to compare with that is a FIFO",
            &["sensor", "render", "--width", "64", "--height", "64", "--side-by-side", "fifo.rec", "--out", "s.png"],
            2,
            "not a regular file",
        ),
        one_on_the_tiny_package("initial latents that are a FIFO", &["--init-latents", "fifo.rec", "--out", "o.png"], "not a regular file"),
        one_on_the_tiny_package(
            "a trillion sampling steps",
            &["--steps", "1000000000000", "--out", "o.png"],
            "steps = 1000000000000 is not valid",
        ),
        one_on_the_tiny_package(
            "an output in a folder that does not exist",
            &["--out", "no-such-folder/o.png"],
            "the folder no-such-folder does not exist",
        ),
        case(
            "a table for a folder that does not exist, before training",
            &["eval", "--downstream", "ds", "--markdown", "no-such-folder/table.md"],
            2,
            "the folder no-such-folder does not exist",
        ),
        case(
            "synthetic twins on the daemon",
            &["synth", "--poses-of", "ds", "--out", "twins", "--daemon", "http://127.0.0.1:9"],
            2,
            "--daemon runs only --fill-missing",
        ),
        case("downstream table of a folder with no dataset", &["eval", "--downstream", "not-a-dataset"], 2, "no dataset under"),
        case("downstream table from too few captured rows", &["eval", "--downstream", "ds", "--sets", "real"], 2, "collect more poses"),
        case(
            "downstream training on CUDA in a CPU build",
            &["eval", "--downstream", "ds", "--device", "cuda"],
            2,
            "built without CUDA training",
        ),
    ];
    // Each platform builds one hardware camera backend: V4L2 on Linux, nokhwa on macOS and Windows.
    if cfg!(target_os = "linux") {
        cases.push(case(
            "a camera backend this platform does not build",
            &["collect", "--config", "nokhwa.toml", "--sensor", "tactip", "--poses", "1", "--out", "cam"],
            2,
            "backend \"nokhwa\" is not built on this platform",
        ));
    }

    let mut table = vec!["| bad input | command | rig says | exit |".to_string(), "|---|---|---|---|".to_string()];
    let mut failures = Vec::new();
    for c in &cases {
        let o = rig(dir).args(&c.args).output().expect("running rig");
        let stderr = String::from_utf8_lossy(&o.stderr);
        let msg = message(&stderr, dir);
        let code = o.status.code();
        table.push(format!(
            "| {} | `rig {}` | {} | {} |",
            c.input,
            c.args.join(" ").replace(env!("CARGO_MANIFEST_DIR"), "<repo>"),
            // As the guide prints it: the checkout as <repo>, angle brackets escaped for Markdown.
            msg.replace(env!("CARGO_MANIFEST_DIR"), "<repo>").replace('<', "&lt;").replace('>', "&gt;").replace('|', "\\|"),
            code.map_or("signal".to_string(), |c| c.to_string())
        ));
        if code != Some(c.code) {
            failures.push(format!("{}: exit {code:?}, expected {}: {stderr}", c.input, c.code));
        }
        if !msg.contains(c.phrase) {
            failures.push(format!("{}: message lacks {:?}: {stderr}", c.input, c.phrase));
        }
        if stderr.contains("panicked") {
            failures.push(format!("{}: panicked: {stderr}", c.input));
        }
    }
    // Nothing of a refused run may be left as a dataset.
    assert!(!dir.join("cal/sphere/tactip/poses.csv").exists(), "a refused calibration started a dataset");
    assert!(!dir.join("cam/sphere/tactip/poses.csv").exists(), "a refused camera backend started a dataset");
    // A refused export leaves the folder it was pointed at as it was.
    let kept: Vec<_> =
        std::fs::read_dir(dir.join("not-a-dataset-either")).expect("ls").filter_map(|e| e.ok()).map(|e| e.file_name()).collect();
    assert_eq!(kept, vec![std::ffi::OsString::from("notes.txt")], "a refused export touched its --out");
    let table = table.join("\n");
    println!("\n{table}\n");
    if let Ok(path) = std::env::var("RIG_BAD_INPUT_TABLE") {
        std::fs::write(&path, format!("{table}\n")).unwrap_or_else(|e| panic!("writing {path}: {e}"));
    }
    assert!(failures.is_empty(), "bad inputs:\n{}\n\n{table}", failures.join("\n"));
}

/// A command whose Cargo feature this build left out (`cargo build --no-default-features`)
/// still parses and exits 1 saying how to rebuild; with the feature it gets past that check
/// and fails on the input instead (exit 2). Each build checks its own side.
#[test]
fn a_command_of_a_feature_left_out_exits_1_saying_how_to_rebuild() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let dir = tmp.path();
    image::RgbImage::new(16, 16).save(dir.join("c.png")).expect("writing a control image");
    let info = rig(dir).arg("info").output().expect("running rig info");
    let listed = String::from_utf8_lossy(&info.stdout).lines().next().unwrap_or_default().to_string();
    for (feature, built, args, input_error) in [
        ("synth", cfg!(feature = "synth"), vec!["synth", "info", "--model", "no-model"], "folder no-model does not exist"),
        (
            "synth",
            cfg!(feature = "synth"),
            vec!["synth", "one", "--model", "no-model", "--control", "c.png", "--prompt", "p", "--out", "o.png"],
            "does not exist",
        ),
        ("synth", cfg!(feature = "synth"), vec!["synth", "--fill-missing", "--dataset", "no-such-folder"], "no-such-folder"),
        (
            "lerobot",
            cfg!(feature = "lerobot"),
            vec!["dataset", "export", "no-such-folder", "--format", "lerobot", "--out", "lr"],
            "no-such-folder",
        ),
    ] {
        let o = rig(dir).args(&args).output().expect("running rig");
        let stderr = String::from_utf8_lossy(&o.stderr);
        let missing = format!("this rig was built without the `{feature}` feature");
        if built {
            assert_eq!(o.status.code(), Some(2), "rig {args:?}: {stderr}");
            assert!(stderr.contains(input_error) && !stderr.contains(&missing), "rig {args:?}: {stderr}");
        } else {
            assert_eq!(o.status.code(), Some(1), "rig {args:?}: {stderr}");
            assert!(stderr.contains(&missing) && stderr.contains("rebuild with `cargo build"), "rig {args:?}: {stderr}");
        }
        assert!(!dir.join("lr").exists(), "a refused export made its --out");
        assert_eq!(listed.contains(feature), built, "rig info says {listed:?}");
    }
}

/// `rig plan show | head -1`: the reader goes away after one line; rig ends without a panic
/// (killed by SIGPIPE, as Unix tools are), not with "failed printing to stdout".
#[test]
fn output_into_a_closed_pipe_ends_quietly() {
    use std::io::{BufRead, BufReader, Read};
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let plan = Path::new(env!("CARGO_MANIFEST_DIR")).join("plans/train.toml");
    // The full 5265-pose grid: ~270 kB of output, far more than a pipe buffers.
    let mut child = rig(dir.path())
        .args(["plan", "show", "--plan"])
        .arg(&plan)
        .args(["--sampling", "full", "--order", "as-sampled"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running rig");
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).unwrap();
    assert!(!first.is_empty(), "rig printed nothing");
    // The reader is dropped here: the pipe is closed with most of the output unwritten.
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let status = child.wait().unwrap();
    assert!(!stderr.contains("panicked"), "rig panicked on a closed stdout: {stderr}");
    use std::os::unix::process::ExitStatusExt;
    assert_eq!(status.signal(), Some(libc::SIGPIPE), "expected the end by SIGPIPE, got {status:?}; stderr: {stderr}");
}
