//! An adaptive collection's choices: `adaptive.csv`, every pose `rig collect --adaptive` chose
//! to press, round by round, with the terms that chose it. The manifest's `[adaptive]` holds
//! the collection's settings; this file holds what grows with the budget, so a collection of
//! any budget its plan allows keeps its manifest small.
//!
//! ```text
//! pose_id,round,reason,distance,spread,error,score
//! 25,1,space-filling,inf,,,
//! 0,1,space-filling,1.2247448713915889,,,
//! 48,2,acquisition,1.2247448713915889,0.9718,1,0.9906
//! ```
//!
//! Rows come in the order chosen: round 1's, then round 2's, and so on, each round whole.
//! `distance` is `inf` for the first pose of a collection (nothing was near it); `spread`,
//! `error` and `score` are empty in round 1 (space-filling) and present in every later round
//! (acquisition). A pose appears once.
//!
//! The file is written whole through [`write_atomic`] before the first press of each round
//! (under the dataset writer's lock): a kill leaves the rounds recorded before or after the
//! new one, never part of a round. It is read through the dataset opener (no symlink, a
//! regular file, at most [`MAX_CHOICES_BYTES`]) and parsed without panicking on any bytes;
//! whether its poses are the plan's and its rounds the settings' is checked by who resumes
//! ([`crate::plan::adaptive::AdaptiveRecord::check_choices`]).

use std::path::Path;

use super::DatasetError;
use super::durable::{Kind, entry_exists, read_below, write_atomic};
use crate::plan::MAX_GRID_POINTS;
use crate::plan::adaptive::{AdaptiveChoice, ChoiceReason};

/// The file's name in a dataset folder.
pub const CHOICES_FILE: &str = "adaptive.csv";
/// Its header line.
pub const CHOICES_HEADER: &str = "pose_id,round,reason,distance,spread,error,score";
/// Largest line read: a pose id, a round, a reason and four numbers of at most 24 characters.
const MAX_LINE_BYTES: u64 = 160;
/// Largest `adaptive.csv` read: one line per pose of the largest grid rig enumerates.
pub const MAX_CHOICES_BYTES: u64 = MAX_GRID_POINTS * MAX_LINE_BYTES + 64;

/// The choices recorded in the dataset at `dir`; `None` when it keeps no `adaptive.csv`.
/// Refuses a malformed file, naming the line.
pub fn read_choices(dir: &Path) -> Result<Option<Vec<AdaptiveChoice>>, DatasetError> {
    if !entry_exists(&dir.join(CHOICES_FILE), Kind::File)? {
        return Ok(None);
    }
    let bytes = read_below(dir, Path::new(CHOICES_FILE), MAX_CHOICES_BYTES)?;
    parse_choices(&bytes, &dir.join(CHOICES_FILE)).map(Some)
}

/// Parses `adaptive.csv` bytes (`path` names it in errors). Never panics.
pub fn parse_choices(bytes: &[u8], path: &Path) -> Result<Vec<AdaptiveChoice>, DatasetError> {
    let bad = |line: u64, reason: String| DatasetError::BadChoices { path: path.to_path_buf(), line, reason };
    let mut lines = bytes.split(|&b| b == b'\n').map(|l| l.strip_suffix(b"\r").unwrap_or(l));
    if lines.next() != Some(CHOICES_HEADER.as_bytes()) {
        return Err(bad(1, format!("the header must be `{CHOICES_HEADER}`")));
    }
    let mut choices: Vec<AdaptiveChoice> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for (i, raw) in lines.enumerate() {
        let line = i as u64 + 2;
        if raw.is_empty() {
            continue; // the split after the final newline
        }
        if choices.len() as u64 >= MAX_GRID_POINTS {
            return Err(bad(line, format!("more than the {MAX_GRID_POINTS} poses a plan can have")));
        }
        let choice = parse_line(raw).map_err(|reason| bad(line, reason))?;
        let last_round = choices.last().map_or(0, |c| c.round);
        if choice.round != last_round && choice.round != last_round + 1 {
            return Err(bad(
                line,
                format!("round {} follows round {last_round}: rounds are recorded whole, in order, from 1", choice.round),
            ));
        }
        if !seen.insert(choice.pose_id) {
            return Err(bad(line, format!("pose {} is chosen twice", choice.pose_id)));
        }
        choices.push(choice);
    }
    Ok(choices)
}

