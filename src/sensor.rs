//! The three vision-based tactile sensors rig knows, and every way they are named.
//!
//! [`SensorKind`] is the one place a sensor's names live:
//!
//! | kind | on disk, on the command line ([`SensorKind::name`]) | label in papers, prompts and the MDS dialect ([`SensorKind::label`]) |
//! |---|---|---|
//! | TacTip | `tactip` | `TacTip` |
//! | ViTac | `vitac` | `ViTac` |
//! | ViTacTip | `vitactip` | `ViTacTip` |
//!
//! Names are read by one parser, [`SensorKind::from_str`], wherever a sensor is named: the
//! command line (`--sensor`, `rig synth one --sensor`, `rig render --sensor`), plan and rig TOML
//! (`[sensors.<name>]`), daemon job requests and dataset manifests. It reads any case
//! (`TacTip`, `tactip` and `TACTIP` are one sensor) and ignores `-` and `_` (`ViTac-Tip`,
//! `vitac_tip`); a name that is none of the three is an error listing the valid names. Names are
//! written in lower case, so a dataset folder or a file name built from a sensor is always one
//! of three fixed words: never a path a manifest or a request could smuggle in. A set of
//! sensors asked for on the command line or in a job request is a [`SensorSet`]
//! (`tactip,vitac` or `all`).

use std::fmt;
use std::str::FromStr;

/// The three sensor kinds of the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SensorKind {
    /// White pins on an opaque black skin.
    TacTip,
    /// Transparent skin: the pressed object is seen directly.
    ViTac,
    /// Transparent skin with dark markers.
    ViTacTip,
}

impl SensorKind {
    /// All kinds, in the order the rig collects them.
    pub const ALL: [SensorKind; 3] = [SensorKind::TacTip, SensorKind::ViTac, SensorKind::ViTacTip];

    /// The name on disk and on the command line: `tactip`, `vitac`, `vitactip` (a dataset's
    /// folder, `calibration/<name>.toml`, `--sensor <name>`).
    pub fn name(&self) -> &'static str {
        match self {
            SensorKind::TacTip => "tactip",
            SensorKind::ViTac => "vitac",
            SensorKind::ViTacTip => "vitactip",
        }
    }

    /// Where `rig calibrate` saves this sensor's calibration and where `rig collect` and
    /// `rig synth --fill-missing` look for it: `calibration/<name>.toml` (relative to the
    /// working directory).
    pub fn calibration_path(&self) -> std::path::PathBuf {
        std::path::Path::new("calibration").join(format!("{}.toml", self.name()))
    }

    /// The name as the papers and the real dataset spell it (`TacTip`, `ViTac`, `ViTacTip`).
    pub fn label(&self) -> &'static str {
        match self {
            SensorKind::TacTip => "TacTip",
            SensorKind::ViTac => "ViTac",
            SensorKind::ViTacTip => "ViTacTip",
        }
    }

    /// The kind whose [`label`](Self::label) is exactly `label` (case-sensitive, as
    /// MultiDiffSense's prompt code compares them).
    pub fn from_label(label: &str) -> Option<SensorKind> {
        Self::ALL.into_iter().find(|k| k.label() == label)
    }

    /// The deepest rig presses this sensor's skin unless the rig configuration says otherwise
    /// (`[sensors.<name>] max_indentation_mm`), mm of indentation into the object's top.
    ///
    /// Conservative on purpose: each is the deepest press published for that skin, never more.
    /// TacTip: the Bristol lab's TacTip collection scripts (`tactile_gym_servo_control`) press
    /// edges 2-3.5 mm and surfaces 0.5-5.5 mm deep; 5 mm stays inside that. ViTac and
    /// ViTacTip: their transparent skins have no published press range beyond MultiDiffSense's
    /// data, pressed at 1.5 mm contact depth plus at most 1 mm: 2.5 mm.
    pub fn default_max_indentation_mm(&self) -> f64 {
        match self {
            SensorKind::TacTip => 5.0,
            SensorKind::ViTac | SensorKind::ViTacTip => 2.5,
        }
    }

    /// MultiDiffSense's `sensor_context` sentence for this sensor (its `prompt_creation.py`).
    pub fn prompt_context(&self) -> &'static str {
        match self {
            SensorKind::TacTip => "captured by a high-resolution tactile only sensor TacTip.",
            SensorKind::ViTac => "captured by a high-resolution vision only sensor ViTac.",
            SensorKind::ViTacTip => "captured by a high-resolution visuo-tactile sensor ViTacTip.",
        }
    }
}

