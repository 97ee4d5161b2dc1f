//! `rig collect --record` then `rig replay`: the real binary records a small seeded collection
//! on the built-in simulated rig (real MG400 client over loopback TCP, simulated sensors),
//! replays it with no simulator into another directory, and the datasets must match: `poses.csv`
//! byte for byte, images by decoded pixels. Damaged recordings must fail with a clear message.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use rig::record::format::{self, Event};

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    c
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Small sensors keep the recording small; two sensors cover the camera interleaving.
const CONFIG: &str = "[sensors.tactip]\nwidth = 48\nheight = 40\n[sensors.vitac]\nwidth = 48\nheight = 40\n";
const SENSORS: [&str; 2] = ["tactip", "vitac"];

/// `rig collect` of a seeded `poses`-pose sphere plan with config `config_toml`, into
/// `dir/recorded/`, recording into `dir/rec.bin`.
fn collect_recorded(dir: &Path, poses: u32, config_toml: &str) -> (Command, PathBuf) {
    let config = dir.join("rig.toml");
    std::fs::write(&config, config_toml).expect("writing the config");
    let rec = dir.join("rec.bin");
    let mut c = rig();
    c.args(["collect", "--object", "sphere", "--poses", &poses.to_string(), "--seed", "11", "--sensor", "tactip,vitac"])
        .arg("--config")
        .arg(&config)
        .arg("--out")
        .arg(dir.join("recorded"))
        .arg("--record")
        .arg(&rec);
    (c, rec)
}

/// Records a seeded 3-pose collection into `dir/rec.bin` and `dir/recorded/`.
fn record(dir: &Path) -> PathBuf {
    let (mut c, rec) = collect_recorded(dir, 3, CONFIG);
    let o = c.output().expect("running rig collect");
    assert!(o.status.success(), "rig collect --record failed:\n{}", text(&o));
    assert!(text(&o).contains("recorded "), "collect must say it recorded:\n{}", text(&o));
    rec
}

fn replay(rec: &Path, out: &Path) -> Output {
    rig().arg("replay").arg(rec).arg("--out").arg(out).args(["--stall-s", "20"]).output().expect("running rig replay")
}

/// Pixel comparison with a readable first difference.
fn assert_same_pixels(a: &Path, b: &Path) {
    let ia = image::open(a).unwrap_or_else(|e| panic!("decoding {}: {e}", a.display())).to_rgb8();
    let ib = image::open(b).unwrap_or_else(|e| panic!("decoding {}: {e}", b.display())).to_rgb8();
    assert_eq!(ia.dimensions(), ib.dimensions(), "{} and {} differ in size", a.display(), b.display());
    let diffs: Vec<_> = ia.enumerate_pixels().filter(|(x, y, p)| ib.get_pixel(*x, *y) != *p).collect();
    if let Some((x, y, p)) = diffs.first() {
        panic!(
            "{} and {} differ in {} pixels; first at ({x}, {y}): {:?} vs {:?}",
            a.display(),
            b.display(),
            diffs.len(),
            p.0,
            ib.get_pixel(*x, *y).0
        );
    }
}

/// The sphere datasets under `a` and `b` hold the same `rows` rows and pixels.
fn assert_same_dataset(a: &Path, b: &Path, rows: usize) {
    for sensor in SENSORS {
        let (da, db) = (a.join("sphere").join(sensor), b.join("sphere").join(sensor));
        let (ca, cb) =
            (std::fs::read(da.join("poses.csv")).expect("recorded csv"), std::fs::read(db.join("poses.csv")).expect("replayed csv"));
        assert_eq!(String::from_utf8_lossy(&ca), String::from_utf8_lossy(&cb), "{sensor}: poses.csv differs");
        assert_eq!(ca.iter().filter(|&&c| c == b'\n').count(), rows + 1, "{sensor}: header and {rows} rows");
        let mut names: Vec<PathBuf> =
            std::fs::read_dir(da.join("images")).expect("images dir").map(|e| e.expect("dir entry").path()).collect();
        names.sort();
        assert_eq!(names.len(), rows, "{sensor}: {rows} images");
        names.push(da.join("reference.png"));
        for image_a in names {
            let rel = image_a.strip_prefix(&da).expect("under the dataset");
            assert_same_pixels(&image_a, &db.join(rel));
        }
    }
}

/// Byte offset of the first pixel byte of the first frame record (layout in `record::format`).
fn first_frame_pixel_offset(bytes: &[u8]) -> usize {
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes")) as usize;
    let mut at = 14 + u32_at(10) + 4;
    loop {
        let (kind, len) = (bytes[at], u32_at(at + 1));
        if kind == 2 {
            // kind, length, then camera, t_s, t_capture_s, seq, width, height, encoding (PNG), and
            // the PNG's signature and IHDR chunk (8 + 25 bytes): the first IDAT's data is 8 further.
            return at + 5 + 1 + 8 + 8 + 8 + 4 + 4 + 1 + 8 + 25 + 8;
        }
        at += 5 + len + 4;
    }
}

