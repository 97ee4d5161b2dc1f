//! The one opener for every path that a request, dataset, manifest, model package or recording
//! can name: beneath a root folder handle, with no symlink in any component, regular files
//! only, sizes bounded before reading.
//!
//! ```text
//!   a path the operator typed (--dataset /data/x) ──► RootDir::open  (its own symlinks followed, once)
//!   a file the operator typed (--plan p.toml)      ──► open_operator_file / read_operator_file (same)
//!   a path a file or request names ("images/3.png") ──► RootDir::{read, open_file, entries, write_atomic, ...}
//!                                                      └─ resolved beneath the root's fd, no symlink anywhere
//! ```
//!
//! A confined path is relative, has no `..` and no symlink in any component (the last included);
//! it is resolved from the root's open file descriptor, never by string. A symlink one folder
//! below an approved path (`R/coll/sphere -> /elsewhere`), a FIFO, a device or a 10 GB "image"
//! are refused with a [`ConfineError`] that names the path as given and the rule it broke, and
//! nothing about what lies outside.
//!
//! Mechanism: on Linux, `openat2(2)` with `RESOLVE_BENEATH | RESOLVE_NO_SYMLINKS |
//! RESOLVE_NO_MAGICLINKS` (the kernel refuses the whole walk atomically, so a component swapped
//! for a symlink between two checks cannot slip through). Where `openat2` is missing (Linux
//! before 5.6, some seccomp sandboxes answer `ENOSYS` or `EPERM`, or another Unix) the same
//! rules are kept by walking the path one component at a time with
//! `openat(O_NOFOLLOW | O_DIRECTORY)` from the held folder fd. Both go through `rustix` (safe
//! syscall wrappers, already in rig's dependency tree); `cap-std` does the same walk but would
//! add a dozen crates and hides which of the two resolutions ran.
//!
//! Files are opened `O_NONBLOCK` (a FIFO or a device cannot block the open) and checked with
//! `fstat` on the opened fd before one byte is read; reads stop at the bound. Writes are
//! atomic: a temp name created exclusively inside the held folder fd, written, fsynced, renamed
//! (`renameat`) over the final name, the folder fsynced.
//!
//! What this does not guarantee: the root itself is the operator's choice and is not checked;
//! hard links to outside files cannot be told from files (a hard link needs write access to
//! the folder, and rig never creates one); a local user who can write inside a root can still
//! change files between two of rig's reads.

use std::ffi::{OsStr, OsString};
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::os::unix::ffi::OsStrExt;
use std::path::{Component, Path, PathBuf};
#[cfg(target_os = "linux")]
use std::sync::atomic::{AtomicBool, Ordering};

use rustix::fs::{AtFlags, FileType, Mode, OFlags};
use rustix::io::Errno;

/// Why a confined path was refused or could not be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfineError {
    #[error("{path}: not a path below {root} (rig takes relative paths without `..` there)")]
    Escapes { root: PathBuf, path: PathBuf },
    #[error("{path}: a symlink on the way; rig follows no symlink below {root}")]
    Symlink { root: PathBuf, path: PathBuf },
    #[error("{path} is not a regular file (it is {found})")]
    NotRegular { path: PathBuf, found: &'static str },
    #[error("{path} is not a folder")]
    NotFolder { path: PathBuf },
    /// Opening found something other than a folder and a look right after found a folder:
    /// the entry was swapped while rig opened it (a symlink or a file put in its place and back).
    #[error("{path} changed while rig opened it (swapped for a symlink or a file and back); rig follows no symlink below {root}")]
    Changed { root: PathBuf, path: PathBuf },
    #[error("{path} is larger than the {max_bytes} bytes rig reads from such a file")]
    TooLarge { path: PathBuf, max_bytes: u64 },
    #[error("{path} does not exist")]
    Missing { path: PathBuf },
    #[error("{path} is not UTF-8 text")]
    NotText { path: PathBuf },
    /// A file rig appends to has another name somewhere (`st_nlink` > 1): appending would grow
    /// a file outside the folder too.
    #[error("{path} has {links} hard links; rig appends only to a file with no other name (copy it to break the link)")]
    HardLinked { path: PathBuf, links: u64 },
    #[error("{op} {path}: {source}")]
    Io {
        op: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl ConfineError {
    /// The path the error is about, as the root's path joined with the path given.
    pub fn path(&self) -> &Path {
        match self {
            ConfineError::Escapes { path, .. }
            | ConfineError::Symlink { path, .. }
            | ConfineError::NotRegular { path, .. }
            | ConfineError::NotFolder { path }
            | ConfineError::Changed { path, .. }
            | ConfineError::TooLarge { path, .. }
            | ConfineError::Missing { path }
            | ConfineError::NotText { path }
            | ConfineError::HardLinked { path, .. }
            | ConfineError::Io { path, .. } => path,
        }
    }

    /// Whether the input broke a rule (exit 2) rather than the machine failing (exit 1).
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, ConfineError::Io { .. })
    }
}

/// What an entry is, read without following a symlink.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntryKind {
    File,
    Folder,
    Symlink,
    /// A FIFO, socket, device or anything else.
    Other,
}

impl EntryKind {
    fn of(t: FileType) -> Self {
        match t {
            FileType::RegularFile => EntryKind::File,
            FileType::Directory => EntryKind::Folder,
            FileType::Symlink => EntryKind::Symlink,
            _ => EntryKind::Other,
        }
    }

    /// "a folder", "a symlink", ... for messages.
    pub fn describe(self) -> &'static str {
        match self {
            EntryKind::File => "a regular file",
            EntryKind::Folder => "a folder",
            EntryKind::Symlink => "a symlink",
            EntryKind::Other => "a FIFO, socket or device",
        }
    }
}

/// One entry of a listed folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    pub name: OsString,
    pub kind: EntryKind,
}

/// What [`RootDir::stat`] found: the kind (never through a symlink) and, for a file, its size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EntryInfo {
    pub kind: EntryKind,
    pub len_bytes: u64,
}

/// How paths below the root are resolved.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Resolution {
    /// `openat2` with `RESOLVE_BENEATH | RESOLVE_NO_SYMLINKS | RESOLVE_NO_MAGICLINKS`, falling
    /// back to the walk when the kernel lacks it.
    Kernel,
    /// Component by component with `openat(O_NOFOLLOW)`.
    Walk,
}

