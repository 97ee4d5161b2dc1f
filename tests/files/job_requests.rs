//! A daemon job's JSON is outside data: whatever bytes arrive, decoding, checking and confining
//! the request ([`JobRequest`], [`JobRequest::check`], [`JobRequest::confine`]) return a value
//! or an error and never panic, and a request that is confined names only paths inside the
//! data root, whatever `..`, absolute paths and symlinks its paths are built from.
//!
//! This is the fuzzing of the job request (proptest, as part of `cargo test`): the request
//! types reach into most of rig, so they have no cargo-fuzz target of their own.

use std::path::{Component, Path, PathBuf};

use proptest::prelude::*;

use crate::mutate;
use rig::jobs::{Confine, JobRequest};
use rig::roots::DataRoots;

/// A data root with a dataset-like folder, a symlink to a folder outside it and a sentinel
/// file outside; the `TempDir`s live as long as the fixture.
struct Fixture {
    _top: tempfile::TempDir,
    root: PathBuf,
    outside: PathBuf,
    roots: DataRoots,
}

impl Fixture {
    fn new() -> Self {
        let top = tempfile::tempdir().expect("tempdir");
        let root = top.path().join("root");
        let outside = top.path().join("outside");
        std::fs::create_dir_all(root.join("ds/edge/tactip")).expect("mkdir");
        std::fs::create_dir_all(&outside).expect("mkdir");
        std::fs::write(outside.join("sentinel.txt"), "untouched").expect("sentinel");
        std::os::unix::fs::symlink(&outside, root.join("escape")).expect("symlink");
        std::os::unix::fs::symlink(outside.join("gone"), root.join("dangling")).expect("symlink");
        let roots = DataRoots::new(std::slice::from_ref(&root), &root).expect("roots");
        let root = root.canonicalize().expect("canonical root");
        let outside = outside.canonicalize().expect("canonical outside");
        Self { _top: top, root, outside, roots }
    }

    /// One of the path pieces a hostile request would try.
    fn segment(&self, k: u8) -> String {
        match k % 10 {
            0 => "..".into(),
            1 => ".".into(),
            2 => "ds".into(),
            3 => "escape".into(),
            4 => "dangling".into(),
            5 => "edge".into(),
            6 => "tactip".into(),
            7 => "new".into(),
            8 => self.outside.display().to_string(),
            _ => "/".into(),
        }
    }

    fn path(&self, ks: &[u8]) -> String {
        ks.iter().map(|&k| self.segment(k)).collect::<Vec<_>>().join("/")
    }
}

/// Every path a request names.
fn paths(request: &JobRequest) -> Vec<PathBuf> {
    match request {
        JobRequest::Collect(r) => [r.stl.clone(), r.plan.clone(), Some(r.out.clone())].into_iter().flatten().collect(),
        // In twins mode the dataset field is not used (the default is left alone).
        JobRequest::Synth(r) => {
            [if r.poses_of.is_none() { Some(r.dataset.clone()) } else { None }, r.poses_of.clone(), r.model.clone(), r.out.clone()]
                .into_iter()
                .flatten()
                .collect()
        }
        JobRequest::Calibrate(r) => r.out.clone().into_iter().collect(),
        JobRequest::Audit(r) => [Some(r.dataset.clone()), r.stl.clone()].into_iter().flatten().collect(),
        JobRequest::Adaptive(r) => {
            let c = &r.collect;
            [c.stl.clone(), c.plan.clone(), Some(c.out.clone()), r.model.clone()].into_iter().flatten().collect()
        }
    }
}

/// A confined path: absolute, no `.` or `..`, and every part of it that exists resolves inside
/// the root (so nothing written or read there lands outside it).
fn assert_inside(root: &Path, path: &Path, request: &str) {
    assert!(path.is_absolute(), "{request}: {} is not absolute", path.display());
    assert!(
        path.components().all(|c| matches!(c, Component::RootDir | Component::Normal(_))),
        "{request}: {} keeps a . or ..",
        path.display()
    );
    assert!(path.starts_with(root), "{request}: {} is outside {}", path.display(), root.display());
    let mut existing = Some(path);
    while let Some(p) = existing {
        if let Ok(real) = p.canonicalize() {
            assert!(real.starts_with(root), "{request}: {} resolves to {} outside the root", path.display(), real.display());
            break;
        }
        existing = p.parent();
    }
}