#[test]
fn a_recorded_collection_replays_to_the_same_dataset_and_damage_is_reported() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let rec = record(tmp.path());

    // Twice: the replay does not depend on timing.
    for out in ["replayed-1", "replayed-2"] {
        let out = tmp.path().join(out);
        let o = replay(&rec, &out);
        assert!(o.status.success(), "rig replay failed:\n{}", text(&o));
        assert!(text(&o).contains("3 poses captured"), "{}", text(&o));
        assert_same_dataset(&tmp.path().join("recorded"), &out, 3);
    }

    // What it holds, without replaying: 3 poses and the reference frame per sensor, decisions
    // recorded, nothing lost.
    let info_out = tmp.path().join("not-written");
    let o = rig().arg("replay").arg(&rec).arg("--info").arg("--out").arg(&info_out).output().expect("running rig replay --info");
    assert!(o.status.success(), "rig replay --info failed:\n{}", text(&o));
    for line in
        ["object sphere, sensors tactip, vitac, 3 planned poses (seed 11)", "camera frames: tactip 4, vitac 4", "connections lost: none"]
    {
        assert!(text(&o).contains(line), "{line:?} missing:\n{}", text(&o));
    }
    let decisions = text(&o)
        .lines()
        .find_map(|l| l.strip_prefix("decisions on the feedback: ")?.split(' ').next()?.parse::<usize>().ok())
        .unwrap_or_else(|| panic!("no count of decisions:\n{}", text(&o)));
    assert!(decisions >= 9, "at least one per move of 3 poses: {decisions}");
    assert!(!info_out.exists(), "--info replays nothing");

    let bytes = std::fs::read(&rec).expect("reading the recording");

    // Cut short, as when the recording run is killed.
    let cut = tmp.path().join("cut.bin");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).expect("writing");
    let o = replay(&cut, &tmp.path().join("from-cut"));
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("truncated"), "a cut recording must say so:\n{}", text(&o));
    assert!(!tmp.path().join("from-cut").exists(), "nothing is written from a damaged recording");

    // One bit flipped inside the pixels of the first recorded frame.
    let mut flipped = bytes.clone();
    let pixel = first_frame_pixel_offset(&bytes);
    flipped[pixel] ^= 0x10;
    let bad = tmp.path().join("flipped.bin");
    std::fs::write(&bad, &flipped).expect("writing");
    let o = replay(&bad, &tmp.path().join("from-flipped"));
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("corrupted") && text(&o).contains("checksum"), "{}", text(&o));

    // A resumed run cannot be recorded: its replay would start from an empty dataset.
    let o = rig()
        .args(["collect", "--poses", "3", "--resume", "--record"])
        .arg(tmp.path().join("resumed.bin"))
        .arg("--out")
        .arg(tmp.path().join("resumed"))
        .output()
        .expect("running rig collect");
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("--resume"), "{}", text(&o));

    // Not a recording at all.
    let o = replay(&tmp.path().join("rig.toml"), &tmp.path().join("from-toml"));
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("not a rig recording"), "{}", text(&o));
}

#[test]
fn a_client_that_sends_something_else_is_a_divergence_naming_both_sides() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let rec = record(tmp.path());
    let raw = format::decode(&std::fs::read(&rec).expect("reading")).expect("a valid recording");

    // Replay with another speed factor: the client's SpeedFactor request no longer matches.
    let mut header: serde_json::Value = serde_json::from_str(&raw.header_json).expect("json header");
    assert_eq!(header["speed_factor_pct"], 100);
    header["speed_factor_pct"] = 37.into();
    let mut bytes = format::encode_preamble(&header.to_string());
    for e in &raw.events {
        bytes.extend(format::encode_event(e));
    }
    bytes.extend(format::encode_end(raw.events.len() as u64));
    let edited = tmp.path().join("edited.bin");
    std::fs::write(&edited, bytes).expect("writing");

    let o = replay(&edited, &tmp.path().join("out"));
    assert_eq!(o.status.code(), Some(3), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("replay diverged at record"), "{t}");
    assert!(t.contains("SpeedFactor(100)") && t.contains("SpeedFactor(37)"), "both sides must be named:\n{t}");
    let first_write = raw.events.iter().position(|e| matches!(e, Event::Socket { direction: format::Direction::ToController, .. }));
    assert!(first_write.is_some(), "the recording holds requests");
}

/// An in-process arm session on the simulator, recorded, and its replay (the alarm and the
/// reordering tests below).
mod session {
    use rig::arm::dobot::client::{ByteStream, Mg400Client, Mg400Config};
    use rig::arm::{Arm, MoveKind};
    use rig::clock::{Clock, MonotonicClock};
    use rig::pose::Pose;
    use rig::record::format::Event;
    use rig::record::replay::{Divergence, ReplaySession};
    use rig::record::{Recorder, Recording, SocketId, connect_recorded};
    use rig::sim::mg400::{SimFaults, SimMg400, SimMg400Config};
    use std::path::Path;
    use std::sync::Arc;
    use std::time::Duration;