/// Set once `openat2` answered ENOSYS or EPERM: every later resolution walks.
#[cfg(target_os = "linux")]
static OPENAT2_MISSING: AtomicBool = AtomicBool::new(false);

/// An open folder that paths are confined beneath.
#[derive(Debug)]
pub struct RootDir {
    fd: OwnedFd,
    path: PathBuf,
    resolution: Resolution,
}

/// The held folder's descriptor (to lock it, or to sync it).
impl AsFd for RootDir {
    fn as_fd(&self) -> std::os::fd::BorrowedFd<'_> {
        self.fd.as_fd()
    }
}

impl RootDir {
    /// Opens the folder the operator named (a path typed on the command line, a configured
    /// data root, a folder already confined by [`crate::roots::DataRoots`]): its own symlinks
    /// are followed, once, here. Everything below it goes through the no-symlink rule.
    pub fn open(path: &Path) -> Result<Self, ConfineError> {
        let fd = rustix::fs::open(path, OFlags::RDONLY | OFlags::DIRECTORY | OFlags::CLOEXEC, Mode::empty()).map_err(|e| match e {
            Errno::NOENT => ConfineError::Missing { path: path.to_path_buf() },
            Errno::NOTDIR => ConfineError::NotFolder { path: path.to_path_buf() },
            e => ConfineError::Io { op: "opening", path: path.to_path_buf(), source: e.into() },
        })?;
        Ok(Self { fd, path: path.to_path_buf(), resolution: Resolution::Kernel })
    }

    /// [`open`](Self::open), resolving below it by the component walk only (the fallback taken
    /// where `openat2` is missing), so tests can exercise it on any kernel.
    pub fn open_walking(path: &Path) -> Result<Self, ConfineError> {
        Ok(Self { resolution: Resolution::Walk, ..Self::open(path)? })
    }

    /// The root's path, for messages and for handing to code that takes paths.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The folder `rel` below the root, as a root of its own.
    pub fn open_dir(&self, rel: impl AsRef<Path>) -> Result<RootDir, ConfineError> {
        let rel = rel.as_ref();
        let parts = self.parts(rel)?;
        let fd = self.resolve_parts(rel, &parts, OFlags::RDONLY | OFlags::DIRECTORY)?;
        Ok(RootDir { fd, path: self.path.join(rel), resolution: self.resolution })
    }

    /// Opens the regular file `rel` for reading. A FIFO, device, socket or folder is refused
    /// without being opened (see `open_regular`).
    pub fn open_file(&self, rel: impl AsRef<Path>) -> Result<File, ConfineError> {
        let (fd, _) = self.open_regular(rel.as_ref(), OFlags::RDONLY)?;
        Ok(File::from(fd))
    }

    /// Opens the regular file `rel` for reading and appending (`poses.csv`), refused like
    /// [`open_file`](Self::open_file) and also when it has another name (a hard link: appending
    /// would grow a file elsewhere too).
    pub fn open_append(&self, rel: impl AsRef<Path>) -> Result<File, ConfineError> {
        let rel = rel.as_ref();
        let (fd, links) = self.open_regular(rel, OFlags::RDWR | OFlags::APPEND)?;
        if links > 1 {
            return Err(ConfineError::HardLinked { path: self.path.join(rel), links });
        }
        Ok(File::from(fd))
    }

    /// Opens the regular file `rel` with `access`, returning it (blocking mode) and its link
    /// count. Its kind is looked at before it is opened: on Linux the path is resolved to an
    /// `O_PATH` descriptor (which opens nothing: no driver sees it, a FIFO does not block, a
    /// serial port's DTR line stays down), checked with `fstat`, and only a regular file is then
    /// opened, through that descriptor (`/proc/self/fd/N`, so the file checked is the file
    /// opened). Where `/proc` is missing, or on another Unix, `rel` is resolved again
    /// non-blocking and must be the same file (device and inode) as the one checked.
    fn open_regular(&self, rel: &Path, access: OFlags) -> Result<(OwnedFd, u64), ConfineError> {
        let parts = self.parts(rel)?;
        let path = self.path.join(rel);
        if parts.is_empty() {
            return Err(ConfineError::NotRegular { path: self.path.clone(), found: EntryKind::Folder.describe() });
        }
        let checked = self.regular_stat(rel, &parts)?;
        #[cfg(target_os = "linux")]
        let reopened = match &checked.1 {
            Some(handle) => {
                let proc_path = format!("/proc/self/fd/{}", std::os::fd::AsRawFd::as_raw_fd(handle));
                match rustix::fs::open(proc_path.as_str(), access | OFlags::NONBLOCK | OFlags::CLOEXEC, Mode::empty()) {
                    Ok(fd) => Some(fd),
                    Err(Errno::NOENT | Errno::NOTDIR) => None,
                    Err(e) => return Err(self.open_error(rel, e)),
                }
            }
            None => None,
        };
        #[cfg(not(target_os = "linux"))]
        let reopened: Option<OwnedFd> = None;
        let fd = match reopened {
            Some(fd) => fd,
            None => self.resolve_parts(rel, &parts, access | OFlags::NONBLOCK)?,
        };
        let stat = rustix::fs::fstat(&fd).map_err(io("inspecting", &path))?;
        let kind = EntryKind::of(FileType::from_raw_mode(stat.st_mode));
        if kind != EntryKind::File {
            return Err(ConfineError::NotRegular { path, found: kind.describe() });
        }
        if (stat.st_dev, stat.st_ino) != (checked.0.st_dev, checked.0.st_ino) {
            // Swapped between the look and the open: refuse rather than guess.
            return Err(ConfineError::Io { op: "opening", path, source: std::io::Error::other("the file changed while it was opened") });
        }
        // Reads of a regular file never block; clear the flag so the File behaves as usual.
        rustix::fs::fcntl_setfl(&fd, access & OFlags::APPEND).map_err(io("opening", &path))?;
        Ok((fd, stat.st_nlink as u64))
    }

