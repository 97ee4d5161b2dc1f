//! End to end: the daemon's page in headless Chromium while a collection runs. The page is
//! loaded twice (`--dump-dom` after a virtual-time budget, so its polling has run); both
//! loads must show every sensor's frame (an image fetched through the token-checked API) and
//! the job's progress, and the second must show newer frames and more progress.
//!
//! Needs Debian's `chromium` (`scripts/setup.sh` installs it). Without it the test fails,
//! unless `RIG_SKIP_BROWSER=1` says to skip it.

use std::path::PathBuf;
use std::time::Duration;

use rig::config::RigConfig;
use rig::daemon::client::DaemonClient;
use rig::daemon::{Daemon, DaemonOptions, JobState, JobView};
use serde_json::json;

const TOKEN: &str = "browser-test-token";

fn chromium() -> Option<PathBuf> {
    let candidates =
        [std::env::var_os("RIG_CHROMIUM").map(PathBuf::from), Some("/usr/bin/chromium".into()), Some("/usr/bin/chromium-browser".into())];
    candidates.into_iter().flatten().find(|p| p.is_file())
}

/// Chromium, or `None` when it is missing and `RIG_SKIP_BROWSER=1` says to skip; missing
/// without that, the test fails.
fn chromium_or_skip() -> Option<PathBuf> {
    if let Some(found) = chromium() {
        return Some(found);
    }
    if std::env::var("RIG_SKIP_BROWSER").is_ok_and(|v| v == "1") {
        eprintln!("RIG_SKIP_BROWSER=1: skipping the browser test (no chromium)");
        return None;
    }
    panic!(
        "chromium not found (/usr/bin/chromium; or set RIG_CHROMIUM): run scripts/setup.sh, which installs Debian's \
         chromium package, or set RIG_SKIP_BROWSER=1 to skip this test explicitly"
    );
}

/// What one load of the page showed.
#[derive(Debug)]
struct PageView {
    /// Sensor -> frame sequence number of the image shown.
    frames: Vec<(String, u64)>,
    /// Progress of the current job shown (`done`, `total`).
    progress: Option<(u64, u64)>,
    /// Whether the jobs table lists job 1 as running.
    job_running: bool,
}

/// The number in `attr="N"` right after `marker` in `dom`.
fn attr_after(dom: &str, marker: &str, attr: &str) -> Option<u64> {
    // The page's own script holds the markers too, as templates; take the rendered element.
    dom.match_indices(marker).find_map(|(at, _)| {
        let rest = &dom[at..];
        let tag = &rest[..rest.find('>')?];
        let value_at = tag.find(&format!("{attr}=\""))? + attr.len() + 2;
        let value = &tag[value_at..];
        value[..value.find('"')?].parse().ok()
    })
}

fn read_page(dom: &str) -> PageView {
    let frames = ["tactip", "vitac", "vitactip"]
        .iter()
        .filter_map(|s| {
            let marker = format!("<img id=\"frame-{s}\"");
            let shown_blob =
                dom.match_indices(&marker).any(|(at, _)| dom[at..].split('>').next().is_some_and(|t| t.contains("src=\"blob:")));
            let seq = attr_after(dom, &marker, "data-seq")?;
            shown_blob.then(|| (s.to_string(), seq))
        })
        .collect();
    let done = attr_after(dom, "id=\"current-progress\"", "data-done");
    let total = attr_after(dom, "id=\"current-progress\"", "data-total");
    PageView { frames, progress: done.zip(total), job_running: dom.contains("<tr id=\"job-1\" data-state=\"running\"") }
}

