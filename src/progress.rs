//! Progress of the long jobs (collect, fill, audit) on standard error, wherever it goes.
//!
//! A job counts its poses into an [`indicatif::ProgressBar`] (the [`crate::jobs::Observer`]'s;
//! the daemon reads the same counter for its status) and names what it works on with the
//! bar's prefix ([`dataset_name`]: `object/sensor`). How that count is shown depends on where
//! standard error goes ([`Mode::for_stderr`]):
//!
//! - **a terminal** ([`Mode::Bar`]): the bar itself, drawn by indicatif, one per dataset, e.g.
//!   `sphere/tactip [#######-----------------------] 12/85 poses  2.1 s/pose  eta 2 min 33 s`;
//!   before the job knows its count it reads `starting`, never a full bar at `0/0`;
//! - **anything else** ([`Mode::Lines`]: a file, a pipe, a SLURM log, `nohup`, CI): nothing is
//!   drawn; a thread prints one plain line per interval ([`DEFAULT_INTERVAL`], or
//!   [`INTERVAL_ENV`] seconds), `sphere/tactip: 12/85 poses, 2.1 s/pose, eta 2 min 33 s`, so a
//!   log stays short and shows that the job is alive.
//!
//! Rates read `poses/s` from one a second up and `s/pose` below it, with one decimal; times
//! read `45 s`, `2 min 33 s`, `1 h 05 min`. The plain line's rate is [`Tracker`]'s: the poses
//! done since the dataset began (its prefix or count changed, or its count went back) over the
//! time since, with the time passed in, so tests drive it with any clock.

use std::io::IsTerminal;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle};

/// The plain lines' interval when [`INTERVAL_ENV`] does not set one.
pub const DEFAULT_INTERVAL: Duration = Duration::from_secs(10);
/// The environment variable that sets the plain lines' interval, in seconds (decimals allowed).
pub const INTERVAL_ENV: &str = "RIG_PROGRESS_INTERVAL_S";
/// The shortest and longest interval [`INTERVAL_ENV`] may set, s.
pub const INTERVAL_BOUNDS_S: (f64, f64) = (0.01, 3600.0);

/// [`INTERVAL_ENV`] holds something other than a number of seconds within [`INTERVAL_BOUNDS_S`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("${INTERVAL_ENV} = {value:?}: the progress interval must be a number of seconds from {} to {}", INTERVAL_BOUNDS_S.0, INTERVAL_BOUNDS_S.1)]
pub struct BadInterval {
    pub value: String,
}

/// How progress is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// An indicatif bar on standard error (a terminal).
    Bar,
    /// One plain line on standard error every `interval` (not a terminal).
    Lines { interval: Duration },
}

impl Mode {
    /// [`Mode::Bar`] when standard error is a terminal, else [`Mode::Lines`] at the interval
    /// [`INTERVAL_ENV`] sets (else [`DEFAULT_INTERVAL`]).
    pub fn for_stderr() -> Result<Mode, BadInterval> {
        let interval = interval_from(std::env::var(INTERVAL_ENV).ok().as_deref())?;
        Ok(if std::io::stderr().is_terminal() { Mode::Bar } else { Mode::Lines { interval } })
    }
}

/// The interval a value of [`INTERVAL_ENV`] sets (`None`: not set, [`DEFAULT_INTERVAL`]).
pub fn interval_from(value: Option<&str>) -> Result<Duration, BadInterval> {
    let Some(value) = value else { return Ok(DEFAULT_INTERVAL) };
    let (lo, hi) = INTERVAL_BOUNDS_S;
    match value.trim().parse::<f64>() {
        Ok(s) if s.is_finite() && (lo..=hi).contains(&s) => Ok(Duration::from_secs_f64(s)),
        _ => Err(BadInterval { value: value.to_string() }),
    }
}

/// The name a progress line gives a dataset folder `.../<object>/<sensor>`: `object/sensor`
/// (the folder's own name when it has no parent).
pub fn dataset_name(dir: &std::path::Path) -> String {
    let mut parts = dir.components().rev().filter_map(|c| match c {
        std::path::Component::Normal(s) => Some(s.to_string_lossy().into_owned()),
        _ => None,
    });
    match (parts.next(), parts.next()) {
        (Some(sensor), Some(object)) => format!("{object}/{sensor}"),
        (Some(only), None) => only,
        _ => dir.display().to_string(),
    }
}

