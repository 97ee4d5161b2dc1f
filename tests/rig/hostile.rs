//! Hostile input: each reproduction of the trust-boundaries issue, run against the real `rig`
//! binary and a real `rig daemon` (loopback only), asserting the refusal (exit code or HTTP
//! status, and message) and that nothing outside the test's temp folders was read or written.
//!
//! Every test works in its own temp folder. "A file outside the roots" is a sentinel file in
//! that folder (`outside/secret.txt`, holding [`SECRET`]): no message may contain its text,
//! and no copy of it may appear anywhere. System files are never touched.
//!
//! Items (numbered as in the issue): 1 ONNX Runtime search and the daemon's fixed library;
//! 2 CSRF and Host; 4 grid, model-size and image-size bombs; 5 symlinks inside a dataset;
//! 6 a manifest `sensor` that is a path; 7 errors that would echo files; 8 verify decodes
//! images; 9 HTTP limits and timeouts; 10 exit codes; 11 ill-posed numbers; 12 the daemon's
//! worker survives bad jobs. (Item 3, job paths against `--root`, lands with the job requests;
//! [`rig::roots`] is unit-tested.)

use crate::{copy_package, tiny_package};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use rig::daemon::client::{HttpResponse, parse_response};
use rig::dataset::{DatasetWriter, Manifest, ObjectInfo, PoseRow};
use rig::plan::PlanSpec;
use rig::sensor::SensorKind;

/// The breaks of the third hostile pass (issue 44).
mod breaks;

/// The sentinel's contents: must never appear in any output.
const SECRET: &str = "SENTINEL-hunter2-do-not-echo";

/// The `rig` binary these tests run: this build's, or the one `RIG_BIN_UNDER_TEST` names (to
/// check that a test fails on an older build, as each test of a fixed break must).
fn rig(cwd: &Path) -> Command {
    let bin = std::env::var_os("RIG_BIN_UNDER_TEST").unwrap_or_else(|| env!("CARGO_BIN_EXE_rig").into());
    let mut c = Command::new(bin);
    c.current_dir(cwd);
    for var in ["RIG_CONFIG", "RIG_ORT_LIB", "ORT_DYLIB_PATH", "RIG_DAEMON_TOKEN", "RIG_DEBUG_PANIC_JOB_KIND"] {
        c.env_remove(var);
    }
    c.env("RIG_LOG", "error");
    c
}

fn run(cwd: &Path, args: &[&str]) -> Output {
    rig(cwd).args(args).output().expect("running rig")
}

fn text(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

/// Asserts the exit code, a phrase of the output, and that the sentinel never shows.
fn expect(out: &Output, code: i32, phrase: &str) -> String {
    let all = text(out);
    assert_eq!(out.status.code(), Some(code), "expected exit {code}:\n{all}");
    assert!(all.contains(phrase), "expected {phrase:?} in:\n{all}");
    assert!(!all.contains(SECRET), "the sentinel's contents leaked:\n{all}");
    all
}

/// A temp folder with `outside/secret.txt` (the sentinel) and `work/` (where rig runs).
struct Sandbox {
    _tmp: tempfile::TempDir,
    top: PathBuf,
}

impl Sandbox {
    fn new() -> Self {
        let tmp = tempfile::tempdir().expect("temp dir");
        let top = tmp.path().canonicalize().expect("canonical");
        std::fs::create_dir_all(top.join("outside")).expect("mkdir");
        std::fs::create_dir_all(top.join("work")).expect("mkdir");
        std::fs::write(top.join("outside/secret.txt"), format!("{SECRET}\nsecond line\n")).expect("sentinel");
        Self { _tmp: tmp, top }
    }
    fn work(&self) -> PathBuf {
        self.top.join("work")
    }
    fn secret(&self) -> PathBuf {
        self.top.join("outside/secret.txt")
    }
    /// No file anywhere in the sandbox but the sentinel itself holds its text.
    fn assert_no_copy_of_the_secret(&self) {
        self.assert_no_copy_of_the_secret_but(&[]);
    }

    /// [`assert_no_copy_of_the_secret`](Self::assert_no_copy_of_the_secret), but for the
    /// fixtures the test itself wrote with the sentinel's text.
    fn assert_no_copy_of_the_secret_but(&self, fixtures: &[PathBuf]) {
        let mut stack = vec![self.top.clone()];
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir).expect("list") {
                let path = entry.expect("entry").path();
                let meta = std::fs::symlink_metadata(&path).expect("lstat");
                if meta.is_dir() {
                    stack.push(path);
                } else if meta.is_file() && path != self.secret() && !fixtures.contains(&path) {
                    let bytes = std::fs::read(&path).expect("read");
                    assert!(
                        !bytes.windows(SECRET.len()).any(|w| w == SECRET.as_bytes()),
                        "{} holds a copy of the sentinel",
                        path.display()
                    );
                }
            }
        }
        assert_eq!(std::fs::read_to_string(self.secret()).expect("sentinel"), format!("{SECRET}\nsecond line\n"), "sentinel changed");
    }
}

fn image(v: u8) -> image::RgbImage {
    image::RgbImage::from_fn(8, 8, |x, y| image::Rgb([v, x as u8, y as u8]))
}

/// A small real dataset at `dir`: the default plan, sphere, TacTip, poses 0..n with 8x8 images
/// and a reference frame.
fn dataset(dir: &Path, n: u32) {
    let manifest = Manifest::new(SensorKind::TacTip, ObjectInfo::named("sphere"), Some(PlanSpec::default()));
    let mut w = DatasetWriter::create(dir, manifest).expect("create");
    w.write_reference(&image(0)).expect("reference");
    for id in 0..n {
        let pose = PlanSpec::default().pose_of(id).expect("on grid");
        w.append(PoseRow::synthetic(id, pose, "m", 1, 2, 1.0), &image(id as u8 + 1)).expect("append");
    }
    w.finish().expect("finish");
}

// ---------------------------------------------------------------------------------------
// The daemon, as a process.

/// `rig daemon` on 127.0.0.1 and an OS-chosen port; killed when dropped.
struct DaemonProcess {
    child: Child,
    addr: SocketAddr,
    /// Every line it printed on stdout so far.
    output: std::sync::Arc<std::sync::Mutex<Vec<String>>>,
}

