//! Data roots: the folders a long-lived service (`rig daemon`) may read and write, and the
//! confinement of every path a request names to them.
//!
//! ```text
//!   --root DIR ... (or the working folder) ──► DataRoots::new ──► canonical roots + base folder
//!   a request's path ──► DataRoots::input  (must exist)      ──► canonical path inside a root
//!                   └──► DataRoots::output (may not exist yet) ─► resolved path inside a root
//! ```
//!
//! Roots are canonicalised once, at start (a root that is itself a symlink is followed then,
//! and only then). A relative path in a request is relative to the base folder captured at
//! start (the daemon's working folder), never to whatever the current folder is later.
//!
//! - [`DataRoots::input`]: the path must exist; it is canonicalised (every symlink resolved,
//!   `..` resolved as the kernel does) and the result must lie inside a root.
//! - [`DataRoots::output`]: the longest existing ancestor is canonicalised; the components
//!   below it (which do not exist yet, so cannot be symlinks) are appended; a `..` among them
//!   is refused; the result must lie inside a root.
//!
//! Both return the resolved path: use it, not the path as given, for the actual file access.
//! Errors name the path as given, never the resolved target (which could describe files
//! outside the roots) and never any file's contents. What this does not cover: a process
//! that can write inside a root can still swap a component for a symlink between the check
//! and the use; the roots confine requests, not other local users.

use std::ffi::OsString;
use std::fmt;
use std::path::{Component, Path, PathBuf};

/// Why a set of roots could not be made.
#[derive(Debug, thiserror::Error)]
pub enum RootsError {
    #[error("data root {root}: {source}")]
    Unreadable {
        root: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("data root {root} is not a folder")]
    NotAFolder { root: PathBuf },
    #[error("the working folder cannot be read: {source}")]
    WorkingFolder {
        #[source]
        source: std::io::Error,
    },
}

/// Why a path was refused.
#[derive(Debug, thiserror::Error)]
pub enum PathError {
    #[error("{field} is empty")]
    Empty { field: String },
    #[error("{field} {given}: outside the data roots ({roots}); start the daemon with --root DIR to let jobs use DIR")]
    Outside { field: String, given: PathBuf, roots: String },
    #[error("{field} {given}: does not exist")]
    Missing { field: String, given: PathBuf },
    #[error("{field} {given}: `..` below the part that exists is not allowed")]
    ParentDir { field: String, given: PathBuf },
    #[error("{field} {given}: a symlink to nothing (rig does not write through symlinks)")]
    DanglingSymlink { field: String, given: PathBuf },
    #[error("{field} {given}: goes through a symlink below the data root (rig follows no symlink below a root)")]
    Symlink { field: String, given: PathBuf },
    #[error("{field} {given}: cannot be resolved ({kind})")]
    Unresolvable { field: String, given: PathBuf, kind: std::io::ErrorKind },
    /// Longer than a path rig can make files below ([`check_length`]); the path itself is not
    /// echoed (it may be kilobytes long).
    #[error(
        "{field}: the path is {problem}; rig takes paths of at most {MAX_PATH_BYTES} bytes (room left below PATH_MAX for the \
         folders and files a job makes in it) and {MAX_NAME_BYTES} bytes a component (NAME_MAX)"
    )]
    TooLong { field: String, given: PathBuf, problem: String },
}

/// Longest path a request may name, bytes, once made absolute: PATH_MAX (4096 with its NUL)
/// less room for what a job makes below it (`<object>/<sensor>/images/.<pose_id>.png.tmp` is
/// at most about 140 bytes).
pub const MAX_PATH_BYTES: usize = 3584;
/// Longest component of a path, bytes (NAME_MAX).
pub const MAX_NAME_BYTES: usize = 255;

/// Refuses a path no file below could be made at: longer than [`MAX_PATH_BYTES`] or with a
/// component longer than [`MAX_NAME_BYTES`]. Checked when a request is checked, before the job
/// is queued, so the job cannot fail on it later.
pub fn check_length(field: &str, path: &Path) -> Result<(), PathError> {
    use std::os::unix::ffi::OsStrExt;
    let too_long = |problem: String| Err(PathError::TooLong { field: field.into(), given: path.into(), problem });
    let total = path.as_os_str().as_bytes().len();
    if total > MAX_PATH_BYTES {
        return too_long(format!("{total} bytes long"));
    }
    if let Some(longest) = path.components().map(|c| c.as_os_str().as_bytes().len()).max()
        && longest > MAX_NAME_BYTES
    {
        return too_long(format!("{total} bytes long with a component of {longest} bytes"));
    }
    Ok(())
}

