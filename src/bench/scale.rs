//! Scale: what the work costs as it grows. Each stage is a `rig` command, run as a child
//! process at three sizes N1 < N2 < N3, with its wall time and its own peak resident memory
//! (the child's `ru_maxrss` from `wait4`, so one stage's memory never hides another's), and
//! the growth exponent of each fitted on a log-log
//! scale (the least-squares slope of ln(cost) against ln(N): 1 is linear, 0 flat, 2 quadratic).
//!
//! | stage | command | N |
//! |---|---|---|
//! | ordering | `rig collect --plan P --poses N --dry-run` (sample, order, check the workspace and the press limit, the pre-flight of the simulated rig: a fixed cost) | poses |
//! | collection | `rig collect --plan P --poses N` on the simulated rig, one sensor | poses (frames) |
//! | verify | `rig dataset verify` of that dataset | frames |
//! | merge | `rig dataset merge --out NEW` of that dataset | frames |
//! | LeRobot export | `rig dataset export --format lerobot` of that dataset | frames |
//! | replay --info | `rig replay REC --info` of the same collection recorded by `rig collect --record` | frames |
//! | replay | `rig replay REC --out NEW` | frames |
//!
//! P is a plan on the 100 x 100 x 10 x 10 grid of `plans/lab-scale.toml` (x, y from -5 to 4.9 mm
//! by 0.1, z from -1 to 0.8 mm by 0.2, yaw from -90 to 72 degrees by 18), Latin hypercube,
//! seed 0. The simulated rig runs [`SIM_TIME_SCALE`] times faster than real time with no settle
//! time, frames of `scale_image_px` square: the stages' cost, not the arm's, is measured. The
//! scratch datasets of a size are removed before the next size starts.
//!
//! A floor under every peak: Linux starts a child's `ru_maxrss` from the size of the process
//! that started it (the high-water mark of the memory it replaced at `execve`), so no peak reads
//! below the bench's own size when it started the child. The bench keeps itself small (it
//! only starts children) and the report states its own peak ([`own_peak_bytes`]), the highest
//! that floor can be.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::Instant;

use super::error::BenchError;
use super::knob::{BenchConfig, Knob};
use super::plot::{Plot, Series};
use super::table::{Column, KnobReport, Row};
use crate::plan::{AxisRange, Order, PlanSpec, Sampling};

/// Speed of the simulated rig's clock in the collection stages (the most a configuration
/// allows is 1000).
pub const SIM_TIME_SCALE: f64 = 500.0;

/// One stage of the table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    Ordering,
    Collection,
    Verify,
    Merge,
    LerobotExport,
    ReplayInfo,
    Replay,
}

impl Stage {
    /// Every stage, in table order.
    pub const ALL: [Stage; 7] =
        [Stage::Ordering, Stage::Collection, Stage::Verify, Stage::Merge, Stage::LerobotExport, Stage::ReplayInfo, Stage::Replay];

    /// The row's label.
    pub fn label(self) -> &'static str {
        match self {
            Stage::Ordering => "ordering (collect --dry-run)",
            Stage::Collection => "collection",
            Stage::Verify => "dataset verify",
            Stage::Merge => "dataset merge",
            Stage::LerobotExport => "LeRobot export",
            Stage::ReplayInfo => "replay --info",
            Stage::Replay => "replay",
        }
    }

    /// Whether this build can run the stage (the LeRobot export needs the `lerobot` feature).
    pub fn built(self) -> bool {
        self != Stage::LerobotExport || crate::features::Feature::Lerobot.built()
    }
}

/// The 100 x 100 x 10 x 10 grid of `plans/lab-scale.toml`, `n_poses` by Latin hypercube.
pub fn lab_scale_plan(n_poses: usize) -> PlanSpec {
    PlanSpec {
        x_mm: AxisRange::new(-5.0, 4.9, 0.1),
        y_mm: AxisRange::new(-5.0, 4.9, 0.1),
        z_mm: AxisRange::new(-1.0, 0.8, 0.2),
        yaw_deg: AxisRange::new(-90.0, 72.0, 18.0),
        sampling: Sampling::Lhs,
        n_poses: Some(n_poses),
        seed: 0,
        order: Order::Optimised,
    }
}

