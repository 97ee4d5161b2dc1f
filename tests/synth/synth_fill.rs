//! `rig synth --fill-missing` on a simulated dataset, with the committed tiny model package:
//! every missing grid pose is filled, and two shards merged give exactly the images of one
//! unsharded run.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    c
}

fn ok(mut c: Command) -> String {
    let o = c.output().expect("running rig");
    let text = String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{c:?} failed:\n{text}");
    text
}

/// pose_id -> (source, decoded pixels) of a dataset.
fn contents(dir: &Path) -> BTreeMap<u32, (String, Vec<u8>)> {
    let rows = rig::dataset::read_rows(dir).expect("rows");
    rows.into_iter()
        .map(|r| {
            let pixels = image::open(dir.join(&r.image)).expect("image").to_rgb8().into_raw();
            (r.pose_id, (r.source.to_string(), pixels))
        })
        .collect()
}

#[test]
fn fill_missing_fills_the_grid_and_shards_merge_to_the_same_images() {
    let tmp = tempfile::tempdir().expect("tempdir");
    // A 2 x 2 x 1 x 3 = 12-pose grid; collect 5, fill 7.
    let ds = collect_vitac_edge(tmp.path(), &grid_plan(5, 3, [-2.0, 2.0, 4.0], [-45.0, 45.0, 45.0]));

    // Copies: one filled in place, one filled by two shards then merged.
    let whole = tmp.path().join("whole");
    let sharded = tmp.path().join("sharded");
    for dst in [&whole, &sharded] {
        copy_dir(&ds, dst);
    }
    let fill = |dataset: &Path, extra: &[&str]| {
        let mut c = rig();
        c.args(["synth", "--fill-missing", "--steps", "3", "--batch", "3", "--dataset"]).arg(dataset).args(extra);
        ok(c)
    };
    let out = fill(&whole, &[]);
    assert!(out.contains("synthesised 7 poses"), "{out}");

    let s1 = tmp.path().join("shard1");
    let s2 = tmp.path().join("shard2");
    fill(&sharded, &["--shard", "1/2", "--out", s1.to_str().expect("utf8")]);
    fill(&sharded, &["--shard", "2/2", "--out", s2.to_str().expect("utf8")]);
    let merged = tmp.path().join("merged");
    let mut m = rig();
    m.args(["dataset", "merge", "--out"]).arg(&merged).arg(&sharded).arg(&s1).arg(&s2);
    ok(m);

    let (a, b) = (contents(&whole), contents(&merged));
    assert_eq!(a.len(), 12, "every grid pose present after filling");
    assert_eq!(a.values().filter(|(s, _)| s == "synthetic").count(), 7);
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (id, (source, pixels)) in &a {
        let (source_b, pixels_b) = &b[id];
        assert_eq!(source, source_b, "pose {id}");
        assert!(pixels == pixels_b, "pose {id}: sharded and unsharded images differ");
    }
    // A second fill finds nothing left to do.
    let again = fill(&whole, &[]);
    assert!(again.contains("synthesised 0 poses"), "{again}");
    for dir in [&whole, &merged] {
        let mut v = rig();
        v.args(["dataset", "verify"]).arg(dir);
        ok(v);
    }
}

/// Collects the edge with the simulated ViTac sensor under `dir` with the plan `plan_toml`;
/// returns the dataset.
/// A random plan of `n_poses` over x in {-2, 2} mm, z = 0 and the given `[min, max, step]` of
/// y (mm) and yaw (deg).
fn grid_plan(n_poses: u32, seed: u64, y_mm: [f64; 3], yaw_deg: [f64; 3]) -> String {
    let axis = |name: &str, [min, max, step]: [f64; 3]| format!("[{name}]\nmin = {min:?}\nmax = {max:?}\nstep = {step:?}\n");
    format!(
        "sampling = \"random\"\nn_poses = {n_poses}\nseed = {seed}\norder = \"optimised\"\n{}{}{}{}",
        axis("x_mm", [-2.0, 2.0, 4.0]),
        axis("y_mm", y_mm),
        axis("z_mm", [0.0, 0.0, 1.0]),
        axis("yaw_deg", yaw_deg)
    )
}

fn collect_vitac_edge(dir: &Path, plan_toml: &str) -> std::path::PathBuf {
    let plan = dir.join("plan.toml");
    std::fs::write(&plan, plan_toml).expect("plan");
    let collected = dir.join("collected");
    let mut c = rig();
    c.args(["collect", "--object", "edge", "--sensor", "vitac", "--plan"]).arg(&plan).arg("--out").arg(&collected);
    ok(c);
    collected.join("edge").join("vitac")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to.join("images")).expect("mkdir");
    for entry in walk(from) {
        let rel = entry.strip_prefix(from).expect("prefix");
        std::fs::copy(&entry, to.join(rel)).expect("copy");
    }
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).expect("read_dir").flatten() {
        let p = e.path();
        if p.is_dir() { out.extend(walk(&p)) } else { out.push(p) }
    }
    out
}