/// The name a collection's progress gives its datasets: `object/sensor`, or
/// `object/tactip+vitac+vitactip` when it captures several sensors at each pose.
pub fn collection_name(object: &str, sensors: &crate::sensor::SensorSet) -> String {
    let names: Vec<&str> = sensors.0.iter().map(|k| k.name()).collect();
    format!("{object}/{}", names.join("+"))
}

/// A rate of `per_s` poses a second, as a person reads it: `3.2 poses/s` from one a second up,
/// `2.1 s/pose` below; `-` when there is none yet.
pub fn format_rate(per_s: f64) -> String {
    if !(per_s.is_finite() && per_s > 0.0) {
        "-".to_string()
    } else if per_s >= 1.0 {
        format!("{per_s:.1} poses/s")
    } else {
        format!("{:.1} s/pose", 1.0 / per_s)
    }
}

/// A duration of `s` seconds: `45 s`, `2 min 33 s`, `1 h 05 min`.
pub fn format_duration(s: f64) -> String {
    if !(s.is_finite() && s >= 0.0) {
        return "-".to_string();
    }
    let whole = s.round() as u64;
    if whole < 60 {
        format!("{whole} s")
    } else if whole < 3600 {
        format!("{} min {:02} s", whole / 60, whole % 60)
    } else {
        format!("{} h {:02} min", whole / 3600, whole / 60 % 60)
    }
}

/// What one look at a progress counter saw.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Seen {
    /// What the job works on (the bar's prefix; may be empty).
    pub name: String,
    pub done: u64,
    /// `None` or 0: not known yet.
    pub total: Option<u64>,
}

/// The plain progress lines: where the current dataset began, and the line for each look.
#[derive(Debug, Clone, Default)]
pub struct Tracker {
    /// (name, total, time s, done) when the current dataset was first seen.
    origin: Option<(String, u64, f64, u64)>,
    /// The count seen last: one lower than it is a new start.
    last_done: u64,
}

impl Tracker {
    /// The line for what was `seen` at `now_s` (any clock, in seconds); `None` while the count
    /// is not known. A new name or total, or a count that went back, starts a new dataset: its
    /// rate counts from there.
    pub fn line(&mut self, now_s: f64, seen: &Seen) -> Option<String> {
        let total = seen.total.filter(|&t| t > 0)?;
        let same = self.origin.as_ref().is_some_and(|(name, t, _, _)| *name == seen.name && *t == total) && seen.done >= self.last_done;
        self.last_done = seen.done;
        if !same {
            self.origin = Some((seen.name.clone(), total, now_s, seen.done));
        }
        let (_, _, t0, done0) = self.origin.as_ref()?;
        let name = if seen.name.is_empty() { String::new() } else { format!("{}: ", seen.name) };
        let count = format!("{name}{}/{total} poses", seen.done.min(total));
        let (elapsed_s, gained) = (now_s - t0, seen.done.saturating_sub(*done0));
        if gained == 0 || elapsed_s <= 0.0 {
            return Some(format!("{count}, starting"));
        }
        let per_s = gained as f64 / elapsed_s;
        let left = total.saturating_sub(seen.done);
        Some(format!("{count}, {}, eta {}", format_rate(per_s), format_duration(left as f64 / per_s)))
    }
}

/// A job's progress display: the bar the job counts into, and in [`Mode::Lines`] the thread
/// that prints its lines. Dropping it (or [`Progress::finish`]) clears the bar and stops the
/// thread.
pub struct Progress {
    bar: ProgressBar,
    lines: Option<(Arc<AtomicBool>, JoinHandle<()>)>,
}

impl Progress {
    /// A display of poses in `mode`, counting into a new bar (the job sets its prefix and length).
    pub fn new(mode: Mode) -> Progress {
        match mode {
            Mode::Bar => {
                let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
                bar.set_style(bar_style());
                Progress { bar, lines: None }
            }
            Mode::Lines { interval } => {
                let bar = ProgressBar::hidden();
                let stop = Arc::new(AtomicBool::new(false));
                let thread = {
                    let (bar, stop) = (bar.clone(), Arc::clone(&stop));
                    std::thread::spawn(move || print_lines(&bar, &stop, interval))
                };
                Progress { bar, lines: Some((stop, thread)) }
            }
        }
    }

