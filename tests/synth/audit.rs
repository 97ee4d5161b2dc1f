//! `rig audit` end to end on the simulated rig with the committed tiny model package: a
//! collected dataset is filled, a seeded share of its synthesised poses is collected again into
//! `audit/`, scored with intervals, summarised in the manifest; a SIGKILLed audit resumes with
//! no row lost or duplicated; `--min-ssim` fails with exit 1.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::cli::{ok, rig, text};

/// A 3 x 2 x 1 x 3 = 18-pose grid of the edge under ViTac: `collected` poses collected, the
/// rest filled with the tiny package (1 step). Returns the dataset.
fn filled_dataset(dir: &Path, collected: u32) -> PathBuf {
    let plan = dir.join("plan.toml");
    std::fs::write(
        &plan,
        format!(
            "sampling = \"random\"\nn_poses = {collected}\nseed = 4\norder = \"optimised\"\n\
             [x_mm]\nmin = -2.0\nmax = 2.0\nstep = 2.0\n[y_mm]\nmin = -1.0\nmax = 1.0\nstep = 2.0\n\
             [z_mm]\nmin = 0.0\nmax = 0.0\nstep = 1.0\n[yaw_deg]\nmin = -45.0\nmax = 45.0\nstep = 45.0\n"
        ),
    )
    .expect("plan");
    let out = dir.join("datasets");
    let mut c = rig();
    c.args(["collect", "--object", "edge", "--sensor", "vitac", "--plan"]).arg(&plan).arg("--out").arg(&out);
    ok(c);
    let ds = out.join("edge").join("vitac");
    let mut f = rig();
    // Standard error is a pipe here, as in a log file: progress comes as plain lines, at an
    // interval short enough for this small fill to print some.
    f.args(["synth", "--fill-missing", "--steps", "1", "--dataset"]).arg(&ds).env("RIG_PROGRESS_INTERVAL_S", "0.01");
    let filled = ok(f);
    assert!(filled.contains(&format!("synthesised {} poses", 18 - collected)), "{filled}");
    let total = 18 - collected;
    assert!(
        filled.lines().any(|l| l.starts_with("edge/vitac: ") && l.contains(&format!("/{total} poses"))),
        "no plain progress line naming the dataset: {filled}"
    );
    assert!(!filled.contains('\r') && !filled.contains("\x1b["), "no terminal bar in a log: {filled:?}");
    // The manifest records the model's size and the frames'; the fill warned if it upscaled.
    let synthesis = rig::dataset::Manifest::load(&ds).expect("manifest").synthesis.expect("[synthesis] recorded by the fill");
    let frames = image::image_dimensions(ds.join("reference.png")).expect("reference.png");
    assert_eq!(synthesis.image_resolution_px, [frames.0, frames.1]);
    assert_eq!(synthesis.upscales(), filled.contains(&format!("upscaled {}", synthesis.upscale_text())), "{filled}");
    ds
}

fn audit(ds: &Path, extra: &[&str]) -> Command {
    let mut c = rig();
    c.args(["audit", "--dataset"]).arg(ds).args(["--size", "64"]).args(extra);
    c
}

fn ids(dir: &Path) -> Vec<u32> {
    rig::dataset::read_rows(dir).map(|rows| rows.iter().map(|r| r.pose_id).collect()).unwrap_or_default()
}

fn synthetic_ids(dir: &Path) -> BTreeSet<u32> {
    let rows = rig::dataset::read_rows(dir).expect("rows");
    rows.iter().filter(|r| r.source == rig::dataset::Source::Synthetic).map(|r| r.pose_id).collect()
}

