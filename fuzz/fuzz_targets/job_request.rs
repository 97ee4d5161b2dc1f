//! Fuzzes the daemon's job requests from JSON to validated request: any bytes as the body of
//! `POST /api/jobs` must decode, check and confine without panicking. A request whose paths
//! are confined names only paths inside the data root (read paths existing, when the job
//! starts), and a refused path is named as given, never by what it resolved to.
//!
//! The paths are resolved in a sandbox this target creates in `fuzz/target/`: a working
//! folder `S/a/work` (the daemon's base) holding the root `data/` (with a plan, a dataset
//! folder, a symlink out of the root and a symlink loop) beside `outside/`, and `S/b/secret/`,
//! the sentinel no path may reach. Inputs with absolute paths or more than two `..` are not
//! resolved, so nothing outside the sandbox is ever looked up.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/synth/limits.rs"]
mod limits;
#[path = "../../src/jobs/request.rs"]
mod request;
#[path = "../../src/roots.rs"]
mod roots;
#[path = "../../src/sensor.rs"]
mod sensor;
#[path = "../../src/synth/settings.rs"]
mod settings;
// The module paths the included files name (`crate::synth::limits`, ...).
mod synth {
    pub(crate) use super::{limits, settings};
}
mod jobs {
    pub(crate) use super::request;
}

use std::path::{Component, Path, PathBuf};
use std::sync::OnceLock;

use jobs::request::{Confine, JobRequest};
use libfuzzer_sys::fuzz_target;
use roots::DataRoots;

struct Sandbox {
    roots: DataRoots,
    root: PathBuf,
}

fn sandbox() -> &'static Sandbox {
    static SANDBOX: OnceLock<Sandbox> = OnceLock::new();
    SANDBOX.get_or_init(|| {
        // Inside the fuzz crate's own build folder (ignored by git), reused by every run.
        let top = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/job-request-sandbox");
        let work = top.join("a/work");
        let secret = top.join("b/secret");
        for dir in [work.join("data/ds"), work.join("outside"), secret.clone()] {
            std::fs::create_dir_all(&dir).expect("sandbox folders");
        }
        std::fs::write(work.join("data/plan.toml"), "n_poses = 2\n").expect("sandbox plan");
        std::fs::write(work.join("data/ds/manifest.toml"), "").expect("sandbox manifest");
        std::fs::write(secret.join("token.txt"), "SENTINEL").expect("sandbox sentinel");
        for (link, target) in [("data/up", secret.as_path()), ("data/loop", Path::new("loop")), ("data/gone", Path::new("nowhere"))] {
            let _ = std::os::unix::fs::symlink(target, work.join(link));
        }
        let roots = DataRoots::new(&[PathBuf::from("data")], &work).expect("sandbox roots");
        let root = roots.roots()[0].clone();
        Sandbox { roots, root }
    })
}

/// Every path the request names, with whether the job reads it.
fn paths<'a>(request: &'a JobRequest) -> Vec<(&'a Path, bool)> {
    let mut out = Vec::new();
    let collect = |r: &'a request::CollectRequest, out: &mut Vec<(&'a Path, bool)>| {
        out.extend(r.stl.as_deref().map(|p| (p, true)));
        out.extend(r.plan.as_deref().map(|p| (p, true)));
        out.push((r.out.as_path(), false));
    };
    match request {
        JobRequest::Collect(r) => collect(r, &mut out),
        JobRequest::Adaptive(r) => {
            collect(&r.collect, &mut out);
            out.extend(r.model.as_deref().map(|p| (p, true)));
        }
        JobRequest::Synth(r) => {
            if r.poses_of.is_none() {
                out.push((r.dataset.as_path(), true));
            }
            out.extend(r.poses_of.as_deref().map(|p| (p, true)));
            out.extend(r.model.as_deref().map(|p| (p, true)));
            out.extend(r.out.as_deref().map(|p| (p, false)));
        }
        JobRequest::Calibrate(r) => out.extend(r.out.as_deref().map(|p| (p, false))),
        JobRequest::Audit(r) => {
            out.push((r.dataset.as_path(), true));
            out.extend(r.stl.as_deref().map(|p| (p, true)));
        }
    }
    out
}

/// True when resolving `path` from the sandbox's base cannot leave the sandbox.
fn stays_in_sandbox(path: &Path) -> bool {
    !path.is_absolute() && path.components().filter(|c| *c == Component::ParentDir).count() <= 2
}

fuzz_target!(|data: &[u8]| {
    let Ok(request) = serde_json::from_slice::<JobRequest>(data) else { return };
    let _ = request.kind();
    let _ = request.check();
    if !paths(&request).iter().all(|(p, _)| stays_in_sandbox(p)) {
        return;
    }
    let sandbox = sandbox();
    for when in [Confine::Submitted, Confine::Starting] {
        let mut confined = request.clone();
        match confined.confine(&sandbox.roots, when) {
            Ok(()) => {
                for (path, read) in paths(&confined) {
                    assert!(path.starts_with(&sandbox.root), "{when:?}: {} escaped the root", path.display());
                    if read && when == Confine::Starting {
                        assert!(path.exists(), "{} was confined as an existing input but does not exist", path.display());
                    }
                }
            }
            Err(e) => {
                // What only the sandbox knows (where a symlink leads, a file's contents) must
                // not appear in the refusal; the roots themselves are named on purpose.
                let message = e.to_string().replace(&sandbox.roots.to_string(), "<roots>");
                let given: Vec<String> = paths(&request).iter().map(|(p, _)| p.display().to_string()).collect();
                for word in ["secret", "SENTINEL", "job-request-sandbox"] {
                    assert!(
                        !message.contains(word) || given.iter().any(|g| g.contains(word)),
                        "the refusal names what a path resolved to or holds ({word}): {message}"
                    );
                }
            }
        }
    }
});