    /// [`Progress::new`] in the mode standard error calls for ([`Mode::for_stderr`]).
    pub fn for_stderr() -> Result<Progress, BadInterval> {
        Ok(Progress::new(Mode::for_stderr()?))
    }

    /// The bar a job counts into (give a clone to the job's observer).
    pub fn bar(&self) -> &ProgressBar {
        &self.bar
    }

    /// Runs `f` (which prints) without the bar drawn over its output.
    pub fn suspend<R>(&self, f: impl FnOnce() -> R) -> R {
        self.bar.suspend(f)
    }

    /// Clears the bar and stops the lines.
    pub fn finish(self) {}
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
        if let Some((stop, thread)) = self.lines.take() {
            stop.store(true, Ordering::Relaxed);
            thread.thread().unpark();
            let _ = thread.join();
        }
    }
}

/// Prints a line every `interval` until `stop`.
fn print_lines(bar: &ProgressBar, stop: &AtomicBool, interval: Duration) {
    let start = Instant::now();
    let mut tracker = Tracker::default();
    let mut next = start + interval;
    // The dataset's start is seen as soon as it happens, so its rate counts from there.
    let look = interval.min(Duration::from_millis(200));
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        let seen = Seen { name: bar.prefix(), done: bar.position(), total: bar.length() };
        let line = tracker.line(now.duration_since(start).as_secs_f64(), &seen);
        if now >= next {
            if let Some(line) = line {
                eprintln!("{line}");
            }
            next = now + interval;
        }
        std::thread::park_timeout(look.min(next.saturating_duration_since(now)).max(Duration::from_millis(1)));
    }
}