impl fmt::Display for SensorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A sensor name that is none of the three.
#[derive(Debug, Clone, thiserror::Error, PartialEq, Eq)]
#[error("unknown sensor {text:?} (expected {expected})")]
pub struct SensorKindParseError {
    /// The name as given.
    pub text: String,
    /// The valid names: `tactip, vitac or vitactip`, and `or all` where a set is asked for.
    pub expected: &'static str,
}

/// The valid names of one sensor, as errors list them.
const EXPECTED_ONE: &str = "tactip, vitac or vitactip, in any case";
/// The valid names of a set of sensors, as errors list them.
const EXPECTED_SET: &str = "tactip, vitac, vitactip or all, in any case, or a comma-separated list";

impl FromStr for SensorKind {
    type Err = SensorKindParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        // Any case, `-` and `_` ignored: `ViTacTip`, `VITACTIP`, `vitac-tip` are one sensor.
        let folded: String = s.trim().chars().filter(|c| !matches!(c, '-' | '_')).collect();
        Self::ALL
            .into_iter()
            .find(|k| !folded.is_empty() && k.name().eq_ignore_ascii_case(&folded))
            .ok_or_else(|| SensorKindParseError { text: s.to_string(), expected: EXPECTED_ONE })
    }
}

impl serde::Serialize for SensorKind {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for SensorKind {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = <std::borrow::Cow<'de, str>>::deserialize(deserializer)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// The sensors a command or a job asks for: `all`, one name, or a comma-separated list
/// (`tactip,vitactip`); repeated names count once, in the order given, and `all` in a list
/// stands for the three. A bad name in a list is the one the error names (`all,gelsight`:
/// `unknown sensor "gelsight"`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SensorSet(pub Vec<SensorKind>);

impl SensorSet {
    /// All three, in collection order.
    pub fn all() -> Self {
        Self(SensorKind::ALL.to_vec())
    }

    /// One sensor.
    pub fn one(kind: SensorKind) -> Self {
        Self(vec![kind])
    }

    /// True when `kind` is in the set.
    pub fn contains(&self, kind: SensorKind) -> bool {
        self.0.contains(&kind)
    }

    /// The kinds, in order.
    pub fn iter(&self) -> impl Iterator<Item = SensorKind> + '_ {
        self.0.iter().copied()
    }
}

impl fmt::Display for SensorSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if *self == Self::all() {
            return f.write_str("all");
        }
        let names: Vec<&str> = self.0.iter().map(SensorKind::name).collect();
        f.write_str(&names.join(","))
    }
}

impl FromStr for SensorSet {
    type Err = SensorKindParseError;
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let mut kinds = Vec::new();
        for part in text.split(',') {
            let named: Vec<SensorKind> = if part.trim().eq_ignore_ascii_case("all") {
                SensorKind::ALL.to_vec()
            } else {
                vec![part.parse().map_err(|e: SensorKindParseError| SensorKindParseError { expected: EXPECTED_SET, ..e })?]
            };
            for kind in named {
                if !kinds.contains(&kind) {
                    kinds.push(kind);
                }
            }
        }
        Ok(Self(kinds))
    }
}

