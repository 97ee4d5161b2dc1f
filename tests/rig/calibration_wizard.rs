//! The interactive wizard, driven through a pseudo-terminal: the real binary runs with a pty
//! (from `libc::openpty`) as its stdin, stdout and stderr, so it sees a terminal as a user's
//! would; the test answers each prompt as it appears (redo, skip, accept, save) and checks the
//! transcript and the saved file. Set `RIG_TRANSCRIPT_OUT=FILE` to keep the transcript.

use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::{FromRawFd, OwnedFd};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const TRUTH: &str =
    "centre_px = [258.0, 252.0]\nscale_px_per_mm = [9.0, 8.2]\nrotation_deg = -4.0\nimage_size = [512, 512]\ndepth_scale_per_mm = 0.03\n";

/// The pty's output so far, with line ends normalised.
fn transcript(buf: &Arc<Mutex<Vec<u8>>>) -> String {
    String::from_utf8_lossy(&buf.lock().unwrap()).replace("\r\n", "\n")
}

/// Waits until `needle` has appeared `count` times.
fn wait_for(buf: &Arc<Mutex<Vec<u8>>>, needle: &str, count: usize) {
    let start = Instant::now();
    while transcript(buf).matches(needle).count() < count {
        assert!(start.elapsed() < Duration::from_secs(120), "waiting for {needle:?} #{count}:\n{}", transcript(buf));
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `rig calibrate --interactive ARGS` (TacTip, simulated with the TRUTH calibration) in `dir`,
/// with a pty as its terminal: the child, the pty's master side, and the transcript as it
/// arrives (read on a thread of its own, returned to join).
fn spawn_wizard(dir: &std::path::Path, args: &[&str]) -> (std::process::Child, File, Arc<Mutex<Vec<u8>>>, std::thread::JoinHandle<()>) {
    std::fs::write(dir.join("truth.toml"), TRUTH).unwrap();
    let (mut master, mut slave) = (-1, -1);
    // SAFETY: openpty writes two new descriptors into the two ints; the null pointers ask for
    // no name, default terminal settings and default size.
    let rc = unsafe { libc::openpty(&mut master, &mut slave, std::ptr::null_mut(), std::ptr::null_mut(), std::ptr::null_mut()) };
    assert_eq!(rc, 0, "openpty: {}", std::io::Error::last_os_error());
    // SAFETY: both descriptors were just opened by openpty and are owned by nothing else.
    let (master, slave) = unsafe { (File::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
    let child = {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_rig"));
        cmd.args(["calibrate", "--sensor", "tactip", "--interactive", "--sim-truth", "truth.toml", "--out", "wizard.toml"])
            .args(args)
            .current_dir(dir)
            .env_remove("RIG_CONFIG")
            .stdin(Stdio::from(slave.try_clone().unwrap()))
            .stdout(Stdio::from(slave.try_clone().unwrap()))
            .stderr(Stdio::from(slave));
        cmd.spawn().expect("spawning rig")
        // The command (and with it the parent's copies of the slave) is dropped here, so the
        // reader sees the end when the child exits.
    };
    let buf = Arc::new(Mutex::new(Vec::new()));
    let mut reader = master.try_clone().unwrap();
    let sink = Arc::clone(&buf);
    let reading = std::thread::spawn(move || {
        let mut chunk = [0u8; 4096];
        // EIO once the child side is closed: the end of the session.
        while let Ok(n) = reader.read(&mut chunk) {
            if n == 0 {
                break;
            }
            sink.lock().unwrap().extend_from_slice(&chunk[..n]);
        }
    });
    (child, master, buf, reading)
}

#[test]
fn wizard_through_a_pseudo_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let (mut child, master, buf, reading) = spawn_wizard(dir.path(), &["--grid", "3", "--depths-mm", "0.5"]);
    let mut master = master;
    let mut answer = |s: &str| master.write_all(s.as_bytes()).unwrap();

    wait_for(&buf, "(q to quit): ", 1);
    answer("\n");
    // The command line asked for one extra depth; the answer asks for two.
    wait_for(&buf, "0 = none) [+0.5]: ", 1);
    answer("-0.5,0.5\n");
    // 9 grid presses + 9 shallower + 9 deeper; the first is redone, the second skipped.
    let mut prompts = 0;
    prompts += 1;
    wait_for(&buf, "q = quit: ", prompts);
    answer("r\n");
    prompts += 1;
    wait_for(&buf, "q = quit: ", prompts);
    answer("\n");
    prompts += 1;
    wait_for(&buf, "q = quit: ", prompts);
    answer("s\n");
    for _ in 0..25 {
        prompts += 1;
        wait_for(&buf, "q = quit: ", prompts);
        answer("a\n");
    }
    wait_for(&buf, "[y/N]: ", 1);
    answer("y\n");
    let status = child.wait().unwrap();
    reading.join().unwrap();
    let text = transcript(&buf);
    if let Ok(path) = std::env::var("RIG_TRANSCRIPT_OUT") {
        std::fs::write(path, &text).unwrap();
    }
    assert!(status.success(), "{text}");
    assert!(text.contains("Mount the calibration indenter"), "{text}");
    assert!(text.contains("Pressing at extra depths -0.5,+0.5 mm: 27 presses."), "{text}");
    assert!(text.contains("[1/27] pressing at x -4.00 mm, y -4.00 mm"), "{text}");
    assert!(text.contains("[27/27] pressing at x -4.00 mm, y +0.00 mm, extra depth +0.50 mm"), "{text}");
    assert_eq!(text.matches("[1/27]").count(), 2, "redo presses again: {text}");
    assert!(text.contains("      again") && text.contains("      skipped"), "{text}");
    assert!(text.contains("Fitting 26 accepted points"), "{text}");
    assert!(text.contains("depth term  +0.0"), "{text}");
    assert!(text.contains("saved wizard.toml"), "{text}");
    let last = text.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or_default();
    assert!(last.starts_with("residual ") && last.ends_with(" mm)"), "{last:?}");
    let saved = rig::calibration::Calibration::load(dir.path().join("wizard.toml")).unwrap();
    let record = saved.fit.clone().unwrap();
    assert_eq!(record.method, "indenter-wizard");
    assert_eq!(record.points.len(), 26);
    assert!((saved.rotation_deg + 4.0).abs() < 0.5 && (saved.scale_px_per_mm[1] - 8.2).abs() < 0.2, "{saved:?}");
    assert!((saved.depth_scale_per_mm - 0.03).abs() < 0.015, "{saved:?}");
}

/// Ctrl-C while the wizard waits for an answer: the wait ends as a quit, the arm retracts,
/// nothing is saved, exit code 4 (as the automatic run and `rig collect`).
#[test]
fn ctrl_c_at_a_prompt_quits_retracts_and_saves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (mut child, mut master, buf, reading) = spawn_wizard(dir.path(), &["--grid", "3", "--depths-mm", "0.5"]);
    wait_for(&buf, "(q to quit): ", 1);
    master.write_all(b"\n").unwrap();
    wait_for(&buf, "0 = none) [+0.5]: ", 1);
    master.write_all(b"\n").unwrap();
    wait_for(&buf, "q = quit: ", 1);
    master.write_all(b"a\n").unwrap();
    // At the second press's question, with the process blocked waiting for the answer.
    wait_for(&buf, "q = quit: ", 2);
    let pid = i32::try_from(child.id()).expect("pid");
    // SAFETY: kill(2) on our own child's pid, with a valid signal number.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGINT) }, 0, "sending SIGINT");
    let status = child.wait().unwrap();
    reading.join().unwrap();
    let text = transcript(&buf);
    assert_eq!(status.code(), Some(4), "{text}");
    assert!(text.contains("interrupt: finishing the current press"), "{text}");
    let last = text.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or_default();
    assert_eq!(last, "interrupted; the arm is retracted and wizard.toml was not written", "{text}");
    assert!(!text.contains("[3/18]"), "no press after the interrupt: {text}");
    assert!(!dir.path().join("wizard.toml").exists(), "{text}");
}
