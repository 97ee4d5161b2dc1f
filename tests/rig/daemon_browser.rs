//! End to end: the daemon's page in headless Chromium while a collection runs. The page is
//! loaded twice (`--dump-dom` after a virtual-time budget, so its polling has run); both
//! loads must show every sensor's frame (an image fetched through the token-checked API) and
//! the job's progress, and the second must show newer frames and more progress. A second
//! test drives the page's job controls (forms, Cancel, Resume) through Chromium's DevTools
//! protocol on `--remote-debugging-pipe` ([`DevTools`]), since `--dump-dom` cannot click; a
//! third checks that a page on another origin cannot queue a job.
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

/// Chromium driven over the DevTools protocol on `--remote-debugging-pipe`: the browser reads
/// JSON messages, each ended by a NUL byte, on its fd 3 and writes its replies and events on
/// its fd 4. Unlike `--dump-dom`, this can click.
struct DevTools {
    child: std::process::Child,
    to_browser: std::io::PipeWriter,
    /// Every message the browser sent, parsed, in order (a reader thread fills it).
    from_browser: tokio::sync::mpsc::UnboundedReceiver<serde_json::Value>,
    next_id: u64,
    profile: tempfile::TempDir,
}

/// A page target of [`DevTools`], attached in flat mode (its commands carry its session id).
struct Tab {
    session: String,
}

/// How long one wait for the page (an element, a message) may take: a hang guard.
const PAGE_WAIT: Duration = Duration::from_secs(60);