    /// Enable, two moves (each waited for, then a settle pause as in a collection, so that
    /// feedback is read between the `Sync()` reply and the next command), ClearError, the
    /// second move again, disable: the outcome of every call, as text.
    pub async fn run(arm: &mut Mg400Client) -> Vec<String> {
        let wait = Duration::from_secs(20);
        let (first, second) = (Pose::new(300.0, 20.0, -20.0, 0.0), Pose::new(260.0, -60.0, -30.0, 20.0));
        let mut log = Vec::new();
        log.push(format!("{:?}", arm.enable().await));
        for target in [first, second] {
            log.push(format!("{:?}", arm.move_to(target, MoveKind::Joint).await));
            log.push(format!("{:?}", arm.wait_arrived(target, wait).await.map(|a| (a.measured, a.error_mm))));
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        log.push(format!("{:?}", arm.clear_error().await));
        log.push(format!("{:?}", arm.move_to(second, MoveKind::Joint).await));
        log.push(format!("{:?}", arm.wait_arrived(second, wait).await.map(|a| (a.measured, a.error_mm))));
        log.push(format!("{:?}", arm.disable().await));
        log
    }

    /// Runs the session on a simulator with `faults`, recording into `path` (multi-threaded,
    /// as `rig collect --record` runs).
    pub fn record(path: &Path, faults: SimFaults) -> Vec<String> {
        record_script(path, faults, run)
    }

    /// [`record`] with another session than [`run`].
    pub fn record_script(path: &Path, faults: SimFaults, script: impl AsyncFn(&mut Mg400Client) -> Vec<String>) -> Vec<String> {
        tokio::runtime::Runtime::new().expect("runtime").block_on(async {
            let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::scaled(20.0));
            let sim = SimMg400::start(SimMg400Config { faults, ..Default::default() }, clock.clone()).await.expect("simulator");
            let recorder = Recorder::create(path, clock.clone()).expect("recording file");
            let mut cfg = Mg400Config::at_addresses(sim.dashboard_addr(), sim.motion_addr(), sim.feedback_addr(), sim.profile());
            cfg.speed_factor_pct = 100;
            let mut arm = connect_recorded(cfg, clock, recorder.clone()).await.expect("connects");
            let header = serde_json::from_str(&format!(
                r#"{{"rig_version":"test","command_line":[],"config_source":null,"object":{{"name":"none"}},"sensors":[],"seed":0,
                   "plan_spec":{},"plan":[],"work_frame":{},"collect":{{"settle_s":0,"frames_per_pose":1,"average_frames":false,
                   "move_timeout_s":20,"retries_per_pose":0}},"profile":{},"speed_factor_pct":100}}"#,
                serde_json::to_string(&rig::plan::PlanSpec::default()).expect("json"),
                serde_json::to_string(&rig::pose::WorkFrame::default()).expect("json"),
                serde_json::to_string(&rig::arm::profile::FirmwareProfile::default_mg400()).expect("json"),
            ))
            .expect("header");
            recorder.begin(&header).expect("header written");
            let log = script(&mut arm).await;
            recorder.finish().expect("recording closed");
            drop(arm);
            sim.shutdown().await;
            log
        })
    }

    /// Replays the session over `events` (of `recording`) on a current-thread runtime, as `rig
    /// replay` does: its log, or where it left the recording. `decisions`: the client's
    /// decisions on the feedback follow the recorded ones, as for a recording of version 5 on.
    pub fn replay(recording: &Recording, events: Vec<Event>, decisions: bool) -> Result<Vec<String>, Divergence> {
        replay_script(recording, events, decisions, Duration::from_secs(5), run)
    }

    /// [`replay`] with another session than [`run`], and a watchdog reporting a replay that
    /// makes no progress for `stall`.
    pub fn replay_script(
        recording: &Recording,
        events: Vec<Event>,
        decisions: bool,
        stall: Duration,
        script: impl AsyncFn(&mut Mg400Client) -> Vec<String>,
    ) -> Result<Vec<String>, Divergence> {
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
        runtime.block_on(async {
            let replay = ReplaySession::new(events, vec![]);
            let watchdog = tokio::spawn(replay.clone().watchdog(stall));
            let mut cfg = Mg400Config::new("replay", recording.header.profile.clone());
            cfg.speed_factor_pct = 100;
            let clock: Arc<dyn Clock> = Arc::new(replay.clock());
            // As rig replay builds it: a lost socket is reopened where the recording reopened it.
            let replayed = |socket| (Box::new(replay.stream(socket)) as Box<dyn ByteStream>, replay.reopen(socket));
            let mut arm = Mg400Client::with_reopen(
                cfg,
                clock,
                [replayed(SocketId::Dashboard), replayed(SocketId::Motion), replayed(SocketId::Feedback)],
            );
            if decisions {
                arm.set_witness(replay.witness());
            }
            let first = arm.wait_first_feedback().await;
            let log = if first.is_ok() { script(&mut arm).await } else { Vec::new() };
            watchdog.abort();
            if let Some(d) = replay.divergence() {
                return Err(d);
            }
            first.expect("first feedback");
            replay.check_finished().expect("every recorded step replayed");
            Ok(log)
        })
    }
}

/// The client alone, through a collision alarm and its recovery: recorded against the
/// simulated MG400 on a multi-threaded runtime (as `rig collect` runs), replayed on one thread
/// with no simulator; every result must be the same.
#[test]
fn an_alarm_and_its_recovery_replay_the_same() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = tmp.path().join("alarm.rec");
    let faults = rig::sim::mg400::SimFaults { collision_at_move: Some(2), ..Default::default() };
    let recorded = session::record(&path, faults);
    assert!(recorded[4].contains("collision"), "the second move must collide: {recorded:#?}");
    let recording = rig::record::Recording::read(&path).expect("reading the recording");
    assert!(recording.version >= 5 && recording.events.iter().any(|e| matches!(e, Event::FeedbackUsed { .. })));
    let replayed = session::replay(&recording, recording.events.clone(), true).unwrap_or_else(|d| panic!("{d}"));
    assert_eq!(replayed, recorded);
}

/// Since format version 5 the recording names the feedback frame each decision of the client
/// went by (in alarm? arrived? enabled? the queue running?). Live, a frame can be logged before a
/// decision and yet not be the one it saw: the reader logs a read, then publishes its frames.
/// A replay publishes a frame as soon as its read is next, so it must decide on the recorded
/// frame, not the newest. This moves every run of feedback reads before up to three events ahead
/// of it (back to the previous feedback, at the time of the first event passed), so that
/// decisions face frames newer than the ones they went by, and replays: the same outcome, for a
/// clean session and for one with a collision alarm.
#[test]
fn decisions_go_by_the_recorded_frame_however_early_the_feedback_is_read() {
    use rig::record::SocketId;
    let is_feedback =
        |e: &Event| matches!(e, Event::Socket { socket: SocketId::Feedback, .. } | Event::Connect { socket: SocketId::Feedback, .. });
    let tmp = tempfile::tempdir().expect("tempdir");
    for (name, faults) in [
        ("clean", rig::sim::mg400::SimFaults::default()),
        ("alarm", rig::sim::mg400::SimFaults { collision_at_move: Some(2), ..Default::default() }),
    ] {
        let path = tmp.path().join(format!("{name}.rec"));
        let recorded = session::record(&path, faults);
        let recording = rig::record::Recording::read(&path).expect("reading the recording");
        let mut events: Vec<Event> = Vec::new();
        let (mut moved, mut past_decisions) = (0, 0);
        let mut rest = recording.events.as_slice();
        while let Some(e) = rest.first() {
            let run = rest.iter().take_while(|e| is_feedback(e)).count();
            // Up to three events ahead of the run, back to the previous feedback.
            let keep = events.len() - events.iter().rev().take(3).take_while(|a| !is_feedback(a)).count();
            if run > 0 && keep < events.len() {
                let ahead = events.split_off(keep);
                past_decisions += ahead.iter().filter(|a| matches!(a, Event::FeedbackUsed { .. })).count();
                let t_first = ahead[0].t_s();
                events.extend(rest[..run].iter().cloned().map(|mut f| {
                    if let Event::Socket { t_s, .. } = &mut f {
                        *t_s = t_first;
                    }
                    f
                }));
                events.extend(ahead);
                moved += 1;
                rest = &rest[run..];
            } else {
                events.push(e.clone());
                rest = &rest[1..];
            }
        }
        assert_eq!(events.len(), recording.events.len());
        assert!(moved >= 5 && past_decisions >= 4, "{name}: {moved} runs moved, {past_decisions} past a decision");
        let replayed = session::replay(&recording, events, true).unwrap_or_else(|d| panic!("{name}: {d}"));
        assert_eq!(replayed, recorded, "{name}");
    }
}

