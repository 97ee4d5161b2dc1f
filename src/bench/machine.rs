//! The machine a bench ran on, for the report's header: CPU model and cores (from
//! `/proc/cpuinfo` where it exists), the OS, rig's version and git commit, the build profile
//! and the date. Every field degrades to `unknown` rather than failing the run.

use std::path::Path;

/// What the report says about the machine and the build.
#[derive(Debug, Clone, PartialEq)]
pub struct MachineInfo {
    pub cpu_model: String,
    /// Logical CPUs listed in `/proc/cpuinfo` (0 when unknown).
    pub cpus_listed: usize,
    /// CPUs this process may use (cgroup and affinity limits applied).
    pub cpus_available: usize,
    pub os: String,
    pub rig_version: String,
    /// Short commit hash, with `-dirty` when the working tree has changes; `None` outside git.
    pub git_commit: Option<String>,
    /// `release` or `debug`.
    pub build_profile: &'static str,
    /// UTC date and time the report was started.
    pub date_utc: String,
    /// 1, 5 and 15 minute load averages when the run started (`/proc/loadavg`): other work
    /// on the machine slows every timing.
    pub load_avg: Option<String>,
}

impl MachineInfo {
    /// Reads what this machine says about itself.
    pub fn collect() -> Self {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let (cpu_model, cpus_listed) = parse_cpuinfo(&cpuinfo);
        let os_release = std::fs::read_to_string("/etc/os-release").unwrap_or_default();
        let kernel = std::fs::read_to_string("/proc/sys/kernel/osrelease").unwrap_or_default();
        let os = describe_os(&os_release, kernel.trim());
        Self {
            cpu_model,
            cpus_listed,
            cpus_available: std::thread::available_parallelism().map_or(0, |n| n.get()),
            os,
            rig_version: crate::version().to_string(),
            git_commit: git_commit(Path::new(env!("CARGO_MANIFEST_DIR"))),
            build_profile: if cfg!(debug_assertions) { "debug" } else { "release" },
            date_utc: crate::dataset::manifest::utc_now(),
            load_avg: std::fs::read_to_string("/proc/loadavg")
                .ok()
                .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
                .filter(|l| !l.is_empty()),
        }
    }

    /// The header lines of the report (a Markdown list).
    pub fn markdown(&self) -> String {
        format!(
            "- machine: {} ({} logical CPUs listed, {} available to rig; load average at the start {})\n- OS: {}\n- rig {} (commit {}), {} build\n- date: {}\n",
            self.cpu_model,
            self.cpus_listed,
            self.cpus_available,
            self.load_avg.as_deref().unwrap_or("unknown"),
            self.os,
            self.rig_version,
            self.git_commit.as_deref().unwrap_or("unknown"),
            self.build_profile,
            self.date_utc
        )
    }
}

/// CPU model name and the number of `processor` entries of `/proc/cpuinfo` text.
pub fn parse_cpuinfo(text: &str) -> (String, usize) {
    let value = |line: &str| line.split_once(':').map(|(_, v)| v.trim().to_string());
    let model = text
        .lines()
        .find(|l| l.starts_with("model name") || l.starts_with("Model") || l.starts_with("cpu model"))
        .and_then(value)
        .unwrap_or_else(|| "unknown CPU".to_string());
    let count = text.lines().filter(|l| l.split(':').next().is_some_and(|k| k.trim() == "processor")).count();
    (model, count)
}

/// `PRETTY_NAME` of os-release text plus the kernel release.
pub fn describe_os(os_release: &str, kernel: &str) -> String {
    let pretty = os_release
        .lines()
        .find_map(|l| l.strip_prefix("PRETTY_NAME="))
        .map(|v| v.trim_matches('"').to_string())
        .unwrap_or_else(|| std::env::consts::OS.to_string());
    if kernel.is_empty() { pretty } else { format!("{pretty}, kernel {kernel}") }
}

/// The commit checked out in `dir`, if git is there to ask.
fn git_commit(dir: &Path) -> Option<String> {
    let run = |args: &[&str]| std::process::Command::new("git").args(args).current_dir(dir).output().ok().filter(|o| o.status.success());
    let head = run(&["rev-parse", "--short=12", "HEAD"])?;
    let hash = String::from_utf8_lossy(&head.stdout).trim().to_string();
    if hash.is_empty() {
        return None;
    }
    let dirty = run(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|o| !o.stdout.is_empty());
    Some(if dirty { format!("{hash}-dirty") } else { hash })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpuinfo_gives_model_and_count() {
        let text = "processor\t: 0\nmodel name\t: AMD EPYC 7B13\nflags\t: x\n\nprocessor\t: 1\nmodel name\t: AMD EPYC 7B13\n";
        assert_eq!(parse_cpuinfo(text), ("AMD EPYC 7B13".to_string(), 2));
        assert_eq!(parse_cpuinfo(""), ("unknown CPU".to_string(), 0));
    }

    #[test]
    fn os_names_the_distribution_and_kernel() {
        let os = describe_os("NAME=\"Ubuntu\"\nPRETTY_NAME=\"Ubuntu 24.04 LTS\"\n", "6.8.0");
        assert_eq!(os, "Ubuntu 24.04 LTS, kernel 6.8.0");
    }
}
