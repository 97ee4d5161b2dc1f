//! An adaptive collection's choices: `adaptive.csv`, every pose `rig collect --adaptive` chose
//! to press, round by round, with the terms that chose it. The manifest's `[adaptive]` holds
//! the collection's settings; this file holds what grows with the budget, so a collection of
//! any budget its plan allows keeps its manifest small.
//!
//! ```text
//! pose_id,round,reason,distance,spread,error,score,distance_weight,spread_weight,error_weight
//! 25,1,space-filling,inf,,,,,,
//! 0,1,space-filling,1.2247448713915889,,,,,,
//! 48,2,acquisition,1.2247448713915889,,1,0.8906,0.1,0,0.4512
//! ```
//!
//! Rows come in the order chosen: round 1's, then round 2's, and so on, each round whole.
//! `distance` is `inf` for the first pose of a collection (nothing was near it); the other
//! columns are empty in round 1 (space-filling). In a later round (acquisition) `error`,
//! `score` and the three weights are present, and `spread` where its weight is above 0 (a round
//! measures the spread only where it counts). A pose appears once. A file with the earlier
//! header (`pose_id,round,reason,distance,spread,error,score`, every term counting 1) is read
//! too; the next round recorded writes the whole file with this header.
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
pub const CHOICES_HEADER: &str = "pose_id,round,reason,distance,spread,error,score,distance_weight,spread_weight,error_weight";
/// The header of the file before the acquisition was weighted: no weight columns.
const UNWEIGHTED_HEADER: &str = "pose_id,round,reason,distance,spread,error,score";
/// Largest line read: a pose id, a round, a reason and seven numbers of at most 24 characters.
const MAX_LINE_BYTES: u64 = 232;
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
    let weighted = match lines.next() {
        Some(h) if h == CHOICES_HEADER.as_bytes() => true,
        Some(h) if h == UNWEIGHTED_HEADER.as_bytes() => false,
        _ => return Err(bad(1, format!("the header must be `{CHOICES_HEADER}` (or the earlier `{UNWEIGHTED_HEADER}`)"))),
    };
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
        let choice = parse_line(raw, weighted).map_err(|reason| bad(line, reason))?;
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