impl serde::Serialize for SensorSet {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for SensorSet {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = <std::borrow::Cow<'de, str>>::deserialize(deserializer)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_labels_and_parsing_agree() {
        for kind in SensorKind::ALL {
            assert_eq!(kind.name().parse::<SensorKind>(), Ok(kind));
            assert_eq!(kind.label().parse::<SensorKind>(), Ok(kind), "labels parse too, case-insensitively");
            assert_eq!(kind.name().to_ascii_uppercase().parse::<SensorKind>(), Ok(kind));
            assert_eq!(SensorKind::from_label(kind.label()), Some(kind));
            assert_eq!(SensorKind::from_label(kind.name()), None, "labels are case-sensitive");
            assert_eq!(kind.to_string(), kind.name());
            assert!(kind.prompt_context().ends_with(&format!("{}.", kind.label())));
        }
        for bad in ["", "-", "gelsight", "tac tip", "a/../../../X", "tactip/", "../tactip", "all"] {
            assert!(bad.parse::<SensorKind>().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn any_case_and_aliases_name_one_sensor() {
        for (text, kind) in [
            ("vitac", SensorKind::ViTac),
            ("ViTac", SensorKind::ViTac),
            ("VITAC", SensorKind::ViTac),
            ("vItAc", SensorKind::ViTac),
            (" tactip ", SensorKind::TacTip),
            ("Tac-Tip", SensorKind::TacTip),
            ("vitac_tip", SensorKind::ViTacTip),
            ("ViTac-Tip", SensorKind::ViTacTip),
        ] {
            assert_eq!(text.parse::<SensorKind>(), Ok(kind), "{text:?}");
        }
    }

    #[test]
    fn a_bad_name_is_named_with_the_valid_ones() {
        let err = "gelsight".parse::<SensorKind>().expect_err("not a sensor");
        let text = err.to_string();
        assert!(text.contains("\"gelsight\"") && text.contains("tactip, vitac or vitactip"), "{text}");
        assert!(!text.contains("all"), "one sensor is asked for: {text}");
        // In a set, the bad name is the one named, `all` is listed as valid, and `all` beside it
        // is not blamed.
        for list in ["all,gelsight", "tactip,gelsight", "gelsight,ALL"] {
            let err = list.parse::<SensorSet>().expect_err("not a set");
            assert_eq!(err.text, "gelsight", "{list}");
            let text = err.to_string();
            assert!(text.contains("\"gelsight\"") && text.contains("or all"), "{text}");
        }
    }

    #[test]
    fn sets_parse_lists_and_all() {
        assert_eq!("all".parse::<SensorSet>(), Ok(SensorSet::all()));
        assert_eq!("ALL".parse::<SensorSet>(), Ok(SensorSet::all()));
        let set: SensorSet = "vitactip, tactip,vitactip".parse().expect("a list");
        assert_eq!(set.0, vec![SensorKind::ViTacTip, SensorKind::TacTip]);
        assert_eq!(set.to_string(), "vitactip,tactip");
        assert_eq!(SensorSet::all().to_string(), "all");
        assert!("tactip,".parse::<SensorSet>().is_err(), "an empty name is not a sensor");
        let set: SensorSet = "vitac,ALL".parse().expect("all in a list");
        assert_eq!(set.0, vec![SensorKind::ViTac, SensorKind::TacTip, SensorKind::ViTacTip]);
        assert_eq!("all,tactip".parse::<SensorSet>(), Ok(SensorSet::all()));
        assert!("tactip,gelsight".parse::<SensorSet>().is_err());
    }

    #[test]
    fn serde_writes_names_and_reads_any_case() {
        #[derive(serde::Serialize, serde::Deserialize, PartialEq, Debug)]
        struct Row {
            sensor: SensorKind,
            sensors: SensorSet,
        }
        let row = Row { sensor: SensorKind::ViTacTip, sensors: SensorSet(vec![SensorKind::ViTac]) };
        let text = toml::to_string(&row).expect("serialises");
        assert_eq!(text, "sensor = \"vitactip\"\nsensors = \"vitac\"\n");
        let back: Row = toml::from_str("sensor = \"ViTacTip\"\nsensors = \"VITAC\"\n").expect("reads labels");
        assert_eq!(back, row);
        let err = toml::from_str::<Row>("sensor = \"a/../../../X\"\nsensors = \"all\"\n").expect_err("not a sensor");
        assert!(err.to_string().contains("unknown sensor"), "{err}");
    }
}