/// What one run of a child `rig` cost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChildCost {
    pub wall_s: f64,
    /// The child's peak resident set size, bytes.
    pub peak_bytes: u64,
}

/// The least-squares slope of `ln y` against `ln x` over the points with both positive and
/// finite; NaN with fewer than two such points or no spread in `x`.
pub fn growth_exponent(points: &[(f64, f64)]) -> f64 {
    let logs: Vec<(f64, f64)> =
        points.iter().filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite()).map(|(x, y)| (x.ln(), y.ln())).collect();
    if logs.len() < 2 {
        return f64::NAN;
    }
    let n = logs.len() as f64;
    let (mx, my) = (logs.iter().map(|p| p.0).sum::<f64>() / n, logs.iter().map(|p| p.1).sum::<f64>() / n);
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    if sxx > 0.0 { sxy / sxx } else { f64::NAN }
}

/// This process's own peak resident memory in bytes (`VmHWM` of `/proc/self/status`), where
/// the system reports it.
pub fn own_peak_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.trim_start_matches("VmHWM:").trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kib * 1024)
}

/// Waits for `child` and returns its exit status and its own peak resident set size in bytes
/// (`wait4`'s `ru_maxrss`: of this child alone, unlike `RUSAGE_CHILDREN`, which keeps the
/// largest child so far).
fn wait_with_peak(child: &std::process::Child) -> std::io::Result<(ExitStatus, u64)> {
    use std::os::unix::process::ExitStatusExt;
    let pid = libc::pid_t::try_from(child.id()).map_err(|_| std::io::Error::other("child pid out of range"))?;
    let mut status: libc::c_int = 0;
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    loop {
        // SAFETY: `status` and `usage` are valid for writes of a c_int and an rusage; `pid` is
        // this process's own child, which nothing else waits for (std's `Child::wait` is never
        // called on it).
        let reaped = unsafe { libc::wait4(pid, &mut status, 0, usage.as_mut_ptr()) };
        if reaped == pid {
            break;
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
    // SAFETY: an all-zero rusage is a valid value (integers and timevals only), and wait4 has
    // filled it in.
    let usage = unsafe { usage.assume_init() };
    let max_rss = u64::try_from(usage.ru_maxrss).unwrap_or(0);
    // Linux reports kilobytes, macOS bytes.
    let peak_bytes = if cfg!(target_os = "macos") { max_rss } else { max_rss * 1024 };
    Ok((ExitStatus::from_raw(status), peak_bytes))
}

/// Runs `exe args` in `cwd` with its output in `log` and returns what it cost; a failed run is
/// an error naming the command and the end of its output.
pub fn run_child(exe: &Path, args: &[OsString], cwd: &Path, log: &Path) -> Result<ChildCost, BenchError> {
    let out = std::fs::File::create(log).map_err(|e| BenchError::io(log, e))?;
    let err = out.try_clone().map_err(|e| BenchError::io(log, e))?;
    let command_line = || {
        std::iter::once(exe.display().to_string())
            .chain(args.iter().map(|a| a.to_string_lossy().into_owned()))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let start = Instant::now();
    let child = Command::new(exe)
        .args(args)
        .current_dir(cwd)
        .env_remove("RIG_CONFIG")
        .stdin(Stdio::null())
        .stdout(out)
        .stderr(err)
        .spawn()
        .map_err(|e| BenchError::io(exe, e))?;
    let (status, peak_bytes) = wait_with_peak(&child).map_err(|e| BenchError::io(exe, e))?;
    let wall_s = start.elapsed().as_secs_f64();
    if !status.success() {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        let tail: Vec<&str> = text.lines().rev().take(6).collect();
        return Err(BenchError::Child {
            command: command_line(),
            status: status.to_string(),
            output: tail.into_iter().rev().collect::<Vec<_>>().join("\n"),
        });
    }
    Ok(ChildCost { wall_s, peak_bytes })
}

fn os(parts: &[&dyn AsRef<std::ffi::OsStr>]) -> Vec<OsString> {
    parts.iter().map(|p| p.as_ref().to_os_string()).collect()
}

/// The `rig` the stages run: `config.rig_exe`, else this executable.
pub(super) fn rig_exe(config: &BenchConfig) -> Result<PathBuf, BenchError> {
    match &config.rig_exe {
        Some(exe) => Ok(exe.clone()),
        None => std::env::current_exe().map_err(|e| BenchError::io(Path::new("rig"), e)),
    }
}

/// Measures every stage at its three sizes (`config.scale_plan_poses` for the ordering,
/// `config.scale_frames` for the others) under `work_dir` (scratch).
pub fn measure(config: &BenchConfig, work_dir: &Path) -> Result<KnobReport, BenchError> {
    let exe = rig_exe(config)?;
    std::fs::create_dir_all(work_dir).map_err(|e| BenchError::io(work_dir, e))?;
    let work = work_dir.canonicalize().map_err(|e| BenchError::io(work_dir, e))?;
    let rig_toml = work.join("rig.toml");
    let px = config.scale_image_px;
    std::fs::write(
        &rig_toml,
        format!(
            "[arm]\nbackend = \"sim\"\nsim_time_scale = {SIM_TIME_SCALE:?}\n[collect]\nsettle_s = 0.0\n\
             [sensors.tactip]\nwidth = {px}\nheight = {px}\n"
        ),
    )
    .map_err(|e| BenchError::io(&rig_toml, e))?;
    let plan_toml = work.join("plan.toml");
    let plan_text = toml::to_string(&lab_scale_plan(1)).map_err(|e| BenchError::io(&plan_toml, std::io::Error::other(e)))?;
    std::fs::write(&plan_toml, plan_text).map_err(|e| BenchError::io(&plan_toml, e))?;
    let log = work.join("child.log");
    let collect = |n: usize, out: &Path| {
        os(&[&"collect", &"--config", &rig_toml, &"--plan", &plan_toml, &"--poses", &n.to_string(), &"--sensor", &"tactip", &"--out", &out])
    };

    let mut costs: Vec<(Stage, Vec<(usize, ChildCost)>)> = Stage::ALL.iter().filter(|s| s.built()).map(|&s| (s, Vec::new())).collect();
    let mut record = |stage: Stage, n: usize, cost: ChildCost| {
        if let Some((_, v)) = costs.iter_mut().find(|(s, _)| *s == stage) {
            v.push((n, cost));
        }
    };

    for &n in &config.scale_plan_poses {
        let mut args = collect(n, &work.join("dry-run"));
        args.push("--dry-run".into());
        record(Stage::Ordering, n, run_child(&exe, &args, &work, &log)?);
    }
    for &n in &config.scale_frames {
        let dir = work.join(format!("frames-{n}"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).map_err(|e| BenchError::io(&dir, e))?;
        let dataset = dir.join("collected").join("sphere").join("tactip");
        record(Stage::Collection, n, run_child(&exe, &collect(n, &dir.join("collected")), &work, &log)?);
        record(Stage::Verify, n, run_child(&exe, &os(&[&"dataset", &"verify", &dataset]), &work, &log)?);
        record(Stage::Merge, n, run_child(&exe, &os(&[&"dataset", &"merge", &"--out", &dir.join("merged"), &dataset]), &work, &log)?);
        if Stage::LerobotExport.built() {
            let args = os(&[&"dataset", &"export", &"--format", &"lerobot", &dataset, &"--out", &dir.join("lerobot")]);
            record(Stage::LerobotExport, n, run_child(&exe, &args, &work, &log)?);
        }
        // The recording of the same collection (not a row: the collection is measured above).
        let recording = dir.join("run.rec");
        let mut args = collect(n, &dir.join("recorded"));
        args.extend(os(&[&"--record", &recording]));
        run_child(&exe, &args, &work, &log)?;
        record(Stage::ReplayInfo, n, run_child(&exe, &os(&[&"replay", &recording, &"--info"]), &work, &log)?);
        record(Stage::Replay, n, run_child(&exe, &os(&[&"replay", &recording, &"--out", &dir.join("replayed")]), &work, &log)?);
        // Scratch only: a leftover folder is harmless, and the next size needs the disk.
        let _ = std::fs::remove_dir_all(&dir);
    }
    report(config, &costs)
}

/// The table, notes and plot of measured `costs`.
pub fn report(config: &BenchConfig, costs: &[(Stage, Vec<(usize, ChildCost)>)]) -> Result<KnobReport, BenchError> {
    const MB: f64 = 1024.0 * 1024.0;
    let mut rows = Vec::new();
    let mut series = Vec::new();
    for (stage, points) in costs {
        if points.len() != 3 {
            return Err(BenchError::Empty { knob: Knob::Scale, reason: "every stage needs three sizes" });
        }
        let time: Vec<(f64, f64)> = points.iter().map(|(n, c)| (*n as f64, c.wall_s)).collect();
        let memory: Vec<(f64, f64)> = points.iter().map(|(n, c)| (*n as f64, c.peak_bytes as f64)).collect();
        let (time_exponent, memory_exponent) = (growth_exponent(&time), growth_exponent(&memory));
        let (n3, last) = points[2];
        let mut values: Vec<f64> = points.iter().map(|(n, _)| *n as f64).collect();
        values.extend(points.iter().map(|(_, c)| c.wall_s));
        values.push(time_exponent);
        values.push(last.wall_s * 1e3 / n3 as f64);
        values.extend(points.iter().map(|(_, c)| c.peak_bytes as f64 / MB));
        values.push(memory_exponent);
        rows.push(Row { label: stage.label().to_string(), values });
        series.push(Series {
            name: stage.label().to_string(),
            points: time.iter().map(|(n, t)| [n.log10(), t.log10()]).collect(),
            labels: vec![String::new(), String::new(), format!("N^{time_exponent:.2}")],
        });
    }
    let sizes = |v: &[usize]| v.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(", ");
    Ok(KnobReport {
        knob: Knob::Scale,
        title: "Scale: what the work costs as it grows".into(),
        label_column: "stage".into(),
        columns: vec![
            Column::new("N1", 0),
            Column::new("N2", 0),
            Column::new("N3", 0),
            Column::new("wall N1 [s]", 2),
            Column::new("wall N2 [s]", 2),
            Column::new("wall N3 [s]", 2),
            Column::new("time exponent", 2),
            Column::new("ms per item at N3", 2),
            Column::new("peak N1 [MB]", 1),
            Column::new("peak N2 [MB]", 1),
            Column::new("peak N3 [MB]", 1),
            Column::new("memory exponent", 2),
        ],
        rows,
        notes: vec![
            format!(
                "Each stage is a `rig` command run as a child process at three sizes: the ordering at {} poses (`rig collect \
                 --dry-run`: sampling, ordering, the workspace and press checks, the pre-flight of the simulated rig), the others at {} frames (a collection on the simulated rig, \
                 one sensor, {px} x {px} px frames, its clock {SIM_TIME_SCALE}x real time and no settle time; `rig dataset verify`, \
                 `rig dataset merge --out NEW` and `rig dataset export --format lerobot` of that dataset; `rig replay --info` and \
                 `rig replay` of the same collection recorded with `rig collect --record`). The plan is a Latin hypercube on the \
                 100 x 100 x 10 x 10 grid of `plans/lab-scale.toml`.",
                sizes(&config.scale_plan_poses),
                sizes(&config.scale_frames),
                px = config.scale_image_px
            ),
            format!(
                "*wall* is the child's wall time; *peak* its own peak resident memory (`ru_maxrss` of `wait4`, the process's fixed \
             footprint of about 15-20 MB included; Linux counts it from the size of the process that started the child, so no \
             peak reads below the bench's own, {floor}); each *exponent* is the least-squares slope of ln(cost) against ln(N) over \
             the three sizes: 1 grows linearly, 0 is flat, 2 quadratic. *ms per item* is the wall time at N3 over N3 (per pose, \
             per frame). The plot shows log10 wall time against log10 N, each stage labelled with its time exponent.",
                floor = own_peak_bytes().map_or_else(|| "not reported here".to_string(), |b| format!("at most {:.1} MB", b as f64 / 1e6))
            ),
        ],
        plot: Plot {
            title: "Scale: wall time against size (log-log)".into(),
            x_label: "log10 N (poses or frames)".into(),
            y_label: "log10 wall time [s]".into(),
            series,
            lines: true,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exponents_of_known_growth() {
        let line: Vec<(f64, f64)> = [10.0, 100.0, 1000.0].iter().map(|&n| (n, 3.0 * n)).collect();
        assert!((growth_exponent(&line) - 1.0).abs() < 1e-12);
        let square: Vec<(f64, f64)> = [10.0, 20.0, 40.0].iter().map(|&n| (n, n * n)).collect();
        assert!((growth_exponent(&square) - 2.0).abs() < 1e-12);
        assert!(growth_exponent(&[(10.0, 5.0), (100.0, 5.0)]).abs() < 1e-12);
        assert!(growth_exponent(&[(10.0, 5.0)]).is_nan());
        assert!(growth_exponent(&[(10.0, 5.0), (10.0, 6.0)]).is_nan());
        assert!(growth_exponent(&[(10.0, 0.0), (20.0, -1.0), (40.0, f64::NAN)]).is_nan());
    }

    #[test]
    fn lab_scale_plan_is_the_file() {
        let file = PlanSpec::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("plans/lab-scale.toml")).expect("plans/lab-scale.toml");
        assert_eq!(PlanSpec { n_poses: Some(1), ..file }, lab_scale_plan(1));
        assert_eq!(lab_scale_plan(1).axis_counts(), [100, 100, 10, 10]);
    }

    /// A child's peak memory is its own: a child that builds a string far larger than this test
    /// process reports at least that, and a small child after it reports much less
    /// (`RUSAGE_CHILDREN` would report the large one again), though never less than this
    /// process's own size (the floor the report states). A failed child is an error with the
    /// end of its output.
    #[test]
    fn a_childs_peak_is_its_own() {
        let dir = tempfile::tempdir().expect("tempdir");
        let log = dir.path().join("log");
        let awk = Path::new("awk");
        let floor = own_peak_bytes().expect("VmHWM in /proc/self/status");
        // A string of 2^k bytes, at least 64 MiB and four times this process's peak.
        let doublings = (floor.max(16 << 20) * 4).next_power_of_two().trailing_zeros();
        let program = format!("BEGIN {{ s = \"x\"; for (i = 0; i < {doublings}; i++) s = s s; print length(s) }}");
        let big = run_child(awk, &os(&[&program]), dir.path(), &log).expect("big child");
        assert_eq!(std::fs::read_to_string(&log).expect("log").trim(), (1u64 << doublings).to_string());
        let small = run_child(awk, &os(&[&"BEGIN { print 1 }"]), dir.path(), &log).expect("small child");
        assert!(big.peak_bytes >= 1 << doublings, "{big:?}");
        let floor_now = own_peak_bytes().expect("VmHWM");
        assert!(
            small.peak_bytes <= floor_now + (16 << 20) && small.peak_bytes < big.peak_bytes / 2,
            "{small:?} after {big:?}, this process {floor_now} bytes"
        );
        let failed = run_child(awk, &os(&[&"BEGIN { print \"no luck\"; exit 3 }"]), dir.path(), &log);
        assert!(matches!(failed, Err(BenchError::Child { ref output, .. }) if output.contains("no luck")), "{failed:?}");
    }
}