impl DevTools {
    fn launch(chromium: &std::path::Path) -> DevTools {
        use std::io::Read;
        use std::os::fd::AsRawFd;
        use std::os::unix::process::CommandExt;

        let (browser_reads, to_browser) = std::io::pipe().expect("pipe to the browser");
        let (from_browser_raw, browser_writes) = std::io::pipe().expect("pipe from the browser");
        // The browser's ends, moved above fd 10 so that placing them on 3 and 4 in the child
        // cannot overwrite one with the other; close-on-exec, so only the 3 and 4 copies stay.
        let high = |fd: &dyn AsRawFd| {
            // SAFETY: F_DUPFD_CLOEXEC on an open descriptor returns a new one or -1.
            let new = unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_DUPFD_CLOEXEC, 10) };
            assert!(new >= 10, "fcntl(F_DUPFD_CLOEXEC): {}", std::io::Error::last_os_error());
            new
        };
        let (read_fd, write_fd) = (high(&browser_reads), high(&browser_writes));
        let profile = tempfile::tempdir().expect("profile dir");
        let log = std::fs::File::create(profile.path().join("chromium.log")).expect("chromium log");
        let mut cmd = std::process::Command::new(chromium);
        cmd.args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--remote-debugging-pipe",
        ])
        .arg(format!("--user-data-dir={}", profile.path().join("data").display()))
        .arg("about:blank")
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(log);
        // SAFETY: only dup2, which is async-signal-safe, runs between fork and exec; dup2 clears
        // close-on-exec on the copies at 3 and 4.
        unsafe {
            cmd.pre_exec(move || {
                if libc::dup2(read_fd, 3) < 0 || libc::dup2(write_fd, 4) < 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = cmd.spawn().expect("starting chromium");
        // SAFETY: the two descriptors from fcntl above, owned here and closed once.
        unsafe {
            libc::close(read_fd);
            libc::close(write_fd);
        }
        drop((browser_reads, browser_writes));

        let (tx, from_browser) = tokio::sync::mpsc::unbounded_channel();
        std::thread::spawn(move || {
            let mut pipe = from_browser_raw;
            let mut pending = Vec::new();
            let mut buf = [0u8; 65536];
            loop {
                let n = match pipe.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                pending.extend_from_slice(&buf[..n]);
                while let Some(end) = pending.iter().position(|&b| b == 0) {
                    let message: Vec<u8> = pending.drain(..=end).collect();
                    let Ok(value) = serde_json::from_slice(&message[..end]) else { continue };
                    if tx.send(value).is_err() {
                        return;
                    }
                }
            }
        });
        DevTools { child, to_browser, from_browser, next_id: 0, profile }
    }

    /// The tail of chromium's own log, for a failure message.
    fn log_tail(&self) -> String {
        let log = std::fs::read_to_string(self.profile.path().join("chromium.log")).unwrap_or_default();
        let start = log.len().saturating_sub(2000);
        log.get(start..).unwrap_or_default().to_string()
    }

    /// Sends one command (to the browser, or to a page's session) and waits for its reply:
    /// its `result`, or its protocol error's message. Events are skipped.
    async fn call(&mut self, session: Option<&str>, method: &str, params: serde_json::Value) -> Result<serde_json::Value, String> {
        use std::io::Write;
        self.next_id += 1;
        let id = self.next_id;
        let mut message = json!({"id": id, "method": method, "params": params});
        if let Some(session) = session {
            message["sessionId"] = json!(session);
        }
        let mut bytes = serde_json::to_vec(&message).expect("JSON");
        bytes.push(0);
        self.to_browser.write_all(&bytes).unwrap_or_else(|e| panic!("writing to chromium: {e}\n{}", self.log_tail()));
        loop {
            let reply = match tokio::time::timeout(PAGE_WAIT, self.from_browser.recv()).await {
                Ok(Some(reply)) => reply,
                Ok(None) => panic!("chromium closed its DevTools pipe during {method}\n{}", self.log_tail()),
                Err(_) => panic!("chromium did not answer {method} within {} s\n{}", PAGE_WAIT.as_secs(), self.log_tail()),
            };
            if reply["id"] != json!(id) {
                continue;
            }
            return match reply.get("error") {
                Some(error) => Err(error["message"].as_str().unwrap_or("unknown error").to_string()),
                None => Ok(reply["result"].clone()),
            };
        }
    }

    /// Opens `url` in a new page and attaches to it.
    async fn open(&mut self, url: &str) -> Tab {
        let target = self.call(None, "Target.createTarget", json!({"url": url})).await.expect("Target.createTarget");
        let target_id = target["targetId"].as_str().expect("targetId").to_string();
        let attached =
            self.call(None, "Target.attachToTarget", json!({"targetId": target_id, "flatten": true})).await.expect("Target.attachToTarget");
        Tab { session: attached["sessionId"].as_str().expect("sessionId").to_string() }
    }

    /// The value of a JavaScript expression in `tab` (a promise is awaited); an exception or a
    /// protocol error (the page still loading, say) is an `Err`.
    async fn eval(&mut self, tab: &Tab, expression: &str) -> Result<serde_json::Value, String> {
        let params = json!({"expression": expression, "awaitPromise": true, "returnByValue": true});
        let result = self.call(Some(&tab.session), "Runtime.evaluate", params).await?;
        if let Some(exception) = result.get("exceptionDetails") {
            return Err(format!("{}: {}", exception["text"], exception["exception"]["description"]));
        }
        Ok(result["result"]["value"].clone())
    }

    /// Waits until `expression` is true in `tab`; panics saying `what` after [`PAGE_WAIT`].
    async fn wait_for(&mut self, tab: &Tab, what: &str, expression: &str) {
        let deadline = tokio::time::Instant::now() + PAGE_WAIT;
        let mut last = Ok(serde_json::Value::Null);
        while tokio::time::Instant::now() < deadline {
            last = self.eval(tab, expression).await;
            if last.as_ref().is_ok_and(|v| v == &json!(true)) {
                return;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        let body = self.eval(tab, "document.body ? document.body.innerText : ''").await;
        panic!("the page did not show {what} within {} s (last: {last:?}); the page read:\n{body:?}", PAGE_WAIT.as_secs());
    }

    /// Fills the fields of form `form` (by name: the API's field names) and clicks its submit
    /// button, as an operator would.
    async fn submit_form(&mut self, tab: &Tab, form: &str, fields: serde_json::Value) {
        let script = format!(
            r#"(() => {{
  const form = document.getElementById({form:?});
  if (!form) return "no form {form}";
  for (const [name, value] of Object.entries({fields})) {{
    const field = form.elements[name];
    if (!field) return "no field " + name;
    if (field.type === "checkbox") field.checked = value; else field.value = String(value);
  }}
  const button = form.querySelector("button[type=submit]");
  if (!button) return "no submit button";
  button.click();
  return "clicked";
}})()"#
        );
        let clicked = self.eval(tab, &script).await;
        assert_eq!(clicked, Ok(json!("clicked")), "filling and submitting {form}");
    }

    /// Clicks the button of `action` (`cancel`, `resume`) in job `id`'s row, once it is there.
    async fn click_job_button(&mut self, tab: &Tab, id: u64, action: &str) {
        let selector = format!("#job-{id} button[data-action={action}]");
        self.wait_for(tab, &format!("a {action} button on job {id}"), &format!("document.querySelector({selector:?}) !== null")).await;
        let clicked = self.eval(tab, &format!("(() => {{ document.querySelector({selector:?}).click(); return true; }})()")).await;
        assert_eq!(clicked, Ok(json!(true)), "clicking {selector}");
    }
}

