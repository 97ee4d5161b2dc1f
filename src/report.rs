//! How a failed command reports itself: the one exit-code table ([`Exit`]), the mapping from
//! every library error to it (shared by the CLI and the daemon's job records), and the error's
//! one-line message.
//!
//! The mapping matches each error type's variants exhaustively ([`Classify`]), so a new
//! variant does not compile until someone decides its exit code. Errors that wrap another
//! (`RigError::Arm`, `FillError::Dataset`, ...) take the code of what they wrap, because a
//! `#[error(transparent)]` wrapper hides its inner error from `source()` chains. The docs'
//! table is [`Exit::markdown_table`]; a test checks the guide's
//! `docs/src/faults.md` holds it verbatim.

use std::fmt;

/// What rig's exit status means. The daemon records the same number for each job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[repr(u8)]
pub enum Exit {
    Success = 0,
    Failure = 1,
    BadInput = 2,
    HardwareFault = 3,
    Interrupted = 4,
}

impl Exit {
    /// Every code, in order.
    pub const ALL: [Exit; 5] = [Exit::Success, Exit::Failure, Exit::BadInput, Exit::HardwareFault, Exit::Interrupted];

    /// The number the process exits with.
    pub fn code(self) -> u8 {
        self as u8
    }

    /// The code of a number, if it is one of the table's.
    pub fn from_code(code: u8) -> Option<Exit> {
        Exit::ALL.into_iter().find(|e| e.code() == code)
    }

    /// What the code means, as the docs say it.
    pub fn meaning(self) -> &'static str {
        match self {
            Exit::Success => "success",
            Exit::Failure => {
                "general failure: a full disk, a dataset held by another process, an internal error, `rig dataset verify` \
                 finding a dataset not clean, `rig audit` below its `--min-ssim`, a command that needs a feature this \
                 rig was built without (`synth`, `lerobot`)"
            }
            Exit::BadInput => {
                "bad input: command line, rig config, plan, object/STL, calibration, firmware profile, model package \
                 (model.toml, tokenizer, ONNX files), dataset files (manifest, CSV header and rows, images, symlinks), a recording file, \
                 sampling settings and sizes out of range, a pose outside the workspace or past the sensor's press \
                 limit (a plan, an audit's rows, a calibration pattern), a path outside the daemon's data roots"
            }
            Exit::HardwareFault => {
                "hardware fault: arm alarms, refused or lost connections once retries are spent (also when opening the \
                 rig), camera failures, a required Modbus peripheral, a device that failed a dry run's pre-flight; \
                 `rig replay`: a divergence from the recording"
            }
            Exit::Interrupted => {
                "interrupted: Ctrl-C or a cancelled daemon job (`rig collect` continues with `--resume`; `rig calibrate` \
                 saved nothing)"
            }
        }
    }

    /// The exit code of an error (its own code when it is an [`ExitStatus`]).
    pub fn of(e: &anyhow::Error) -> Exit {
        if let Some(status) = e.downcast_ref::<ExitStatus>() {
            return Exit::from_code(status.0).unwrap_or(Exit::Failure);
        }
        e.chain().find_map(classify).unwrap_or(Exit::Failure)
    }

    /// The table the guide holds (`docs/src/faults.md`, "Exit codes"), generated from this enum.
    pub fn markdown_table() -> String {
        let mut table = String::from("| exit | meaning |\n|---|---|\n");
        for e in Exit::ALL {
            table.push_str(&format!("| {} | {} |\n", e.code(), e.meaning()));
        }
        table
    }
}

impl fmt::Display for Exit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.code())
    }
}

/// The exit code (0 success, 1 general failure, 2 bad input, 3 hardware or protocol fault,
/// 4 interrupted) of an error: [`Exit::of`] as a number.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    Exit::of(e).code()
}

/// An error that knows its exit code.
pub trait Classify {
    fn exit(&self) -> Exit;
}