/// One line's choice, or what is wrong with it.
fn parse_line(raw: &[u8]) -> Result<AdaptiveChoice, String> {
    let text = std::str::from_utf8(raw).map_err(|_| "not UTF-8 text".to_string())?;
    let fields: Vec<&str> = text.split(',').collect();
    let [pose_id, round, reason, distance, spread, error, score] = fields[..] else {
        return Err(format!("{} fields, not the header's 7", fields.len()));
    };
    let whole = |name: &str, t: &str| {
        t.parse::<u32>().ok().filter(|_| t.bytes().all(|b| b.is_ascii_digit())).ok_or_else(|| format!("{name} `{t}` is not a whole number"))
    };
    let pose_id = whole("pose_id", pose_id)?;
    let round = whole("round", round)? as usize;
    if round == 0 {
        return Err("round 0: rounds count from 1".to_string());
    }
    let reason = match reason {
        "space-filling" => ChoiceReason::SpaceFilling,
        "acquisition" => ChoiceReason::Acquisition,
        other => return Err(format!("reason `{other}` is neither `space-filling` nor `acquisition`")),
    };
    let distance = match distance.parse::<f64>() {
        Ok(d) if d >= 0.0 => d,
        _ => return Err(format!("distance `{distance}` is not a number of 0 or more (or `inf`)")),
    };
    let term = |name: &str, t: &str| -> Result<Option<f64>, String> {
        if t.is_empty() {
            return Ok(None);
        }
        match t.parse::<f64>() {
            Ok(v) if (0.0..=1.0).contains(&v) => Ok(Some(v)),
            _ => Err(format!("{name} `{t}` is not a number from 0 to 1 (each term is divided by its round's largest)")),
        }
    };
    let (spread, error, score) = (term("spread", spread)?, term("error", error)?, term("score", score)?);
    let terms = [spread, error, score].iter().filter(|t| t.is_some()).count();
    match (round, reason, terms) {
        (1, ChoiceReason::SpaceFilling, 0) | (2.., ChoiceReason::Acquisition, 3) => {}
        (1, _, _) => return Err("round 1 is space-filling, with no spread, error or score".to_string()),
        _ => return Err(format!("round {round} is by acquisition, with its spread, error and score")),
    }
    Ok(AdaptiveChoice { pose_id, round, reason, distance, spread, error, score })
}

/// The bytes of `adaptive.csv` for `choices`.
pub fn choices_bytes(choices: &[AdaptiveChoice]) -> Vec<u8> {
    let mut out = String::with_capacity(CHOICES_HEADER.len() + 1 + choices.len() * 48);
    out.push_str(CHOICES_HEADER);
    out.push('\n');
    let term = |v: Option<f64>| v.map(|x| x.to_string()).unwrap_or_default();
    for c in choices {
        let reason = match c.reason {
            ChoiceReason::SpaceFilling => "space-filling",
            ChoiceReason::Acquisition => "acquisition",
        };
        out.push_str(&format!(
            "{},{},{reason},{},{},{},{}\n",
            c.pose_id,
            c.round,
            c.distance,
            term(c.spread),
            term(c.error),
            term(c.score)
        ));
    }
    out.into_bytes()
}