    /// What `rel` is, looked at without opening it: its `fstat` and (Linux) the `O_PATH`
    /// descriptor it was taken on; an error unless it is a regular file.
    fn regular_stat(&self, rel: &Path, parts: &[&OsStr]) -> Result<(rustix::fs::Stat, Option<OwnedFd>), ConfineError> {
        let path = self.path.join(rel);
        #[cfg(target_os = "linux")]
        let (stat, handle) = {
            let handle = self.resolve_parts(rel, parts, OFlags::PATH)?;
            (rustix::fs::fstat(&handle).map_err(io("inspecting", &path))?, Some(handle))
        };
        #[cfg(not(target_os = "linux"))]
        let (stat, handle) = {
            let (last, folders) = parts.split_last().ok_or_else(|| ConfineError::NotRegular { path: path.clone(), found: "a folder" })?;
            let parent_rel: PathBuf = folders.iter().collect();
            let parent = self.resolve_parts(&parent_rel, folders, OFlags::RDONLY | OFlags::DIRECTORY)?;
            let stat = rustix::fs::statat(&parent, *last, AtFlags::SYMLINK_NOFOLLOW).map_err(|e| self.open_error(rel, e))?;
            (stat, None::<OwnedFd>)
        };
        match EntryKind::of(FileType::from_raw_mode(stat.st_mode)) {
            EntryKind::File => Ok((stat, handle)),
            EntryKind::Symlink => Err(ConfineError::Symlink { root: self.path.clone(), path }),
            kind => Err(ConfineError::NotRegular { path, found: kind.describe() }),
        }
    }

    /// The bytes of the regular file `rel`, refused when larger than `max_bytes` (checked on
    /// the opened file before reading, and again while reading).
    pub fn read(&self, rel: impl AsRef<Path>, max_bytes: u64) -> Result<Vec<u8>, ConfineError> {
        let rel = rel.as_ref();
        let file = self.open_file(rel)?;
        let path = self.path.join(rel);
        read_bounded(file, &path, max_bytes)
    }

    /// [`read`](Self::read), as UTF-8 text.
    pub fn read_text(&self, rel: impl AsRef<Path>, max_bytes: u64) -> Result<String, ConfineError> {
        let rel = rel.as_ref();
        let bytes = self.read(rel, max_bytes)?;
        String::from_utf8(bytes).map_err(|_| ConfineError::NotText { path: self.path.join(rel) })
    }

    /// What `rel` is (never following a symlink, the last component included), `None` when it
    /// does not exist. A symlink on the way to it is an error.
    pub fn stat(&self, rel: impl AsRef<Path>) -> Result<Option<EntryInfo>, ConfineError> {
        let rel = rel.as_ref();
        let parts = self.parts(rel)?;
        let Some((last, folders)) = parts.split_last() else {
            return Ok(Some(EntryInfo { kind: EntryKind::Folder, len_bytes: 0 }));
        };
        let parent_rel: PathBuf = folders.iter().collect();
        let parent = match self.resolve_parts(&parent_rel, folders, OFlags::RDONLY | OFlags::DIRECTORY) {
            Ok(fd) => fd,
            Err(ConfineError::Missing { .. }) => return Ok(None),
            Err(e) => return Err(e),
        };
        match rustix::fs::statat(&parent, *last, AtFlags::SYMLINK_NOFOLLOW) {
            Ok(st) => Ok(Some(EntryInfo { kind: EntryKind::of(FileType::from_raw_mode(st.st_mode)), len_bytes: st.st_size as u64 })),
            Err(Errno::NOENT) => Ok(None),
            Err(e) => Err(io("inspecting", &self.path.join(rel))(e)),
        }
    }

    /// The entries of the folder `rel` (`""` for the root), sorted by name, each with its kind
    /// as the folder says it (a symlink is reported as one, never followed).
    pub fn entries(&self, rel: impl AsRef<Path>) -> Result<Vec<Entry>, ConfineError> {
        let rel = rel.as_ref();
        let dir = if rel.as_os_str().is_empty() { self.reopen()? } else { self.open_dir(rel)? };
        let path = self.path.join(rel);
        let mut list = rustix::fs::Dir::read_from(&dir.fd).map_err(io("listing", &path))?;
        let mut out = Vec::new();
        while let Some(entry) = list.read() {
            let entry = entry.map_err(io("listing", &path))?;
            let name = entry.file_name().to_bytes();
            if name == b"." || name == b".." {
                continue;
            }
            let mut kind = EntryKind::of(entry.file_type());
            if entry.file_type() == FileType::Unknown {
                // Some file systems do not say: ask, without following.
                let st = rustix::fs::statat(&dir.fd, entry.file_name(), AtFlags::SYMLINK_NOFOLLOW).map_err(io("listing", &path))?;
                kind = EntryKind::of(FileType::from_raw_mode(st.st_mode));
            }
            out.push(Entry { name: OsStr::from_bytes(name).to_os_string(), kind });
        }
        out.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(out)
    }

    /// The folder `rel` and every missing folder above it, created one at a time below the
    /// root (`mkdirat`), none of them through a symlink. Returns it as a root.
    pub fn create_dir_all(&self, rel: impl AsRef<Path>) -> Result<RootDir, ConfineError> {
        let rel = rel.as_ref();
        let parts = self.parts(rel)?;
        let mut cur = self.reopen()?;
        let mut done = PathBuf::new();
        for part in parts {
            done.push(part);
            let path = self.path.join(&done);
            match rustix::fs::mkdirat(&cur.fd, part, Mode::from_raw_mode(0o777)) {
                Ok(()) | Err(Errno::EXIST) => {}
                Err(e) => return Err(io("creating", &path)(e)),
            }
            let fd = cur.step_into(part, &done)?;
            cur = RootDir { fd, path, resolution: self.resolution };
        }
        Ok(cur)
    }

    /// Creates the file `rel` (it must not exist; its folder must) and opens it for writing.
    pub fn create_new(&self, rel: impl AsRef<Path>) -> Result<File, ConfineError> {
        let rel = rel.as_ref();
        let (dir, name) = self.parent_of(rel)?;
        let fd = rustix::fs::openat(
            &dir.fd,
            name.as_os_str(),
            OFlags::WRONLY | OFlags::CREATE | OFlags::EXCL | OFlags::NOFOLLOW | OFlags::CLOEXEC,
            Mode::from_raw_mode(0o666),
        )
        .map_err(io("creating", &self.path.join(rel)))?;
        Ok(File::from(fd))
    }