/// The exit code of one error of the chain, if its type is one rig knows.
fn classify(cause: &(dyn std::error::Error + 'static)) -> Option<Exit> {
    macro_rules! try_types {
        ($($t:ty),* $(,)?) => {
            $(if let Some(e) = cause.downcast_ref::<$t>() { return Some(e.exit()); })*
        };
    }
    try_types!(
        UsageError,
        crate::arm::ArmError,
        crate::camera::CameraError,
        crate::collect::CollectError,
        crate::config::ConfigError,
        crate::plan::PlanError,
        crate::dataset::DatasetError,
        crate::synth::SynthError,
        crate::synth::scheduler::SchedulerError,
        crate::synth::limits::BadSetting,
        crate::synth::settings::UnknownSampler,
        crate::synth::settings::BadShard,
        crate::jobs::RequestError,
        crate::synth::fill::FillError,
        crate::rigs::RigError,
        crate::rigs::PreflightError,
        crate::io::modbus::ModbusError,
        crate::calibration::press::PressError,
        crate::calibration::wizard::WizardError,
        crate::calibration::CalibrationError,
        crate::arm::profile::ProfileError,
        crate::geometry::stl::StlError,
        crate::geometry::objects::ObjectError,
        crate::sensor::SensorKindParseError,
        crate::roots::PathError,
        crate::roots::RootsError,
        crate::jobs::JobError,
        crate::fence::FenceError,
        crate::geometry::objects::ObjectResolveError,
        crate::arm::profile::ProfileLookupError,
        crate::record::replay::ReplayError,
        crate::eval::compare_real::CompareRealError,
        crate::confine::ConfineError,
        crate::dataset::named::NamedFileError,
        crate::features::FeatureMissing,
    );
    #[cfg(feature = "lerobot")]
    try_types!(crate::dataset::lerobot::LerobotError);
    None
}

impl Classify for UsageError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

/// A setting out of its range, an unknown sampler, a shard not written `i/n`: the caller's.
macro_rules! bad_input {
    ($($t:ty),*) => {
        $(impl Classify for $t {
            fn exit(&self) -> Exit {
                Exit::BadInput
            }
        })*
    };
}
bad_input!(crate::synth::limits::BadSetting, crate::synth::settings::UnknownSampler, crate::synth::settings::BadShard);

impl Classify for crate::jobs::RequestError {
    fn exit(&self) -> Exit {
        match self {
            crate::jobs::RequestError::BadOption { .. } | crate::jobs::RequestError::Setting(_) => Exit::BadInput,
            crate::jobs::RequestError::Path(e) => e.exit(),
        }
    }
}

impl Classify for crate::arm::ArmError {
    fn exit(&self) -> Exit {
        use crate::arm::ArmError as A;
        match self {
            // rig refused to send a target outside the profile's workspace: the plan asked for it.
            A::Unreachable { .. } => Exit::BadInput,
            A::Io { .. } | A::Timeout { .. } | A::Fault { .. } | A::Refused { .. } | A::Protocol(_) => Exit::HardwareFault,
        }
    }
}

impl Classify for crate::camera::CameraError {
    fn exit(&self) -> Exit {
        match self {
            // The rig config names a backend this platform does not build.
            crate::camera::CameraError::NotBuilt { .. } => Exit::BadInput,
            _ => Exit::HardwareFault,
        }
    }
}

impl Classify for crate::io::modbus::ModbusError {
    fn exit(&self) -> Exit {
        if self.is_recoverable() { Exit::HardwareFault } else { Exit::BadInput }
    }
}

impl Classify for crate::collect::CollectError {
    fn exit(&self) -> Exit {
        use crate::collect::CollectError as C;
        match self {
            C::Arm(e) => e.exit(),
            C::Camera(e) => e.exit(),
            C::Dataset(e) => e.exit(),
            C::RetriesExhausted { .. } | C::CameraRetriesExhausted { .. } | C::PeripheralRetriesExhausted { .. } => Exit::HardwareFault,
            C::Peripheral(e) => e.exit(),
            C::Mismatch { .. } => Exit::BadInput,
        }
    }
}

impl Classify for crate::config::ConfigError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::eval::compare_real::CompareRealError {
    fn exit(&self) -> Exit {
        use crate::eval::compare_real::CompareRealError as C;
        match self {
            C::Mesh(e) => e.exit(),
            C::PoseLog(e) => e.exit(),
            C::FrameName { .. }
            | C::Image { .. }
            | C::FrameSize { .. }
            | C::TooSmall { .. }
            | C::NoPose { .. }
            | C::TooFewFrames { .. }
            | C::NoObjects { .. }
            | C::TooManyFrames { .. }
            | C::ReadDir { .. } => Exit::BadInput,
            C::Metrics(_) | C::CreateDir { .. } | C::Write { .. } => Exit::Failure,
        }
    }
}

impl Classify for crate::plan::PlanError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::dataset::DatasetError {
    fn exit(&self) -> Exit {
        use crate::dataset::DatasetError as D;
        match self {
            D::NotEmpty { .. }
            | D::NotADataset { .. }
            | D::StlMissing { .. }
            | D::FolderMissing { .. }
            | D::StlChanged { .. }
            | D::StlUnusable { .. }
            | D::ManifestMismatch { .. }
            | D::ManifestParse { .. }
            | D::ManifestPlan { .. }
            | D::BadHeader { .. }
            | D::MalformedRow { .. }
            | D::DuplicateRow { .. }
            | D::MissingImage { .. }
            | D::MalformedMds { .. }
            | D::Unclean { .. }
            | D::MergeConflict { .. }
            | D::MixedSources { .. }
            | D::Symlink { .. }
            | D::NotRegular { .. }
            | D::TooLarge { .. }
            | D::BadImage { .. }
            | D::BadOrder { .. }
            | D::OrderMismatch { .. }
            | D::BadChoices { .. }
            | D::ChoicesMismatch { .. }
            | D::WrongImageSize { .. } => Exit::BadInput,
            D::Io { .. }
            | D::DiskFull { .. }
            | D::ManifestWrite { .. }
            | D::DuplicatePose { .. }
            | D::InvalidRow { .. }
            | D::Encode { .. }
            | D::Locked { .. }
            | D::CsvWrite { .. } => Exit::Failure,
            D::Confined(e) => e.exit(),
            D::Named(e) => e.exit(),
        }
    }
}

#[cfg(feature = "lerobot")]
impl Classify for crate::dataset::lerobot::LerobotError {
    fn exit(&self) -> Exit {
        use crate::dataset::lerobot::LerobotError as L;
        match self {
            L::Dataset(e) => e.exit(),
            L::NoDatasets { .. } | L::Layout { .. } | L::OutNotEmpty { .. } | L::BadOption(_) | L::RowTooLarge { .. } => Exit::BadInput,
            L::Write { .. } => Exit::Failure,
        }
    }
}

impl Classify for crate::synth::scheduler::SchedulerError {
    fn exit(&self) -> Exit {
        use crate::synth::scheduler::SchedulerError as S;
        match self {
            S::Io { source, .. } => io_exit(source),
            S::Json { .. } | S::Unsupported { .. } | S::BadStepCount { .. } | S::OutOfRange { .. } | S::OutOfBounds { .. } => {
                Exit::BadInput
            }
        }
    }
}

/// An I/O error reading a file a user or a package named: bad input when the file is not
/// what rig reads (too large, not UTF-8: `InvalidData`; a FIFO, a device or a folder:
/// `InvalidInput`; a symlink loop, or a symlink where none may be: `ELOOP`), else a failure
/// (a full disk, a permission, a lost mount).
fn io_exit(e: &std::io::Error) -> Exit {
    if matches!(e.kind(), std::io::ErrorKind::InvalidData | std::io::ErrorKind::InvalidInput) || e.raw_os_error() == Some(libc::ELOOP) {
        Exit::BadInput
    } else {
        Exit::Failure
    }
}

/// The input is fine; this build lacks the part that handles it.
impl Classify for crate::features::FeatureMissing {
    fn exit(&self) -> Exit {
        Exit::Failure
    }
}

impl Classify for crate::synth::SynthError {
    fn exit(&self) -> Exit {
        use crate::synth::SynthError as S;
        match self {
            // The package, the request or a path the user gave.
            S::MissingFiles { .. }
            | S::ModelToml { .. }
            | S::BadModelConfig { .. }
            | S::BadRequest { .. }
            | S::BadModelFile { .. }
            | S::Tokenizer { .. }
            | S::NoEndToken { .. }
            | S::MissingTensor { .. }
            | S::WrongElementType { .. }
            | S::WrongShape { .. }
            | S::UnexpectedInput { .. }
            | S::ResidualCountMismatch { .. }
            | S::OrtLibraryMissing { .. }
            | S::OrtLibraryUntrusted { .. }
            | S::Npy(_) => Exit::BadInput,
            #[cfg(feature = "synth")]
            S::OrtLoad { .. } => Exit::BadInput,
            S::FeatureMissing(e) => e.exit(),
            S::Scheduler { source, .. } => source.exit(),
            S::Confined(e) => e.exit(),
            S::Io { source, .. } => io_exit(source),
            // A cancel request stopped the sampling loop.
            S::Cancelled => Exit::Interrupted,
            // Set-up (scripts/setup.sh not run), or a failure while running a loaded model.
            S::OrtLibraryNotFound { .. } | S::ProviderUnavailable { .. } | S::UnexpectedOutputShape { .. } | S::Image { .. } => {
                Exit::Failure
            }
            #[cfg(feature = "synth")]
            S::Ort { .. } => Exit::Failure,
        }
    }
}

impl Classify for crate::synth::fill::FillError {
    fn exit(&self) -> Exit {
        use crate::synth::fill::FillError as F;
        match self {
            F::Dataset(e) => e.exit(),
            F::Synth(e) => e.exit(),
            F::NoPlan { .. } | F::Object { .. } | F::Calibration { .. } => Exit::BadInput,
        }
    }
}

impl Classify for crate::rigs::RigError {
    fn exit(&self) -> Exit {
        use crate::rigs::RigError as R;
        match self {
            R::UnknownSensor(_)
            | R::Object { .. }
            | R::Profile { .. }
            | R::Calibration { .. }
            | R::BackendUnavailable { .. }
            | R::SimulatedSensorOnRealArm { .. }
            | R::SerialPort(_) => Exit::BadInput,
            // A refused or lost arm connection, also when the rig is opened.
            R::Arm(e) => e.exit(),
            R::Camera { source, .. } => source.exit(),
            R::Modbus(e) => e.exit(),
            R::Sim(_) | R::Moved { .. } => Exit::Failure,
        }
    }
}

impl Classify for crate::fence::FenceError {
    fn exit(&self) -> Exit {
        use crate::fence::FenceError as F;
        match self {
            // rig refused to send the arm there: the plan, the rows or the pattern asked for it.
            F::Unreachable { .. } | F::TooDeep { .. } => Exit::BadInput,
        }
    }
}

impl Classify for crate::calibration::wizard::WizardError {
    fn exit(&self) -> Exit {
        use crate::calibration::wizard::WizardError as W;
        match self {
            W::Io(_) => Exit::Failure,
            W::Press(e) => e.exit(),
        }
    }
}

impl Classify for crate::rigs::PreflightError {
    /// The worst of the devices that failed: a hardware fault (3) before bad input (2).
    fn exit(&self) -> Exit {
        let codes = self.failed.iter().map(|(_, e)| e.exit());
        codes.fold(Exit::Success, |worst, e| match (worst, e) {
            (Exit::HardwareFault, _) | (_, Exit::HardwareFault) => Exit::HardwareFault,
            (Exit::BadInput, _) | (_, Exit::BadInput) => Exit::BadInput,
            (_, e) => e,
        })
    }
}

impl Classify for crate::calibration::press::PressError {
    fn exit(&self) -> Exit {
        use crate::calibration::press::PressError as P;
        match self {
            P::Arm(e) => e.exit(),
            P::Camera(e) => e.exit(),
            P::Fence(e) => e.exit(),
            P::Cancelled { .. } => Exit::Interrupted,
            P::NoReference | P::Fit(_) | P::Unchecked { .. } => Exit::Failure,
        }
    }
}

impl Classify for crate::calibration::CalibrationError {
    fn exit(&self) -> Exit {
        use crate::calibration::CalibrationError as C;
        match self {
            C::Read { .. } | C::Parse { .. } | C::Invalid { .. } => Exit::BadInput,
            C::Write { .. } | C::Encode { .. } => Exit::Failure,
        }
    }
}

impl Classify for crate::arm::profile::ProfileError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::geometry::stl::StlError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::geometry::objects::ObjectError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::sensor::SensorKindParseError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::confine::ConfineError {
    fn exit(&self) -> Exit {
        if self.is_bad_input() { Exit::BadInput } else { Exit::Failure }
    }
}

impl Classify for crate::dataset::named::NamedFileError {
    fn exit(&self) -> Exit {
        match self {
            crate::dataset::named::NamedFileError::Outside { .. } | crate::dataset::named::NamedFileError::NotRegular { .. } => {
                Exit::BadInput
            }
            crate::dataset::named::NamedFileError::Confined { source, .. } => source.exit(),
        }
    }
}

impl Classify for crate::roots::PathError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::roots::RootsError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::jobs::JobError {
    fn exit(&self) -> Exit {
        use crate::jobs::JobError as J;
        match self {
            J::Plan(e) => e.exit(),
            J::Object(e) => e.exit(),
            J::Profile(e) => e.exit(),
            J::Collect(e) => e.exit(),
            J::Dataset { source, .. } => source.exit(),
            J::Fill { source, .. } => source.exit(),
            J::Model { source, .. } => source.exit(),
            J::Press(e) => e.exit(),
            J::Fence(e) => e.exit(),
            J::Request(e) => e.exit(),
            J::Settings(e) => e.exit(),
            J::Replay(e) => e.exit(),
            J::SensorNotOpen { .. } => Exit::BadInput,
            // Every scoring error is bad input: datasets missing, unpaired or inconsistent.
            J::Audit { .. } => Exit::BadInput,
            J::SaveCalibration { .. } | J::Worker { .. } | J::AuditWrite { .. } => Exit::Failure,
        }
    }
}

impl Classify for crate::geometry::objects::ObjectResolveError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::arm::profile::ProfileLookupError {
    fn exit(&self) -> Exit {
        Exit::BadInput
    }
}

impl Classify for crate::record::replay::ReplayError {
    fn exit(&self) -> Exit {
        use crate::record::replay::ReplayError as R;
        match self {
            R::Collect(e) => e.exit(),
            R::Dataset(e) => e.exit(),
            // The replay no longer follows the recording.
            R::Diverged(_) | R::Leftover { .. } | R::PeripheralsDiverged(_) => Exit::HardwareFault,
            // The recording could not be read on: damaged (bad input), or the disk failed.
            R::Recording(e) if e.is_bad_input() => Exit::BadInput,
            R::Recording(_) => Exit::Failure,
        }
    }
}

/// Bad input on the command line (exit code 2).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

/// A [`UsageError`] with this message.
pub fn usage(message: &str) -> UsageError {
    UsageError(message.to_string())
}

/// An error that carries its own exit code.
#[derive(Debug, thiserror::Error)]
#[error("exit status {0}")]
pub struct ExitStatus(pub u8);

impl From<Exit> for ExitStatus {
    fn from(e: Exit) -> Self {
        ExitStatus(e.code())
    }
}

/// The error and its causes on one line, `outer: cause: root`, leaving out a cause whose text
/// the line already holds (many errors here name their source in their own message, as
/// `"binding {addr}: {source}"`, so `{:#}` would print it twice).
pub fn error_report(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("binding {addr}: {source}")]
    struct Bind {
        addr: String,
        #[source]
        source: std::io::Error,
    }

    #[test]
    fn a_cause_already_in_the_message_is_printed_once() {
        let io = std::io::Error::new(std::io::ErrorKind::AddrInUse, "address in use");
        let e = anyhow::Error::new(Bind { addr: "127.0.0.1:8080".into(), source: io }).context("starting the daemon");
        assert_eq!(format!("{e:#}"), "starting the daemon: binding 127.0.0.1:8080: address in use: address in use");
        assert_eq!(error_report(&e), "starting the daemon: binding 127.0.0.1:8080: address in use");
    }

    #[test]
    fn causes_not_in_the_message_are_all_kept() {
        let e = anyhow::anyhow!("root cause").context("middle").context("outer");
        assert_eq!(error_report(&e), "outer: middle: root cause");
        assert_eq!(exit_code(&e), 1);
        assert_eq!(exit_code(&anyhow::Error::new(usage("bad flag"))), 2);
        assert_eq!(exit_code(&anyhow::Error::new(ExitStatus(4))), 4);
    }

    #[test]
    fn wrapped_errors_take_the_code_of_what_they_wrap() {
        use crate::arm::ArmError;
        use crate::dataset::DatasetError;
        // Item 10 of the trust issue: a refused arm connection when the rig opens is a
        // hardware fault, though `RigError::Arm` is transparent and hides it from the chain.
        let refused = ArmError::Io {
            context: "connecting to the MG400 dashboard port at 127.0.0.1:1".into(),
            source: std::io::Error::from(std::io::ErrorKind::ConnectionRefused),
        };
        let e = anyhow::Error::new(crate::rigs::RigError::Arm(refused)).context("opening the rig");
        assert_eq!(Exit::of(&e), Exit::HardwareFault);
        // A bad CSV row is bad input, like a bad header.
        let row = DatasetError::MalformedRow { path: "p".into(), line: 3, reason: "x".into() };
        assert_eq!(Exit::of(&anyhow::Error::new(crate::synth::fill::FillError::Dataset(row))), Exit::BadInput);
        let header = DatasetError::BadHeader { path: "p".into(), found: String::new(), expected: String::new() };
        assert_eq!(Exit::of(&anyhow::Error::new(header)), Exit::BadInput);
        // A corrupt model file or tokenizer is bad input; a full disk is not.
        let onnx = crate::synth::SynthError::BadModelFile { file: "unet/model.onnx".into(), reason: "protobuf".into() };
        assert_eq!(Exit::of(&anyhow::Error::new(onnx).context("loading")), Exit::BadInput);
        let tok = crate::synth::SynthError::Tokenizer { path: "t.json".into(), reason: "x".into() };
        assert_eq!(Exit::of(&anyhow::Error::new(tok)), Exit::BadInput);
        let full = DatasetError::io("writing", "x")(std::io::Error::from_raw_os_error(libc::ENOSPC));
        assert_eq!(Exit::of(&anyhow::Error::new(full)), Exit::Failure);
        assert_eq!(Exit::from_code(3), Some(Exit::HardwareFault));
        assert_eq!(Exit::from_code(9), None);
        // A setting out of range, a bad shard or sampler, a refused request: bad input, bare
        // or wrapped.
        let size = crate::synth::limits::check_size("size", (100_000, 100_000), 8).expect_err("too large");
        assert_eq!(Exit::of(&anyhow::Error::new(size.clone())), Exit::BadInput);
        assert_eq!(Exit::of(&anyhow::Error::new(crate::jobs::RequestError::Setting(size)).context("checking")), Exit::BadInput);
        let shard = "0/3".parse::<crate::synth::settings::Shard>().expect_err("shard 0");
        assert_eq!(Exit::of(&anyhow::Error::new(shard)), Exit::BadInput);
        let sampler = "euler".parse::<crate::synth::SchedulerKind>().expect_err("unknown");
        assert_eq!(Exit::of(&anyhow::Error::new(sampler)), Exit::BadInput);
    }

    /// The guide's Faults page (`docs/src/faults.md`, "Exit codes") holds the table generated
    /// from [`Exit`], verbatim.
    #[test]
    fn the_docs_table_is_the_enum() {
        let table = Exit::markdown_table();
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let faults = std::fs::read_to_string(root.join("docs/src/faults.md")).expect("docs/src/faults.md");
        assert!(faults.contains(&table), "docs/src/faults.md must hold this exit-code table verbatim:\n{table}");
        for e in Exit::ALL {
            assert_eq!(Exit::from_code(e.code()), Some(e));
        }
    }
}