/// Records `choices` in the dataset at `dir` (atomically, durably) unless it records them
/// already. The choices kept there must be where `choices` starts: a recorded round is never
/// chosen again or dropped. Returns whether it wrote.
pub fn keep_choices(dir: &Path, choices: &[AdaptiveChoice]) -> Result<bool, DatasetError> {
    let file = read_choices(dir)?;
    let kept = file.as_deref().unwrap_or_default();
    if kept.len() > choices.len() || *kept != choices[..kept.len()] {
        return Err(DatasetError::ChoicesMismatch {
            path: dir.join(CHOICES_FILE),
            reason: format!("it records {} choices that are not where this collection's {} choices start", kept.len(), choices.len()),
        });
    }
    if file.is_some() && kept.len() == choices.len() {
        return Ok(false);
    }
    write_atomic(dir, CHOICES_FILE, &choices_bytes(choices))?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn choice(pose_id: u32, round: usize) -> AdaptiveChoice {
        let acquisition = round > 1;
        AdaptiveChoice {
            pose_id,
            round,
            reason: if acquisition { ChoiceReason::Acquisition } else { ChoiceReason::SpaceFilling },
            distance: if pose_id == 25 { f64::INFINITY } else { 0.1 * f64::from(pose_id) + 1.0 / 3.0 },
            spread: acquisition.then_some(0.971_834_5),
            error: acquisition.then_some(1.0),
            score: acquisition.then_some(1.0 / 3.0),
        }
    }

    #[test]
    fn round_trip_exactly_and_extend_round_by_round() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert_eq!(read_choices(dir.path()).expect("read"), None);
        let round1 = vec![choice(25, 1), choice(0, 1)];
        assert!(keep_choices(dir.path(), &round1).expect("keep"));
        let text = std::fs::read_to_string(dir.path().join(CHOICES_FILE)).expect("text");
        assert!(text.starts_with("pose_id,round,reason,distance,spread,error,score\n25,1,space-filling,inf,,,\n0,1,"), "{text}");
        assert_eq!(read_choices(dir.path()).expect("read"), Some(round1.clone()), "the numbers come back bit for bit");
        assert!(!keep_choices(dir.path(), &round1).expect("the same again"), "nothing new: not written");
        let mut two = round1.clone();
        two.extend([choice(48, 2), choice(8, 2)]);
        assert!(keep_choices(dir.path(), &two).expect("round 2 added"));
        assert_eq!(read_choices(dir.path()).expect("read"), Some(two.clone()));
        // A record that does not start with what is kept is refused, and the file kept.
        let other = vec![choice(3, 1), choice(0, 1), choice(48, 2)];
        assert!(matches!(keep_choices(dir.path(), &other), Err(DatasetError::ChoicesMismatch { .. })));
        assert!(matches!(keep_choices(dir.path(), &round1), Err(DatasetError::ChoicesMismatch { .. })), "a round dropped");
        assert_eq!(read_choices(dir.path()).expect("read"), Some(two));
    }

    #[test]
    fn malformed_files_are_refused_naming_the_line() {
        let path = Path::new("adaptive.csv");
        let ok = "pose_id,round,reason,distance,spread,error,score\r\n25,1,space-filling,inf,,,\r\n4,2,acquisition,0.5,0.25,1,0.5";
        assert_eq!(parse_choices(ok.as_bytes(), path).expect("crlf, no final newline").len(), 2);
        let h = "pose_id,round,reason,distance,spread,error,score\n";
        for (body, line) in [
            ("", 1),
            ("pose_id,round\n1,1\n", 1),
            ("1,1,space-filling,0.5,,\n", 2),
            ("1,1,space-filling,0.5,,,,\n", 2),
            ("-1,1,space-filling,0.5,,,\n", 2),
            ("+1,1,space-filling,0.5,,,\n", 2),
            ("99999999999,1,space-filling,0.5,,,\n", 2),
            ("1,0,space-filling,0.5,,,\n", 2),
            ("1,1,nearest,0.5,,,\n", 2),
            ("1,1,space-filling,-0.5,,,\n", 2),
            ("1,1,space-filling,NaN,,,\n", 2),
            ("1,1,space-filling,0.5,0.1,0.2,0.3\n", 2),
            ("1,1,space-filling,0.5,,,\n2,2,acquisition,0.5,0.1,,0.3\n", 3),
            ("1,1,space-filling,0.5,,,\n2,2,acquisition,0.5,0.1,1.5,0.3\n", 3),
            ("1,1,space-filling,0.5,,,\n2,2,acquisition,0.5,0.1,inf,0.3\n", 3),
            ("1,1,space-filling,0.5,,,\n2,3,acquisition,0.5,0.1,0.2,0.3\n", 3),
            ("1,1,space-filling,0.5,,,\n2,2,acquisition,0.5,0.1,0.2,0.3\n3,1,space-filling,0.5,,,\n", 4),
            ("1,1,space-filling,0.5,,,\n1,1,space-filling,0.5,,,\n", 3),
            ("\u{ff},1,space-filling,0.5,,,\n", 2),
        ] {
            let bytes = if line == 1 { body.to_string() } else { format!("{h}{body}") };
            match parse_choices(bytes.as_bytes(), path) {
                Err(DatasetError::BadChoices { line: l, .. }) => assert_eq!(l, line, "{body:?}"),
                other => panic!("{body:?}: {other:?}"),
            }
        }
        assert!(matches!(
            parse_choices(b"pose_id,round,reason,distance,spread,error,score\n\xff\n", path),
            Err(DatasetError::BadChoices { line: 2, .. })
        ));
    }

    #[test]
    fn a_symlinked_file_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::write(dir.path().join("elsewhere.csv"), format!("{CHOICES_HEADER}\n")).expect("write");
        std::os::unix::fs::symlink(dir.path().join("elsewhere.csv"), dir.path().join(CHOICES_FILE)).expect("symlink");
        assert!(matches!(read_choices(dir.path()), Err(DatasetError::Symlink { .. })));
        assert!(keep_choices(dir.path(), &[choice(25, 1)]).is_err());
        assert_eq!(std::fs::read_to_string(dir.path().join("elsewhere.csv")).expect("text"), format!("{CHOICES_HEADER}\n"));
    }
}