/// The client's feedback reader logs a read, then publishes its frames; the job may look at the
/// newest frame in between. So a frame can be logged before a `Sync()` reply and yet be the
/// newest the job sees after it, and the job may act before the next frame arrives. The replay
/// publishes every frame as soon as it is next, so arrival must not need a frame newer than the
/// one held after the reply. This rewrites a clean recording into that order. Each socket's
/// bytes stay in their order; only where the feedback falls between the other sockets' events
/// changes. Where the feedback right after a `Sync()` reply runs up to a read whose last frame
/// shows the arm at rest (mode 5), those reads move before the reply (at its time), and the
/// rest of that feedback moves after the job's next event. A recording of version 4 or older
/// (no decisions recorded), so the replayed client decides on the frames it holds.
#[test]
fn feedback_logged_before_a_sync_reply_but_seen_after_it_replays_the_same() {
    use rig::arm::dobot::proto::{FeedbackDecoder, RobotMode};
    use rig::record::SocketId;
    use rig::record::format::Direction;
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = tmp.path().join("clean.rec");
    let recorded = session::record(&path, rig::sim::mg400::SimFaults::default());
    let mut recording = rig::record::Recording::read(&path).expect("reading the recording");
    recording.events.retain(|e| !matches!(e, Event::FeedbackUsed { .. }));
    let is_feedback = |e: &Event| matches!(e, Event::Socket { socket: SocketId::Feedback, .. });
    let is_sync_reply = |e: &Event| {
        matches!(e, Event::Socket { socket: SocketId::Motion, direction: Direction::FromController, bytes, .. }
            if bytes.ends_with(b"Sync();"))
    };
    // Whether the last frame completed by each feedback read shows the arm at rest.
    let mut decoder = FeedbackDecoder::new();
    let mut at_rest = false;
    let rests: Vec<bool> = recording
        .events
        .iter()
        .map(|e| {
            if let Event::Socket { socket: SocketId::Feedback, bytes, .. } = e {
                decoder.push(bytes);
                while let Some(frame) = decoder.next_frame() {
                    at_rest = frame.mode() == RobotMode::Enabled;
                }
            }
            at_rest
        })
        .collect();
    let mut events: Vec<(Event, bool)> = recording.events.iter().cloned().zip(rests).collect();
    let mut moved = 0;
    let mut i = 0;
    while i < events.len() {
        let run = events[i + 1..].iter().take_while(|(e, _)| is_feedback(e)).count();
        if is_sync_reply(&events[i].0)
            && let Some(upto) = events[i + 1..i + 1 + run].iter().position(|&(_, rest)| rest)
            && i + 1 + run < events.len()
        {
            // Reads i+1 ..= i+1+upto go before the reply; the rest of the run after the job's event.
            let reply_t = events[i].0.t_s();
            let before: Vec<(Event, bool)> = events.drain(i + 1..i + 2 + upto).collect();
            let after: Vec<(Event, bool)> = events.drain(i + 1..i + run - upto).collect();
            events.splice(i + 2..i + 2, after);
            let n = before.len();
            events.splice(
                i..i,
                before.into_iter().map(|(mut e, rest)| {
                    if let Event::Socket { t_s, .. } = &mut e {
                        *t_s = reply_t;
                    }
                    (e, rest)
                }),
            );
            i += n;
            moved += 1;
        }
        i += 1;
    }
    assert!(moved >= 1, "no Sync() reply is followed by feedback showing the arm at rest");
    let events: Vec<Event> = events.into_iter().map(|(e, _)| e).collect();
    assert_eq!(events.len(), recording.events.len());
    let replayed = session::replay(&recording, events, false).unwrap_or_else(|d| panic!("{d}"));
    assert_eq!(replayed, recorded);
}

/// A wait for arrival that timed out (for a pose the arm was not sent to: the queue is empty,
/// so `Sync()` answers at once, and the feedback never shows that pose) is recorded as such and
/// replays as a timeout at the same point, although a replay takes no time.
#[test]
fn a_wait_that_timed_out_replays_as_a_timeout() {
    use rig::arm::dobot::client::Mg400Client;
    use rig::arm::{Arm, MoveKind};
    use rig::pose::Pose;
    async fn script(arm: &mut Mg400Client) -> Vec<String> {
        let target = Pose::new(250.0, -80.0, -40.0, 30.0);
        let elsewhere = Pose::new(250.0, -80.0, -40.0, 31.0);
        let mut log = vec![format!("{:?}", arm.enable().await), format!("{:?}", arm.move_to(target, MoveKind::Joint).await)];
        for (pose, wait_ms) in [(target, 20_000), (elsewhere, 300), (target, 20_000)] {
            let arrived = arm.wait_arrived(pose, std::time::Duration::from_millis(wait_ms)).await;
            log.push(match arrived {
                Ok(a) => format!("arrived at {:?}", a.measured),
                Err(e) => format!("timed out: {}", matches!(e, rig::arm::ArmError::Timeout { .. })),
            });
        }
        log.push(format!("{:?}", arm.disable().await));
        log
    }
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = tmp.path().join("timeout.rec");
    let recorded = session::record_script(&path, rig::sim::mg400::SimFaults::default(), script);
    assert!(recorded[2].starts_with("arrived") && recorded[4].starts_with("arrived"), "{recorded:#?}");
    assert_eq!(recorded[3], "timed out: true", "{recorded:#?}");
    let recording = rig::record::Recording::read(&path).expect("reading the recording");
    assert!(recording.events.iter().any(|e| matches!(e, Event::FeedbackUsed { seq: None, .. })), "no timed-out wait recorded");
    let replayed = session::replay_script(&recording, recording.events.clone(), true, std::time::Duration::from_secs(5), script)
        .unwrap_or_else(|d| panic!("{d}"));
    assert_eq!(replayed, recorded);
}