impl DaemonProcess {
    fn start(cwd: &Path, extra: &[&str], env: &[(&str, &str)]) -> Self {
        let mut cmd = rig(cwd);
        cmd.args(["daemon", "--listen", "127.0.0.1:0", "--idle-refresh-ms", "0", "--sensor", "tactip"]).args(extra);
        for (k, v) in env {
            cmd.env(k, v);
        }
        let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::null()).spawn().expect("spawning rig daemon");
        let stdout = child.stdout.take().expect("stdout");
        let (tx, rx) = std::sync::mpsc::channel();
        let output = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let lines = std::sync::Arc::clone(&output);
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if let Some(rest) = line.strip_prefix("rig daemon listening on http://") {
                    let _ = tx.send(rest.split_whitespace().next().unwrap_or_default().to_string());
                }
                lines.lock().expect("output lines").push(line);
            }
        });
        let addr = rx.recv_timeout(Duration::from_secs(120)).expect("the daemon did not say where it listens");
        Self { child, addr: addr.parse().expect("listen address"), output }
    }

    /// One request on a fresh connection; `head` without the Host line (added unless `host` is
    /// given in it).
    fn send(&self, request: &str) -> HttpResponse {
        let mut stream = TcpStream::connect(self.addr).expect("connect");
        stream.set_read_timeout(Some(Duration::from_secs(30))).expect("timeout");
        stream.write_all(request.as_bytes()).expect("write");
        let mut raw = Vec::new();
        let _ = stream.read_to_end(&mut raw);
        parse_response(&raw).unwrap_or_else(|e| panic!("malformed response ({e}): {:?}", String::from_utf8_lossy(&raw)))
    }

    /// A request with the daemon's own Host, `headers` (each ending in CRLF) and `body`.
    fn request(&self, method: &str, path: &str, headers: &str, body: &str) -> HttpResponse {
        self.send(&format!(
            "{method} {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n{headers}Content-Length: {}\r\n\r\n{body}",
            self.addr,
            body.len()
        ))
    }

    fn get_json(&self, path: &str) -> serde_json::Value {
        let r = self.request("GET", path, "", "");
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        serde_json::from_slice(&r.body).expect("json")
    }

    /// Queues a job the way rig's client does; returns its id.
    fn submit(&self, job: &serde_json::Value) -> u64 {
        let r = self.request("POST", "/api/jobs", "Content-Type: application/json\r\nX-Rig-Client: test\r\n", &job.to_string());
        assert_eq!(r.status, 201, "{}", String::from_utf8_lossy(&r.body));
        serde_json::from_slice::<serde_json::Value>(&r.body).expect("json")["id"].as_u64().expect("id")
    }

    /// Polls a job until it is final.
    fn wait_final(&self, id: u64) -> serde_json::Value {
        let t0 = Instant::now();
        loop {
            let job = self.get_json(&format!("/api/jobs/{id}"));
            if matches!(job["state"].as_str(), Some("done" | "failed" | "cancelled")) {
                return job;
            }
            assert!(t0.elapsed() < Duration::from_secs(300), "job {id} never ended: {job}");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    fn job_count(&self) -> usize {
        self.get_json("/api/jobs").as_array().expect("list").len()
    }

    /// Polls a job until it is running.
    fn wait_running(&self, id: u64) {
        let t0 = Instant::now();
        while self.get_json(&format!("/api/jobs/{id}"))["state"] != "running" {
            assert!(t0.elapsed() < Duration::from_secs(120), "job {id} never started");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Sends SIGTERM and waits for the process to end; returns how long it took, its exit
    /// status and what it printed.
    fn terminate(&mut self, within: Duration) -> (Duration, std::process::ExitStatus, String) {
        let pid = i32::try_from(self.child.id()).expect("pid");
        let t0 = Instant::now();
        // SAFETY: kill(2) on our own child's pid, with a valid signal number.
        assert_eq!(unsafe { libc::kill(pid, libc::SIGTERM) }, 0, "sending SIGTERM");
        loop {
            if let Some(status) = self.child.try_wait().expect("polling the daemon") {
                let elapsed = t0.elapsed();
                // The reader thread sees the last lines once the pipe closes.
                std::thread::sleep(Duration::from_millis(100));
                return (elapsed, status, self.output.lock().expect("output lines").join("\n"));
            }
            let out = self.output.lock().expect("output lines").join("\n");
            assert!(t0.elapsed() < within, "the daemon still runs {:?} after SIGTERM; it printed:\n{out}", t0.elapsed());
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for DaemonProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn error_of(r: &HttpResponse) -> String {
    assert_eq!(r.header("content-type"), Some("application/json"), "status {} body {:?}", r.status, String::from_utf8_lossy(&r.body));
    let v: serde_json::Value = serde_json::from_slice(&r.body).expect("a JSON error body");
    v["error"].as_str().expect("an error message").to_string()
}

// ---------------------------------------------------------------------------------------

/// (Item 1.) A library planted in the current folder's `.rig/onnxruntime/` is never loaded; the
/// library that is loaded is named.
#[test]
fn onnx_runtime_is_not_taken_from_the_current_folder() {
    let sb = Sandbox::new();
    let planted = sb.work().join(".rig/onnxruntime");
    std::fs::create_dir_all(&planted).expect("mkdir");
    // Not a library: if rig tried to load it, the error would name it.
    std::fs::write(planted.join("libonnxruntime.so"), b"planted, would run in rig if loaded").expect("plant");
    let model = tiny_package();
    let out = run(&sb.work(), &["synth", "info", "--model", model.to_str().expect("utf-8")]);
    let all = expect(&out, 0, "runtime");
    assert!(!all.contains(&planted.display().to_string()), "the planted library was looked at:\n{all}");
    assert!(all.contains("from the checkout's .rig/onnxruntime/"), "which library, and why, is said:\n{all}");
}

/// (Item 1.) A daemon job cannot name the library to load.
#[test]
fn a_daemon_job_cannot_choose_the_onnx_runtime_library() {
    let sb = Sandbox::new();
    let daemon = DaemonProcess::start(&sb.work(), &[], &[]);
    let job = serde_json::json!({"kind": "synth", "dataset": sb.work(), "ort_lib": sb.top.join("outside/libevil.so")});
    let r = daemon.request("POST", "/api/jobs", "Content-Type: application/json\r\nX-Rig-Client: t\r\n", &job.to_string());
    assert_eq!(r.status, 400);
    assert!(error_of(&r).contains("unknown field `ort_lib`"), "{}", error_of(&r));
    assert_eq!(daemon.job_count(), 0);
}

/// (Item 2.) Requests a browser page on another site can make are refused, and nothing is queued.
#[test]
fn cross_site_requests_and_foreign_hosts_are_refused() {
    let sb = Sandbox::new();
    let daemon = DaemonProcess::start(&sb.work(), &[], &[]);
    let job = serde_json::json!({"kind": "collect", "object": "edge", "sensor": "tactip", "poses": 1, "out": sb.work()}).to_string();
    let json = "Content-Type: application/json\r\n";
    let cases: Vec<(&str, String, u16, &str)> = vec![
        ("a POST with no Content-Type (a no-cors fetch of a Blob)", String::new(), 403, "X-Rig-Client"),
        ("a text/plain POST (a form or a no-cors fetch)", "Content-Type: text/plain\r\n".into(), 403, "X-Rig-Client"),
        ("JSON without the client header", json.into(), 403, "X-Rig-Client"),
        ("the client header but text/plain", "Content-Type: text/plain\r\nX-Rig-Client: x\r\n".into(), 415, "application/json"),
        ("the client header and no Content-Type", "X-Rig-Client: x\r\n".into(), 415, "application/json"),
        ("a foreign Origin", format!("{json}X-Rig-Client: x\r\nOrigin: http://attacker.example\r\n"), 403, "Origin"),
    ];
    for (what, headers, status, phrase) in &cases {
        let r = daemon.request("POST", "/api/jobs", headers, &job);
        assert_eq!(r.status, *status, "{what}: {}", String::from_utf8_lossy(&r.body));
        assert!(error_of(&r).contains(phrase), "{what}: {}", error_of(&r));
    }
    // DNS rebinding: the attacker's name in Host, everything else right.
    let rebound = daemon.send(&format!(
        "POST /api/jobs HTTP/1.1\r\nHost: attacker.example:{}\r\nConnection: close\r\n{json}X-Rig-Client: x\r\nContent-Length: {}\r\n\r\n{job}",
        daemon.addr.port(),
        job.len()
    ));
    assert_eq!(rebound.status, 403);
    assert!(error_of(&rebound).contains("Host"), "{}", error_of(&rebound));
    let read = daemon.send("GET /api/status HTTP/1.1\r\nHost: attacker.example\r\nConnection: close\r\n\r\n");
    assert_eq!(read.status, 403, "a rebound page cannot read the status either");
    // A CORS preflight gets no Access-Control-Allow-* headers: the browser sends nothing more.
    let preflight =
        daemon.request("OPTIONS", "/api/jobs", "Origin: http://attacker.example\r\nAccess-Control-Request-Method: POST\r\n", "");
    assert_eq!(preflight.status, 405);
    assert!(preflight.headers.iter().all(|(n, _)| !n.starts_with("access-control-")), "{:?}", preflight.headers);
    error_of(&preflight);
    // Cancel is state-changing too.
    let r = daemon.request("POST", "/api/jobs/1/cancel", "", "");
    assert_eq!(r.status, 403);
    assert_eq!(daemon.job_count(), 0, "nothing was queued");

    // The control: the same job with both headers is accepted.
    let ok = daemon.request("POST", "/api/jobs", &format!("{json}X-Rig-Client: x\r\n"), &job);
    assert_eq!(ok.status, 201, "{}", String::from_utf8_lossy(&ok.body));
    let ok = daemon.request("POST", "/api/jobs/1/cancel", "X-Rig-Client: x\r\n", "");
    assert!(ok.status == 200 || ok.status == 409, "{}", String::from_utf8_lossy(&ok.body));
}

/// (Items 4 and 11.) Inputs that used to allocate until the OOM killer or abort are refused at once.
#[test]
fn grid_model_and_image_size_bombs_are_refused_before_allocating() {
    let sb = Sandbox::new();
    let ds = sb.work().join("ds");
    dataset(&ds, 2);
    let manifest = std::fs::read_to_string(ds.join("manifest.toml")).expect("manifest");
    let bomb = manifest.replacen("step = 1.0", "step = 1e-12", 1);
    assert_ne!(bomb, manifest, "the fixture has a step to shrink");
    std::fs::write(ds.join("manifest.toml"), bomb).expect("write");
    let t0 = Instant::now();
    for extra in [&["--dry-run"][..], &["--steps", "1"][..]] {
        let mut args = vec!["synth", "--fill-missing", "--dataset", "ds"];
        args.extend_from_slice(extra);
        expect(&run(&sb.work(), &args), 2, "grid");
    }
    assert!(t0.elapsed() < Duration::from_secs(60), "refused only after {:?}", t0.elapsed());

    let pkg = copy_package(&sb.work().join("pkg"));
    std::fs::write(pkg.join("model.toml"), "name = \"huge\"\nresolution = [100000, 100000]\n").expect("write");
    expect(&run(&sb.work(), &["synth", "info", "--model", "pkg"]), 2, "resolution");

    let control = sb.work().join("control.png");
    image(3).save(&control).expect("png");
    let tiny = tiny_package();
    let one = |size: &str| {
        let model = tiny.to_str().expect("utf-8");
        run(
            &sb.work(),
            &[
                "synth",
                "one",
                "--model",
                model,
                "--control",
                "control.png",
                "--prompt",
                "p",
                "--steps",
                "1",
                "--size",
                size,
                "--out",
                "o.png",
            ],
        )
    };
    expect(&one("100000x100000"), 2, "1 to 2048");
    // 72 is a multiple of 8 but the tiny UNet downsamples once: sizes must divide by 16.
    expect(&one("72x72"), 2, "multiples of 16");
    assert!(!sb.work().join("o.png").exists());
}

/// (Item 11.) Numbers that mean nothing are refused with ranges that mean something; dpm++2m's step
/// limit is the one it states.
#[test]
fn ill_posed_numbers_are_refused_with_true_ranges() {
    let sb = Sandbox::new();
    dataset(&sb.work().join("ds"), 2);
    for (flag, value, phrase) in [("--guidance", "1e30", "from 1 to 30"), ("--eta", "1e30", "from 0 to 1"), ("--eta", "NaN", "from 0 to 1")]
    {
        let out = run(&sb.work(), &["synth", "--fill-missing", "--dataset", "ds", "--steps", "1", flag, value]);
        expect(&out, 2, phrase);
    }
    let control = sb.work().join("control.png");
    image(3).save(&control).expect("png");
    let tiny = tiny_package();
    let out = run(
        &sb.work(),
        &[
            "synth",
            "one",
            "--model",
            tiny.to_str().expect("utf-8"),
            "--control",
            "control.png",
            "--prompt",
            "p",
            "--steps",
            "1000",
            "--scheduler",
            "dpm++2m",
            "--out",
            "o.png",
        ],
    );
    let all = expect(&out, 2, "1..=999");
    assert!(!all.contains("1..=1000"), "{all}");
}

/// (Item 5.) Symlinks inside a dataset are refused by verify, export, merge and the writers.
#[test]
fn symlinks_inside_a_dataset_are_never_followed() {
    use std::os::unix::fs::symlink;
    let sb = Sandbox::new();
    let w = sb.work();
    dataset(&w.join("ds"), 3);
    std::fs::remove_file(w.join("ds/images/2.png")).expect("rm");
    symlink(sb.secret(), w.join("ds/images/2.png")).expect("symlink");

    let all = expect(&run(&w, &["dataset", "verify", "ds"]), 1, "symlink");
    assert!(all.contains("NOT clean"), "{all}");
    expect(&run(&w, &["dataset", "export", "ds", "--format", "mds", "--out", "x.csv", "--images-out", "exported"]), 2, "symlink");
    expect(&run(&w, &["dataset", "merge", "--out", "merged", "ds"]), 2, "not verify clean");
    // An MDS export whose --out is a symlink replaces the link with the file, whole.
    dataset(&w.join("ds4"), 2);
    let secret_text = std::fs::read(sb.secret()).expect("secret");
    symlink(sb.secret(), w.join("x4.csv")).expect("symlink");
    expect(&run(&w, &["dataset", "export", "ds4", "--format", "mds", "--out", "x4.csv"]), 0, "wrote 2 rows");
    assert!(!std::fs::symlink_metadata(w.join("x4.csv")).expect("lstat").file_type().is_symlink(), "the link is replaced");
    assert_eq!(std::fs::read(sb.secret()).expect("secret"), secret_text, "nothing was written through the symlink");
    // A symlinked poses.csv or images/ makes the writers refuse, not write through.
    dataset(&w.join("ds2"), 2);
    std::fs::rename(w.join("ds2/poses.csv"), w.join("poses-moved.csv")).expect("mv");
    symlink(sb.secret(), w.join("ds2/poses.csv")).expect("symlink");
    expect(&run(&w, &["synth", "--fill-missing", "--dry-run", "--dataset", "ds2"]), 2, "symlink");
    expect(&run(&w, &["synth", "--fill-missing", "--steps", "1", "--limit", "1", "--dataset", "ds2"]), 2, "symlink");
    let out_dir = sb.top.join("outside/images");
    std::fs::create_dir(&out_dir).expect("mkdir");
    dataset(&w.join("ds3"), 1);
    std::fs::remove_dir_all(w.join("ds3/images")).expect("rm");
    symlink(&out_dir, w.join("ds3/images")).expect("symlink");
    expect(&run(&w, &["synth", "--fill-missing", "--steps", "1", "--limit", "1", "--dataset", "ds3"]), 2, "symlink");
    assert_eq!(std::fs::read_dir(&out_dir).expect("list").count(), 0, "something was written through the symlink");
    sb.assert_no_copy_of_the_secret();
}

/// (Item 6.) A manifest whose `sensor` is a path is refused before any file name is built from it.
#[test]
fn a_manifest_sensor_that_is_a_path_is_refused() {
    let sb = Sandbox::new();
    let w = sb.work();
    dataset(&w.join("ds"), 1);
    let manifest = std::fs::read_to_string(w.join("ds/manifest.toml")).expect("manifest");
    let evil = manifest.replace("sensor = \"tactip\"", "sensor = \"a/../../../outside/X\"");
    assert_ne!(evil, manifest);
    std::fs::write(w.join("ds/manifest.toml"), evil).expect("write");
    std::fs::create_dir(w.join("exported")).expect("mkdir");
    expect(&run(&w, &["dataset", "export", "ds", "--format", "mds", "--out", "x.csv", "--images-out", "exported"]), 2, "manifest");
    assert!(!sb.top.join("outside/X").exists() && std::fs::read_dir(sb.top.join("outside")).expect("list").count() == 1);
    assert_eq!(std::fs::read_dir(w.join("exported")).expect("list").count(), 0);
}

/// (Item 7.) Files that are not what rig expects are named, never echoed.
#[test]
fn errors_never_echo_file_contents() {
    let sb = Sandbox::new();
    let w = sb.work();
    let secret = sb.secret();
    let secret = secret.to_str().expect("utf-8");
    std::fs::write(w.join("rig.toml"), format!("[sensors.tactip]\ncalibration = \"{secret}\"\n")).expect("write");
    expect(&run(&w, &["collect", "--config", "rig.toml", "--sensor", "tactip", "--poses", "1", "--out", "o"]), 2, "calibration");
    expect(&run(&w, &["collect", "--plan", secret, "--dry-run"]), 2, "not a valid plan");
    expect(&run(&w, &["collect", "--config", secret, "--dry-run"]), 2, "rig config");
    // A TOML file that parses, with the secret as a value of the wrong type.
    std::fs::write(w.join("typed.toml"), format!("[collect]\nframes_per_pose = \"{SECRET}\"\n")).expect("write");
    expect(&run(&w, &["collect", "--config", "typed.toml", "--dry-run"]), 2, "line 2");
    dataset(&w.join("ds"), 1);
    std::fs::copy(sb.secret(), w.join("ds/manifest.toml")).expect("copy");
    expect(&run(&w, &["synth", "--fill-missing", "--dry-run", "--dataset", "ds"]), 2, "manifest");
    dataset(&w.join("ds2"), 1);
    std::fs::copy(sb.secret(), w.join("ds2/poses.csv")).expect("copy");
    expect(&run(&w, &["dataset", "verify", "ds2"]), 1, "not a header");
    let pkg = copy_package(&w.join("pkg"));
    std::fs::copy(sb.secret(), pkg.join("model.toml")).expect("copy");
    expect(&run(&w, &["synth", "info", "--model", "pkg"]), 2, "model.toml");
    std::fs::write(w.join("mds.csv"), format!("image_name,data_name,obj_id,pose_id,pose_1,pose_2,pose_3,pose_4,pose_5,pose_6,move_1,move_2,move_3,move_4,move_5,move_6\nf.png,d,1,{SECRET},0,0,0,0,0,0,0,0,0,0,0,0\n")).expect("write");
    expect(&run(&w, &["dataset", "import", "mds.csv"]), 2, "pose_id");
    // An MDS image name that climbs out of --images.
    std::fs::write(w.join("climb.csv"), "image_name,data_name,obj_id,pose_id,pose_1,pose_2,pose_3,pose_4,pose_5,pose_6,move_1,move_2,move_3,move_4,move_5,move_6\n../outside/secret.txt,d,1,1,0,0,0,0,0,0,0,0,0,0,0,0\n").expect("write");
    expect(&run(&w, &["dataset", "import", "climb.csv", "--out", "imported", "--images", "."]), 2, "plain file name");
    let fixtures = ["typed.toml", "ds/manifest.toml", "ds2/poses.csv", "pkg/model.toml", "mds.csv"].map(|f| w.join(f));
    sb.assert_no_copy_of_the_secret_but(&fixtures);
}

/// (Item 8.) `verify` decodes every image and checks its size.
#[test]
fn verify_decodes_every_image() {
    let sb = Sandbox::new();
    let w = sb.work();
    dataset(&w.join("ds"), 4);
    expect(&run(&w, &["dataset", "verify", "ds"]), 0, "clean");
    std::fs::write(w.join("ds/images/0.png"), b"").expect("empty");
    std::fs::write(w.join("ds/images/1.png"), b"\x89PNG\r\n\x1a\nnot really").expect("corrupt");
    image::RgbImage::new(16, 8).save(w.join("ds/images/2.png")).expect("wrong size");
    let all = expect(&run(&w, &["dataset", "verify", "ds"]), 1, "bad images 3");
    assert!(all.contains("unreadable image") && all.contains("16x8 px"), "{all}");
    // A merge refuses it; an export of it would not be a dataset anyone can use.
    expect(&run(&w, &["dataset", "merge", "--out", "merged", "ds"]), 2, "not verify clean");
}

/// (Item 9.) HTTP: every error is JSON, a huge Content-Length is refused before its body, a slow
/// head is cut off, idle connections are closed.
#[test]
fn http_limits_and_timeouts() {
    let sb = Sandbox::new();
    let daemon = DaemonProcess::start(&sb.work(), &[], &[]);
    // A huge Content-Length: a JSON 413 at once, without sending the body.
    let t0 = Instant::now();
    let r = daemon.send(&format!(
        "POST /api/jobs HTTP/1.1\r\nHost: {}\r\nContent-Type: application/json\r\nX-Rig-Client: x\r\nContent-Length: 99999999999\r\n\r\n",
        daemon.addr
    ));
    assert_eq!(r.status, 413);
    assert!(error_of(&r).contains("bytes"), "{}", error_of(&r));
    assert!(t0.elapsed() < Duration::from_secs(5), "the 413 took {:?}", t0.elapsed());
    // Every other error status is JSON too.
    for (method, path, status) in
        [("GET", "/nope", 404), ("PUT", "/api/jobs", 405), ("GET", "/api/jobs/x", 400), ("GET", "/api/jobs/99", 404)]
    {
        let r = daemon.request(method, path, "X-Rig-Client: x\r\n", "");
        assert_eq!(r.status, status, "{method} {path}");
        error_of(&r);
    }
    let r = daemon.request("POST", "/api/jobs", "Content-Type: application/json\r\nX-Rig-Client: x\r\n", "{not json");
    assert_eq!(r.status, 400);
    error_of(&r);

    // Slowloris: half a request head, then nothing. The daemon closes the connection.
    let timeout = rig::daemon::serve::HEADER_TIMEOUT;
    let mut slow = TcpStream::connect(daemon.addr).expect("connect");
    slow.write_all(b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ").expect("write");
    let mut idle = TcpStream::connect(daemon.addr).expect("connect");
    for s in [&slow, &idle] {
        s.set_read_timeout(Some(timeout + Duration::from_secs(20))).expect("timeout");
    }
    let t0 = Instant::now();
    for (what, stream) in [("a slow head", &mut slow), ("an idle connection", &mut idle)] {
        let mut buf = Vec::new();
        match stream.read_to_end(&mut buf) {
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {
                panic!("{what}: the daemon kept the connection open past {:?}", t0.elapsed())
            }
            // Closed (or reset): what was wanted.
            _ => {}
        }
        assert!(t0.elapsed() < timeout + Duration::from_secs(15), "{what}: closed only after {:?}", t0.elapsed());
    }
    // The daemon still answers.
    assert_eq!(daemon.request("GET", "/api/status", "", "").status, 200);
}

/// (Item 10.) Exit codes agree with the table: corrupt model files and bad CSV rows are bad input
/// (2), a refused arm connection at start is a hardware fault (3).
#[test]
fn exit_codes_follow_the_table() {
    let sb = Sandbox::new();
    let w = sb.work();
    let pkg = copy_package(&w.join("corrupt-onnx"));
    std::fs::write(pkg.join("unet/model.onnx"), b"not a model").expect("write");
    expect(&run(&w, &["synth", "info", "--model", "corrupt-onnx"]), 2, "unet/model.onnx");
    let pkg = copy_package(&w.join("corrupt-tokenizer"));
    std::fs::write(pkg.join("tokenizer/tokenizer.json"), b"{\"model\": 5}").expect("write");
    expect(&run(&w, &["synth", "info", "--model", "corrupt-tokenizer"]), 2, "tokenizer");

    dataset(&w.join("ds"), 2);
    let csv = w.join("ds/poses.csv");
    let mut rows = std::fs::read_to_string(&csv).expect("csv");
    rows.push_str("5,x,0,0,0,,,,,images/5.png,real,,,,,,,\n");
    std::fs::write(&csv, rows).expect("write");
    expect(&run(&w, &["synth", "--fill-missing", "--dry-run", "--dataset", "ds"]), 2, "line 4");

    // An arm that refuses the connection: a port just closed.
    let port = std::net::TcpListener::bind("127.0.0.1:0").expect("bind").local_addr().expect("addr").port();
    std::fs::write(
        w.join("refused.toml"),
        format!(
            "[arm]\nbackend = \"mg400\"\nhost = \"127.0.0.1\"\ndashboard_port = {port}\nmotion_port = {port}\nfeedback_port = {port}\n"
        ),
    )
    .expect("write");
    expect(&run(&w, &["collect", "--config", "refused.toml", "--sensor", "tactip", "--poses", "1", "--out", "o"]), 3, "127.0.0.1");
}

/// (Issue 35, item 13.) A dataset collected with `--stl mypart.stl` names an STL that resolves
/// from anywhere: filling it from another folder uses that file. When the file is gone, the error
/// names it and the manifest (exit 2) instead of `unknown object "mypart"`; a file whose bytes
/// changed is refused by its sha256.
#[test]
fn an_stl_named_by_a_dataset_resolves_from_anywhere_or_is_named() {
    let sb = Sandbox::new();
    let w = sb.work();
    let lab = w.join("lab");
    std::fs::create_dir_all(&lab).expect("mkdir");
    let sphere = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/objects/sphere.stl")).expect("library sphere");
    std::fs::write(lab.join("mypart.stl"), &sphere).expect("write STL");
    // A three-point grid, two collected: the fill has one pose to make.
    std::fs::write(
        lab.join("plan.toml"),
        "sampling = \"random\"\nn_poses = 2\nseed = 1\norder = \"optimised\"\nx_mm = { min = 0.0, max = 2.0, step = 1.0 }\n\
         y_mm = { min = 0.0, max = 0.0, step = 1.0 }\nz_mm = { min = 0.0, max = 0.0, step = 1.0 }\n\
         yaw_deg = { min = 0.0, max = 0.0, step = 1.0 }\n",
    )
    .expect("write plan");
    expect(&run(&lab, &["collect", "--stl", "mypart.stl", "--plan", "plan.toml", "--sensor", "tactip", "--out", "ds"]), 0, "collected 2");
    let manifest = std::fs::read_to_string(lab.join("ds/mypart/tactip/manifest.toml")).expect("manifest");
    let stored = lab.join("mypart.stl").canonicalize().expect("canonical");
    assert!(manifest.contains(&format!("stl_path = \"{}\"", stored.display())), "not stored absolute:\n{manifest}");

    let tiny = tiny_package();
    let fill = || {
        run(&w, &["synth", "--fill-missing", "--dataset", "lab/ds/mypart/tactip", "--model", tiny.to_str().expect("utf-8"), "--steps", "1"])
    };
    std::fs::rename(lab.join("mypart.stl"), w.join("moved.stl")).expect("move the STL away");
    // Outside the dataset and the working folder, a missing STL and another file read alike
    // (nothing is learned about files outside), but the message names the file and the manifest.
    let all = expect(&fill(), 2, "or it is not there");
    assert!(
        all.contains(&format!("STL {} named by lab/ds/mypart/tactip/manifest.toml is not a path below", stored.display())),
        "the missing file and the manifest are not named:\n{all}"
    );
    assert!(!all.contains("unknown object"), "{all}");
    // Another file at that path is not the STL the dataset was made with.
    std::fs::write(
        lab.join("mypart.stl"),
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/objects/edge.stl")).expect("edge"),
    )
    .expect("write");
    let changed = expect(&fill(), 2, "this is not that file");
    assert_eq!(changed, all, "a changed STL outside reads as a missing one");
    std::fs::rename(w.join("moved.stl"), lab.join("mypart.stl")).expect("move the STL back");
    expect(&fill(), 0, "synthesised 1 poses");
    expect(&run(&w, &["dataset", "verify", "lab/ds/mypart/tactip"]), 0, "rows 3");
}

/// (Issue 35, item 14.) A daemon job whose path lies outside the daemon's data roots is bad
/// input for the command that sent it (exit 2), and the message says how to allow the folder.
#[test]
fn a_daemon_job_outside_the_roots_exits_2_and_names_root() {
    let sb = Sandbox::new();
    let w = sb.work();
    let daemon = DaemonProcess::start(&w, &[], &[]);
    let url = format!("http://{}", daemon.addr);
    let outside = sb.secret().parent().expect("outside folder").join("tour");
    let out = run(
        &w,
        &["collect", "--daemon", &url, "--object", "edge", "--sensor", "tactip", "--poses", "1", "--out", outside.to_str().expect("utf-8")],
    );
    let all = expect(&out, 2, "outside the data roots");
    assert!(all.contains("--root"), "{all}");
    assert!(!outside.exists(), "a refused job wrote outside the roots");
    assert_eq!(daemon.job_count(), 0, "a refused job was queued");
}

/// (Item 12.) Two runs racing into one empty folder: the loser says the dataset is held.
#[test]
fn two_collections_racing_into_one_folder() {
    let sb = Sandbox::new();
    let w = sb.work();
    let start = || {
        rig(&w)
            .args(["collect", "--object", "sphere", "--sensor", "tactip", "--poses", "20", "--out", "race", "--resume"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn")
    };
    let (a, b) = (start(), start());
    let outs = [a.wait_with_output().expect("a"), b.wait_with_output().expect("b")];
    let failed: Vec<&Output> = outs.iter().filter(|o| !o.status.success()).collect();
    for out in &failed {
        let all = text(out);
        assert!(all.contains("held by another process"), "{all}");
        assert!(!all.contains("No such file or directory"), "{all}");
        assert_eq!(out.status.code(), Some(1), "{all}");
    }
    assert!(failed.len() < 2, "one of them must win");
    // Whatever the interleaving, the dataset is whole.
    expect(&run(&w, &["dataset", "verify", "race/sphere/tactip"]), 0, "clean");
}

/// (Items 4 and 12.) Bad jobs fail alone: ten in a row, each followed by a good job that runs, with the
/// daemon answering throughout. The bad jobs are inputs that used to abort the daemon (a model
/// package with a 100000 x 100000 resolution, a dataset whose plan has a 1e-12 mm step) and a
/// genuine panic inside a job (`RIG_DEBUG_PANIC_JOB_KIND=calibrate`, a hook only debug builds
/// have: no real input is known to panic).
#[test]
fn the_daemon_survives_ten_bad_jobs_in_a_row() {
    let sb = Sandbox::new();
    let w = sb.work();
    let pkg = copy_package(&w.join("huge"));
    std::fs::write(pkg.join("model.toml"), "name = \"huge\"\nresolution = [100000, 100000]\n").expect("write");
    dataset(&w.join("ds/sphere/tactip"), 2);
    dataset(&w.join("bomb"), 1);
    let manifest = std::fs::read_to_string(w.join("bomb/manifest.toml")).expect("manifest");
    std::fs::write(w.join("bomb/manifest.toml"), manifest.replacen("step = 1.0", "step = 1e-12", 1)).expect("write");

    let daemon = DaemonProcess::start(&w, &[], &[("RIG_DEBUG_PANIC_JOB_KIND", "calibrate")]);
    for round in 0..10 {
        let (bad, expect_code, phrase) = match round % 3 {
            0 => (serde_json::json!({"kind": "calibrate", "sensor": "tactip", "out": w.join("cal.toml")}), 1, "panic"),
            1 => (serde_json::json!({"kind": "synth", "dataset": w.join("ds/sphere/tactip"), "model": pkg, "steps": 1}), 2, "resolution"),
            _ => (serde_json::json!({"kind": "synth", "dataset": w.join("bomb"), "steps": 1}), 2, "grid"),
        };
        let id = daemon.submit(&bad);
        let job = daemon.wait_final(id);
        assert_eq!(job["state"], "failed", "round {round}: {job}");
        assert_eq!(job["exit_code"], expect_code, "round {round}: {job}");
        assert!(job["error"].as_str().is_some_and(|e| e.contains(phrase)), "round {round}: {job}");
        assert_eq!(daemon.request("GET", "/api/status", "", "").status, 200, "round {round}: the daemon stopped answering");

        let good = serde_json::json!({"kind": "collect", "object": "sphere", "sensor": "tactip", "poses": 1, "seed": round, "out": w.join(format!("good{round}"))});
        let id = daemon.submit(&good);
        let job = daemon.wait_final(id);
        assert_eq!(job["state"], "done", "round {round}: the good job after a bad one: {job}");
    }
    assert!(!w.join("cal.toml").exists());
}

// ---------------------------------------------------------------------------------------
// Off the walked path (the trust items of the issue of that name): every path a request,
// dataset, manifest, model package or recording names goes through `rig::confine`.

/// Waits for `child` at most `deadline` (a FIFO used to block forever); kills it past that.
fn wait_or_kill(mut child: Child, deadline: Duration) -> Output {
    let t0 = Instant::now();
    while child.try_wait().expect("try_wait").is_none() {
        if t0.elapsed() > deadline {
            let _ = child.kill();
            let out = child.wait_with_output().expect("output");
            panic!("still running after {deadline:?} (killed):\n{}", text(&out));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.wait_with_output().expect("output")
}

/// `rig args...` in `cwd`, given at most 60 s.
fn run_bounded(cwd: &Path, args: &[&str]) -> Output {
    let child = rig(cwd).args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("spawn");
    wait_or_kill(child, Duration::from_secs(60))
}

fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.to_str().expect("utf-8")).expect("c string");
    // SAFETY: mkfifo on a NUL-terminated path the test owns.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo {}", path.display());
}

/// Every file below `dir`, relative, with its bytes (a snapshot to compare before and after).
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).expect("list") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                stack.push(path);
            } else {
                out.push((path.strip_prefix(dir).expect("below").to_path_buf(), std::fs::read(&path).expect("read")));
            }
        }
    }
    out.sort();
    out
}

/// (Item 1.) A symlink below an approved path is never followed: a daemon collection into an
/// `out` whose object folder is a symlink, a synth job over a folder of datasets holding a
/// symlinked one (with an orphan image a fill would delete), a model package whose
/// model.toml or tokenizer.json is a symlink.
#[test]
fn symlinks_below_an_approved_path_are_never_followed() {
    use std::os::unix::fs::symlink;
    let sb = Sandbox::new();
    let w = sb.work();
    let victim = sb.top.join("outside/victim");
    std::fs::create_dir(&victim).expect("mkdir");
    std::fs::create_dir(w.join("coll")).expect("mkdir");
    symlink(&victim, w.join("coll/sphere")).expect("symlink");

    let daemon = DaemonProcess::start(&w, &[], &[]);
    let id = daemon.submit(&serde_json::json!({"kind": "collect", "object": "sphere", "sensor": "tactip", "poses": 1, "out": "coll"}));
    let job = daemon.wait_final(id);
    assert_eq!(job["state"], "failed", "{job}");
    assert_eq!(job["exit_code"], 2, "{job}");
    assert!(job["error"].as_str().is_some_and(|e| e.contains("symlink")), "{job}");
    assert_eq!(std::fs::read_dir(&victim).expect("list").count(), 0, "a dataset was written through the symlink");
    drop(daemon);

    // A dataset outside with an image no row names: opening it for a fill would delete it.
    let vds = sb.top.join("outside/vds");
    dataset(&vds, 2);
    image(9).save(vds.join("images/777.png")).expect("orphan");
    let before = snapshot(&vds);
    std::fs::create_dir(w.join("multi")).expect("mkdir");
    symlink(&vds, w.join("multi/obj")).expect("symlink");
    let tiny = tiny_package();
    let tiny = tiny.to_str().expect("utf-8");
    let out = run(&w, &["synth", "--fill-missing", "--dataset", "multi", "--model", tiny, "--steps", "1", "--limit", "1"]);
    expect(&out, 2, "symlink");
    assert!(snapshot(&vds) == before, "the dataset outside changed");

    // Package files that are symlinks are not read.
    let pkg = copy_package(&w.join("pkg"));
    std::fs::remove_file(pkg.join("model.toml")).expect("rm");
    symlink(sb.secret(), pkg.join("model.toml")).expect("symlink");
    expect(&run(&w, &["synth", "info", "--model", "pkg"]), 2, "symlink");
    let pkg = copy_package(&w.join("pkg2"));
    std::fs::rename(pkg.join("tokenizer"), sb.top.join("outside/tokenizer")).expect("mv");
    symlink(sb.top.join("outside/tokenizer"), pkg.join("tokenizer")).expect("symlink");
    expect(&run(&w, &["synth", "info", "--model", "pkg2"]), 2, "symlink");
    sb.assert_no_copy_of_the_secret();
}

/// (Item 5.) The LeRobot export refuses a dataset whose `images/` is a symlink, as MDS export
/// and fill do, and writes nothing.
#[test]
fn lerobot_export_does_not_read_through_a_symlinked_images_folder() {
    use std::os::unix::fs::symlink;
    let sb = Sandbox::new();
    let w = sb.work();
    dataset(&w.join("ds"), 2);
    let outside_images = sb.top.join("outside/images");
    std::fs::rename(w.join("ds/images"), &outside_images).expect("mv");
    symlink(&outside_images, w.join("ds/images")).expect("symlink");
    let out = run(&w, &["dataset", "export", "ds", "--format", "lerobot", "--out", "lr"]);
    expect(&out, 2, "symlink");
    assert!(!w.join("lr").exists(), "an export was written");
    let leftovers: Vec<_> = std::fs::read_dir(&w).expect("list").map(|e| e.expect("entry").file_name()).collect();
    assert_eq!(leftovers.len(), 1, "only ds: {leftovers:?}");
}

/// (Item 6.) `rig replay` refuses a recording whose header names an object that is a path
/// (absolute or climbing out), and a recording "file" that is a FIFO, at once.
#[test]
fn replay_refuses_object_paths_and_non_regular_recordings() {
    let sb = Sandbox::new();
    let w = sb.work();
    expect(&run(&w, &["collect", "--object", "sphere", "--sensor", "tactip", "--poses", "1", "--out", "o", "--record", "r.rec"]), 0, "");
    let recording = rig::record::Recording::read(&w.join("r.rec")).expect("a recording");
    let target = sb.top.join("outside/made-by-replay");
    for (i, name) in [target.to_str().expect("utf-8").to_string(), "../../outside/climbed".to_string()].into_iter().enumerate() {
        let mut header = recording.header.clone();
        header.object.name = name.clone();
        let mut bytes = rig::record::format::encode_preamble(&serde_json::to_string(&header).expect("json"));
        for e in &recording.events {
            bytes.extend(rig::record::format::encode_event(e));
        }
        bytes.extend(rig::record::format::encode_end(recording.events.len() as u64));
        let file = w.join(format!("evil{i}.rec"));
        std::fs::write(&file, bytes).expect("write");
        let file = file.to_str().expect("utf-8");
        expect(&run(&w, &["replay", file, "--out", "replayed/a/b"]), 2, "object.name");
        expect(&run(&w, &["replay", file, "--info"]), 2, "object.name");
    }
    assert!(!target.exists() && !sb.top.join("outside/climbed").exists() && !w.join("replayed").exists());
    assert_eq!(std::fs::read_dir(sb.top.join("outside")).expect("list").count(), 1, "only the sentinel");

    let fifo = w.join("fifo.rec");
    mkfifo(&fifo);
    expect(&run_bounded(&w, &["replay", "fifo.rec", "--info"]), 2, "not a regular file");
}

/// (Item 7.) `rig eval` and `rig calibrate --from-dataset` read a dataset's images by the dataset
/// rules: no symlink, no FIFO, and an image's pixel count bounded before decoding.
#[test]
fn eval_and_calibrate_read_images_by_the_dataset_rules() {
    use rig::dataset::Source;
    use rig::pose::Pose;
    use std::os::unix::fs::symlink;
    let sb = Sandbox::new();
    let w = sb.work();
    let poses = [(1, Pose::new(0.0, 0.0, 0.0, 0.0)), (2, Pose::new(2.0, -1.0, 0.5, 30.0))];
    let write = |dir: &Path, source: Source| {
        let mut manifest = Manifest::new(SensorKind::TacTip, ObjectInfo::named("sphere"), None);
        manifest.calibration = Some("default".into());
        let mut w = DatasetWriter::create(dir, manifest).expect("create");
        w.write_reference(&image(0)).expect("reference");
        for (id, pose) in poses {
            let row = match source {
                Source::Synthetic => PoseRow::synthetic(id, pose, "m", 0, 1, 1.0),
                other => PoseRow::commanded_only(id, pose, other),
            };
            w.append(row, &image(id as u8)).expect("append");
        }
        w.finish().expect("finish");
    };
    write(&w.join("real"), Source::Real);
    write(&w.join("syn"), Source::Synthetic);
    image(200).save(sb.top.join("outside/ref.png")).expect("png");
    std::fs::remove_file(w.join("real/reference.png")).expect("rm");
    symlink(sb.top.join("outside/ref.png"), w.join("real/reference.png")).expect("symlink");
    expect(&run_bounded(&w, &["eval", "--real", "real", "--synthetic", "syn"]), 2, "symlink");
    std::fs::remove_file(w.join("real/reference.png")).expect("rm");
    image(0).save(w.join("real/reference.png")).expect("png");
    std::fs::remove_file(w.join("syn/images/2.png")).expect("rm");
    mkfifo(&w.join("syn/images/2.png"));
    expect(&run_bounded(&w, &["eval", "--real", "real", "--synthetic", "syn"]), 2, "not a regular file");

    // calibrate --from-dataset: a symlinked images/, a FIFO, an 8192 x 8192 16-bit PNG.
    let cal = |ds: &str| run_bounded(&w, &["calibrate", "--sensor", "tactip", "--from-dataset", ds, "--out", "cal.toml"]);
    write(&w.join("c1"), Source::Real);
    std::fs::rename(w.join("c1/images"), sb.top.join("outside/c1-images")).expect("mv");
    symlink(sb.top.join("outside/c1-images"), w.join("c1/images")).expect("symlink");
    expect(&cal("c1"), 2, "symlink");
    write(&w.join("c2"), Source::Real);
    std::fs::remove_file(w.join("c2/images/1.png")).expect("rm");
    mkfifo(&w.join("c2/images/1.png"));
    expect(&cal("c2"), 2, "not a regular file");
    write(&w.join("c3"), Source::Real);
    std::fs::write(w.join("c3/images/1.png"), png_claiming(8192, 8192)).expect("write");
    expect(&cal("c3"), 2, "pixels");
    assert!(!w.join("cal.toml").exists());
}

/// A small 16-bit RGB PNG whose header says `width` x `height` (CRC fixed; the pixel data is
/// that of a 2 x 2 image, so only a decoder that trusts the header allocates for the claim).
fn png_claiming(width: u32, height: u32) -> Vec<u8> {
    let small = image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_pixel(2, 2, image::Rgb([1, 2, 3]));
    let mut png = Vec::new();
    small.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).expect("encode");
    png[16..20].copy_from_slice(&width.to_be_bytes());
    png[20..24].copy_from_slice(&height.to_be_bytes());
    let crc = crc32(&png[12..29]);
    png[29..33].copy_from_slice(&crc.to_be_bytes());
    png
}

/// CRC-32 (IEEE), as PNG chunks use.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
        }
    }
    c ^ 0xFFFF_FFFF
}

