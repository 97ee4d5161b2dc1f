//! The `rig` binary: parses arguments and hands over to the library (`rig::cli`).

fn main() -> std::process::ExitCode {
    rig::cli::main()
}
