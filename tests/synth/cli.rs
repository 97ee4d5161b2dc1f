//! Running the rig binary from the tests: the command, its output, success.

use std::process::{Command, Output};

/// `rig` in the repository root, with no rig config from the environment.
pub fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    c
}

/// Standard output, then standard error.
pub fn text(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr)
}

/// Runs `c`, which must succeed; its output.
pub fn ok(mut c: Command) -> String {
    let o = c.output().expect("running rig");
    assert!(o.status.success(), "{c:?} failed:\n{}", text(&o));
    text(&o)
}