impl PathError {
    /// The path as the request gave it (`None` for an empty one).
    pub fn given(&self) -> Option<&Path> {
        match self {
            PathError::Empty { .. } => None,
            PathError::Outside { given, .. }
            | PathError::Missing { given, .. }
            | PathError::ParentDir { given, .. }
            | PathError::DanglingSymlink { given, .. }
            | PathError::Symlink { given, .. }
            | PathError::Unresolvable { given, .. }
            | PathError::TooLong { given, .. } => Some(given),
        }
    }
}

/// The folders requests may touch, canonical, and the folder relative paths start from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DataRoots {
    roots: Vec<PathBuf>,
    base: PathBuf,
}

impl fmt::Display for DataRoots {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let list: Vec<String> = self.roots.iter().map(|r| r.display().to_string()).collect();
        f.write_str(&list.join(", "))
    }
}

impl DataRoots {
    /// Roots `dirs` (relative ones against `base`), or `base` alone when `dirs` is empty.
    /// Each must be an existing folder; all are canonicalised now.
    pub fn new(dirs: &[PathBuf], base: &Path) -> Result<Self, RootsError> {
        let base = canonical_folder(base)?;
        let given: Vec<PathBuf> = if dirs.is_empty() { vec![base.clone()] } else { dirs.to_vec() };
        let mut roots = Vec::with_capacity(given.len());
        for dir in given {
            let root = canonical_folder(&base.join(&dir)).map_err(|e| match e {
                RootsError::Unreadable { source, .. } => RootsError::Unreadable { root: dir.clone(), source },
                RootsError::NotAFolder { .. } => RootsError::NotAFolder { root: dir.clone() },
                other => other,
            })?;
            if !roots.contains(&root) {
                roots.push(root);
            }
        }
        Ok(Self { roots, base })
    }

    /// [`new`](Self::new) with the current working folder as the base.
    pub fn from_working_folder(dirs: &[PathBuf]) -> Result<Self, RootsError> {
        let cwd = std::env::current_dir().map_err(|source| RootsError::WorkingFolder { source })?;
        Self::new(dirs, &cwd)
    }

    /// The canonical roots.
    pub fn roots(&self) -> &[PathBuf] {
        &self.roots
    }

    /// The canonical folder relative paths are taken from.
    pub fn base(&self) -> &Path {
        &self.base
    }

    /// Whether the canonical path `path` lies inside a root (a root itself counts).
    pub fn contains(&self, path: &Path) -> bool {
        self.roots.iter().any(|r| path.starts_with(r))
    }