    /// Writes `rel` atomically and durably: `.<name>.tmp` created exclusively in the held
    /// folder, written, fsynced, renamed over `<name>` (replacing a symlink there rather than
    /// writing through it), the folder fsynced. A failed write removes its temp file.
    pub fn write_atomic(&self, rel: impl AsRef<Path>, bytes: &[u8]) -> Result<(), ConfineError> {
        self.write_atomic_with(rel, |f| f.write_all(bytes))
    }

    /// [`write_atomic`](Self::write_atomic) with the content written by `fill` (a test can make
    /// it fail as a full disk would).
    pub fn write_atomic_with(
        &self,
        rel: impl AsRef<Path>,
        fill: impl FnOnce(&mut File) -> std::io::Result<()>,
    ) -> Result<(), ConfineError> {
        let rel = rel.as_ref();
        let (dir, name) = self.parent_of(rel)?;
        let mut tmp_name = OsString::from(".");
        tmp_name.push(&name);
        tmp_name.push(".tmp");
        let tmp_path = dir.path.join(&tmp_name);
        // A temp file left by a killed run (or planted): removing it removes a link, never its target.
        match rustix::fs::unlinkat(&dir.fd, tmp_name.as_os_str(), AtFlags::empty()) {
            Ok(()) | Err(Errno::NOENT) => {}
            Err(e) => return Err(io("removing", &tmp_path)(e)),
        }
        let fd = rustix::fs::openat(
            &dir.fd,
            tmp_name.as_os_str(),
            OFlags::WRONLY | OFlags::CREATE | OFlags::EXCL | OFlags::NOFOLLOW | OFlags::CLOEXEC,
            Mode::from_raw_mode(0o666),
        )
        .map_err(io("creating", &tmp_path))?;
        let mut file = File::from(fd);
        let written = fill(&mut file).and_then(|()| file.sync_all());
        drop(file);
        let renamed = written
            .and_then(|()| rustix::fs::renameat(&dir.fd, tmp_name.as_os_str(), &dir.fd, name.as_os_str()).map_err(std::io::Error::from));
        if let Err(e) = renamed {
            // A full disk must not leave the temp file behind (it would make a dataset unclean).
            let _ = rustix::fs::unlinkat(&dir.fd, tmp_name.as_os_str(), AtFlags::empty());
            return Err(ConfineError::Io { op: "writing", path: self.path.join(rel), source: e });
        }
        dir.sync()
    }

    /// Makes renames and removals in this folder durable (`fsync` on the held descriptor).
    pub fn sync(&self) -> Result<(), ConfineError> {
        rustix::fs::fsync(&self.fd).map_err(io("syncing", &self.path))
    }

    /// Removes the empty folder `rel` (never following a symlink); absent is fine.
    pub fn remove_dir(&self, rel: impl AsRef<Path>) -> Result<(), ConfineError> {
        let rel = rel.as_ref();
        let (dir, name) = self.parent_of(rel)?;
        match rustix::fs::unlinkat(&dir.fd, name.as_os_str(), AtFlags::REMOVEDIR) {
            Ok(()) | Err(Errno::NOENT) => Ok(()),
            Err(e) => Err(io("removing", &self.path.join(rel))(e)),
        }
    }

    /// Removes the file (or symlink: the link, never its target) `rel`; absent is fine.
    pub fn remove_file(&self, rel: impl AsRef<Path>) -> Result<(), ConfineError> {
        let rel = rel.as_ref();
        let (dir, name) = self.parent_of(rel)?;
        match rustix::fs::unlinkat(&dir.fd, name.as_os_str(), AtFlags::empty()) {
            Ok(()) | Err(Errno::NOENT) => Ok(()),
            Err(e) => Err(io("removing", &self.path.join(rel))(e)),
        }
    }

    /// A second handle on the same folder.
    fn reopen(&self) -> Result<RootDir, ConfineError> {
        let fd = self.fd.try_clone().map_err(|e| ConfineError::Io { op: "opening", path: self.path.clone(), source: e })?;
        Ok(RootDir { fd, path: self.path.clone(), resolution: self.resolution })
    }

    /// The folder holding `rel` (opened confined) and `rel`'s last component.
    fn parent_of(&self, rel: &Path) -> Result<(RootDir, OsString), ConfineError> {
        let parts = self.parts(rel)?;
        let Some((last, folders)) = parts.split_last() else {
            return Err(ConfineError::NotRegular { path: self.path.clone(), found: EntryKind::Folder.describe() });
        };
        let name = last.to_os_string();
        if folders.is_empty() {
            return Ok((self.reopen()?, name));
        }
        let parent_rel: PathBuf = folders.iter().collect();
        Ok((self.open_dir(parent_rel)?, name))
    }

