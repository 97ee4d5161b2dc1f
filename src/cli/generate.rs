//! `rig generate man|completions`: the man pages (clap_mangen) and shell completions
//! (clap_complete), made from the same clap definitions the binary parses with, so they cannot
//! drift from it.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Subcommand;

/// Arguments of `rig generate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub what: What,
}

/// What to generate.
#[derive(Debug, Subcommand)]
pub enum What {
    /// Man pages: rig.1 and one page per subcommand (rig-collect.1, rig-synth-one.1, ...).
    #[command(after_help = crate::cli::examples::GENERATE_MAN)]
    Man {
        /// Output folder (created when absent).
        #[arg(long, default_value = "man")]
        out: PathBuf,
    },
    /// Shell completions, to standard output or into a folder.
    #[command(after_help = crate::cli::examples::GENERATE_COMPLETIONS)]
    Completions {
        /// bash, zsh, fish, elvish or powershell.
        shell: clap_complete::Shell,
        /// Output folder (created when absent); the file is named as the shell expects.
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

/// Runs `rig generate` for `command`, the whole command-line interface (`Cli::command()`; the
/// dispatcher passes it in so this module does not import it).
pub fn run(args: Args, mut command: clap::Command) -> anyhow::Result<()> {
    match args.what {
        What::Man { out } => {
            let pages = write_man_pages(command, &out)?;
            println!("wrote {} man pages into {}", pages.len(), out.display());
            Ok(())
        }
        What::Completions { shell, out: Some(out) } => {
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            let path = clap_complete::generate_to(shell, &mut command, "rig", &out)
                .with_context(|| format!("writing {shell} completions into {}", out.display()))?;
            println!("wrote {}", path.display());
            Ok(())
        }
        What::Completions { shell, out: None } => {
            clap_complete::generate(shell, &mut command, "rig", &mut std::io::stdout());
            Ok(())
        }
    }
}

/// Writes `rig.1` and a page per (nested) subcommand of `command` into `out`; returns their paths.
pub fn write_man_pages(command: clap::Command, out: &Path) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    clap_mangen::generate_to(command, out).with_context(|| format!("writing man pages into {}", out.display()))?;
    let mut pages: Vec<PathBuf> = std::fs::read_dir(out)
        .with_context(|| format!("listing {}", out.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "1"))
        .collect();
    pages.sort();
    Ok(pages)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{CommandFactory, Parser};

    /// Every command and subcommand, by its path of names (`["synth", "one"]`).
    fn all_commands(cmd: &clap::Command, path: Vec<String>, into: &mut Vec<(Vec<String>, clap::Command)>) {
        for sub in cmd.get_subcommands().filter(|s| s.get_name() != "help") {
            let mut p = path.clone();
            p.push(sub.get_name().to_string());
            into.push((p.clone(), sub.clone()));
            all_commands(sub, p, into);
        }
    }

    #[test]
    fn every_subcommand_has_examples_and_every_example_parses() {
        let mut commands = Vec::new();
        all_commands(&crate::cli::Cli::command(), Vec::new(), &mut commands);
        assert!(commands.len() >= 25, "{} commands", commands.len());
        let mut examples = 0;
        for (path, cmd) in &commands {
            let help = cmd.get_after_help().map(|h| h.to_string()).unwrap_or_default();
            assert!(help.starts_with("Examples:\n"), "`rig {}` has no examples in its --help", path.join(" "));
            let lines: Vec<&str> = help.lines().skip(1).map(str::trim).filter(|l| l.starts_with("rig ")).collect();
            assert!((1..=3).contains(&lines.len()), "`rig {}`: {} examples", path.join(" "), lines.len());
            // At least one example runs this very command.
            assert!(lines.iter().any(|l| l.starts_with(&format!("rig {}", path.join(" ")))), "`rig {}`: {lines:?}", path.join(" "));
            for line in lines {
                let words: Vec<&str> = line.split_whitespace().collect();
                if let Err(e) = crate::cli::Cli::try_parse_from(&words) {
                    panic!("the example `{line}` of `rig {}` does not parse: {e}", path.join(" "));
                }
                examples += 1;
            }
        }
        assert!(examples >= commands.len());
    }

    #[test]
    fn a_misspelt_example_would_fail_to_parse() {
        // What the test above relies on: clap refuses a flag that does not exist.
        assert!(crate::cli::Cli::try_parse_from(["rig", "collect", "--objct", "edge"]).is_err());
        assert!(crate::cli::Cli::try_parse_from(["rig", "collect", "--object", "edge"]).is_ok());
    }

    #[test]
    fn man_pages_cover_every_subcommand_and_show_the_examples() {
        let dir = tempfile::tempdir().expect("tempdir");
        let pages = write_man_pages(crate::cli::Cli::command(), dir.path()).expect("man pages");
        let names: Vec<String> = pages.iter().filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned())).collect();
        for expected in ["rig.1", "rig-collect.1", "rig-synth-one.1", "rig-dataset-verify.1", "rig-generate-completions.1"] {
            assert!(names.iter().any(|n| n == expected), "{expected} missing from {names:?}");
        }
        let collect = std::fs::read_to_string(dir.path().join("rig-collect.1")).expect("rig-collect.1");
        assert!(collect.contains("plans/demo.toml"), "the examples are in the man page");
        assert!(collect.contains("\\-\\-resume"), "the options are in the man page");
    }

    #[test]
    fn completions_name_the_subcommands_and_their_flags() {
        let mut bash = Vec::new();
        clap_complete::generate(clap_complete::Shell::Bash, &mut crate::cli::Cli::command(), "rig", &mut bash);
        let bash = String::from_utf8(bash).expect("utf-8");
        for word in ["collect", "fill-missing", "--poses-of", "contact-sheet", "--twin-size"] {
            assert!(bash.contains(word), "{word} not in the bash completions");
        }
    }
}