/// A reply that did not come in time (the simulator answers every command 2 s late; the first
/// `Sync()` waits 1.5 s) is recorded, and the replay gives up on it where the recording did,
/// not on its clock: the replay's watchdog, at 1 s, would report a replay that waited 1.5 s for
/// nothing. The late reply is then read and skipped by the next `Sync()`, in both runs.
#[test]
fn a_reply_that_timed_out_replays_as_a_timeout_without_waiting() {
    use rig::arm::dobot::client::Mg400Client;
    use std::time::Duration;
    async fn script(arm: &mut Mg400Client) -> Vec<String> {
        let mut log = Vec::new();
        for wait in [Duration::from_millis(1500), Duration::from_secs(10)] {
            log.push(match arm.sync(wait).await {
                Ok(()) => "synced".to_string(),
                Err(e) => format!("timed out: {}", matches!(e, rig::arm::ArmError::Timeout { .. })),
            });
        }
        log
    }
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = tmp.path().join("late.rec");
    let faults = rig::sim::mg400::SimFaults { reply_delay: Duration::from_secs(2), ..Default::default() };
    let recorded = session::record_script(&path, faults, script);
    assert_eq!(recorded, ["timed out: true", "synced"]);
    let recording = rig::record::Recording::read(&path).expect("reading the recording");
    assert!(
        recording.events.iter().any(|e| matches!(e, Event::ReplyTimedOut { socket: rig::record::SocketId::Motion, .. })),
        "no timed-out reply recorded"
    );
    let replayed = session::replay_script(&recording, recording.events.clone(), true, Duration::from_secs(1), script)
        .unwrap_or_else(|d| panic!("{d}"));
    assert_eq!(replayed, recorded);
}

/// Ctrl-C during a recorded collection: the recording says where the job stopped, and the
/// replay stops there too, retracting exactly as the recorded run did.
#[test]
fn an_interrupted_recording_replays_to_the_same_partial_dataset() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    // A simulated clock at real speed: the run lasts long enough to be interrupted mid-plan.
    let (mut c, rec) = collect_recorded(dir, 40, &format!("{CONFIG}[arm]\nsim_time_scale = 1.0\n"));
    let mut child = c.stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::piped()).spawn().expect("starting rig collect");
    // Wait for two captured rows, then interrupt.
    let csv = dir.join("recorded/sphere/vitac/poses.csv");
    let rows = |p: &Path| std::fs::read_to_string(p).map_or(0, |t| t.lines().count().saturating_sub(1));
    let t0 = std::time::Instant::now();
    while rows(&csv) < 2 {
        assert!(t0.elapsed().as_secs() < 120, "no two rows in 120 s");
        assert!(child.try_wait().expect("polling rig").is_none(), "rig collect ended before it was interrupted");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let pid = i32::try_from(child.id()).expect("pid");
    // SAFETY: kill(2) on our own child's pid, with a valid signal number.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGINT) }, 0, "sending SIGINT");
    let o = child.wait_with_output().expect("waiting for rig collect");
    assert_eq!(o.status.code(), Some(4), "an interrupted collection exits 4:\n{}", text(&o));
    assert!(text(&o).contains("interrupted: ") && text(&o).contains("recorded "), "{}", text(&o));
    let captured = rows(&csv);
    assert!((2..40).contains(&captured), "{captured} rows:\n{}", text(&o));

    let recording = format::decode(&std::fs::read(&rec).expect("reading the recording")).expect("a whole recording");
    let interrupts: Vec<&Event> = recording.events.iter().filter(|e| matches!(e, Event::Interrupt { .. })).collect();
    assert!(
        matches!(interrupts.as_slice(), [Event::Interrupt { captured: c, .. }] if *c as usize == captured),
        "one interrupt record at {captured} poses: {interrupts:?}"
    );

    let out = dir.join("replayed");
    let o = replay(&rec, &out);
    assert!(o.status.success(), "rig replay failed:\n{}", text(&o));
    assert!(
        text(&o).contains(&format!("{captured} poses captured")) && text(&o).contains("stopped where the recorded run was interrupted"),
        "{}",
        text(&o)
    );
    for sensor in SENSORS {
        let a = std::fs::read_to_string(dir.join("recorded/sphere").join(sensor).join("poses.csv")).expect("recorded csv");
        let b = std::fs::read_to_string(out.join("sphere").join(sensor).join("poses.csv")).expect("replayed csv");
        assert_eq!(a, b, "{sensor}: poses.csv differs");
    }
}