/// (Item 8.) An STL or calibration path in a manifest that leads outside the dataset is refused
/// in the same words whether or not a file is there, and nothing of such a file is shown.
#[test]
fn manifest_paths_outside_the_dataset_reveal_nothing() {
    let sb = Sandbox::new();
    let w = sb.work();
    let stl = sb.top.join("outside/part.stl");
    let mut bytes = b"NOT-AN-STL-HEADER ".to_vec();
    bytes.resize(200, b'x');
    std::fs::write(&stl, &bytes).expect("write");
    let tiny = tiny_package();
    let tiny = tiny.to_str().expect("utf-8");
    let fill = |ds: &str| run(&w, &["synth", "--fill-missing", "--dataset", ds, "--model", tiny, "--steps", "1", "--limit", "1"]);
    let with_manifest = |ds: &str, edit: &dyn Fn(String) -> String| {
        dataset(&w.join(ds), 1);
        let manifest = std::fs::read_to_string(w.join(ds).join("manifest.toml")).expect("manifest");
        let edited = edit(manifest.clone());
        assert_ne!(edited, manifest, "the edit applied");
        std::fs::write(w.join(ds).join("manifest.toml"), edited).expect("write");
    };
    let mut messages = Vec::new();
    for (ds, path) in [("s1", stl.clone()), ("s2", sb.top.join("outside/missing.stl"))] {
        let path = path.display().to_string();
        with_manifest(ds, &|m| m.replace("[object]\nname = \"sphere\"", &format!("[object]\nname = \"sphere\"\nstl_path = \"{path}\"")));
        let all = expect(&fill(ds), 2, "not a path below the dataset folder");
        assert!(!all.contains("200") && !all.contains("NOT-AN-STL"), "{all}");
        messages.push(all.replace(&path, "P").replace(ds, "D"));
    }
    let secret = sb.secret().display().to_string();
    let missing = sb.top.join("outside/missing.toml").display().to_string();
    for (ds, path) in [("c1", secret.as_str()), ("c2", missing.as_str())] {
        with_manifest(ds, &|m| {
            let mut lines: Vec<String> = m.lines().map(|l| l.to_string()).collect();
            lines.insert(0, format!("calibration = \"{path}\""));
            lines.join("\n") + "\n"
        });
        let all = expect(&fill(ds), 2, "not a path below the dataset folder");
        messages.push(all.replace(path, "P").replace(ds, "D"));
    }
    assert_eq!(messages[0], messages[1], "an STL outside: the same words whether it exists or not");
    assert_eq!(messages[2], messages[3], "a calibration outside: the same words whether it exists or not");
    sb.assert_no_copy_of_the_secret();
}

