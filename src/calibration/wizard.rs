//! The interactive calibration wizard (`rig calibrate --interactive`).
//!
//! The flow: say what to mount and where, wait for the user, ask for the extra press depths
//! (when the pattern presses at depths: the depth term of the calibration needs at least two),
//! take the no-contact reference, then for each offset of the pattern press, show the detection and ask accept / redo / skip
//! / quit; fit the accepted points, show the mapping and residuals, and ask before saving.
//! It is written against [`WizardIo`] (print a line, ask a question) and
//! [`PressStation`], so tests drive it with scripted answers and a fake station, and the binary
//! drives it with the terminal and the real (or simulated) rig.

use super::FitPoint;
use super::fit::{FitOptions, PointFit, fit_points};
use super::press::{Press, PressError, PressPattern, PressStation};

/// The wizard's terminal.
pub trait WizardIo {
    /// Shows a line of text.
    fn say(&mut self, line: &str) -> std::io::Result<()>;
    /// Asks a question; `None` when the input has ended.
    fn ask(&mut self, question: &str) -> std::io::Result<Option<String>>;
}

/// Errors that end the wizard.
#[derive(Debug, thiserror::Error)]
pub enum WizardError {
    #[error("terminal: {0}")]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Press(#[from] PressError),
}

/// How the wizard ended.
#[derive(Debug, Clone)]
pub enum WizardOutcome {
    /// Fitted and the user agreed to save.
    Save(Box<PointFit>),
    /// Fitted, but the user declined to save.
    Discarded(Box<PointFit>),
    /// The user quit (or the input ended) before a fit.
    Quit,
    /// The accepted points could not be fitted; the reason was shown.
    Unfitted,
}

/// Largest extra indentation the wizard accepts, mm (either way): further up the indenter
/// may not touch the skin at all, further down presses harder than the pattern was checked for.
pub const MAX_EXTRA_DEPTH_MM: f64 = 1.0;

/// Parses the answer to the depth question: empty keeps `current`, `0`/`none` presses only at
/// the contact depth, otherwise comma- or space-separated mm within
/// ±[`MAX_EXTRA_DEPTH_MM`]. `Err` holds the text to show.
fn parse_depths(text: &str, current: &[f64]) -> Result<Vec<f64>, String> {
    let t = text.trim();
    if t.is_empty() {
        return Ok(current.to_vec());
    }
    if t.eq_ignore_ascii_case("none") {
        return Ok(Vec::new());
    }
    let mut depths = Vec::new();
    for part in t.split([',', ' ']).filter(|p| !p.trim().is_empty()) {
        let v: f64 = part.trim().parse().map_err(|_| format!("{part:?} is not a number of mm"))?;
        if !v.is_finite() || v.abs() > MAX_EXTRA_DEPTH_MM {
            return Err(format!("{v} mm is beyond ±{MAX_EXTRA_DEPTH_MM} mm"));
        }
        if v != 0.0 && !depths.contains(&v) {
            depths.push(v);
        }
    }
    Ok(depths)
}

fn format_depths(depths: &[f64]) -> String {
    if depths.is_empty() { "none".to_string() } else { depths.iter().map(|d| format!("{d:+}")).collect::<Vec<_>>().join(",") }
}

/// What the user said about a press.
enum Answer {
    Accept,
    Redo,
    Skip,
    Quit,
}

fn answer(text: Option<String>, detected: bool) -> Answer {
    match text.as_deref().map(str::trim).map(str::to_ascii_lowercase).as_deref() {
        None | Some("q") | Some("quit") => Answer::Quit,
        Some("" | "a" | "y" | "accept") if detected => Answer::Accept,
        Some("r" | "redo") => Answer::Redo,
        Some("s" | "skip") => Answer::Skip,
        // An empty answer to a failed press means "redo", anything unknown too.
        _ => Answer::Redo,
    }
}