    /// `rel`'s normal components; an absolute path or a `..` is refused.
    fn parts<'a>(&self, rel: &'a Path) -> Result<Vec<&'a OsStr>, ConfineError> {
        let mut parts = Vec::new();
        for c in rel.components() {
            match c {
                Component::Normal(p) => parts.push(p),
                Component::CurDir => {}
                Component::RootDir | Component::Prefix(_) | Component::ParentDir => {
                    return Err(ConfineError::Escapes { root: self.path.clone(), path: self.path.join(rel) });
                }
            }
        }
        Ok(parts)
    }

    /// Opens `parts` (the components of `rel`) below the root with `flags`, by `openat2` or by
    /// the walk; a symlink anywhere is refused.
    fn resolve_parts(&self, rel: &Path, parts: &[&OsStr], flags: OFlags) -> Result<OwnedFd, ConfineError> {
        if parts.is_empty() {
            return Ok(self.reopen()?.fd);
        }
        #[cfg(target_os = "linux")]
        if self.resolution == Resolution::Kernel && !OPENAT2_MISSING.load(Ordering::Relaxed) {
            let joined: PathBuf = parts.iter().collect();
            let resolve =
                rustix::fs::ResolveFlags::BENEATH | rustix::fs::ResolveFlags::NO_SYMLINKS | rustix::fs::ResolveFlags::NO_MAGICLINKS;
            // EAGAIN: a rename raced the lookup; the kernel asks to try again.
            for _ in 0..8 {
                match rustix::fs::openat2(&self.fd, joined.as_path(), flags | OFlags::NOFOLLOW | OFlags::CLOEXEC, Mode::empty(), resolve) {
                    Ok(fd) => return Ok(fd),
                    Err(Errno::AGAIN) => continue,
                    Err(Errno::NOSYS | Errno::PERM) => {
                        OPENAT2_MISSING.store(true, Ordering::Relaxed);
                        break;
                    }
                    // A symlink somewhere: say which component, by walking.
                    Err(Errno::LOOP | Errno::XDEV | Errno::NOTDIR) => return self.walk(rel, parts, flags),
                    Err(e) => return Err(self.open_error(rel, e)),
                }
            }
        }
        self.walk(rel, parts, flags)
    }

    /// The component walk: each folder opened `O_DIRECTORY | O_NOFOLLOW` from the last.
    fn walk(&self, rel: &Path, parts: &[&OsStr], flags: OFlags) -> Result<OwnedFd, ConfineError> {
        let mut cur: Option<OwnedFd> = None;
        let mut done = PathBuf::new();
        for (i, part) in parts.iter().enumerate() {
            done.push(part);
            let at = cur.as_ref().map_or(self.fd.as_fd(), |fd| fd.as_fd());
            let last = i + 1 == parts.len();
            let step_flags = if last { flags } else { OFlags::RDONLY | OFlags::DIRECTORY };
            let fd = match rustix::fs::openat(at, *part, step_flags | OFlags::NOFOLLOW | OFlags::CLOEXEC, Mode::empty()) {
                Ok(fd) => fd,
                Err(e) => return Err(self.classify_failure(at, part, &done, !last || flags.contains(OFlags::DIRECTORY), e)),
            };
            cur = Some(fd);
        }
        cur.ok_or_else(|| ConfineError::Escapes { root: self.path.clone(), path: self.path.join(rel) })
    }

    /// One step of [`create_dir_all`](Self::create_dir_all): `part` below this folder.
    fn step_into(&self, part: &OsStr, done: &Path) -> Result<OwnedFd, ConfineError> {
        rustix::fs::openat(&self.fd, part, OFlags::RDONLY | OFlags::DIRECTORY | OFlags::NOFOLLOW | OFlags::CLOEXEC, Mode::empty())
            .map_err(|e| self.classify_failure(self.fd.as_fd(), part, done, true, e))
    }

    /// Why opening `part` in `at` failed: a symlink, not a folder (`want_folder`) or not a
    /// file, missing, or I/O.
    fn classify_failure(&self, at: std::os::fd::BorrowedFd<'_>, part: &OsStr, done: &Path, want_folder: bool, e: Errno) -> ConfineError {
        let path = self.path.join(done);
        match rustix::fs::statat(at, part, AtFlags::SYMLINK_NOFOLLOW) {
            Ok(st) if FileType::from_raw_mode(st.st_mode) == FileType::Symlink => ConfineError::Symlink { root: self.path.clone(), path },
            // `O_DIRECTORY | O_NOFOLLOW` said "not a folder" yet the entry is one now: it was
            // swapped between the two calls.
            Ok(st) if e == Errno::NOTDIR && want_folder && FileType::from_raw_mode(st.st_mode) == FileType::Directory => {
                ConfineError::Changed { root: self.path.clone(), path }
            }
            Ok(_) if e == Errno::NOTDIR && want_folder => ConfineError::NotFolder { path },
            Ok(st) if e == Errno::NOTDIR => {
                ConfineError::NotRegular { path, found: EntryKind::of(FileType::from_raw_mode(st.st_mode)).describe() }
            }
            _ => self.open_error(done, e),
        }
    }

    fn open_error(&self, rel: &Path, e: Errno) -> ConfineError {
        let path = self.path.join(rel);
        match e {
            Errno::NOENT => ConfineError::Missing { path },
            // `O_DIRECTORY | O_NOFOLLOW` on a symlink answers ENOTDIR: look at what is there
            // (a look only; nothing is opened through it).
            Errno::NOTDIR => {
                match rustix::fs::statat(&self.fd, rel, AtFlags::SYMLINK_NOFOLLOW).map(|st| FileType::from_raw_mode(st.st_mode)) {
                    Ok(FileType::Symlink) => ConfineError::Symlink { root: self.path.clone(), path },
                    Ok(FileType::Directory) => ConfineError::Changed { root: self.path.clone(), path },
                    _ => ConfineError::NotFolder { path },
                }
            }
            Errno::LOOP => ConfineError::Symlink { root: self.path.clone(), path },
            Errno::XDEV => ConfineError::Escapes { root: self.path.clone(), path },
            e => io("opening", &path)(e),
        }
    }
}

/// Reads at most `max_bytes` of an open regular file (its size checked first).
pub fn read_bounded(file: File, path: &Path, max_bytes: u64) -> Result<Vec<u8>, ConfineError> {
    let len = file.metadata().map_err(|e| ConfineError::Io { op: "reading", path: path.to_path_buf(), source: e })?.len();
    if len > max_bytes {
        return Err(ConfineError::TooLarge { path: path.to_path_buf(), max_bytes });
    }
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max_bytes + 1).read_to_end(&mut bytes).map_err(|e| ConfineError::Io {
        op: "reading",
        path: path.to_path_buf(),
        source: e,
    })?;
    if bytes.len() as u64 > max_bytes {
        return Err(ConfineError::TooLarge { path: path.to_path_buf(), max_bytes });
    }
    Ok(bytes)
}