// Off the walked path (issue 35): reproductions 2, 3, 4 and 9.

/// A copy of the tiny package with `scheduler_config.json`'s `num_train_timesteps` and, when
/// given, `model.toml`'s `sampling_steps` replaced.
fn package_with_steps(dir: &Path, train_steps: u64, sampling_steps: Option<u64>) -> PathBuf {
    let pkg = copy_package(dir);
    let config = pkg.join("scheduler/scheduler_config.json");
    let json = std::fs::read_to_string(&config).expect("scheduler config");
    let mut changed = json.replace("\"num_train_timesteps\": 1000", &format!("\"num_train_timesteps\": {train_steps}"));
    assert!(json.contains("\"num_train_timesteps\": 1000,"), "the fixture names its training timesteps");
    // Over 10000 timesteps the fixture's betas would drive the last cumulative alpha to about
    // 1e-22 (refused as unusable): smaller betas keep a long schedule valid.
    changed = changed.replace("\"beta_end\": 0.012", "\"beta_end\": 0.002").replace("\"beta_start\": 0.00085", "\"beta_start\": 0.0001");
    std::fs::write(&config, changed).expect("write");
    if let Some(n) = sampling_steps {
        let toml = std::fs::read_to_string(pkg.join("model.toml")).expect("model.toml");
        std::fs::write(pkg.join("model.toml"), format!("{toml}sampling_steps = {n}\n")).expect("write");
    }
    pkg
}