/// Runs the wizard. `what` names the sensor and `save_to` where it would be saved (shown only).
pub async fn run_wizard<S: PressStation, I: WizardIo>(
    io: &mut I,
    station: &mut S,
    pattern: &PressPattern,
    fit_options: &FitOptions,
    what: &str,
    save_to: &str,
) -> Result<WizardOutcome, WizardError> {
    io.say(&format!("Calibrating {what}: pixel-to-mm mapping from {} presses.", pattern.offsets.len()))?;
    io.say("Mount the calibration indenter (an 8 mm radius sphere) on the plinth at the work-frame origin,")?;
    io.say("directly under the sensor centre, and keep the sensor skin clean and unpressed.")?;
    if matches!(answer(io.ask("Press Enter when it is mounted (q to quit): ")?, true), Answer::Quit) {
        return Ok(WizardOutcome::Quit);
    }
    let mut owned = None;
    let current = pattern.extra_depths_mm();
    if !current.is_empty() {
        io.say("The scale can change with how deep the skin is pressed; presses at other depths measure that.")?;
        let question = format!("Extra press depths beyond the contact, mm (comma-separated, 0 = none) [{}]: ", format_depths(&current));
        loop {
            let Some(text) = io.ask(&question)? else {
                return Ok(WizardOutcome::Quit);
            };
            if matches!(text.trim(), "q" | "quit") {
                return Ok(WizardOutcome::Quit);
            }
            match parse_depths(&text, &current) {
                Ok(depths) => {
                    let p = pattern.with_extra_depths(&depths);
                    io.say(&format!("Pressing at extra depths {} mm: {} presses.", format_depths(&depths), p.offsets.len()))?;
                    if depths.len() < 2 {
                        io.say("(Fewer than two extra depths: the depth term may be left at 0.)")?;
                    }
                    owned = Some(p);
                    break;
                }
                Err(why) => io.say(&format!("      {why}; again"))?,
            }
        }
    }
    let pattern = owned.as_ref().unwrap_or(pattern);
    // The depths may have changed: the pattern as it will be pressed passes the fence first.
    station.check_pattern(pattern)?;
    io.say("Taking the no-contact reference frame above the indenter...")?;
    station.take_reference().await?;
    let mut points: Vec<FitPoint> = Vec::new();
    let n = pattern.offsets.len();
    let mut k = 0;
    while k < n {
        let offset = pattern.offsets[k];
        io.say(&format!(
            "[{}/{n}] pressing at x {:+.2} mm, y {:+.2} mm, extra depth {:+.2} mm",
            k + 1,
            offset.x_mm,
            offset.y_mm,
            offset.z_mm
        ))?;
        let press: Press = station.press(offset).await?;
        let detected = press.contact.is_ok();
        let question = match &press.contact {
            Ok(c) => {
                io.say(&format!("      {c}"))?;
                "      Enter/a = accept, r = redo, s = skip, q = quit: "
            }
            Err(e) => {
                io.say(&format!("      no detection: {e}"))?;
                "      r = redo, s = skip, q = quit: "
            }
        };
        match answer(io.ask(question)?, detected) {
            Answer::Accept => {
                if let Some(p) = press.point() {
                    points.push(p);
                }
                k += 1;
            }
            Answer::Skip => {
                io.say("      skipped")?;
                k += 1;
            }
            Answer::Redo => io.say("      again")?,
            Answer::Quit => {
                station.finish().await?;
                io.say("Quit: nothing saved.")?;
                return Ok(WizardOutcome::Quit);
            }
        }
    }
    station.finish().await?;
    io.say(&format!("Fitting {} accepted points...", points.len()))?;
    let fit = match fit_points(&points, fit_options, "indenter-wizard") {
        Ok(f) => f,
        Err(e) => {
            io.say(&format!("Cannot fit: {e}. Nothing saved."))?;
            return Ok(WizardOutcome::Unfitted);
        }
    };
    for line in describe_fit(&fit) {
        io.say(&line)?;
    }
    let yes = io.ask(&format!("Save to {save_to}? [y/N]: "))?;
    if matches!(yes.as_deref().map(str::trim), Some("y" | "Y" | "yes")) {
        Ok(WizardOutcome::Save(Box::new(fit)))
    } else {
        io.say("Not saved.")?;
        Ok(WizardOutcome::Discarded(Box::new(fit)))
    }
}