impl Drop for DevTools {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Polls the API until job `id` exists and `done` holds for it.
async fn job_when(client: &DaemonClient, id: u64, what: &str, done: impl Fn(&JobView) -> bool) -> JobView {
    let deadline = tokio::time::Instant::now() + PAGE_WAIT;
    let mut last = None;
    while tokio::time::Instant::now() < deadline {
        if let Ok(j) = client.get_json::<JobView>(&format!("/api/jobs/{id}")).await {
            if done(&j) {
                return j;
            }
            last = Some(j);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("job {id} was not {what} within {} s: {last:?}", PAGE_WAIT.as_secs());
}

/// A token-less daemon on the simulated rig with `tmp` its data root, its worker kept busy by a
/// long collection (job 1, running) so that the page's jobs wait in the queue, and its page open
/// in headless Chromium with job 1 shown.
async fn busy_daemon_with_page(chromium: &std::path::Path, tmp: &std::path::Path) -> (Daemon, DaemonClient, DevTools, Tab) {
    let mut options = DaemonOptions::local(RigConfig::builtin_sim());
    options.roots = Some(rig::roots::DataRoots::new(&[tmp.to_path_buf()], tmp).expect("data roots"));
    options.idle_refresh = None;
    let daemon = Daemon::start(options).await.expect("daemon starts");
    let client = DaemonClient::new(&format!("http://{}", daemon.addr()), None).expect("client");
    let blocker = json!({"kind": "collect", "object": "edge", "sensor": "tactip", "poses": 4000, "out": tmp.join("blocker")});
    let r = client.request("POST", "/api/jobs", Some(blocker.to_string().as_bytes())).await.expect("submit");
    assert_eq!(r.status, 201, "{}", String::from_utf8_lossy(&r.body));
    job_when(&client, 1, "running", |j| j.state == JobState::Running).await;
    let mut browser = DevTools::launch(chromium);
    let tab = browser.open(&format!("http://{}/", daemon.addr())).await;
    browser.wait_for(&tab, "job 1 in its jobs table", "document.getElementById('job-1') !== null").await;
    (daemon, client, browser, tab)
}

/// The page's job controls, clicked in a real browser against a token-less daemon (so the
/// page's requests pass the CSRF rule only with the `X-Rig-Client` header): a refused audit
/// shows the API's reason; the collect form queues the job it describes; Cancel cancels it;
/// Resume queues the same request with `resume: true`, which runs once Cancel has stopped the
/// job ahead of it; the fill form synthesises two poses into that collection and the audit form
/// presses them again (both run to their end); and a script on the page that leaves the header
/// out is still refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_submits_cancels_and_resumes_jobs() {
    use rig::jobs::JobRequest;

    let Some(chromium) = chromium_or_skip() else { return };
    let tmp = tempfile::tempdir().expect("tempdir");
    let (daemon, client, mut browser, tab) = busy_daemon_with_page(&chromium, tmp.path()).await;

    // A job the API refuses: the page shows its reason, and nothing is queued.
    let dataset = tmp.path().join("blocker/edge/tactip");
    browser.submit_form(&tab, "form-audit", json!({"dataset": dataset, "fraction": 5})).await;
    browser
        .wait_for(
            &tab,
            "the API's refusal of the audit",
            "document.getElementById('msg-audit').textContent.includes('refused (400): bad job: fraction: 5: must be above 0 and at most 1')",
        )
        .await;

    // The collect form queues the job its fields describe.
    let out = tmp.path().join("page");
    browser.submit_form(&tab, "form-collect", json!({"object": "cross", "sensor": "tactip", "poses": 3, "seed": 7, "out": out})).await;
    let submitted = job_when(&client, 2, "queued", |_| true).await;
    let JobRequest::Collect(spec) = &submitted.spec else { panic!("job 2 is not a collection: {submitted:?}") };
    assert_eq!(
        (spec.object.as_str(), spec.sensor.to_string().as_str(), spec.poses, spec.seed, spec.resume),
        ("cross", "tactip", Some(3), Some(7), false),
        "job 2 is not what the form said: {spec:?}"
    );
    assert_eq!((spec.stl.as_ref(), spec.plan.as_ref()), (None, None), "fields left empty must be left out: {spec:?}");
    let tmp_real = tmp.path().canonicalize().expect("tmp");
    assert!(spec.out.file_name().is_some_and(|n| n == "page") && spec.out.parent() == Some(tmp_real.as_path()), "out: {spec:?}");
    assert_eq!(submitted.state, JobState::Queued, "{submitted:?}");
    browser.wait_for(&tab, "the queued job's id", "document.getElementById('msg-collect').textContent === 'queued collect job 2'").await;

    // Cancel, on the queued job.
    browser.click_job_button(&tab, 2, "cancel").await;
    let cancelled = job_when(&client, 2, "cancelled", |j| j.state.is_final()).await;
    assert_eq!(cancelled.state, JobState::Cancelled, "{cancelled:?}");

    // Resume: the same request again, with resume: true.
    browser.click_job_button(&tab, 2, "resume").await;
    let resumed = job_when(&client, 3, "queued", |_| true).await;
    let JobRequest::Collect(mut expected) = submitted.spec.clone() else { unreachable!("checked above") };
    expected.resume = true;
    assert_eq!(resumed.spec, JobRequest::Collect(expected), "the resumed job is not job 2's request with resume: true");

    // Cancel, on the running job: it stops, and the resumed collection runs to its end.
    browser.click_job_button(&tab, 1, "cancel").await;
    let stopped = job_when(&client, 1, "stopped", |j| j.state.is_final()).await;
    assert_eq!(stopped.state, JobState::Cancelled, "{stopped:?}");
    let finished = job_when(&client, 3, "finished", |j| j.state.is_final()).await;
    assert_eq!((finished.state, finished.exit_code), (JobState::Done, Some(0)), "{finished:?}");
    assert_eq!(rig::dataset::read_rows(&out.join("cross/tactip")).expect("rows").len(), 3, "{finished:?}");

    // The fill and audit forms, on that collection (their jobs need the `synth` feature).
    #[cfg(feature = "synth")]
    fill_and_audit_from_the_page(&mut browser, &tab, &client, &out.join("cross/tactip"), tmp.path()).await;
    let jobs_submitted = if cfg!(feature = "synth") { 5 } else { 3 };

    // The CSRF rule still holds on the page's own origin: without X-Rig-Client, refused.
    let script = format!(
        r#"fetch("/api/jobs", {{ method: "POST", headers: {{ "Content-Type": "application/json" }}, body: JSON.stringify({}) }}).then(r => r.status)"#,
        json!({"kind": "collect", "poses": 1, "out": tmp.path().join("csrf")})
    );
    assert_eq!(browser.eval(&tab, &script).await, Ok(json!(403)), "a POST without X-Rig-Client");
    let jobs: Vec<JobView> = client.get_json("/api/jobs").await.expect("jobs");
    assert_eq!(jobs.len(), jobs_submitted, "{jobs:?}");

    drop(browser);
    daemon.shutdown().await.expect("clean shutdown");
}

/// Jobs 4 and 5 of [`the_page_submits_cancels_and_resumes_jobs`], from the page's fill and audit
/// forms on the 3-pose collection `collected` (inside the data root `tmp`).
#[cfg(feature = "synth")]
async fn fill_and_audit_from_the_page(
    browser: &mut DevTools,
    tab: &Tab,
    client: &DaemonClient,
    collected: &std::path::Path,
    tmp: &std::path::Path,
) {
    use rig::jobs::JobRequest;

    // The fill form: two of the plan's missing poses synthesised into that collection with the
    // tiny package (copied inside the data roots), one sampling step.
    let pkg = crate::copy_package(&tmp.join("pkg"));
    browser.submit_form(tab, "form-synth", json!({"dataset": collected, "model": pkg, "steps": 1, "limit": 2})).await;
    let fill = job_when(client, 4, "filled", |j| j.state.is_final()).await;
    assert_eq!((fill.state, fill.exit_code), (JobState::Done, Some(0)), "{fill:?}");
    let JobRequest::Synth(fill_spec) = &fill.spec else { panic!("job 4 is not a fill: {fill:?}") };
    assert_eq!((fill_spec.steps, fill_spec.limit), (Some(1), Some(2)), "{fill_spec:?}");
    browser.wait_for(tab, "the fill's id", "document.getElementById('msg-synth').textContent === 'queued synth job 4'").await;
    let rows = rig::dataset::read_rows(collected).expect("rows");
    assert_eq!((rows.len(), rows.iter().filter(|r| !r.source.is_captured()).count()), (5, 2), "{rows:?}");

    // The audit form: both synthesised poses pressed again on the simulated rig and measured;
    // the dataset's manifest records the audit.
    browser.submit_form(tab, "form-audit", json!({"dataset": collected, "fraction": 1, "seed": 3})).await;
    let audit = job_when(client, 5, "audited", |j| j.state.is_final()).await;
    assert_eq!((audit.state, audit.exit_code), (JobState::Done, Some(0)), "{audit:?}");
    let JobRequest::Audit(audit_spec) = &audit.spec else { panic!("job 5 is not an audit: {audit:?}") };
    assert_eq!((audit_spec.fraction, audit_spec.seed), (1.0, 3), "{audit_spec:?}");
    let manifest = rig::dataset::Manifest::load(collected).expect("manifest");
    assert_eq!(manifest.audit.as_ref().map(|a| a.audited_poses), Some(2), "{:?}", manifest.audit);
}

/// The page's adaptive form queues the `adaptive` job its fields describe (the collection's
/// fields nested in `collect`, fields left empty left out); Cancel stops it while it waits;
/// Resume queues the same request with `resume: true` in its collection, which then presses the
/// budget over the rounds and fills the rest of the plan.
#[cfg(feature = "synth")]
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_submits_and_resumes_an_adaptive_collection() {
    use rig::jobs::JobRequest;

    let Some(chromium) = chromium_or_skip() else { return };
    let tmp = tempfile::tempdir().expect("tempdir");
    let (daemon, client, mut browser, tab) = busy_daemon_with_page(&chromium, tmp.path()).await;

    // The 18-pose grid of the adaptive command's tests, and the tiny package, in the data root.
    let plan = crate::adaptive::plan(tmp.path(), true);
    let pkg = crate::copy_package(&tmp.path().join("pkg"));
    let out = tmp.path().join("adaptive");
    let fields = json!({
        "collect.object": "sphere", "collect.sensor": "tactip", "collect.plan": plan, "collect.out": out,
        "budget": 6, "rounds": 3, "seeds_per_pose": 2, "model": pkg, "steps": 1,
    });
    browser.submit_form(&tab, "form-adaptive", fields).await;
    let submitted = job_when(&client, 2, "queued", |_| true).await;
    let JobRequest::Adaptive(spec) = &submitted.spec else { panic!("job 2 is not an adaptive collection: {submitted:?}") };
    assert_eq!(
        (spec.budget, spec.rounds, spec.seeds_per_pose, spec.steps, spec.collect.object.as_str(), spec.collect.sensor.to_string().as_str()),
        (6, 3, 2, Some(1), "sphere", "tactip"),
        "job 2 is not what the form said: {spec:?}"
    );
    assert_eq!((spec.collect.stl.as_ref(), spec.collect.poses, spec.collect.resume), (None, None, false), "{spec:?}");
    assert!(spec.collect.plan.as_ref().is_some_and(|p| p.ends_with("plan.toml")), "{spec:?}");
    browser.wait_for(&tab, "the queued job's id", "document.getElementById('msg-adaptive').textContent === 'queued adaptive job 2'").await;

    browser.click_job_button(&tab, 2, "cancel").await;
    let cancelled = job_when(&client, 2, "cancelled", |j| j.state.is_final()).await;
    assert_eq!(cancelled.state, JobState::Cancelled, "{cancelled:?}");
    browser.click_job_button(&tab, 2, "resume").await;
    let resumed = job_when(&client, 3, "queued", |_| true).await;
    let JobRequest::Adaptive(mut expected) = submitted.spec.clone() else { unreachable!("checked above") };
    expected.collect.resume = true;
    assert_eq!(resumed.spec, JobRequest::Adaptive(expected), "the resumed job is not job 2's request with collect.resume: true");

    browser.click_job_button(&tab, 1, "cancel").await;
    job_when(&client, 1, "stopped", |j| j.state.is_final()).await;
    let finished = job_when(&client, 3, "finished", |j| j.state.is_final()).await;
    assert_eq!((finished.state, finished.exit_code), (JobState::Done, Some(0)), "{finished:?}");
    let dataset = out.join("sphere/tactip");
    let chosen = crate::adaptive::choices(&dataset);
    let per_round: Vec<usize> = (1..=3).map(|r| chosen.iter().filter(|c| c.1 == r).count()).collect();
    assert_eq!(per_round, vec![2, 2, 2], "{chosen:?}");
    let rows = crate::adaptive::rows(&dataset);
    assert_eq!((rows.len(), rows.iter().filter(|r| r.1 == "synthetic").count()), (18, 12), "{rows:?}");

    drop(browser);
    daemon.shutdown().await.expect("clean shutdown");
}