async fn load_page(chromium: &PathBuf, url: &str) -> String {
    let profile = tempfile::tempdir().expect("profile dir");
    let mut cmd = tokio::process::Command::new(chromium);
    cmd.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--virtual-time-budget=3000",
        "--dump-dom",
    ])
    .arg(format!("--user-data-dir={}", profile.path().display()))
    .arg(url)
    .kill_on_drop(true);
    // A hang guard, not a speed assertion.
    let out = tokio::time::timeout(Duration::from_secs(120), cmd.output())
        .await
        .expect("chromium did not finish loading the page within 120 s")
        .expect("running chromium");
    assert!(out.status.success(), "chromium failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

async fn job(client: &DaemonClient, id: u64) -> JobView {
    client.get_json(&format!("/api/jobs/{id}")).await.expect("GET job")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_frames_and_progress_that_update() {
    let Some(chromium) = chromium_or_skip() else { return };
    let tmp = tempfile::tempdir().expect("tempdir");
    let mut options = DaemonOptions::local(RigConfig::builtin_sim());
    options.roots = Some(rig::roots::DataRoots::new(&[tmp.path().to_path_buf()], tmp.path()).expect("data roots"));
    options.token = Some(TOKEN.into());
    let daemon = Daemon::start(options).await.expect("daemon starts");
    let client = DaemonClient::new(&format!("http://{}", daemon.addr()), Some(TOKEN.into())).expect("client");
    let body = json!({"kind": "collect", "object": "edge", "poses": 400, "out": tmp.path()}).to_string();
    let r = client.request("POST", "/api/jobs", Some(body.as_bytes())).await.expect("submit");
    assert_eq!(r.status, 201, "{}", String::from_utf8_lossy(&r.body));
    let url = format!("http://{}/#token={TOKEN}", daemon.addr());

    let mut views = Vec::new();
    for load in 0..2 {
        // Wait for the job to move on from what the previous load showed.
        let shown = views.last().and_then(|v: &PageView| v.progress).map_or(0, |(done, _)| done);
        for _ in 0..6000 {
            let j = job(&client, 1).await;
            assert!(!j.state.is_final(), "the job ended before the page was loaded twice: {j:?}");
            if j.state == JobState::Running && j.progress.done > shown {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let dom = load_page(&chromium, &url).await;
        let view = read_page(&dom);
        eprintln!("load {load}: {view:?}");
        assert_eq!(view.frames.len(), 3, "load {load}: not every sensor's frame is shown: {view:?}\n{dom}");
        assert!(view.progress.is_some_and(|(done, total)| done >= 1 && total == 400), "load {load}: {view:?}");
        assert!(view.job_running, "load {load}: the jobs table does not list job 1 as running");
        views.push(view);
    }
    let (first, second) = (&views[0], &views[1]);
    let (Some((done1, _)), Some((done2, _))) = (first.progress, second.progress) else { unreachable!("checked above") };
    assert!(done2 > done1, "the progress did not move between loads: {done1} then {done2}");
    for ((sensor, seq1), (_, seq2)) in first.frames.iter().zip(&second.frames) {
        assert!(seq2 > seq1, "{sensor}: the frame did not change between loads ({seq1} then {seq2})");
    }

    let r = client.request("POST", "/api/jobs/1/cancel", None).await.expect("cancel");
    assert_eq!(r.status, 200);
    daemon.shutdown().await.expect("clean shutdown");
}

/// A tiny HTTP server on 127.0.0.1:0 that answers every request with `page` (as HTML) and
/// records each request's method and path.
async fn page_server(page: String) -> (std::net::SocketAddr, std::sync::Arc<std::sync::Mutex<Vec<String>>>) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let addr = listener.local_addr().expect("addr");
    let seen = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let log = std::sync::Arc::clone(&seen);
    tokio::spawn(async move {
        while let Ok((mut stream, _)) = listener.accept().await {
            let log = std::sync::Arc::clone(&log);
            let page = page.clone();
            tokio::spawn(async move {
                let mut buf = vec![0u8; 65536];
                let mut got = Vec::new();
                // The head is enough to record; a body, if any, is read as far as it came.
                while !got.windows(4).any(|w| w == b"\r\n\r\n") {
                    match tokio::time::timeout(Duration::from_secs(5), stream.read(&mut buf)).await {
                        Ok(Ok(n)) if n > 0 => got.extend_from_slice(&buf[..n]),
                        _ => break,
                    }
                }
                let head = String::from_utf8_lossy(&got);
                let first = head.lines().next().unwrap_or_default().to_string();
                log.lock().expect("log").push(first);
                let response = format!(
                    "HTTP/1.1 200 OK\r\ncontent-type: text/html\r\ncontent-length: {}\r\nconnection: close\r\n\r\n{page}",
                    page.len()
                );
                let _ = stream.write_all(response.as_bytes()).await;
            });
        }
    });
    (addr, seen)
}

/// CSRF: a page served from another loopback origin tries every request a page can make
/// without the daemon's consent (no-cors fetches with a text/plain body and with an untyped
/// Blob, a JSON form post, and a preflighted fetch) against a token-less daemon. Nothing may be
/// queued. The same requests against a recording server prove the browser did send them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_page_on_another_origin_cannot_submit_a_job() {
    let Some(chromium) = chromium_or_skip() else { return };
    let tmp = tempfile::tempdir().expect("tempdir");
    let mut options = DaemonOptions::local(RigConfig::builtin_sim());
    options.roots = Some(rig::roots::DataRoots::new(&[tmp.path().to_path_buf()], tmp.path()).expect("data roots"));
    options.idle_refresh = None;
    let daemon = Daemon::start(options).await.expect("daemon starts");
    let target = format!("http://{}", daemon.addr());
    let (recorder, recorded) = page_server("recorded".into()).await;
    let recorder = format!("http://{recorder}");

    let job = json!({"kind": "collect", "object": "edge", "sensor": "tactip", "poses": 1, "out": tmp.path()}).to_string();
    let attack = format!(
        r#"<!doctype html><html><body>
<iframe name="sink1"></iframe><iframe name="sink2"></iframe>
<form id="f1" method="POST" enctype="text/plain" target="sink1" action="{target}/api/jobs"><input name='{{"kind":"collect","poses":1,"x":"' value='"}}'></form>
<form id="f2" method="POST" enctype="text/plain" target="sink2" action="{recorder}/form"><input name='{{"kind":"collect","poses":1,"x":"' value='"}}'></form>
<script>
const body = {job:?};
for (const base of ["{target}", "{recorder}"]) {{
  fetch(base + "/api/jobs", {{ method: "POST", mode: "no-cors", body }}).catch(() => {{}});
  fetch(base + "/api/jobs", {{ method: "POST", mode: "no-cors", body: new Blob([body]) }}).catch(() => {{}});
  fetch(base + "/api/jobs", {{ method: "POST", headers: {{ "Content-Type": "application/json", "X-Rig-Client": "x" }}, body }}).catch(() => {{}});
  fetch(base + "/api/jobs/1/cancel", {{ method: "POST", mode: "no-cors" }}).catch(() => {{}});
}}
document.getElementById("f1").submit();
document.getElementById("f2").submit();
document.body.setAttribute("data-sent", "yes");
</script></body></html>"#
    );
    let (attacker, _) = page_server(attack).await;
    let dom = load_page(&chromium, &format!("http://{attacker}/")).await;
    assert!(dom.contains("data-sent=\"yes\""), "the attacking page's script did not run:\n{dom}");

    // The control: the browser did send the simple requests and the form post (and a preflight).
    let seen = recorded.lock().expect("log").clone();
    let posts = seen.iter().filter(|l| l.starts_with("POST /api/jobs ")).count();
    assert!(posts >= 2, "the browser did not send the no-cors posts to the recorder: {seen:?}");
    assert!(seen.iter().any(|l| l.starts_with("POST /form")), "the browser did not post the form: {seen:?}");
    assert!(seen.iter().any(|l| l.starts_with("OPTIONS /api/jobs")), "no preflight for the JSON post: {seen:?}");

    // The daemon queued nothing.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let client = DaemonClient::new(&target, None).expect("client");
    let jobs: Vec<JobView> = client.get_json("/api/jobs").await.expect("jobs");
    assert!(jobs.is_empty(), "a page on another origin queued a job: {jobs:?}");
    daemon.shutdown().await.expect("clean shutdown");
}