/// Human-readable lines about a fit: the mapping, conditioning, outliers and the residual
/// (the last line is [`PointFit::residual_line`]).
pub fn describe_fit(fit: &PointFit) -> Vec<String> {
    let c = &fit.calibration;
    let outliers: Vec<String> =
        fit.inlier.iter().enumerate().filter(|(_, k)| !**k).map(|(i, _)| format!("{i} ({:.1} px)", fit.residuals_px[i])).collect();
    vec![
        format!("centre      ({:.2}, {:.2}) px", c.centre_px[0], c.centre_px[1]),
        format!("scale       x {:.3} px/mm, y {:.3} px/mm", c.scale_px_per_mm[0], c.scale_px_per_mm[1]),
        format!("rotation    {:.3} deg", c.rotation_deg),
        format!("depth term  {}", fit.depth),
        format!(
            "points      {} ({} inliers), condition {:.2}, affine shear {:.4}, max residual {:.2} px",
            fit.inlier.len(),
            fit.inlier.iter().filter(|k| **k).count(),
            fit.condition,
            fit.shear,
            fit.max_px
        ),
        format!("outliers    {}", if outliers.is_empty() { "none".to_string() } else { outliers.join(", ") }),
        fit.residual_line(),
    ]
}

/// [`WizardIo`] over a line-oriented reader and writer (stdin and stdout in the binary).
pub struct LineIo<R, W> {
    pub input: R,
    pub output: W,
}

