//! Running the rig binary from a test: in the test's folder, without `$RIG_CONFIG` (a user's
//! configuration must not leak in), with quiet logs; its output as one text.

use std::path::Path;
use std::process::{Command, Output};

/// `rig ARGS` in `dir`, not yet run.
pub fn rig_cmd(dir: &Path, args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.args(args).current_dir(dir).env_remove("RIG_CONFIG").env("RIG_LOG", "error");
    c
}

/// `rig ARGS` in `dir`, run to the end.
pub fn rig(dir: &Path, args: &[&str]) -> Output {
    rig_cmd(dir, args).output().expect("running rig")
}

/// Standard output, then standard error.
pub fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// The output, after checking the exit code is `code`.
pub fn expect_code(o: &Output, code: i32) -> String {
    let t = text(o);
    assert_eq!(o.status.code(), Some(code), "{t}");
    t
}
