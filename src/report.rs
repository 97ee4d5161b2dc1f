//! How a failed command reports itself: the exit code of an error (shared by the CLI and the
//! daemon's job records) and its one-line message.

/// Exit codes: 1 general failure (including a full disk), 2 bad input (usage, config, plan,
/// object, calibration, profile, model package and dataset files; a plan outside the
/// workspace), 3 hardware or protocol fault (arm alarms and lost connections once retries are
/// spent, camera failures), 4 interrupted. the README's "Bad input" table lists each bad input.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    if let Some(code) = e.downcast_ref::<ExitStatus>() {
        return code.0;
    }
    if e.downcast_ref::<UsageError>().is_some()
        || matches!(e.downcast_ref::<crate::collect::CollectError>(), Some(crate::collect::CollectError::Unreachable { .. }))
    {
        return 2;
    }
    for cause in e.chain() {
        if cause.downcast_ref::<crate::arm::ArmError>().is_some() || cause.downcast_ref::<crate::camera::CameraError>().is_some() {
            return 3;
        }
        if let Some(e) = cause.downcast_ref::<crate::collect::CollectError>() {
            use crate::collect::CollectError as C;
            match e {
                C::RetriesExhausted { .. }
                | C::CameraRetriesExhausted { .. }
                | C::PeripheralRetriesExhausted { .. }
                | C::Arm(_)
                | C::Camera(_) => return 3,
                C::Peripheral(e) if e.is_recoverable() => return 3,
                C::Peripheral(_) => return 2,
                C::Unreachable { .. } | C::Mismatch { .. } => return 2,
                C::Dataset(_) => {}
            }
        }
        if let Some(e) = cause.downcast_ref::<crate::jobs::JobError>()
            && matches!(e, crate::jobs::JobError::BadOption { .. } | crate::jobs::JobError::SensorNotOpen { .. })
        {
            return 2;
        }
        if cause.downcast_ref::<crate::config::ConfigError>().is_some()
            || cause.downcast_ref::<crate::geometry::objects::ObjectResolveError>().is_some()
            || cause.downcast_ref::<crate::arm::profile::ProfileLookupError>().is_some()
        {
            return 2;
        }
        if let Some(e) = cause.downcast_ref::<crate::synth::SynthError>() {
            use crate::synth::SynthError as S;
            if matches!(e, S::MissingFiles { .. } | S::ModelToml { .. } | S::BadModelConfig { .. } | S::BadRequest { .. }) {
                return 2;
            }
        }
        if let Some(e) = cause.downcast_ref::<crate::rigs::RigError>() {
            use crate::rigs::RigError as R;
            if matches!(e, R::UnknownSensor(_) | R::Object(_) | R::Profile(_) | R::Calibration { .. }) {
                return 2;
            }
            if let R::Modbus(m) = e {
                return if m.is_recoverable() { 3 } else { 2 };
            }
        }
        if cause.downcast_ref::<crate::plan::PlanError>().is_some() {
            return 2;
        }
        if let Some(e) = cause.downcast_ref::<crate::dataset::DatasetError>() {
            use crate::dataset::DatasetError as D;
            if matches!(
                e,
                D::NotEmpty { .. }
                    | D::NotADataset { .. }
                    | D::ManifestMismatch { .. }
                    | D::MalformedMds { .. }
                    | D::BadHeader { .. }
                    | D::ManifestParse { .. }
            ) {
                return 2;
            }
        }
    }
    1
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
}