/// One line's choice, or what is wrong with it; `weighted`: the file has the weight columns.
fn parse_line(raw: &[u8], weighted: bool) -> Result<AdaptiveChoice, String> {
    let text = std::str::from_utf8(raw).map_err(|_| "not UTF-8 text".to_string())?;
    let fields: Vec<&str> = text.split(',').collect();
    let columns = if weighted { 10 } else { 7 };
    if fields.len() != columns {
        return Err(format!("{} fields, not the header's {columns}", fields.len()));
    }
    let (pose_id, round, reason, distance) = (fields[0], fields[1], fields[2], fields[3]);
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
    let term = |k: usize| -> Result<Option<f64>, String> {
        let (name, t) = (CHOICES_HEADER.split(',').nth(k).unwrap_or("term"), fields.get(k).copied().unwrap_or(""));
        if t.is_empty() {
            return Ok(None);
        }
        match t.parse::<f64>() {
            Ok(v) if (0.0..=1.0).contains(&v) => Ok(Some(v)),
            _ => Err(format!(
                "{name} `{t}` is not a number from 0 to 1 (each term is scaled to its round's range, each weight is a correlation of 0 to 1)"
            )),
        }
    };
    let (spread, error, score) = (term(4)?, term(5)?, term(6)?);
    let (distance_weight, spread_weight, error_weight) = (term(7)?, term(8)?, term(9)?);
    let any = [spread, error, score, distance_weight, spread_weight, error_weight].iter().any(Option::is_some);
    let acquisition_ok = error.is_some()
        && score.is_some()
        && match (distance_weight, spread_weight, error_weight) {
            // Weighted: some term counts, and the spread is measured exactly where it does.
            (Some(wd), Some(ws), Some(we)) => wd + ws + we > 0.0 && spread.is_some() == (ws > 0.0),
            // A round recorded before the acquisition was weighted: every term.
            (None, None, None) => spread.is_some(),
            _ => false,
        };
    match (round, reason) {
        (1, ChoiceReason::SpaceFilling) if !any => {}
        (2.., ChoiceReason::Acquisition) if acquisition_ok => {}
        (1, _) => return Err("round 1 is space-filling, with no spread, error, score or weights".to_string()),
        _ if weighted => {
            return Err(format!(
                "round {round} is by acquisition, with its error, score and weights (not all 0), and its spread where the spread's weight \
                 is above 0 (or, recorded before the weights, its spread, error and score)"
            ));
        }
        _ => return Err(format!("round {round} is by acquisition, with its spread, error and score")),
    }
    Ok(AdaptiveChoice { pose_id, round, reason, distance, spread, error, score, distance_weight, spread_weight, error_weight })
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
            "{},{},{reason},{},{},{},{},{},{},{}\n",
            c.pose_id,
            c.round,
            c.distance,
            term(c.spread),
            term(c.error),
            term(c.score),
            term(c.distance_weight),
            term(c.spread_weight),
            term(c.error_weight)
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
            // Round 3's spread is not measured (its weight is 0).
            spread: (round == 2).then_some(0.971_834_5),
            error: acquisition.then_some(1.0),
            score: acquisition.then_some(1.0 / 3.0),
            distance_weight: acquisition.then_some(0.0),
            spread_weight: acquisition.then_some(if round == 2 { 0.25 } else { 0.0 }),
            error_weight: acquisition.then_some(0.618_033_988_7),
        }
    }

    #[test]
    fn round_trip_exactly_and_extend_round_by_round() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert_eq!(read_choices(dir.path()).expect("read"), None);
        let round1 = vec![choice(25, 1), choice(0, 1)];
        assert!(keep_choices(dir.path(), &round1).expect("keep"));
        let text = std::fs::read_to_string(dir.path().join(CHOICES_FILE)).expect("text");
        assert!(text.starts_with(&format!("{CHOICES_HEADER}\n25,1,space-filling,inf,,,,,,\n0,1,")), "{text}");
        assert_eq!(read_choices(dir.path()).expect("read"), Some(round1.clone()), "the numbers come back bit for bit");
        assert!(!keep_choices(dir.path(), &round1).expect("the same again"), "nothing new: not written");
        let mut two = round1.clone();
        two.extend([choice(48, 2), choice(8, 2), choice(9, 3)]);
        assert!(keep_choices(dir.path(), &two).expect("rounds 2 and 3 added"));
        assert_eq!(read_choices(dir.path()).expect("read"), Some(two.clone()));
        // A record that does not start with what is kept is refused, and the file kept.
        let other = vec![choice(3, 1), choice(0, 1), choice(48, 2)];
        assert!(matches!(keep_choices(dir.path(), &other), Err(DatasetError::ChoicesMismatch { .. })));
        assert!(matches!(keep_choices(dir.path(), &round1), Err(DatasetError::ChoicesMismatch { .. })), "a round dropped");
        assert_eq!(read_choices(dir.path()).expect("read"), Some(two));
    }

    /// A file recorded before the acquisition was weighted is read (no weights), and the next
    /// round recorded rewrites it with the weight columns.
    #[test]
    fn a_file_without_weights_is_read_and_rewritten_with_them() {
        let dir = tempfile::tempdir().expect("tempdir");
        let old = "pose_id,round,reason,distance,spread,error,score\n25,1,space-filling,inf,,,\n4,2,acquisition,0.5,0.25,1,0.5\n";
        std::fs::write(dir.path().join(CHOICES_FILE), old).expect("write");
        let kept = read_choices(dir.path()).expect("read").expect("kept");
        assert_eq!((kept[1].spread, kept[1].score, kept[1].distance_weight, kept[1].error_weight), (Some(0.25), Some(0.5), None, None));
        let mut more = kept.clone();
        more.push(choice(9, 3));
        assert!(keep_choices(dir.path(), &more).expect("round 3 added"));
        let text = std::fs::read_to_string(dir.path().join(CHOICES_FILE)).expect("text");
        assert!(
            text.starts_with(&format!("{CHOICES_HEADER}\n25,1,space-filling,inf,,,,,,\n4,2,acquisition,0.5,0.25,1,0.5,,,\n")),
            "{text}"
        );
        assert_eq!(read_choices(dir.path()).expect("read"), Some(more));
        // Without weights, an acquisition has all three terms.
        let h = "pose_id,round,reason,distance,spread,error,score\n1,1,space-filling,0.5,,,\n";
        for (body, ok) in [("2,2,acquisition,0.5,0.1,0.2,0.3\n", true), ("2,2,acquisition,0.5,,0.2,0.3\n", false)] {
            assert_eq!(parse_choices(format!("{h}{body}").as_bytes(), Path::new("a.csv")).is_ok(), ok, "{body:?}");
        }
    }

    #[test]
    fn malformed_files_are_refused_naming_the_line() {
        let path = Path::new("adaptive.csv");
        let ok = format!(
            "{CHOICES_HEADER}\r\n25,1,space-filling,inf,,,,,,\r\n4,2,acquisition,0.5,0.25,1,0.5,0,0.2,0.7\r\n5,2,acquisition,0.5,,1,0.5,0.1,0,0.7"
        );
        assert_eq!(parse_choices(ok.as_bytes(), path).expect("crlf, no final newline").len(), 3);
        let h = &format!("{CHOICES_HEADER}\n");
        for (body, line) in [
            ("", 1),
            ("pose_id,round\n1,1\n", 1),
            ("1,1,space-filling,0.5,,,,,\n", 2),
            ("1,1,space-filling,0.5,,,,,,,\n", 2),
            ("1,1,space-filling,0.5,,,\n", 2),
            ("-1,1,space-filling,0.5,,,,,,\n", 2),
            ("+1,1,space-filling,0.5,,,,,,\n", 2),
            ("99999999999,1,space-filling,0.5,,,,,,\n", 2),
            ("1,0,space-filling,0.5,,,,,,\n", 2),
            ("1,1,nearest,0.5,,,,,,\n", 2),
            ("1,1,space-filling,-0.5,,,,,,\n", 2),
            ("1,1,space-filling,NaN,,,,,,\n", 2),
            ("1,1,space-filling,0.5,0.1,0.2,0.3,,,\n", 2),
            ("1,1,space-filling,0.5,,,,1,0.1,0.2\n", 2),
            ("1,1,space-filling,0.5,,,,,,\n2,2,acquisition,0.5,0.1,,0.3,1,0.1,0.1\n", 3),
            ("1,1,space-filling,0.5,,,,,,\n2,2,acquisition,0.5,0.1,1.5,0.3,1,0.1,0.1\n", 3),
            ("1,1,space-filling,0.5,,,,,,\n2,2,acquisition,0.5,0.1,inf,0.3,1,0.1,0.1\n", 3),
            ("1,1,space-filling,0.5,,,,,,\n2,2,acquisition,0.5,0.1,0.2,0.3,1,0.1,1.5\n", 3),
            ("1,1,space-filling,0.5,,,,,,\n2,2,acquisition,0.5,0.1,0.2,0.3,1,,0.1\n", 3),
            ("1,1,space-filling,0.5,,,,,,\n2,2,acquisition,0.5,0.1,0.2,0.3,1,0,0.1\n", 3),
            ("1,1,space-filling,0.5,,,,,,\n2,2,acquisition,0.5,,0.2,0.3,1,0.4,0.1\n", 3),
            ("1,1,space-filling,0.5,,,,,,\n2,2,acquisition,0.5,,0.2,0.3,0,0,0\n", 3),
            ("1,1,space-filling,0.5,,,,,,\n2,3,acquisition,0.5,0.1,0.2,0.3,1,0.1,0.1\n", 3),
            ("1,1,space-filling,0.5,,,,,,\n2,2,acquisition,0.5,0.1,0.2,0.3,1,0.1,0.1\n3,1,space-filling,0.5,,,,,,\n", 4),
            ("1,1,space-filling,0.5,,,,,,\n1,1,space-filling,0.5,,,,,,\n", 3),
            ("\u{ff},1,space-filling,0.5,,,,,,\n", 2),
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
        assert!(matches!(
            parse_choices(format!("{CHOICES_HEADER}\n\u{ff}\n").as_bytes(), path),
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
