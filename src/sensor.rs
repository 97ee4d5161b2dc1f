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
//! Names are read case-insensitively (`TacTip`, `tactip` and `TACTIP` are one sensor) and
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
#[error("unknown sensor {text:?} (expected tactip, vitac or vitactip)")]
pub struct SensorKindParseError {
    pub text: String,
}

impl FromStr for SensorKind {
    type Err = SensorKindParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let trimmed = s.trim();
        Self::ALL.into_iter().find(|k| k.name().eq_ignore_ascii_case(trimmed)).ok_or_else(|| SensorKindParseError { text: s.to_string() })
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
/// (`tactip,vitactip`); repeated names count once, in the order given.
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
        if text.trim().eq_ignore_ascii_case("all") {
            return Ok(Self::all());
        }
        let mut kinds = Vec::new();
        for part in text.split(',') {
            let kind: SensorKind = part.parse()?;
            if !kinds.contains(&kind) {
                kinds.push(kind);
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
        for bad in ["", "gelsight", "tac tip", "a/../../../X", "tactip/", "../tactip"] {
            assert!(bad.parse::<SensorKind>().is_err(), "{bad:?}");
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