/// The terminal bar: named, with a rate and ETA a person reads, and `starting` (an empty bar)
/// until the count is known.
fn bar_style() -> ProgressStyle {
    let known = |state: &ProgressState| state.len().filter(|&l| l > 0);
    ProgressStyle::with_template("{prefix} [{gauge}] {count}  {rate}  {eta_text}")
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .with_key("gauge", move |state: &ProgressState, w: &mut dyn std::fmt::Write| {
            const WIDTH: u64 = 30;
            let filled = known(state).map_or(0, |len| (WIDTH * state.pos().min(len)) / len);
            let _ = write!(w, "{}{}", "#".repeat(filled as usize), "-".repeat((WIDTH - filled) as usize));
        })
        .with_key("count", move |state: &ProgressState, w: &mut dyn std::fmt::Write| {
            let _ = match known(state) {
                Some(len) => write!(w, "{}/{len} poses", state.pos()),
                None => write!(w, "starting"),
            };
        })
        .with_key("rate", move |state: &ProgressState, w: &mut dyn std::fmt::Write| {
            if known(state).is_some() && state.pos() > 0 {
                let _ = write!(w, "{}", format_rate(state.per_sec()));
            }
        })
        .with_key("eta_text", move |state: &ProgressState, w: &mut dyn std::fmt::Write| {
            if known(state).is_some() && state.pos() > 0 {
                let _ = write!(w, "eta {}", format_duration(state.eta().as_secs_f64()));
            }
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seen(name: &str, done: u64, total: u64) -> Seen {
        Seen { name: name.into(), done, total: Some(total) }
    }

    #[test]
    fn rates_and_times_read_as_a_person_reads_them() {
        assert_eq!(format_rate(12.4487), "12.4 poses/s");
        assert_eq!(format_rate(1.0), "1.0 poses/s");
        assert_eq!(format_rate(0.48), "2.1 s/pose");
        assert_eq!(format_rate(0.0), "-");
        assert_eq!(format_rate(f64::NAN), "-");
        assert_eq!(format_duration(44.6), "45 s");
        assert_eq!(format_duration(153.0), "2 min 33 s");
        assert_eq!(format_duration(3900.0), "1 h 05 min");
        assert_eq!(format_duration(f64::INFINITY), "-");
    }

    #[test]
    fn the_tracker_counts_each_dataset_from_its_own_start() {
        let mut t = Tracker::default();
        assert_eq!(t.line(0.0, &Seen { name: "sphere/tactip".into(), done: 0, total: None }), None, "count not known yet");
        assert_eq!(t.line(0.0, &seen("sphere/tactip", 0, 0)), None, "a count of 0 is not known either");
        assert_eq!(t.line(1.0, &seen("sphere/tactip", 0, 85)).as_deref(), Some("sphere/tactip: 0/85 poses, starting"));
        // 10 poses in 20 s: 2.0 s/pose, 75 left: 150 s.
        assert_eq!(t.line(21.0, &seen("sphere/tactip", 10, 85)).as_deref(), Some("sphere/tactip: 10/85 poses, 2.0 s/pose, eta 2 min 30 s"));
        // The next dataset starts its own rate, even at the same count.
        assert_eq!(t.line(22.0, &seen("sphere/vitac", 0, 85)).as_deref(), Some("sphere/vitac: 0/85 poses, starting"));
        assert_eq!(t.line(32.0, &seen("sphere/vitac", 40, 85)).as_deref(), Some("sphere/vitac: 40/85 poses, 4.0 poses/s, eta 11 s"));
        // A count that goes back (a bar reset under the same name) starts again too.
        assert_eq!(t.line(33.0, &seen("sphere/vitac", 5, 85)).as_deref(), Some("sphere/vitac: 5/85 poses, starting"));
        // A resumed collection starts part way: its rate counts only what this run did.
        let mut t = Tracker::default();
        t.line(0.0, &seen("", 30, 50));
        assert_eq!(t.line(10.0, &seen("", 40, 50)).as_deref(), Some("40/50 poses, 1.0 poses/s, eta 10 s"));
    }

    #[test]
    fn the_interval_comes_from_the_environment_within_bounds() {
        assert_eq!(interval_from(None), Ok(DEFAULT_INTERVAL));
        assert_eq!(interval_from(Some("2.5")), Ok(Duration::from_millis(2500)));
        assert_eq!(interval_from(Some(" 60 ")), Ok(Duration::from_secs(60)));
        for bad in ["", "ten", "0", "-1", "NaN", "inf", "1e9"] {
            assert!(interval_from(Some(bad)).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn a_dataset_is_named_by_object_and_sensor() {
        assert_eq!(dataset_name(std::path::Path::new("datasets/sphere/tactip")), "sphere/tactip");
        assert_eq!(dataset_name(std::path::Path::new("/tmp/x/out/edge/vitac/")), "edge/vitac");
        assert_eq!(dataset_name(std::path::Path::new("tactip")), "tactip");
    }

    /// A terminal that keeps what was drawn last.
    #[derive(Debug, Default, Clone)]
    struct Screen(Arc<std::sync::Mutex<String>>);

    impl indicatif::TermLike for Screen {
        fn width(&self) -> u16 {
            120
        }
        fn move_cursor_up(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn move_cursor_down(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn move_cursor_right(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn move_cursor_left(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn write_line(&self, s: &str) -> std::io::Result<()> {
            self.write_str(s)
        }
        fn write_str(&self, s: &str) -> std::io::Result<()> {
            if !s.trim().is_empty() {
                *self.0.lock().expect("screen") = s.to_string();
            }
            Ok(())
        }
        fn clear_line(&self) -> std::io::Result<()> {
            Ok(())
        }
        fn flush(&self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn the_terminal_bar_is_named_and_says_starting_until_the_count_is_known() {
        let screen = Screen::default();
        let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::term_like(Box::new(screen.clone())));
        bar.set_style(bar_style());
        bar.set_prefix("sphere/tactip");
        bar.set_length(0);
        bar.tick();
        let shown = screen.0.lock().expect("screen").clone();
        assert_eq!(shown.trim_end(), format!("sphere/tactip [{}] starting", "-".repeat(30)), "not a full bar at 0/0");
        bar.set_length(85);
        bar.set_position(17);
        bar.tick();
        let shown = screen.0.lock().expect("screen").clone();
        assert!(shown.starts_with(&format!("sphere/tactip [{}{}] 17/85 poses", "#".repeat(6), "-".repeat(24))), "{shown}");
    }
}