/// `rig` with its address space limited to `bytes` (RLIMIT_AS): an allocation past it fails.
fn run_limited(cwd: &Path, args: &[&str], bytes: u64) -> Output {
    run_with_limit(cwd, args, libc::RLIMIT_AS, bytes)
}

/// The type `setrlimit` takes its resource as (glibc's own; an int elsewhere).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
type Resource = libc::__rlimit_resource_t;
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
type Resource = libc::c_int;

/// `rig` with the resource limit `resource` (RLIMIT_AS, RLIMIT_DATA) set to `bytes`: an
/// allocation past it fails (Rust aborts the process).
fn run_with_limit(cwd: &Path, args: &[&str], resource: Resource, bytes: u64) -> Output {
    use std::os::unix::process::CommandExt;
    let mut cmd = rig(cwd);
    cmd.args(args);
    // SAFETY: setrlimit is async-signal-safe and touches only the child's own limits.
    unsafe {
        cmd.pre_exec(move || {
            let limit = libc::rlimit { rlim_cur: bytes, rlim_max: bytes };
            if libc::setrlimit(resource, &limit) == 0 { Ok(()) } else { Err(std::io::Error::last_os_error()) }
        });
    }
    cmd.output().expect("running rig")
}

/// (Reproduction 2.) `num_train_timesteps` of 1e12 (which aborted rig: a 4 TB allocation) and
/// 3e8 (2.3 GB before the refusal) are refused as bad input, before the schedule is allocated;
/// a daemon job naming such a package fails alone and the next job runs.
#[test]
fn scheduler_timestep_bombs_are_refused_before_allocating() {
    let sb = Sandbox::new();
    let w = sb.work();
    for n in [1_000_000_000_000u64, 300_000_000] {
        let dir = w.join(format!("bomb-{n}"));
        package_with_steps(&dir, n, None);
        // 3e8 f32 betas alone are 1.2 GB: under a 1 GiB address space the refusal must come
        // before any of it is allocated.
        let out = run_limited(&w, &["synth", "info", "--model", dir.to_str().expect("utf-8")], 1 << 30);
        let all = expect(&out, 2, "num_train_timesteps");
        assert!(all.contains("2 to 10000"), "the bound is said:\n{all}");
    }

    dataset(&w.join("ds/sphere/tactip"), 2);
    let daemon = DaemonProcess::start(&w, &[], &[]);
    let job =
        serde_json::json!({"kind": "synth", "dataset": w.join("ds/sphere/tactip"), "model": w.join("bomb-1000000000000"), "steps": 1});
    let id = daemon.submit(&job);
    let job = daemon.wait_final(id);
    assert_eq!((job["state"].as_str(), job["exit_code"].as_u64()), (Some("failed"), Some(2)), "{job}");
    assert!(job["error"].as_str().is_some_and(|e| e.contains("num_train_timesteps")), "{job}");
    let good = serde_json::json!({"kind": "collect", "object": "sphere", "sensor": "tactip", "poses": 1, "out": w.join("good")});
    let id = daemon.submit(&good);
    assert_eq!(daemon.wait_final(id)["state"], "done", "the daemon goes on after the bad package");
}