/// Opens the regular file the operator typed (`--plan plans/edge.toml`, `--control hint.png`,
/// `--stl part.stl`): like [`RootDir::open`] for a folder, the operator's own symlinks are
/// followed, once, here. The open cannot block (`O_NONBLOCK`: a FIFO or a device answers at
/// once) and the kind is checked with `fstat` on the opened descriptor, so nothing can be
/// swapped in between a check and the open. Paths a file or a request names go through a
/// [`RootDir`] instead.
pub fn open_operator_file(path: &Path) -> Result<File, ConfineError> {
    // A device is never opened at all (opening a serial port raises its DTR line, which resets
    // some boards): its kind is looked at first, then checked again on what was opened.
    let missing = |e: Errno| match e {
        Errno::NOENT | Errno::NOTDIR => ConfineError::Missing { path: path.to_path_buf() },
        e => ConfineError::Io { op: "inspecting", path: path.to_path_buf(), source: e.into() },
    };
    let kind = EntryKind::of(FileType::from_raw_mode(rustix::fs::stat(path).map_err(missing)?.st_mode));
    if kind != EntryKind::File {
        return Err(ConfineError::NotRegular { path: path.to_path_buf(), found: kind.describe() });
    }
    let fd = rustix::fs::open(path, OFlags::RDONLY | OFlags::NONBLOCK | OFlags::CLOEXEC, Mode::empty()).map_err(|e| match e {
        Errno::NOENT | Errno::NOTDIR => ConfineError::Missing { path: path.to_path_buf() },
        e => ConfineError::Io { op: "opening", path: path.to_path_buf(), source: e.into() },
    })?;
    let stat = rustix::fs::fstat(&fd).map_err(io("inspecting", path))?;
    let kind = EntryKind::of(FileType::from_raw_mode(stat.st_mode));
    if kind != EntryKind::File {
        return Err(ConfineError::NotRegular { path: path.to_path_buf(), found: kind.describe() });
    }
    rustix::fs::fcntl_setfl(&fd, OFlags::empty()).map_err(io("opening", path))?;
    Ok(File::from(fd))
}

/// The bytes of the regular file the operator typed ([`open_operator_file`]), at most
/// `max_bytes` (checked on the opened file before reading, and again while reading).
pub fn read_operator_file(path: &Path, max_bytes: u64) -> Result<Vec<u8>, ConfineError> {
    read_bounded(open_operator_file(path)?, path, max_bytes)
}

/// Splits `path` (a path the operator or a request gave, already confined to its roots) into
/// the folder it lives in, opened as a root, and its file name: the folder's own symlinks are
/// the operator's, the file name must not be one.
pub fn open_parent(path: &Path) -> Result<(RootDir, OsString), ConfineError> {
    let name =
        path.file_name().ok_or_else(|| ConfineError::NotRegular { path: path.to_path_buf(), found: EntryKind::Folder.describe() })?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => RootDir::open(p)?,
        // A bare file name: the working folder, shown as nothing so messages name `name` alone.
        _ => RootDir { path: PathBuf::new(), ..RootDir::open(Path::new("."))? },
    };
    Ok((dir, name.to_os_string()))
}

/// Reads the regular file the operator named at `path` (its folder may be reached through the
/// operator's symlinks; the file itself must not be a symlink, a FIFO or a device), bounded.
pub fn read_named_file(path: &Path, max_bytes: u64) -> Result<Vec<u8>, ConfineError> {
    let (dir, name) = open_parent(path)?;
    let file = dir.open_file(&name)?;
    read_bounded(file, path, max_bytes)
}