#[test]
fn audit_collects_a_seeded_share_scores_it_and_writes_the_summary() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let ds = filled_dataset(tmp.path(), 6);
    let before = std::fs::read_to_string(ds.join("poses.csv")).expect("csv");
    let out = ok(audit(&ds, &["--fraction", "0.5", "--seed", "3"]));
    // The totals with their 95% intervals are printed.
    assert!(out.contains("| figure | n | mean | 95% interval |"), "{out}");
    assert!(out.contains("| contact SSIM (RGB) | 6 |"), "{out}");
    assert!(out.contains("SSIM (grey, min-max; MultiDiffSense)"), "{out}");
    // One verdict line against the two baselines; unless the fill beats both, it names a cause.
    let verdict = out.lines().find(|l| l.starts_with("verdict: the fill ")).unwrap_or_else(|| panic!("no verdict line: {out}"));
    let synthesis = rig::dataset::Manifest::load(&ds).expect("manifest").synthesis.expect("[synthesis]");
    if !verdict.contains("beats both baselines") {
        let cause = if synthesis.upscales() {
            format!("Likely cause: the fill upscales {}", synthesis.upscale_text())
        } else {
            "Likely cause: the model".into()
        };
        assert!(verdict.contains(&cause), "{verdict}");
    }
    // Six of the twelve synthesised poses, each collected once, apart from the dataset.
    let audit_ds = ds.join("audit").join("edge").join("vitac");
    let got = ids(&audit_ds);
    assert_eq!(got.len(), 6, "{got:?}");
    let unique: BTreeSet<u32> = got.iter().copied().collect();
    assert_eq!(unique.len(), 6, "duplicated rows: {got:?}");
    assert!(unique.is_subset(&synthetic_ids(&ds)), "audited poses must be synthesised ones: {got:?}");
    let rows = rig::dataset::read_rows(&audit_ds).expect("audit rows");
    assert!(rows.iter().all(|r| r.source == rig::dataset::Source::Simulated), "captured rows are simulated");
    assert_eq!(std::fs::read_to_string(ds.join("poses.csv")).expect("csv"), before, "the dataset's rows are untouched");
    // The report, the panel of the worst poses, and the summary `rig dataset verify` prints.
    let report = std::fs::read_to_string(ds.join("audit").join("report.md")).expect("report.md");
    assert!(report.contains("95% interval") && report.contains("![worst poses](worst-poses.png)"), "{report}");
    assert!(report.contains(&verdict.replacen("verdict:", "**Verdict:**", 1)), "{report}");
    let panel = image::open(ds.join("audit").join("worst-poses.png")).expect("panel").to_rgb8();
    assert_eq!(panel.dimensions(), (128, 4 * 64));
    let verify = ok({
        let mut v = rig();
        v.args(["dataset", "verify"]).arg(&ds);
        v
    });
    assert!(verify.contains("6 of 12 synthetic poses collected again (fraction 0.5, seed 3)"), "{verify}");
    assert!(verify.contains("contact SSIM (RGB): "), "{verify}");
    let mut v = rig();
    v.args(["dataset", "verify"]).arg(&audit_ds);
    ok(v);
    // Synthetic twins of the audited dataset are not what the audit judged: their manifest
    // carries no audit summary.
    let twins = ds.parent().expect("object folder").parent().expect("datasets").join("twins");
    let mut t = rig();
    t.args(["synth", "--steps", "1", "--poses-of"]).arg(&ds).arg("--out").arg(&twins);
    ok(t);
    let twin_manifest = std::fs::read_to_string(twins.join("manifest.toml")).expect("twins' manifest");
    assert!(!twin_manifest.contains("[audit]"), "{twin_manifest}");

    // The same draw again: nothing to collect, the same poses scored.
    let again = ok(audit(&ds, &["--fraction", "0.5", "--seed", "3"]));
    assert!(again.contains("collected 0 poses (6 already present"), "{again}");
    assert_eq!(ids(&audit_ds), got);
    // Another draw into the same folder is refused as bad input.
    let other = audit(&ds, &["--fraction", "0.5", "--seed", "4"]).output().expect("rig audit");
    assert_eq!(other.status.code(), Some(2), "{}", text(&other));
    // A bound no synthesised image reaches fails with exit 1; a bound every one meets passes.
    let strict = audit(&ds, &["--fraction", "0.5", "--seed", "3", "--min-ssim", "1"]).output().expect("rig audit");
    assert_eq!(strict.status.code(), Some(1), "{}", text(&strict));
    assert!(text(&strict).contains("below --min-ssim 1"), "{}", text(&strict));
    ok(audit(&ds, &["--fraction", "0.5", "--seed", "3", "--min-ssim", "-1"]));
}

#[test]
fn a_killed_audit_resumes_with_no_row_lost_or_duplicated() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let ds = filled_dataset(tmp.path(), 4);
    let audit_ds = ds.join("audit").join("edge").join("vitac");
    let all = synthetic_ids(&ds);
    assert_eq!(all.len(), 14);
    // Kill it once it has written a row and before it has written them all.
    let mut child = audit(&ds, &["--fraction", "1"]).stdout(Stdio::null()).stderr(Stdio::null()).spawn().expect("spawning rig audit");
    let start = Instant::now();
    let mut at_kill = 0;
    while start.elapsed() < Duration::from_secs(60) {
        at_kill = ids(&audit_ds).len();
        if at_kill >= 2 || child.try_wait().expect("try_wait").is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let _ = child.kill(); // SIGKILL on Unix
    let _ = child.wait();
    let after_kill = ids(&audit_ds).len();
    assert!(after_kill < all.len(), "the kill came after the last row ({after_kill}); nothing was resumed");
    assert!(at_kill >= 1, "killed before any row");
    assert!(!ds.join("audit").join("report.md").exists(), "a killed audit writes no report");
    let out = ok(audit(&ds, &["--fraction", "1"]));
    assert!(out.contains(&format!("({after_kill} already present")), "{out}");
    let got = ids(&audit_ds);
    let unique: BTreeSet<u32> = got.iter().copied().collect();
    assert_eq!(got.len(), all.len(), "rows: {got:?}");
    assert_eq!(unique, all, "every drawn pose exactly once: {got:?}");
    let mut v = rig();
    v.args(["dataset", "verify"]).arg(&audit_ds);
    ok(v);
    assert!(ds.join("audit").join("report.md").is_file());
}