/// (Reproduction 3.) A package asking for 40,000,000 sampling steps (or training timesteps) is
/// refused by the documented bound (10000); one at the bound runs, and both a cancel through
/// the API and SIGTERM stop it: the cancel within a sampling step (not by abandoning the job),
/// SIGTERM ending the daemon within 5 s with the arm disabled. The job list is paged and the
/// queue bounded meanwhile (reproduction 4).
#[test]
fn the_longest_synth_job_stops_on_cancel_and_on_sigterm() {
    let sb = Sandbox::new();
    let w = sb.work();
    let huge = package_with_steps(&w.join("huge"), 1000, Some(40_000_000));
    expect(&run(&w, &["synth", "info", "--model", huge.to_str().expect("utf-8")]), 2, "sampling_steps");
    let huge = package_with_steps(&w.join("huge-train"), 40_000_000, Some(40_000_000));
    expect(&run(&w, &["synth", "info", "--model", huge.to_str().expect("utf-8")]), 2, "1 to 10000");
    let long = package_with_steps(&w.join("long"), 10_000, Some(10_000));
    dataset(&w.join("ds/sphere/tactip"), 2);

    let mut daemon = DaemonProcess::start(&w, &[], &[]);
    let job = serde_json::json!({"kind": "synth", "dataset": w.join("ds/sphere/tactip"), "model": long});
    let id = daemon.submit(&job);
    daemon.wait_running(id);

    // While it runs: the queue is bounded and the list comes in pages.
    let queue_one = |k: usize| {
        daemon.submit(
            &serde_json::json!({"kind": "collect", "object": "sphere", "sensor": "tactip", "poses": 1, "out": w.join(format!("q{k}"))}),
        )
    };
    let mut queued: Vec<u64> = (0..60).map(queue_one).collect();
    let r = daemon.request("GET", "/api/jobs", "", "");
    assert_eq!(r.status, 200);
    let page: Vec<serde_json::Value> = serde_json::from_slice(&r.body).expect("a JSON list");
    assert_eq!(page.len(), 50, "a page holds at most 50 jobs");
    assert_eq!(page.last().and_then(|j| j["id"].as_u64()), queued.last().copied(), "the newest page, oldest first");
    assert_eq!(r.header("x-rig-jobs-total"), Some("61"));
    let before = r.header("x-rig-next-before").expect("a cursor to older jobs").to_string();
    let older: Vec<serde_json::Value> =
        serde_json::from_value(daemon.get_json(&format!("/api/jobs?limit=20&before={before}"))).expect("list");
    assert_eq!(older.iter().filter_map(|j| j["id"].as_u64()).collect::<Vec<_>>(), [vec![id], queued[..10].to_vec()].concat());
    let capped: Vec<serde_json::Value> = serde_json::from_value(daemon.get_json("/api/jobs?limit=100000")).expect("list");
    assert_eq!(capped.len(), 50);
    let r = daemon.request("GET", "/api/jobs?limit=0", "", "");
    assert_eq!(r.status, 400);
    assert!(error_of(&r).contains("limit"), "{}", error_of(&r));
    queued.extend((60..100).map(queue_one));
    let full = serde_json::json!({"kind": "collect", "object": "sphere", "sensor": "tactip", "poses": 1, "out": w.join("q-full")});
    let r = daemon.request("POST", "/api/jobs", "Content-Type: application/json\r\nX-Rig-Client: t\r\n", &full.to_string());
    assert_eq!(r.status, 503, "{}", String::from_utf8_lossy(&r.body));
    assert!(error_of(&r).contains("queue"), "{}", error_of(&r));

    for q in &queued {
        let r = daemon.request("POST", &format!("/api/jobs/{q}/cancel"), "X-Rig-Client: t\r\n", "");
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    }

    // A cancel stops the sampling within a step: the job ends cancelled, not abandoned. (The
    // package loads in about a second; a batch of 10000 steps takes minutes, so after a few
    // seconds the job is sampling.)
    std::thread::sleep(Duration::from_secs(3));
    let r = daemon.request("POST", &format!("/api/jobs/{id}/cancel"), "X-Rig-Client: t\r\n", "");
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    let t0 = Instant::now();
    let ended = daemon.wait_final(id);
    assert_eq!(ended["state"], "cancelled", "{ended}");
    assert!(!ended["message"].as_str().unwrap_or_default().contains("abandoned"), "the sampling loop did not see the cancel: {ended}");
    assert!(t0.elapsed() < Duration::from_secs(60), "the cancel took {:?}", t0.elapsed());

    // SIGTERM during the same job: the daemon ends within 5 s, the arm disabled.
    let id = daemon.submit(&job);
    daemon.wait_running(id);
    std::thread::sleep(Duration::from_secs(3));
    let (elapsed, status, out) = daemon.terminate(Duration::from_secs(60));
    assert!(elapsed <= Duration::from_secs(5), "SIGTERM took {elapsed:?}:\n{out}");
    assert!(out.contains("stopped: arm disabled"), "{out}");
    assert_eq!(status.code(), Some(0), "{out}");
}