/// The arm's dashboard connection is closed, unanswered, at its 6th command (`DisableRobot()`
/// at the end of the run). The recorded run reconnects and finishes, as an unrecorded one does;
/// the recording holds the loss and the reconnection, and the replay loses and reopens the
/// socket at the same points, to the same dataset.
#[test]
fn a_lost_arm_connection_is_recorded_with_its_reconnection_and_replays_the_same() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (mut c, rec) = collect_recorded(tmp.path(), 3, &format!("{CONFIG}[sim.faults]\ndrop_dashboard_after = 5\n"));
    let o = c.output().expect("running rig collect");
    let recorded = text(&o);
    assert!(o.status.success(), "the recorded run reconnects and finishes:\n{recorded}");
    let events = format::decode(&std::fs::read(&rec).expect("reading the recording")).expect("a complete recording").events;
    let lost: Vec<usize> = events.iter().enumerate().filter(|(_, e)| e.is_connection_lost()).map(|(i, _)| i).collect();
    let reopened: Vec<usize> = events.iter().enumerate().filter(|(_, e)| matches!(e, Event::Connect { .. })).map(|(i, _)| i).collect();
    assert_eq!((lost.len(), reopened.len()), (1, 1), "one loss, one reconnection");
    assert!(
        matches!(events[lost[0]], Event::Socket { socket: format::SocketId::Dashboard, direction: format::Direction::FromController, .. }),
        "the dashboard's, seen by a read: {:?}",
        events[lost[0]]
    );
    assert!(
        matches!(
            events[reopened[0]],
            Event::Connect { socket: format::SocketId::Dashboard, outcome: format::ConnectOutcome::Connected, .. }
        ),
        "{:?}",
        events[reopened[0]]
    );
    assert!(lost[0] < reopened[0]);
    // DisableRobot() is sent again on the new connection.
    assert!(events[reopened[0]..].iter().any(|e| matches!(e, Event::Socket { bytes, .. } if bytes.starts_with(b"DisableRobot()"))));

    for out in ["replayed-1", "replayed-2"] {
        let out = tmp.path().join(out);
        let o = replay(&rec, &out);
        assert!(o.status.success(), "rig replay failed:\n{}", text(&o));
        assert_same_dataset(&tmp.path().join("recorded"), &out, 3);
    }
}

/// Every socket of the simulated arm is closed every 0.7 s of rig time, so the recorded run
/// loses and reopens all three (the feedback too) several times, mid-move and mid-capture; it
/// still finishes, and the replay reopens them at the same points, to the same dataset.
#[test]
fn a_run_whose_sockets_keep_dropping_replays_the_same() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (mut c, rec) = collect_recorded(tmp.path(), 5, &format!("{CONFIG}[sim.faults]\ndrop_sockets_every_s = 0.7\n"));
    let o = c.output().expect("running rig collect");
    assert!(o.status.success(), "the recorded run reconnects and finishes:\n{}", text(&o));
    let events = format::decode(&std::fs::read(&rec).expect("reading the recording")).expect("a complete recording").events;
    let reopened = |socket| events.iter().filter(|e| matches!(e, Event::Connect { socket: s, .. } if *s == socket)).count();
    for socket in format::SocketId::ALL {
        assert!(reopened(socket) >= 1, "the {} socket was never reopened", socket.name());
    }
    let out = tmp.path().join("replayed");
    let o = replay(&rec, &out);
    assert!(o.status.success(), "rig replay failed:\n{}", text(&o));
    assert_same_dataset(&tmp.path().join("recorded"), &out, 5);
}

/// A 2-pose collection of 32 x 24 frames recorded by rig's format-5 writer (raw frames), and
/// the dataset that run wrote (`tests/data/recording-v5/README.md` says how they were made).
fn fixture_v5() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/recording-v5")
}

/// Offset, kind and body length of every record of a recording (layout in `record::format`).
fn record_spans(bytes: &[u8]) -> Vec<(usize, u8, usize)> {
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes")) as usize;
    let mut at = 14 + u32_at(10) + 4;
    let mut spans = Vec::new();
    while at < bytes.len() {
        spans.push((at, bytes[at], u32_at(at + 1)));
        at += 5 + u32_at(at + 1) + 4;
    }
    spans
}

/// A record of `kind` with `body`, checksummed.
fn record_bytes(kind: u8, body: &[u8]) -> Vec<u8> {
    let len = (body.len() as u32).to_le_bytes();
    [&[kind][..], &len, body, &format::crc32(&[&[kind], &len, body]).to_le_bytes()].concat()
}

/// A PNG of `width` x `height` 8-bit RGB pixels as the format checks it (signature, IHDR, IDAT,
/// IEND, checksummed chunks) whose IDAT data are not a zlib stream: it passes every check made
/// without inflating it, and does not inflate.
fn png_claiming(width: u32, height: u32) -> Vec<u8> {
    let ihdr = [&width.to_be_bytes()[..], &height.to_be_bytes(), &[8, 2, 0, 0, 0]].concat();
    let chunk = |kind: &[u8; 4], data: &[u8]| {
        [&(data.len() as u32).to_be_bytes()[..], kind, data, &format::crc32(&[kind, data]).to_be_bytes()].concat()
    };
    [&b"\x89PNG\r\n\x1a\n"[..], &chunk(b"IHDR", &ihdr), &chunk(b"IDAT", b"never inflated"), &chunk(b"IEND", b"")].concat()
}

/// `events` encoded in the current format under `header`.
fn encode_recording(header: &str, events: &[Event]) -> Vec<u8> {
    let mut bytes = format::encode_preamble(header);
    for e in events {
        bytes.extend(format::encode_event(e));
    }
    bytes.extend(format::encode_end(events.len() as u64));
    bytes
}

/// Starts the command in argv[2:] from a fresh fork of this small process, waits for it, writes
/// its peak resident memory (KiB) to argv[1] and exits with its code. A child's `ru_maxrss`
/// starts from the resident size of the process it was forked from (Linux carries the old
/// memory's high-water mark across `execve`), so `rig` spawned straight from the test binary,
/// which holds the memory of every test running beside it, would report that instead of its own.
const MEASURE_PY: &str = "import os, sys
pid = os.fork()
if pid == 0:
    os.execv(sys.argv[2], sys.argv[2:])
_, status, usage = os.wait4(pid, 0)
with open(sys.argv[1], 'w') as f:
    f.write(str(usage.ru_maxrss))