    /// An existing file or folder a request reads: canonicalised (symlinks resolved) and
    /// inside a root. `field` names the request field in errors (`"plan"`, `"dataset"`).
    pub fn input(&self, field: &str, given: &Path) -> Result<PathBuf, PathError> {
        let absolute = self.absolute(field, given)?;
        match absolute.canonicalize() {
            Ok(canonical) if self.contains(&canonical) => self.no_symlink_below_root(field, given, &absolute, canonical),
            Ok(_) => Err(self.outside(field, given)),
            // Only a path lexically inside a root may say it is missing: elsewhere that would
            // tell a caller which files exist outside the roots.
            Err(_) if !self.contains(&lexical(&absolute)) => Err(self.outside(field, given)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(PathError::Missing { field: field.into(), given: given.into() }),
            Err(e) => Err(PathError::Unresolvable { field: field.into(), given: given.into(), kind: e.kind() }),
        }
    }

    /// A file or folder a request writes, which may not exist yet: its longest existing
    /// ancestor canonicalised, the rest appended (no `..` there), inside a root.
    pub fn output(&self, field: &str, given: &Path) -> Result<PathBuf, PathError> {
        let absolute = self.absolute(field, given)?;
        let mut existing = absolute.as_path();
        let mut tail: Vec<OsString> = Vec::new();
        let canonical = loop {
            match existing.canonicalize() {
                Ok(c) => break c,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(_) if !self.contains(&lexical(&absolute)) => return Err(self.outside(field, given)),
                Err(e) => return Err(PathError::Unresolvable { field: field.into(), given: given.into(), kind: e.kind() }),
            }
            match (existing.parent(), existing.file_name()) {
                (Some(parent), Some(name)) => {
                    tail.push(name.to_os_string());
                    existing = parent;
                }
                // `..` as the last component has no file name: it is below the existing part.
                (Some(_), None) => return Err(PathError::ParentDir { field: field.into(), given: given.into() }),
                (None, _) => return Err(self.outside(field, given)),
            }
        };
        // `Path::file_name` skips `.`; a `..` component anywhere in the tail is refused.
        if absolute.strip_prefix(existing).is_ok_and(|rest| rest.components().any(|c| c == Component::ParentDir)) {
            return Err(PathError::ParentDir { field: field.into(), given: given.into() });
        }
        // The first missing component may still be a symlink whose target is missing: writing
        // there would create the target, wherever it points.
        if let Some(first) = tail.last()
            && canonical.join(first).symlink_metadata().is_ok()
        {
            return Err(PathError::DanglingSymlink { field: field.into(), given: given.into() });
        }
        let resolved = tail.iter().rev().fold(canonical, |path, name| path.join(name));
        if self.contains(&resolved) {
            self.no_symlink_below_root(field, given, &absolute, resolved)
        } else {
            Err(self.outside(field, given))
        }
    }

    /// `resolved` (inside a root) when the path as given reached it without a symlink below the
    /// root: the given path, `..` applied, is a root (or the operator's own symlink to one)
    /// followed by components that resolve to exactly themselves. A path that reaches a root
    /// from outside every root (a link elsewhere pointing in) is not below a root and is kept.
    fn no_symlink_below_root(&self, field: &str, given: &Path, absolute: &Path, resolved: PathBuf) -> Result<PathBuf, PathError> {
        let lexical = lexical(absolute);
        for ancestor in lexical.ancestors() {
            let Ok(root) = ancestor.canonicalize() else { continue };
            if self.roots.contains(&root) {
                let below = lexical.strip_prefix(ancestor).unwrap_or(Path::new(""));
                let expected = if below.as_os_str().is_empty() { root } else { root.join(below) };
                return if expected == resolved {
                    Ok(resolved)
                } else {
                    Err(PathError::Symlink { field: field.into(), given: given.into() })
                };
            }
        }
        Ok(resolved)
    }

    fn absolute(&self, field: &str, given: &Path) -> Result<PathBuf, PathError> {
        if given.as_os_str().is_empty() {
            return Err(PathError::Empty { field: field.into() });
        }
        let absolute = self.base.join(given);
        check_length(field, &absolute)?;
        Ok(absolute)
    }

    fn outside(&self, field: &str, given: &Path) -> PathError {
        PathError::Outside { field: field.into(), given: given.into(), roots: self.to_string() }
    }
}

fn canonical_folder(dir: &Path) -> Result<PathBuf, RootsError> {
    let canonical = dir.canonicalize().map_err(|source| RootsError::Unreadable { root: dir.to_path_buf(), source })?;
    if !canonical.is_dir() {
        return Err(RootsError::NotAFolder { root: dir.to_path_buf() });
    }
    Ok(canonical)
}

/// `path` with `.` dropped and `..` applied textually (only to decide which error to give
/// for a path that cannot be canonicalised; never used for access).
fn lexical(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use std::os::unix::ffi::OsStrExt;
    use std::os::unix::fs::symlink;

    use super::*;

    /// A temp folder holding `root/` (with `root/data/plan.toml` and `root/out/`) and, beside
    /// it, `outside/secret.txt`: the sentinel no path may reach.
    struct Fixture {
        _tmp: tempfile::TempDir,
        top: PathBuf,
        roots: DataRoots,
    }

    fn fixture() -> Fixture {
        let tmp = tempfile::tempdir().expect("temp dir");
        let top = tmp.path().canonicalize().expect("canonical temp dir");
        for dir in ["root/data", "root/out", "outside"] {
            std::fs::create_dir_all(top.join(dir)).expect("mkdir");
        }
        std::fs::write(top.join("root/data/plan.toml"), "x").expect("write");
        std::fs::write(top.join("outside/secret.txt"), "sentinel").expect("write");
        let roots = DataRoots::new(&[PathBuf::from("root")], &top).expect("roots");
        Fixture { _tmp: tmp, top, roots }
    }

    #[test]
    fn inputs_inside_resolve_and_outside_are_refused() {
        let f = fixture();
        let plan = f.roots.input("plan", Path::new("root/data/plan.toml")).expect("inside");
        assert_eq!(plan, f.top.join("root/data/plan.toml"));
        // An absolute path inside works too, and `..` that stays inside is resolved.
        assert_eq!(f.roots.input("plan", &f.top.join("root/out/../data/plan.toml")).expect("inside"), plan);
        for escape in ["outside/secret.txt", "root/../outside/secret.txt", "root/data/../../outside/secret.txt", "/"] {
            let e = f.roots.input("plan", Path::new(escape)).expect_err(escape);
            assert!(matches!(e, PathError::Outside { .. }), "{escape}: {e}");
            assert!(e.to_string().contains(escape) && !e.to_string().contains("sentinel"), "{e}");
        }
        let e = f.roots.input("plan", Path::new("root/data/nope.toml")).expect_err("missing");
        assert!(matches!(e, PathError::Missing { .. }), "{e}");
        // A missing file outside the roots is "outside", not "missing": no existence oracle.
        let e = f.roots.input("plan", &f.top.join("outside/nope")).expect_err("outside");
        assert!(matches!(e, PathError::Outside { .. }), "{e}");
        assert!(matches!(f.roots.input("plan", Path::new("")), Err(PathError::Empty { .. })));
    }

    /// A path no file could be made below (30 components of 255 bytes, or one of 256) is
    /// refused whether it is given or made absolute from the base; NAME_MAX itself is fine.
    #[test]
    fn paths_too_long_for_files_below_are_refused() {
        let f = fixture();
        let long = vec!["d".repeat(255); 30].join("/");
        let e = f.roots.output("out", &Path::new("root/out").join(&long)).expect_err("7.7 kB");
        assert!(matches!(e, PathError::TooLong { .. }) && e.to_string().contains("bytes a component"), "{e}");
        assert!(!e.to_string().contains(&long), "the path is not echoed");
        assert!(matches!(check_length("out", Path::new(&"n".repeat(256))), Err(PathError::TooLong { .. })));
        check_length("out", Path::new(&"n".repeat(255))).expect("NAME_MAX is a name");
        let deep_but_fine = vec!["d".repeat(200); 10].join("/");
        f.roots.output("out", &Path::new("root/out").join(deep_but_fine)).expect("2 kB of path");
    }

    #[test]
    fn symlinks_escaping_the_roots_are_refused() {
        let f = fixture();
        symlink(f.top.join("outside/secret.txt"), f.top.join("root/data/link.toml")).expect("symlink");
        symlink(f.top.join("outside"), f.top.join("root/out/escape")).expect("symlink");
        symlink(f.top.join("root/data/plan.toml"), f.top.join("root/out/inner.toml")).expect("symlink");
        let e = f.roots.input("plan", Path::new("root/data/link.toml")).expect_err("escapes");
        assert!(matches!(e, PathError::Outside { .. }), "{e}");
        assert!(!e.to_string().contains("secret"), "the resolved target is not named: {e}");
        assert!(matches!(f.roots.input("plan", Path::new("root/out/escape/secret.txt")), Err(PathError::Outside { .. })));
        // A symlink below a root is refused even when it stays inside: it is not the path named.
        let e = f.roots.input("plan", Path::new("root/out/inner.toml")).expect_err("a symlink below the root");
        assert!(matches!(e, PathError::Symlink { .. }), "{e}");
        symlink(f.top.join("root/data"), f.top.join("root/out/data-link")).expect("symlink");
        for through in ["root/out/data-link/plan.toml", "root/out/data-link/../data/plan.toml"] {
            assert!(matches!(f.roots.input("plan", Path::new(through)), Err(PathError::Symlink { .. })), "{through}");
        }
        for out in ["root/out/data-link/new.toml", "root/out/data-link/a/b", "root/out/data-link"] {
            assert!(matches!(f.roots.output("out", Path::new(out)), Err(PathError::Symlink { .. })), "{out}");
        }
        // Outputs through a symlinked folder, existing or not yet, are refused.
        for out in ["root/out/escape/new.toml", "root/out/escape/a/b/c", "root/out/escape", "root/data/link.toml"] {
            assert!(matches!(f.roots.output("out", Path::new(out)), Err(PathError::Outside { .. })), "{out}");
        }
        // A dangling symlink pointing outside: its target does not exist yet.
        symlink(f.top.join("outside/new.txt"), f.top.join("root/out/dangling")).expect("symlink");
        let e = f.roots.output("out", Path::new("root/out/dangling")).expect_err("a dangling symlink is not a place to write");
        assert!(matches!(e, PathError::DanglingSymlink { .. }), "{e}");
        assert!(f.roots.output("out", Path::new("root/out/dangling/x")).is_err());
    }

    #[test]
    fn outputs_may_not_exist_yet_but_may_not_climb_out() {
        let f = fixture();
        assert_eq!(f.roots.output("out", Path::new("root/out/a/b/cal.toml")).expect("inside"), f.top.join("root/out/a/b/cal.toml"));
        assert_eq!(f.roots.output("out", Path::new("root/out")).expect("inside"), f.top.join("root/out"));
        assert_eq!(f.roots.output("out", Path::new("root/./out/x")).expect("inside"), f.top.join("root/out/x"));
        for escape in ["../../x", "root/new/../../outside/x", "root/out/new/../../../outside/x", "root/out/x/.."] {
            let e = f.roots.output("out", Path::new(escape)).expect_err(escape);
            assert!(matches!(e, PathError::ParentDir { .. } | PathError::Outside { .. }), "{escape}: {e}");
        }
        assert!(matches!(f.roots.output("out", Path::new("root/out/x/..")), Err(PathError::ParentDir { .. })));
        assert!(matches!(f.roots.output("out", Path::new("outside/new.txt")), Err(PathError::Outside { .. })));
        assert!(matches!(f.roots.output("out", Path::new("root2/x")), Err(PathError::Outside { .. })), "a sibling with the root's prefix");
        // `..` in the part that exists is resolved as the kernel would.
        assert_eq!(f.roots.output("out", Path::new("root/data/../out/y")).expect("inside"), f.top.join("root/out/y"));
        assert!(!f.top.join("outside/new.txt").exists() && !f.top.join("root/out/a").exists(), "checks create nothing");
    }

    #[test]
    fn a_root_that_is_a_symlink_is_followed_once() {
        let f = fixture();
        symlink(f.top.join("root"), f.top.join("root-link")).expect("symlink");
        let roots = DataRoots::new(&[PathBuf::from("root-link")], &f.top).expect("roots");
        assert_eq!(roots.roots(), &[f.top.join("root")]);
        assert_eq!(roots.input("plan", Path::new("root-link/data/plan.toml")).expect("inside"), f.top.join("root/data/plan.toml"));
        assert_eq!(roots.output("out", Path::new("root/out/n")).expect("inside"), f.top.join("root/out/n"));
        assert!(matches!(roots.input("x", Path::new("outside/secret.txt")), Err(PathError::Outside { .. })));
    }

    #[test]
    fn relative_paths_start_from_the_base_and_roots_are_checked() {
        let f = fixture();
        let base_is_root = DataRoots::new(&[], &f.top.join("root")).expect("roots");
        assert_eq!(base_is_root.roots(), &[f.top.join("root")]);
        assert_eq!(base_is_root.input("plan", Path::new("data/plan.toml")).expect("inside"), f.top.join("root/data/plan.toml"));
        assert!(matches!(base_is_root.input("plan", Path::new("../outside/secret.txt")), Err(PathError::Outside { .. })));
        let two = DataRoots::new(&[PathBuf::from("root/data"), f.top.join("root/out")], &f.top).expect("roots");
        assert_eq!(two.roots().len(), 2);
        assert!(two.output("out", Path::new("root/out/z")).is_ok());
        assert!(two.output("out", Path::new("root/z")).is_err());
        assert!(matches!(DataRoots::new(&[PathBuf::from("nope")], &f.top), Err(RootsError::Unreadable { .. })));
        assert!(matches!(DataRoots::new(&[PathBuf::from("root/data/plan.toml")], &f.top), Err(RootsError::NotAFolder { .. })));
    }

    #[test]
    fn non_utf8_names_work_and_are_shown_lossily() {
        let f = fixture();
        let name = std::ffi::OsStr::from_bytes(b"caf\xe9");
        let inside = f.top.join("root/out").join(name);
        std::fs::create_dir(&inside).expect("mkdir non-UTF-8");
        assert_eq!(f.roots.input("dataset", &inside).expect("inside"), inside);
        assert_eq!(f.roots.output("out", &inside.join("x")).expect("inside"), inside.join("x"));
        let outside = f.top.join("outside").join(name);
        let e = f.roots.output("out", &outside).expect_err("outside");
        assert!(e.to_string().contains("caf\u{fffd}"), "{e}");
        assert_eq!(e.given(), Some(outside.as_path()));
    }
}