/// (Reproduction 3.) A job blocked in a read that never returns (a FIFO inside its package)
/// cannot hold the queue or the shutdown: a cancel ends it (the next job runs) and SIGTERM ends
/// the daemon within 5 s with the arm disabled.
#[test]
fn a_job_blocked_on_a_fifo_is_stoppable() {
    let sb = Sandbox::new();
    let w = sb.work();
    let pkg = copy_package(&w.join("fifo-pkg"));
    let fifo = pkg.join("extra.fifo");
    let c = std::ffi::CString::new(fifo.to_str().expect("utf-8")).expect("c string");
    // SAFETY: mkfifo on a NUL-terminated path inside our temp folder.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    dataset(&w.join("ds/sphere/tactip"), 2);
    let job = serde_json::json!({"kind": "synth", "dataset": w.join("ds/sphere/tactip"), "model": pkg, "steps": 1});

    let mut daemon = DaemonProcess::start(&w, &[], &[]);
    let id = daemon.submit(&job);
    std::thread::sleep(Duration::from_secs(2));
    let _ = daemon.request("POST", &format!("/api/jobs/{id}/cancel"), "X-Rig-Client: t\r\n", "");
    let ended = daemon.wait_final(id);
    // Cancelled (abandoned in its read) or, where the FIFO is refused outright, failed as bad input.
    assert!(ended["state"] == "cancelled" || ended["exit_code"] == 2, "{ended}");
    let good = serde_json::json!({"kind": "collect", "object": "sphere", "sensor": "tactip", "poses": 1, "out": w.join("good")});
    let next = daemon.submit(&good);
    assert_eq!(daemon.wait_final(next)["state"], "done", "the queue goes on");

    let id = daemon.submit(&job);
    std::thread::sleep(Duration::from_secs(2));
    let state = daemon.get_json(&format!("/api/jobs/{id}"))["state"].clone();
    let (elapsed, status, out) = daemon.terminate(Duration::from_secs(60));
    assert!(elapsed <= Duration::from_secs(5), "SIGTERM (job {state}) took {elapsed:?}:\n{out}");
    assert!(out.contains("stopped: arm disabled"), "{out}");
    assert_eq!(status.code(), Some(0), "{out}");
}