sys.exit(os.waitstatus_to_exitcode(status) if os.WIFEXITED(status) else 128)
";

/// Runs `rig` with `args` and its output into files in `dir`: its exit code, its output, and
/// its peak resident memory in bytes (the kernel's count for that process alone, taken by
/// [`MEASURE_PY`]).
fn run_measured(dir: &Path, args: &[&std::ffi::OsStr]) -> (Option<i32>, String, u64) {
    let (out, err, peak) = (dir.join("measured.out"), dir.join("measured.err"), dir.join("measured.peak"));
    let rig = rig();
    let mut measured = Command::new("python3");
    measured.arg("-c").arg(MEASURE_PY).arg(&peak).arg(rig.get_program()).args(args);
    if let Some(cwd) = rig.get_current_dir() {
        measured.current_dir(cwd);
    }
    for (key, value) in rig.get_envs() {
        match value {
            Some(value) => measured.env(key, value),
            None => measured.env_remove(key),
        };
    }
    let status = measured
        .stdout(std::fs::File::create(&out).expect("stdout file"))
        .stderr(std::fs::File::create(&err).expect("stderr file"))
        .status()
        .expect("starting python3 and rig");
    let text = format!("{}{}", std::fs::read_to_string(out).expect("stdout"), std::fs::read_to_string(err).expect("stderr"));
    let peak_kib: u64 = std::fs::read_to_string(&peak).expect("the peak").trim().parse().expect("a number of KiB");
    (status.code(), text, peak_kib * 1024)
}

/// A recording written by the previous format version (5: raw frames, no encoding byte) still
/// replays, to the dataset its run wrote: `poses.csv` byte for byte, images pixel for pixel.
#[test]
fn a_recording_of_format_version_5_replays_to_the_dataset_it_recorded() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let fixture = fixture_v5();
    let o = rig().arg("replay").arg(fixture.join("v5.rec")).arg("--info").output().expect("running rig replay --info");
    assert!(o.status.success() && text(&o).contains("format version 5, 187 events"), "{}", text(&o));
    let out = tmp.path().join("replayed");
    let o = replay(&fixture.join("v5.rec"), &out);
    assert!(o.status.success(), "rig replay failed:\n{}", text(&o));
    let (recorded, replayed) = (fixture.join("recorded-tactip"), out.join("sphere/tactip"));
    let csv = |d: &Path| std::fs::read_to_string(d.join("poses.csv")).expect("poses.csv");
    assert_eq!(csv(&recorded), csv(&replayed));
    for rel in ["reference.png", "images/3141.png", "images/7779.png"] {
        assert_same_pixels(&recorded.join(rel), &replayed.join(rel));
    }
}

/// (Issue 44, break 3.) A frame of another size than the camera the header names is refused
/// with exit 2, naming the record's offset and both sizes, before anything is allocated for it
/// or written: a 1 x 1 frame in the 32 x 24 recording of format 5 (whose frames are raw, so
/// rig before this check read the file too, and replayed it with exit 0); in the current
/// format, a PNG frame that says 4000 x 4000 and one that says 20000 x 20000 (400 Mpx, past the
/// bound on any frame); and, in a header without the camera's size (recordings made before rig
/// recorded it), a frame of another size than the camera's first.
#[test]
fn a_frame_of_another_size_than_the_cameras_is_refused_before_anything_is_written() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let original = std::fs::read(fixture_v5().join("v5.rec")).expect("the fixture");
    let frames: Vec<(usize, u8, usize)> = record_spans(&original).into_iter().filter(|(_, kind, _)| *kind == 2).collect();
    assert_eq!(frames.len(), 3, "the reference and two poses");
    let refused = |name: &str, bytes: &[u8], message: &str| {
        let file = tmp.path().join(name);
        std::fs::write(&file, bytes).expect("writing");
        let out = tmp.path().join(format!("{name}-out"));
        for info in [false, true] {
            let mut c = rig();
            c.arg("replay").arg(&file).arg("--out").arg(&out).args(["--stall-s", "20"]);
            if info {
                c.arg("--info");
            }
            let o = c.output().expect("running rig replay");
            assert_eq!(o.status.code(), Some(2), "{name} (--info {info}): {}", text(&o));
            assert!(text(&o).contains(message), "{name} (--info {info}): {message:?} not in\n{}", text(&o));
            assert!(!out.exists(), "{name}: nothing is written");
        }
    };

    // Format 5: the second pose's frame (record 2 of 3) cut down to one pixel.
    let (at, _, len) = frames[2];
    let body = &original[at + 5..at + 5 + len];
    // camera, t_s, t_capture_s, seq (25 bytes), then width, height and the pixels.
    let one_pixel = [&body[..25], &1u32.to_le_bytes(), &1u32.to_le_bytes(), &[7, 8, 9]].concat();
    let v5 = [&original[..at], &record_bytes(2, &one_pixel)[..], &original[at + 5 + len + 4..]].concat();
    let record = record_spans(&original).iter().position(|s| s.0 == at).expect("the record");
    refused(
        "one-pixel.rec",
        &v5,
        &format!("record {record} at byte {at} is a 1x1 frame of camera tactip, but the header's camera is 32x24"),
    );

    // The current format, PNG frames whose IHDR says what the record says (never inflated).
    let raw = format::decode(&original).expect("the fixture decodes");
    let last_frame = raw.events.iter().rposition(|e| matches!(e, Event::Frame(_))).expect("a frame");
    let with_frame = |header: &str, width: u32, height: u32| {
        let mut events = raw.events.clone();
        let Event::Frame(f) = &mut events[last_frame] else { unreachable!("a frame") };
        (f.width, f.height, f.pixels) = (width, height, format::FramePixels::Png(png_claiming(width, height)));
        let bytes = encode_recording(header, &events);
        let at = record_spans(&bytes)[last_frame].0;
        (bytes, at)
    };
    let (bytes, at) = with_frame(&raw.header_json, 4000, 4000);
    refused(
        "4000.rec",
        &bytes,
        &format!("record {last_frame} at byte {at} is a 4000x4000 frame of camera tactip, but the header's camera is 32x24"),
    );
    let (bytes, at) = with_frame(&raw.header_json, 20000, 20000);
    refused(
        "20000.rec",
        &bytes,
        &format!("record {last_frame} at byte {at}: a frame of 20000x20000 pixels is more than the 16777216 rig reads"),
    );

    // A header without the camera's size: the camera's first frame sets it.
    let mut header: serde_json::Value = serde_json::from_str(&raw.header_json).expect("json header");
    header["sensors"][0].as_object_mut().expect("a sensor").remove("capture");
    let (bytes, at) = with_frame(&header.to_string(), 1, 1);
    refused(
        "no-capture.rec",
        &bytes,
        &format!("record {last_frame} at byte {at} is a 1x1 frame of camera tactip, but its first frame was 32x24"),
    );
}

