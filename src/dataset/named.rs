//! Files a dataset's manifest names: the object's STL (`object.stl_path`) and the calibration
//! (`calibration`). A manifest comes from whoever made the dataset, so a path in it is as
//! untrusted as the dataset: it could name any file on the machine, and an error that said
//! "missing", "permission denied" or "not a valid STL (84 bytes, header ...)" would tell whoever
//! asked (a daemon request) what lies there.
//!
//! Where such a path may lead, in order:
//!
//! 1. a relative path (no `..`) below the dataset folder, through [`crate::confine`] (no
//!    symlink in any component, a regular file, bounded): where a self-contained dataset keeps
//!    them;
//! 2. a relative path (no `..`) below the working folder rig runs in (the daemon's base folder),
//!    the same way: what `rig collect` has written (`calibration/tactip.toml`);
//! 3. for an STL with a `stl_sha256` in the manifest, any path, read as a regular file with a
//!    size bound, used only when its bytes hash to that sha256.
//!
//! Anything else (an absolute calibration path, an absolute STL without a hash, a path with
//! `..`) is refused without being looked at, and every failure of case 3 (missing, too large,
//! another file) gives the same [`NamedFileError::Outside`]: nothing is learned about a
//! regular file outside the dataset and the working folder.
//!
//! A path that names something other than a regular file (`/dev/ptmx`, `/dev/zero`, a FIFO, a
//! folder) is never opened, in any of the three places: its kind is looked at first
//! ([`crate::confine`]), and it is refused as [`NamedFileError::NotRegular`] (or, below the
//! dataset or the working folder, [`NamedFileError::Confined`]), an error no caller replaces
//! with a library object. This says that such a path is not a regular file, and no more.

use std::path::{Component, Path};

use sha2::{Digest, Sha256};

use crate::confine::{ConfineError, RootDir};

/// Why a file a manifest names cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum NamedFileError {
    /// Outside the dataset and the working folder (or, for an STL, not the file its sha256
    /// names): refused with the same words whatever is or is not there.
    #[error(
        "{field} {named:?} is not a path below the dataset folder or the working folder, and rig reads no other file a manifest names \
         (copy the file into the dataset and name it relative to the dataset)"
    )]
    Outside { field: &'static str, named: String },
    /// A path (outside the dataset and the working folder) that names a device, FIFO, socket or
    /// folder: refused before it is opened, and never replaced by a library object.
    #[error("{field} {named:?} is not a regular file (it is {found}); rig opens no device, FIFO or socket a manifest names")]
    NotRegular { field: &'static str, named: String, found: &'static str },
    /// Below the dataset or the working folder, but not a file rig may read there.
    #[error("{field}: {source}")]
    Confined {
        field: &'static str,
        #[source]
        source: ConfineError,
    },
}

/// The bytes of the file the manifest of the dataset at `dataset` names as `named` (`field`
/// says which, for messages), at most `max_bytes`; `Ok(None)` when a plain relative path names
/// no file in either place. `sha256` (hex) is the manifest's hash of the file, if it has one.
pub fn read_named(
    dataset: &Path,
    field: &'static str,
    named: &str,
    sha256: Option<&str>,
    max_bytes: u64,
) -> Result<Option<Vec<u8>>, NamedFileError> {
    let outside = || NamedFileError::Outside { field, named: named.to_string() };
    let path = Path::new(named);
    let plain_relative = !named.is_empty() && path.components().all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
    if plain_relative {
        for folder in [Some(dataset.to_path_buf()), std::env::current_dir().ok()].into_iter().flatten() {
            let found = RootDir::open(&folder).and_then(|root| root.read(path, max_bytes));
            match found {
                Ok(bytes) => return Ok(Some(bytes)),
                Err(ConfineError::Missing { .. }) => continue,
                Err(source) => return Err(NamedFileError::Confined { field, source }),
            }
        }
        return Ok(None);
    }
    // Not below either folder: only a file the manifest's hash names, and no word on why not.
    let Some(expected) = sha256 else { return Err(outside()) };
    match crate::confine::read_named_file(path, max_bytes) {
        Ok(bytes) if hex::encode(Sha256::digest(&bytes)).eq_ignore_ascii_case(expected) => Ok(Some(bytes)),
        // Looked at, never opened: said, so that no caller takes something else in its place.
        Err(ConfineError::NotRegular { found, .. }) => Err(NamedFileError::NotRegular { field, named: named.to_string(), found }),
        _ => Err(outside()),
    }
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::symlink;

    use super::*;

    #[test]
    fn relative_paths_read_below_the_dataset_and_outside_paths_say_nothing() {
        let tmp = tempfile::tempdir().expect("temp dir");
        let top = tmp.path().canonicalize().expect("canonical");
        let ds = top.join("ds");
        std::fs::create_dir_all(ds.join("parts")).expect("mkdir");
        std::fs::write(ds.join("parts/a.stl"), b"solid a").expect("write");
        std::fs::write(top.join("secret.stl"), b"SECRET 200 bytes").expect("write");
        symlink(top.join("secret.stl"), ds.join("parts/link.stl")).expect("symlink");

        assert_eq!(read_named(&ds, "stl_path", "parts/a.stl", None, 100).expect("inside"), Some(b"solid a".to_vec()));
        assert_eq!(read_named(&ds, "stl_path", "parts/nope-xyz.stl", None, 100).expect("absent"), None);
        let e = read_named(&ds, "stl_path", "parts/link.stl", None, 100).expect_err("a symlink");
        assert!(matches!(e, NamedFileError::Confined { source: ConfineError::Symlink { .. }, .. }), "{e}");

        // Outside: an existing file, a missing one and `..` give the same words.
        let existing = top.join("secret.stl").display().to_string();
        let missing = top.join("missing.stl").display().to_string();
        let mut messages = Vec::new();
        for (named, sha) in [(existing.as_str(), None), (missing.as_str(), None), ("../secret.stl", None), (existing.as_str(), Some("00"))]
        {
            let e = read_named(&ds, "calibration", named, sha, 100).expect_err(named);
            assert!(matches!(e, NamedFileError::Outside { .. }), "{named}: {e}");
            assert!(!e.to_string().contains("SECRET"), "{e}");
            messages.push(e.to_string().replace(named, "X"));
        }
        assert!(messages.windows(2).all(|w| w[0] == w[1]), "{messages:?}");
        // A FIFO (or a device: only named) with a hash is refused for what it is, never opened.
        let fifo = top.join("part.stl");
        let c = std::ffi::CString::new(fifo.to_str().expect("utf-8")).expect("c string");
        // SAFETY: mkfifo on a NUL-terminated path in the test's temp folder.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        for named in [fifo.display().to_string(), "/dev/zero".to_string(), "/dev/null".to_string()] {
            let e = read_named(&ds, "stl_path", &named, Some("00"), 100).expect_err(&named);
            assert!(matches!(e, NamedFileError::NotRegular { .. }) && e.to_string().contains("not a regular file"), "{e}");
        }
        // With the right hash, an STL outside is read.
        let sha = hex::encode(Sha256::digest(b"SECRET 200 bytes"));
        assert!(read_named(&ds, "stl_path", &existing, Some(&sha), 100).expect("hash matches").is_some());
    }
}