/// (Reproduction 4.) Clients that ask and never read hold a connection for the write timeout at
/// most: the daemon closes them, and a fresh client is served. (Reproduction 9.) hyper's own
/// 400 and 431 answers carry the JSON error body every other error has.
#[test]
fn clients_that_never_read_are_cut_off_and_parse_errors_are_json() {
    let sb = Sandbox::new();
    let daemon = DaemonProcess::start(&sb.work(), &[], &[]);
    let r = daemon.send("BLAH\r\n\r\n");
    assert_eq!(r.status, 400);
    assert!(error_of(&r).contains("not valid HTTP"), "{}", error_of(&r));
    let r = daemon.send(&format!("GET /api/status HTTP/1.1\r\nHost: {}\r\nX-Big: {}\r\n\r\n", daemon.addr, "a".repeat(20_000)));
    assert_eq!(r.status, 431);
    assert!(error_of(&r).contains("16384 bytes"), "{}", error_of(&r));

    // Each slow reader pipelines 2000 page requests (about 14 MB of answers) into a small
    // receive buffer and reads nothing.
    let request = format!("GET / HTTP/1.1\r\nHost: {}\r\n\r\n", daemon.addr).repeat(2000);
    let slow: Vec<TcpStream> = (0..8)
        .map(|_| {
            let s = TcpStream::connect(daemon.addr).expect("connect");
            let size: libc::c_int = 4096;
            // SAFETY: setsockopt on a socket we own, with a c_int option value.
            let rc = unsafe {
                use std::os::fd::AsRawFd;
                libc::setsockopt(
                    s.as_raw_fd(),
                    libc::SOL_SOCKET,
                    libc::SO_RCVBUF,
                    (&size as *const libc::c_int).cast(),
                    std::mem::size_of::<libc::c_int>() as libc::socklen_t,
                )
            };
            assert_eq!(rc, 0);
            let mut writer = s.try_clone().expect("clone");
            let request = request.clone();
            std::thread::spawn(move || {
                let _ = writer.write_all(request.as_bytes());
            });
            s
        })
        .collect();
    let timeout = rig::daemon::serve::WRITE_TIMEOUT;
    std::thread::sleep(timeout + Duration::from_secs(5));
    // A fresh client is served meanwhile.
    assert_eq!(daemon.request("GET", "/api/status", "", "").status, 200);
    for (k, mut s) in slow.into_iter().enumerate() {
        s.set_read_timeout(Some(Duration::from_secs(20))).expect("timeout");
        let mut got = Vec::new();
        let mut buf = vec![0u8; 1 << 16];
        let closed = loop {
            match s.read(&mut buf) {
                Ok(0) => break true,
                Ok(n) => got.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => break true,
                Err(_) => break false,
            }
        };
        let answers = got.windows(15).filter(|w| *w == &b"HTTP/1.1 200 OK"[..]).count();
        assert!(closed, "slow reader {k}: the daemon kept its connection open ({answers} answers read)");
        assert!(answers < 2000, "slow reader {k}: every answer came, so the daemon never gave up on it");
    }
}

/// (Reproduction 9.) Exit codes agree with the table: a model.toml that is too large or not
/// UTF-8 and a symlink loop inside a package are bad input (2), as is `--daemon https://...`;
/// a plan's missing key is named.
#[test]
fn package_files_and_daemon_urls_exit_with_the_tables_codes() {
    let sb = Sandbox::new();
    let w = sb.work();
    let pkg = copy_package(&w.join("big"));
    std::fs::write(pkg.join("model.toml"), format!("name = \"x\"\n# {}\n", "a".repeat(2 << 20))).expect("write");
    expect(&run(&w, &["synth", "info", "--model", "big"]), 2, "model.toml");
    let pkg = copy_package(&w.join("latin1"));
    std::fs::write(pkg.join("model.toml"), b"name = \"caf\xe9\"\n").expect("write");
    expect(&run(&w, &["synth", "info", "--model", "latin1"]), 2, "UTF-8");
    let pkg = copy_package(&w.join("loop"));
    std::os::unix::fs::symlink("b", pkg.join("a")).expect("symlink");
    std::os::unix::fs::symlink("a", pkg.join("b")).expect("symlink");
    expect(&run(&w, &["synth", "info", "--model", "loop"]), 2, "loop");

    let all = expect(&run(&w, &["collect", "--poses", "1", "--daemon", "https://127.0.0.1:7700"]), 2, "https is not supported");
    assert!(all.contains("SSH tunnel"), "{all}");

    std::fs::write(w.join("plan.toml"), "sampling = \"full\"\n[x_mm]\nmin = 0.0\nmax = 1.0\nstep = 1.0\n").expect("write");
    expect(&run(&w, &["collect", "--plan", "plan.toml", "--dry-run"]), 2, "missing field `y_mm`");
}