/// Issue 43: a recording is read one record at a time. The format-5 fixture with 3,000,960
/// one-byte feedback reads appended after its last event (2,084 copies of its last feedback
/// frame; a 60 MB file), written record by record: `--info` counts them and `rig replay`
/// replays the run to the same dataset (the reads after the job are the feedback a client
/// leaves unread) each in under 100 MB of resident memory. Holding the events, as rig did
/// before, takes about 6 bytes of memory per byte of such a file: 345 MB here.
#[test]
fn three_million_records_are_counted_and_replayed_in_bounded_memory() {
    use std::io::Write;
    const PADDING: usize = 1440 * 2084;
    const MAX_RSS_BYTES: u64 = 100 << 20;
    let tmp = tempfile::tempdir().expect("tempdir");
    let original = std::fs::read(fixture_v5().join("v5.rec")).expect("the fixture");
    let raw = format::decode(&original).expect("the fixture decodes");
    let feedback = |e: &Event| match e {
        Event::Socket { socket: format::SocketId::Feedback, direction: format::Direction::FromController, bytes, t_s } => {
            Some((bytes.clone(), *t_s))
        }
        _ => None,
    };
    let (frame, t_s) = raw.events.iter().rev().filter_map(feedback).find(|(bytes, _)| bytes.len() == 1440).expect("a whole frame");
    let reads = raw.events.iter().filter_map(feedback).count();
    let t_last = raw.events.last().expect("events").t_s().max(t_s);

    // The fixture up to its end record, the padding, a new end record: streamed to the file.
    let end = *record_spans(&original).last().expect("records");
    assert_eq!(end.1, 0xFF, "the end record is last");
    let rec = tmp.path().join("long.rec");
    let mut file = std::io::BufWriter::new(std::fs::File::create(&rec).expect("creating"));
    file.write_all(&original[..end.0]).expect("writing");
    for i in 0..PADDING {
        let read = Event::Socket {
            socket: format::SocketId::Feedback,
            direction: format::Direction::FromController,
            t_s: t_last,
            bytes: vec![frame[i % 1440]],
        };
        file.write_all(&format::encode_event(&read)).expect("writing");
    }
    file.write_all(&format::encode_end((raw.events.len() + PADDING) as u64)).expect("writing");
    file.into_inner().expect("flushing").sync_all().expect("syncing");
    assert!(std::fs::metadata(&rec).expect("size").len() > 60_000_000);

    let (code, out, rss) = run_measured(tmp.path(), &["replay".as_ref(), rec.as_os_str(), "--info".as_ref()]);
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains(&format!("feedback socket: 0 writes, {} reads", reads + PADDING)), "{out}");
    assert!(rss < MAX_RSS_BYTES, "--info took {} MB", rss >> 20);

    let replayed = tmp.path().join("replayed");
    let (code, out, rss) = run_measured(
        tmp.path(),
        &["replay".as_ref(), rec.as_os_str(), "--out".as_ref(), replayed.as_os_str(), "--stall-s".as_ref(), "20".as_ref()],
    );
    assert_eq!(code, Some(0), "{out}");
    assert!(rss < MAX_RSS_BYTES, "the replay took {} MB", rss >> 20);
    let csv = |d: &Path| std::fs::read_to_string(d.join("poses.csv")).expect("poses.csv");
    assert_eq!(csv(&fixture_v5().join("recorded-tactip")), csv(&replayed.join("sphere/tactip")));
}

/// A frame whose PNG passes every check made without inflating it (its size, its chunks, the
/// record's checksum) but does not inflate: the replay stops at it with exit 2, naming it, and
/// the dataset holds the pose before it.
#[test]
fn a_frame_whose_png_does_not_inflate_stops_the_replay_with_exit_2() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let raw = format::decode(&std::fs::read(fixture_v5().join("v5.rec")).expect("the fixture")).expect("the fixture decodes");
    let mut events = raw.events.clone();
    let last_frame = events.iter().rposition(|e| matches!(e, Event::Frame(_))).expect("a frame");
    let Event::Frame(f) = &mut events[last_frame] else { unreachable!("a frame") };
    f.pixels = format::FramePixels::Png(png_claiming(32, 24));
    let bytes = encode_recording(&raw.header_json, &events);
    let at = record_spans(&bytes)[last_frame].0;
    let rec = tmp.path().join("bad-png.rec");
    std::fs::write(&rec, bytes).expect("writing");
    let o = rig().arg("replay").arg(&rec).arg("--info").output().expect("running rig replay --info");
    assert!(o.status.success(), "--info inflates nothing: {}", text(&o));
    let out = tmp.path().join("out");
    let o = replay(&rec, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains(&format!("record {last_frame} at byte {at}: frame ")) && text(&o).contains("does not decode"),
        "{}",
        text(&o)
    );
    let rows = std::fs::read_to_string(out.join("sphere/tactip/poses.csv")).expect("poses.csv");
    assert_eq!(rows.lines().count(), 2, "the header and the first pose: {rows}");
}