/// Decodes, checks and confines `json` both ways; returns how far it got.
fn run(fixture: &Fixture, json: &[u8]) -> u8 {
    let Ok(request) = serde_json::from_slice::<JobRequest>(json) else { return 0 };
    let _ = request.check();
    let mut reached = 1;
    for when in [Confine::Submitted, Confine::Starting] {
        let mut confined = request.clone();
        if confined.confine(&fixture.roots, when).is_ok() {
            reached = 2;
            let text = String::from_utf8_lossy(json);
            for p in paths(&confined) {
                assert_inside(&fixture.root, &p, &text);
            }
        }
    }
    reached
}

/// Valid jobs of each kind, the starting points of the mutations.
const SEEDS: [&str; 6] = [
    r#"{"kind": "collect", "object": "edge", "sensor": "tactip", "poses": 3, "seed": 1, "out": "ds", "resume": true}"#,
    r#"{"kind": "synth", "dataset": "ds/edge/tactip", "shard": "1/2", "out": "new", "steps": 4, "guidance": 1.5, "eta": 0.2, "sampler": "ddim", "image_range": "minmax", "batch": 2, "limit": 3}"#,
    r#"{"kind": "calibrate", "sensor": "vitac", "out": "cal/vitac.toml", "grid": 3, "span_mm": 2.0, "depths_mm": [-0.5, 0.5]}"#,
    r#"{"kind": "synth", "poses_of": "ds", "out": "twins", "twin_size": "model"}"#,
    r#"{"kind": "audit", "dataset": "ds/edge/tactip", "fraction": 0.2, "seed": 3, "min_ssim": 0.5, "size_px": 64}"#,
    r#"{"kind": "adaptive", "collect": {"object": "edge", "sensor": "tactip", "out": "ds", "resume": true}, "budget": 6, "rounds": 3, "seeds_per_pose": 2, "model": "ds/edge", "steps": 2}"#,
];

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        let fixture = Fixture::new();
        run(&fixture, &bytes);
    }

    #[test]
    fn mutated_jobs_never_panic(which in 0usize..6, edits in prop::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 1..6)) {
        let fixture = Fixture::new();
        run(&fixture, &mutate(SEEDS[which].as_bytes(), &edits));
    }

    /// Paths built from `..`, `.`, absolute paths, a symlink out of the root and a dangling
    /// one: whatever is accepted stays inside the root.
    #[test]
    fn confined_paths_stay_inside_the_root(
        kind in 0u8..4,
        a in prop::collection::vec(any::<u8>(), 1..5),
        b in prop::collection::vec(any::<u8>(), 1..5),
    ) {
        let fixture = Fixture::new();
        let (pa, pb) = (fixture.path(&a), fixture.path(&b));
        let job = match kind {
            0 => serde_json::json!({"kind": "collect", "plan": pa, "out": pb}),
            1 => serde_json::json!({"kind": "synth", "dataset": pa, "model": pa, "out": pb}),
            2 => serde_json::json!({"kind": "adaptive", "collect": {"plan": pa, "out": pb}, "budget": 4, "model": pa}),
            _ => serde_json::json!({"kind": "calibrate", "out": pb}),
        };
        run(&fixture, job.to_string().as_bytes());
        let sentinel = std::fs::read_to_string(fixture.outside.join("sentinel.txt")).ok();
        prop_assert_eq!(sentinel.as_deref(), Some("untouched"));
    }
}

/// The seeds decode, check and confine, so the mutations start from jobs that get all the way;
/// and the path builder does reach outside the root, so the property above is tested.
#[test]
fn seeds_are_accepted_and_escapes_refused() {
    let fixture = Fixture::new();
    for seed in SEEDS {
        let request: JobRequest = serde_json::from_str(seed).expect(seed);
        request.check().expect(seed);
        assert_eq!(run(&fixture, seed.as_bytes()), 2, "{seed}");
    }
    for escape in [fixture.path(&[0, 7]), fixture.path(&[3, 7]), fixture.path(&[8]), fixture.path(&[4])] {
        let mut request: JobRequest = serde_json::from_value(serde_json::json!({"kind": "collect", "out": escape})).expect("job");
        assert!(request.confine(&fixture.roots, Confine::Submitted).is_err(), "{escape} was accepted");
    }
    let mut inside: JobRequest = serde_json::from_value(serde_json::json!({"kind": "collect", "out": "ds/../new"})).expect("job");
    assert!(inside.confine(&fixture.roots, Confine::Starting).is_ok());
}