/// `rig render --controls-of` writes, for every row, the hint `rig synth --fill-missing` feeds
/// the model (the object pressed in by the work frame's contact depth) and the row's prompt.
#[test]
fn render_controls_of_matches_single_renders_and_prompts() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let collected = tmp.path().join("collected");
    let mut c = rig();
    c.args(["collect", "--object", "cuboid", "--sensor", "tactip", "--poses", "4", "--seed", "5", "--out"]).arg(&collected);
    ok(c);
    let ds = collected.join("cuboid").join("tactip");
    let out = tmp.path().join("controls");
    let mut c = rig();
    c.args(["render", "--controls-of"]).arg(&ds).args(["--size", "64x48", "--out"]).arg(&out);
    let text = ok(c);
    assert!(text.contains("wrote 4 control images (64x48)"), "{text}");

    let manifest = rig::dataset::Manifest::load(&ds).expect("manifest");
    let depth_mm = manifest.work_frame.map(|w| w.contact_depth_mm).expect("work frame");
    let prompts = std::fs::read_to_string(out.join("prompts.csv")).expect("prompts.csv");
    let rows = rig::dataset::read_rows(&ds).expect("rows");
    assert_eq!(rows.len(), 4);
    for row in &rows {
        let pose = row.commanded();
        let single = tmp.path().join(format!("single-{}.png", row.pose_id));
        let arg = format!("{},{},{},{}", pose.x_mm, pose.y_mm, pose.z_mm + depth_mm, pose.yaw_deg);
        let mut c = rig();
        c.args(["render", "--object", "cuboid", "--pose", &arg, "--sensor", "control", "--size", "64x48", "--out"]).arg(&single);
        ok(c);
        let a = image::open(out.join(format!("{}.png", row.pose_id))).expect("batch png").to_rgb8();
        let b = image::open(&single).expect("single png").to_rgb8();
        assert_eq!(a.dimensions(), (64, 48));
        assert!(a == b, "pose {}: batch and single control images differ", row.pose_id);
        let prompt = rig::synth::prompt::mds_prompt(rig::sensor::SensorKind::TacTip, &pose);
        assert!(prompts.contains(&format!("{},TacTip,\"{}\"", row.pose_id, prompt)), "pose {}: {prompts}", row.pose_id);
    }

    // Not a dataset: bad input, exit code 2.
    let mut c = rig();
    c.args(["render", "--controls-of"]).arg(tmp.path()).arg("--out").arg(&out);
    let o = c.output().expect("running rig");
    assert_eq!(o.status.code(), Some(2), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A package's `sampler` (model.toml) is what every fill samples with unless `--sampler` says
/// otherwise: a fill with no flag gives exactly the images of `--sampler dpm++2m` when the
/// package names it, and not those of `--sampler ddim`. Likewise its `eta`.
#[test]
fn the_packages_sampling_settings_are_the_fills_default() {
    let tmp = tempfile::tempdir().expect("tempdir");
    // A 2 x 1 x 1 x 2 = 4-pose grid; collect 2, fill 2.
    let ds = collect_vitac_edge(tmp.path(), &grid_plan(2, 5, [0.0, 0.0, 1.0], [0.0, 45.0, 45.0]));
    // The tiny package, saying dpm++2m and 3 steps.
    let tiny = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tiny-package");
    let package = tmp.path().join("package");
    for file in walk(&tiny) {
        let dst = package.join(file.strip_prefix(&tiny).expect("prefix"));
        std::fs::create_dir_all(dst.parent().expect("parent")).expect("mkdir");
        std::fs::copy(&file, &dst).expect("copy");
    }
    let toml = std::fs::read_to_string(package.join("model.toml")).expect("model.toml");
    assert!(!toml.contains("sampler") && !toml.contains("sampling_steps"), "the tiny package already names a sampler");
    std::fs::write(package.join("model.toml"), format!("{toml}sampler = \"dpm++2m\"\nsampling_steps = 3\n")).expect("model.toml");

    let fill = |name: &str, extra: &[&str]| {
        let dst = tmp.path().join(name);
        copy_dir(&ds, &dst);
        let mut c = rig();
        c.args(["synth", "--fill-missing", "--model"]).arg(&package).arg("--dataset").arg(&dst).args(extra);
        let out = ok(c);
        assert!(out.contains("synthesised 2 poses"), "{out}");
        contents(&dst).into_iter().filter(|(_, (s, _))| s == "synthetic").collect::<BTreeMap<_, _>>()
    };
    let default = fill("default", &[]);
    let dpm = fill("dpm", &["--sampler", "dpm++2m", "--steps", "3"]);
    let ddim = fill("ddim", &["--sampler", "ddim", "--steps", "3"]);
    let two_steps = fill("two-steps", &["--steps", "2"]);
    assert_eq!(default.len(), 2);
    assert!(default == dpm, "no --sampler, no --steps: not the package's dpm++2m at 3 steps");
    assert!(default != ddim, "dpm++2m and ddim gave the same images: the test cannot tell them apart");
    assert!(default != two_steps, "2 and 3 steps gave the same images: the test cannot tell them apart");
    // --conditioning-scale reaches the ControlNet: at 0 the hint is ignored.
    let unhinted = fill("unhinted", &["--conditioning-scale", "0"]);
    assert!(default != unhinted, "--conditioning-scale 0 changed nothing");

    // The package's eta is the fill's default as well (with DDIM: DPM-Solver++ has none).
    std::fs::write(package.join("model.toml"), format!("{toml}sampler = \"ddim\"\nsampling_steps = 3\neta = 0.5\n")).expect("model.toml");
    let eta_default = fill("eta-default", &[]);
    assert!(eta_default == fill("eta-half", &["--eta", "0.5"]), "no --eta: not the package's eta 0.5");
    assert!(eta_default != fill("eta-zero", &["--eta", "0"]), "eta 0.5 and 0 gave the same images: the test cannot tell them apart");
    // --image-range minmax writes the same samples with other pixel values than the clamp.
    assert!(eta_default != fill("minmax", &["--image-range", "minmax"]), "--image-range minmax changed nothing");
}