fn io(op: &'static str, path: &Path) -> impl FnOnce(Errno) -> ConfineError {
    let path = path.to_path_buf();
    move |e| ConfineError::Io { op, path, source: e.into() }
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::symlink;

    use super::*;

    /// `top/root/{a/b/file.txt, a/file.txt, file.txt}` and `top/outside/secret.txt`.
    fn fixture() -> (tempfile::TempDir, PathBuf) {
        let tmp = tempfile::tempdir().expect("temp dir");
        let top = tmp.path().to_path_buf();
        std::fs::create_dir_all(top.join("root/a/b")).expect("mkdir");
        std::fs::create_dir_all(top.join("outside/a/b")).expect("mkdir");
        for f in ["root/a/b/file.txt", "root/a/file.txt", "root/file.txt"] {
            std::fs::write(top.join(f), "inside").expect("write");
        }
        for f in ["outside/secret.txt", "outside/a/b/file.txt", "outside/a/file.txt", "outside/file.txt"] {
            std::fs::write(top.join(f), "sentinel").expect("write");
        }
        (tmp, top)
    }

    fn roots(top: &Path) -> [RootDir; 2] {
        [RootDir::open(&top.join("root")).expect("root"), RootDir::open_walking(&top.join("root")).expect("root")]
    }

    #[test]
    fn plain_paths_below_the_root_read() {
        let (_tmp, top) = fixture();
        for root in roots(&top) {
            assert_eq!(root.read_text("a/b/file.txt", 100).expect("read"), "inside");
            assert_eq!(root.read_text("./a/./file.txt", 100).expect("read"), "inside");
            assert_eq!(root.open_dir("a").expect("dir").read_text("b/file.txt", 100).expect("read"), "inside");
            assert!(matches!(root.read("a/nope.txt", 100), Err(ConfineError::Missing { .. })));
            assert!(matches!(root.read("nope/x.txt", 100), Err(ConfineError::Missing { .. })));
        }
    }

    /// The race the dataset writer meets when `images/` is swapped with a symlink and back:
    /// the open answers ENOTDIR (a symlink under `O_DIRECTORY | O_NOFOLLOW`) and the look
    /// right after finds a folder again. That is a change under rig's feet, named as such
    /// (with the word symlink), never "not a folder".
    #[test]
    fn a_folder_that_was_not_one_a_moment_ago_is_reported_as_changed() {
        let (_tmp, top) = fixture();
        for root in roots(&top) {
            let walked = root.classify_failure(root.fd.as_fd(), OsStr::new("a"), Path::new("a"), true, Errno::NOTDIR);
            assert!(matches!(walked, ConfineError::Changed { .. }), "{walked}");
            assert!(walked.to_string().contains("symlink") && walked.is_bad_input(), "{walked}");
            let kernel = root.open_error(Path::new("a"), Errno::NOTDIR);
            assert!(matches!(kernel, ConfineError::Changed { .. }), "{kernel}");
            // Still a symlink, or a file: said as they are.
            symlink(top.join("outside/a"), top.join("root/now-a-link")).expect("symlink");
            let link = root.open_error(Path::new("now-a-link"), Errno::NOTDIR);
            assert!(matches!(link, ConfineError::Symlink { .. }), "{link}");
            let file = root.classify_failure(root.fd.as_fd(), OsStr::new("file.txt"), Path::new("file.txt"), true, Errno::NOTDIR);
            assert!(matches!(file, ConfineError::NotFolder { .. }), "{file}");
            std::fs::remove_file(top.join("root/now-a-link")).expect("rm");
        }
    }

    #[test]
    fn a_symlink_at_any_depth_is_refused() {
        let (_tmp, top) = fixture();
        let outside = top.join("outside");
        // Depth 0: the file itself; 1: its folder; 2: the folder above; and a link that stays inside.
        symlink(outside.join("file.txt"), top.join("root/link.txt")).expect("symlink");
        symlink(outside.join("a"), top.join("root/a/b/deep")).expect("symlink");
        symlink(outside.join("a"), top.join("root/la")).expect("symlink");
        symlink(top.join("root/file.txt"), top.join("root/a/inner.txt")).expect("symlink");
        symlink("../../outside/file.txt", top.join("root/a/relative.txt")).expect("symlink");
        for root in roots(&top) {
            for rel in
                ["link.txt", "la/file.txt", "la/b/file.txt", "a/b/deep/file.txt", "a/b/deep/b/file.txt", "a/inner.txt", "a/relative.txt"]
            {
                let e = root.read(rel, 100).expect_err(rel);
                assert!(matches!(e, ConfineError::Symlink { .. }), "{rel}: {e}");
                assert!(!e.to_string().contains("sentinel") && !e.to_string().contains("outside"), "{e}");
            }
            assert!(matches!(root.open_dir("la"), Err(ConfineError::Symlink { .. })));
            assert!(matches!(root.entries("la"), Err(ConfineError::Symlink { .. })));
            assert!(matches!(root.create_dir_all("la/new"), Err(ConfineError::Symlink { .. })));
            assert!(matches!(root.write_atomic("la/new.txt", b"x"), Err(ConfineError::Symlink { .. })));
            assert!(matches!(root.stat("la/file.txt"), Err(ConfineError::Symlink { .. })));
            assert_eq!(root.stat("la").expect("stat").map(|i| i.kind), Some(EntryKind::Symlink));
        }
        assert!(!outside.join("a/new").exists() && !outside.join("a/new.txt").exists());
        assert_eq!(std::fs::read_to_string(outside.join("file.txt")).expect("read"), "sentinel");
    }

    #[test]
    fn parent_folders_and_absolute_paths_are_refused() {
        let (_tmp, top) = fixture();
        let secret = top.join("outside/secret.txt");
        for root in roots(&top) {
            for rel in ["../outside/secret.txt", "a/../../outside/secret.txt", "a/..", secret.to_str().expect("utf-8"), "/"] {
                let e = root.read(rel, 100).expect_err(rel);
                assert!(matches!(e, ConfineError::Escapes { .. }), "{rel}: {e}");
            }
            assert!(matches!(root.create_dir_all("../x"), Err(ConfineError::Escapes { .. })));
            assert!(matches!(root.write_atomic("../x.txt", b"x"), Err(ConfineError::Escapes { .. })));
            assert!(matches!(root.remove_file("../outside/secret.txt"), Err(ConfineError::Escapes { .. })));
        }
        assert!(secret.exists() && !top.join("x").exists() && !top.join("x.txt").exists());
    }

    #[test]
    fn fifos_folders_and_oversized_files_are_refused_before_reading() {
        let (_tmp, top) = fixture();
        let fifo = top.join("root/a/fifo");
        let c_path = std::ffi::CString::new(fifo.as_os_str().as_bytes()).expect("no NUL in a temp path");
        // SAFETY: mkfifo reads a NUL-terminated path we own (rustix has no mkfifoat on macOS).
        assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0, "mkfifo: {}", std::io::Error::last_os_error());
        for root in roots(&top) {
            // Would block forever if it were opened for reading the usual way.
            let e = root.read("a/fifo", 100).expect_err("a FIFO");
            assert!(matches!(e, ConfineError::NotRegular { found: "a FIFO, socket or device", .. }), "{e}");
            let e = root.read("a", 100).expect_err("a folder");
            assert!(matches!(e, ConfineError::NotRegular { found: "a folder", .. }), "{e}");
            assert!(matches!(root.read("", 100), Err(ConfineError::NotRegular { .. })));
            assert!(matches!(root.read("a/file.txt/x", 100), Err(ConfineError::NotFolder { .. })), "a file used as a folder");
            let e = root.read("file.txt", 5).expect_err("six bytes");
            assert!(matches!(e, ConfineError::TooLarge { max_bytes: 5, .. }), "{e}");
            assert_eq!(root.read("file.txt", 6).expect("exactly the bound"), b"inside");
            assert_eq!(root.stat("a/fifo").expect("stat").map(|i| i.kind), Some(EntryKind::Other));
            assert_eq!(root.stat("file.txt").expect("stat"), Some(EntryInfo { kind: EntryKind::File, len_bytes: 6 }));
            assert_eq!(root.stat("nope/deeper").expect("stat"), None);
        }
        std::fs::write(top.join("root/bin"), [0xff, 0xfe]).expect("write");
        assert!(matches!(RootDir::open(&top.join("root")).expect("root").read_text("bin", 10), Err(ConfineError::NotText { .. })));
    }

    /// A file with another name is opened for reading but never for appending (appending would
    /// grow the file outside too); a file with one name is appended to.
    #[test]
    fn appends_refuse_a_file_with_another_name() {
        let (_tmp, top) = fixture();
        std::fs::hard_link(top.join("outside/file.txt"), top.join("root/linked.txt")).expect("hard link");
        for root in roots(&top) {
            let e = root.open_append("linked.txt").expect_err("two names");
            assert!(matches!(e, ConfineError::HardLinked { links: 2, .. }) && e.is_bad_input(), "{e}");
            assert_eq!(root.read_text("linked.txt", 100).expect("reading is fine"), "sentinel");
            root.open_append("file.txt").expect("one name").write_all(b"+").expect("append");
            assert!(matches!(root.open_append("a"), Err(ConfineError::NotRegular { found: "a folder", .. })));
        }
        assert_eq!(std::fs::read_to_string(top.join("outside/file.txt")).expect("read"), "sentinel");
        assert_eq!(std::fs::read_to_string(top.join("root/file.txt")).expect("read"), "inside++");
    }

    /// Devices are refused from their kind alone: named here, never opened.
    #[test]
    fn devices_are_refused_before_any_open() {
        let dev = RootDir::open(Path::new("/dev")).expect("/dev is a folder");
        for name in ["null", "zero"] {
            let e = dev.read(name, 100).expect_err(name);
            assert!(matches!(e, ConfineError::NotRegular { found: "a FIFO, socket or device", .. }), "{name}: {e}");
        }
        assert!(matches!(read_named_file(Path::new("/dev/zero"), 100), Err(ConfineError::NotRegular { .. })));
    }

    #[test]
    fn listing_reports_symlinks_without_following_them() {
        let (_tmp, top) = fixture();
        symlink(top.join("outside"), top.join("root/a/escape")).expect("symlink");
        for root in roots(&top) {
            let list = root.entries("a").expect("list");
            let kinds: Vec<(String, EntryKind)> = list.iter().map(|e| (e.name.to_string_lossy().into_owned(), e.kind)).collect();
            assert_eq!(
                kinds,
                vec![("b".into(), EntryKind::Folder), ("escape".into(), EntryKind::Symlink), ("file.txt".into(), EntryKind::File)]
            );
            assert_eq!(root.entries("").expect("list").len(), 2);
        }
    }

    #[test]
    fn writes_stay_below_the_root_and_replace_symlinks() {
        let (_tmp, top) = fixture();
        symlink(top.join("outside/file.txt"), top.join("root/a/over.txt")).expect("symlink");
        symlink(top.join("outside/secret.txt"), top.join("root/a/.planted.txt.tmp")).expect("symlink");
        for (i, root) in roots(&top).into_iter().enumerate() {
            let made = root.create_dir_all(format!("new{i}/x/y")).expect("mkdir");
            assert_eq!(made.path(), top.join(format!("root/new{i}/x/y")));
            root.create_dir_all(format!("new{i}/x")).expect("already there is fine");
            made.write_atomic("f.txt", b"hello").expect("write");
            assert_eq!(std::fs::read_to_string(top.join(format!("root/new{i}/x/y/f.txt"))).expect("read"), "hello");
            root.write_atomic("a/over.txt", b"replaced").expect("write over a symlink");
            root.write_atomic("a/planted.txt", b"p").expect("a planted temp symlink is removed");
            let mut f = root.create_new(format!("new{i}/c.txt")).expect("create");
            f.write_all(b"c").expect("write");
            assert!(root.create_new(format!("new{i}/c.txt")).is_err(), "exclusive");
            root.remove_file(format!("new{i}/c.txt")).expect("remove");
            root.remove_file(format!("new{i}/c.txt")).expect("absent is fine");
            assert!(matches!(root.create_dir_all("file.txt/x"), Err(ConfineError::NotFolder { .. })));
        }
        assert!(!std::fs::symlink_metadata(top.join("root/a/over.txt")).expect("lstat").file_type().is_symlink());
        assert_eq!(std::fs::read_to_string(top.join("outside/file.txt")).expect("read"), "sentinel");
        assert_eq!(std::fs::read_to_string(top.join("outside/secret.txt")).expect("read"), "sentinel");
    }

    #[test]
    fn the_root_itself_may_be_reached_through_the_operators_symlink() {
        let (_tmp, top) = fixture();
        symlink(top.join("root"), top.join("root-link")).expect("symlink");
        let root = RootDir::open(&top.join("root-link")).expect("the operator's symlink");
        assert_eq!(root.read_text("a/file.txt", 100).expect("read"), "inside");
        assert!(matches!(RootDir::open(&top.join("root/file.txt")), Err(ConfineError::NotFolder { .. })));
        assert!(matches!(RootDir::open(&top.join("nope")), Err(ConfineError::Missing { .. })));
        symlink(top.join("outside/secret.txt"), top.join("root/named-link")).expect("symlink");
        assert!(matches!(read_named_file(&top.join("root/named-link"), 100), Err(ConfineError::Symlink { .. })));
        assert_eq!(read_named_file(&top.join("root-link/file.txt"), 100).expect("read"), b"inside");
    }

    #[test]
    fn a_file_the_operator_typed_follows_their_symlinks_and_is_bounded() {
        let (_tmp, top) = fixture();
        symlink(top.join("root/a/file.txt"), top.join("typed-link.txt")).expect("symlink");
        assert_eq!(read_operator_file(&top.join("typed-link.txt"), 100).expect("the operator's symlink"), b"inside");
        assert_eq!(read_operator_file(&top.join("root/file.txt"), 6).expect("exactly the bound"), b"inside");
        assert!(matches!(read_operator_file(&top.join("root/file.txt"), 5), Err(ConfineError::TooLarge { max_bytes: 5, .. })));
        assert!(matches!(read_operator_file(&top.join("root/a"), 100), Err(ConfineError::NotRegular { found: "a folder", .. })));
        assert!(matches!(read_operator_file(&top.join("root/nope"), 100), Err(ConfineError::Missing { .. })));
        assert!(matches!(read_operator_file(&top.join("root/file.txt/x"), 100), Err(ConfineError::Missing { .. })));
        let fifo = top.join("fifo");
        let c_path = std::ffi::CString::new(fifo.as_os_str().as_bytes()).expect("no NUL in a temp path");
        // SAFETY: mkfifo reads a NUL-terminated path we own.
        assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0, "mkfifo: {}", std::io::Error::last_os_error());
        // Would block forever if it were opened for reading the usual way.
        let e = open_operator_file(&fifo).expect_err("a FIFO");
        assert!(matches!(e, ConfineError::NotRegular { found: "a FIFO, socket or device", .. }), "{e}");
        symlink(&fifo, top.join("fifo-link")).expect("symlink");
        assert!(matches!(open_operator_file(&top.join("fifo-link")), Err(ConfineError::NotRegular { .. })), "through a symlink too");
    }
}