impl<R: std::io::BufRead, W: std::io::Write> WizardIo for LineIo<R, W> {
    fn say(&mut self, line: &str) -> std::io::Result<()> {
        writeln!(self.output, "{line}")?;
        self.output.flush()
    }
    fn ask(&mut self, question: &str) -> std::io::Result<Option<String>> {
        write!(self.output, "{question}")?;
        self.output.flush()?;
        let mut line = String::new();
        if self.input.read_line(&mut line)? == 0 {
            return Ok(None);
        }
        Ok(Some(line.trim_end_matches(['\r', '\n']).to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::Calibration;
    use crate::calibration::detect::{Contact, DetectError};
    use crate::pose::Pose;

    /// A station whose detections follow a known calibration exactly, except that the first
    /// press at one offset sees nothing.
    struct FakeStation {
        truth: Calibration,
        presses: usize,
        finished: bool,
        /// The pattern was handed to the fence before anything moved.
        checked: bool,
        /// The index of the press the stand-in fence refused.
        refused: Option<usize>,
    }

    impl PressStation for FakeStation {
        fn check_pattern(&mut self, pattern: &PressPattern) -> Result<(), PressError> {
            // A stand-in fence: nothing deeper than 0.5 mm past the contact depth.
            if let Some((k, o)) = pattern.offsets.iter().enumerate().find(|(_, o)| o.z_mm > 0.5) {
                self.refused = Some(k);
                let limit =
                    crate::config::PressLimit { sensor: crate::sensor::SensorKind::TacTip, max_indentation_mm: 2.0, configured: true };
                return Err(PressError::Fence(crate::fence::FenceError::TooDeep {
                    poses: crate::fence::PoseSource::Presses,
                    pose_id: k as u32,
                    plan_pose: *o,
                    indentation_mm: 1.5 + o.z_mm,
                    contact_depth_mm: 1.5,
                    limit,
                }));
            }
            self.checked = true;
            Ok(())
        }
        async fn take_reference(&mut self) -> Result<(), PressError> {
            Ok(())
        }
        async fn press(&mut self, offset: Pose) -> Result<Press, PressError> {
            self.presses += 1;
            let p = super::super::press::sensor_point_mm(&offset);
            let (u, v) = self.truth.mm_to_px(p[0], p[1]);
            let contact = if self.presses == 2 {
                Err(DetectError::NoContact { peak: 1.0, floor: 0.5, contrast: 3.0 })
            } else {
                Ok(Contact { centroid_px: [u, v], area_px: 100, peak: 50.0, floor: 1.0, moved_markers: None, outline_radius_px: None })
            };
            Ok(Press { offset, measured: offset, depth_mm: 1.5 + offset.z_mm, contact })
        }
        async fn finish(&mut self) -> Result<(), PressError> {
            self.finished = true;
            Ok(())
        }
    }

    fn run(script: &str) -> (WizardOutcome, String, FakeStation) {
        let truth = Calibration { rotation_deg: 4.0, scale_px_per_mm: [9.0, 8.0], ..Calibration::default_for(512, 512) };
        let mut station = FakeStation { truth, presses: 0, finished: false, checked: false, refused: None };
        let mut io = LineIo { input: script.as_bytes(), output: Vec::new() };
        let pattern = PressPattern::grid(2, 3.0, &[]);
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        let outcome = rt.block_on(run_wizard(&mut io, &mut station, &pattern, &FitOptions::default(), "test", "out.toml")).unwrap();
        (outcome, String::from_utf8_lossy(&io.output).into_owned(), station)
    }

    #[test]
    fn redo_skip_and_save() {
        // Mounted; offset 1 accepted; offset 2's first press sees nothing -> redo, then
        // accepted; offsets 3 and 4 accepted; save.
        let (outcome, text, station) = run("\n\nr\n\na\n\ny\n");
        assert!(station.finished && station.checked);
        assert_eq!(station.presses, 5, "{text}");
        let WizardOutcome::Save(fit) = outcome else { panic!("{text}") };
        assert_eq!(fit.inlier.len(), 4);
        assert!((fit.calibration.rotation_deg - 4.0).abs() < 1e-6);
        assert!(text.contains("no detection"), "{text}");
        assert!(text.lines().any(|l| l.starts_with("residual ")), "{text}");
    }

    #[test]
    fn asks_for_the_depths_when_the_pattern_presses_at_depths() {
        let truth = Calibration { scale_px_per_mm: [9.0, 8.0], ..Calibration::default_for(512, 512) };
        let mut station = FakeStation { truth, presses: 0, finished: false, checked: false, refused: None };
        // Mounted; a bad answer, then one depth; 4 + 9 presses (the second sees nothing: redo).
        let script = "\n2.5\n0.5\n\nr\n\n\n\n\n\n\n\n\n\n\n\n\ny\n";
        let mut io = LineIo { input: script.as_bytes(), output: Vec::new() };
        let pattern = PressPattern::grid(2, 3.0, &[-0.5, 0.5]);
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        let outcome = rt.block_on(run_wizard(&mut io, &mut station, &pattern, &FitOptions::default(), "test", "out.toml")).unwrap();
        let text = String::from_utf8_lossy(&io.output).into_owned();
        assert!(text.contains("[-0.5,+0.5]: "), "{text}");
        assert!(text.contains("beyond ±1 mm; again"), "{text}");
        assert!(text.contains("extra depths +0.5 mm: 13 presses"), "{text}");
        assert!(text.contains("[13/13] pressing at x -3.00 mm, y +0.00 mm, extra depth +0.50 mm"), "{text}");
        let WizardOutcome::Save(fit) = outcome else { panic!("{text}") };
        assert_eq!(fit.inlier.len(), 13);
        assert_eq!(parse_depths("", &[0.5]), Ok(vec![0.5]));
        assert_eq!(parse_depths("none", &[0.5]), Ok(vec![]));
        assert_eq!(parse_depths("-0.5, 0.5 0", &[]), Ok(vec![-0.5, 0.5]));
        assert!(parse_depths("x", &[]).is_err() && parse_depths("nan", &[]).is_err());
    }

    /// The depths the user answers change the pattern: the new pattern passes the fence before
    /// the reference frame is taken, and a refused one ends the wizard with nothing pressed.
    #[test]
    fn the_pattern_after_the_depth_question_passes_the_fence_before_anything_moves() {
        let truth = Calibration::default_for(512, 512);
        let mut station = FakeStation { truth, presses: 0, finished: false, checked: false, refused: None };
        let mut io = LineIo { input: "\n1.0\n".as_bytes(), output: Vec::new() };
        let pattern = PressPattern::grid(2, 3.0, &[-0.5, 0.5]);
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        let e = rt.block_on(run_wizard(&mut io, &mut station, &pattern, &FitOptions::default(), "test", "out.toml")).unwrap_err();
        let text = String::from_utf8_lossy(&io.output).into_owned();
        assert!(e.to_string().contains("calibration press 5") && e.to_string().contains("press limit of 2 mm"), "{e}");
        assert_eq!((station.refused, station.presses, station.checked), (Some(4), 0, false), "{text}");
        assert!(!text.contains("Taking the no-contact reference"), "{text}");
    }

    #[test]
    fn skipping_to_too_few_points_is_refused_and_quit_saves_nothing() {
        let (outcome, text, _) = run("\n\nr\ns\ns\ns\n");
        assert!(matches!(outcome, WizardOutcome::Unfitted), "{text}");
        assert!(text.contains("Cannot fit"), "{text}");
        let (outcome, _, station) = run("\n\nq\n");
        assert!(matches!(outcome, WizardOutcome::Quit));
        assert!(station.finished);
        let (outcome, _, _) = run("\n\nr\n\n\n\nn\n");
        assert!(matches!(outcome, WizardOutcome::Discarded(_)));
    }
}
