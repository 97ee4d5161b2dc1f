//! File access inside a dataset folder: atomic, durable writes, and reads and writes that
//! never follow a symlink or touch anything but a regular file (or, for `images/`, a folder).
//!
//! A dataset folder may come from anyone (an import, a copy from a colleague, a daemon
//! request). A symlink planted in it (`images/518.png -> <some other file>`, `poses.csv ->`
//! elsewhere) would make rig read a file it was never asked to read, or write where it was
//! never asked to write. So every entry rig opens inside a dataset is opened with
//! `O_NOFOLLOW` (and `O_NONBLOCK`, so a FIFO cannot block the open) and checked with `fstat`;
//! folders are checked with `lstat`. The dataset folder itself may be a symlink: that is where
//! the user chose to put it.
//!
//! [`write_atomic`]: temp file `.<name>.tmp` created new (never through an existing entry),
//! written, fsynced, renamed over `<name>` (which replaces a symlink there rather than writing
//! through it), then the folder is fsynced. A failed write (a full disk) removes its temp file.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

use super::error::DatasetError;

/// Largest `manifest.toml` read.
pub const MAX_MANIFEST_BYTES: u64 = crate::untrusted::MAX_CONFIG_BYTES;
/// Largest `poses.csv` read (a full grid of 1M poses with Modbus readings fits).
pub const MAX_POSES_CSV_BYTES: u64 = 512 << 20;
/// Longest line of `poses.csv` (a row is about 150 bytes; Modbus readings add a few dozen).
pub const MAX_CSV_LINE_BYTES: usize = 64 << 10;
/// Largest image file read (a 512 x 512 PNG is under 1 MB).
pub const MAX_IMAGE_BYTES: u64 = 64 << 20;
/// Largest image side decoded, px.
pub const MAX_IMAGE_SIDE_PX: u32 = 8192;
/// Most pixels decoded in one image (4096 x 4096; a tactile frame is under 2 Mpx): checked
/// from the header before decoding, so an 8192 x 8192 16-bit PNG is refused, not decoded.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 24;
/// Most memory the decoder may take for one image (16 Mpx of 16-bit RGBA is 128 MiB).
const MAX_DECODE_BYTES: u64 = 256 << 20;

/// What an entry of a dataset must be.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    File,
    Folder,
}

/// Whether `path` exists as `kind`: `Ok(false)` when absent, an error when it is a symlink or
/// something else (`lstat`: a symlink is never followed).
pub fn entry_exists(path: &Path, kind: Kind) -> Result<bool, DatasetError> {
    match std::fs::symlink_metadata(path) {
        Ok(meta) if meta.file_type().is_symlink() => Err(DatasetError::Symlink { path: path.to_path_buf() }),
        Ok(meta) if (kind == Kind::File && meta.is_file()) || (kind == Kind::Folder && meta.is_dir()) => Ok(true),
        Ok(_) => Err(DatasetError::NotRegular { path: path.to_path_buf(), expected: kind_name(kind) }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) => Err(DatasetError::io("inspecting", path)(e)),
    }
}

fn kind_name(kind: Kind) -> &'static str {
    match kind {
        Kind::File => "a regular file",
        Kind::Folder => "a folder",
    }
}

/// Opens a regular file inside a dataset without following a symlink; `append` opens it for
/// reading and appending.
pub fn open_regular(path: &Path, append: bool) -> Result<File, DatasetError> {
    let mut options = OpenOptions::new();
    options.read(true).custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_CLOEXEC);
    if append {
        options.append(true);
    }
    let file = match options.open(path) {
        Ok(f) => f,
        // O_NOFOLLOW on a symlink: ELOOP.
        Err(e) if e.raw_os_error() == Some(libc::ELOOP) => return Err(DatasetError::Symlink { path: path.to_path_buf() }),
        Err(e) => return Err(DatasetError::io(if append { "opening" } else { "reading" }, path)(e)),
    };
    let meta = file.metadata().map_err(DatasetError::io("reading", path))?;
    if !meta.is_file() {
        return Err(DatasetError::NotRegular { path: path.to_path_buf(), expected: kind_name(Kind::File) });
    }
    Ok(file)
}

/// Reads `rel` (a path a dataset's own files name, such as a row's `images/3.png`) below the
/// dataset folder `dir` through [`crate::confine`]: no symlink in any component (`images/`
/// included), a regular file, at most `max_bytes`.
pub fn read_below(dir: &Path, rel: &Path, max_bytes: u64) -> Result<Vec<u8>, DatasetError> {
    Ok(crate::confine::RootDir::open(dir)?.read(rel, max_bytes)?)
}

/// Decodes image bytes with bounds on the side and the memory the decoder may take.
pub fn decode_image(bytes: &[u8]) -> Result<image::DynamicImage, String> {
    let reader = || image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format().map_err(|e| e.to_string());
    // The header alone: the pixel count is bounded before anything is allocated for pixels.
    let (width, height) = reader()?.into_dimensions().map_err(|e| e.to_string())?;
    if u64::from(width) * u64::from(height) > MAX_IMAGE_PIXELS {
        return Err(format!("{width}x{height} px is more than the {MAX_IMAGE_PIXELS} pixels rig decodes"));
    }
    let mut reader = reader()?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE_PX);
    limits.max_image_height = Some(MAX_IMAGE_SIDE_PX);
    limits.max_alloc = Some(MAX_DECODE_BYTES);
    reader.limits(limits);
    reader.decode().map_err(|e| e.to_string())
}

/// The folder `path` inside a dataset, created when absent; refused when it is a symlink or
/// not a folder.
pub fn ensure_folder(path: &Path) -> Result<(), DatasetError> {
    if entry_exists(path, Kind::Folder)? {
        return Ok(());
    }
    match std::fs::create_dir(path) {
        Ok(()) => Ok(()),
        // Made by someone else meanwhile: check what it is.
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => entry_exists(path, Kind::Folder).map(|_| ()),
        Err(e) => Err(DatasetError::io("creating", path)(e)),
    }
}

/// Writes `dir/name` atomically and durably (see the module docs).
pub fn write_atomic(dir: &Path, name: &str, bytes: &[u8]) -> Result<(), DatasetError> {
    write_atomic_with(dir, name, |f| f.write_all(bytes))
}

/// [`write_atomic`] with the content written by `fill` (a test can make it fail).
pub(crate) fn write_atomic_with(dir: &Path, name: &str, fill: impl FnOnce(&mut File) -> std::io::Result<()>) -> Result<(), DatasetError> {
    let tmp = dir.join(format!(".{name}.tmp"));
    let dest = dir.join(name);
    // A temp file left by a killed run (or planted): removing it removes a link, never its target.
    match std::fs::remove_file(&tmp) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(DatasetError::io("removing", &tmp)(e)),
    }
    let mut f = OpenOptions::new()
        .write(true)
        .create_new(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
        .open(&tmp)
        .map_err(DatasetError::io("creating", &tmp))?;
    let written =
        fill(&mut f).map_err(DatasetError::io("writing", &tmp)).and_then(|()| f.sync_all().map_err(DatasetError::io("syncing", &tmp)));
    drop(f);
    if let Err(e) = written {
        // A full disk must not leave the temp file behind (it would make the dataset unclean).
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    if let Err(e) = std::fs::rename(&tmp, &dest) {
        let _ = std::fs::remove_file(&tmp);
        return Err(DatasetError::io("renaming into place", &dest)(e));
    }
    fsync_dir(dir)
}

/// Makes renames and removals in `dir` durable.
pub fn fsync_dir(dir: &Path) -> Result<(), DatasetError> {
    File::open(dir).and_then(|d| d.sync_all()).map_err(DatasetError::io("syncing directory", dir))
}

/// Whether `name` is a plain file name: not empty, no path separator, not `.` or `..`, no NUL.
/// File names built from a file's contents (an MDS `image_name`, an `obj_id`) must pass this
/// before they are joined to a folder.
pub fn is_plain_file_name(name: &str) -> bool {
    !name.is_empty() && name != "." && name != ".." && !name.contains(['/', '\\', '\0']) && name.len() <= 255
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::symlink;

    use super::*;

    #[test]
    fn symlinks_and_non_regular_entries_are_refused() {
        let tmp = tempfile::tempdir().expect("temp dir");
        let d = tmp.path();
        std::fs::write(d.join("outside.txt"), "sentinel").expect("write");
        std::fs::write(d.join("file"), "x").expect("write");
        symlink(d.join("outside.txt"), d.join("link")).expect("symlink");
        std::fs::create_dir(d.join("folder")).expect("mkdir");
        symlink(d.join("folder"), d.join("folder-link")).expect("symlink");

        use crate::confine::ConfineError;
        let below = |rel: &str, max: u64| read_below(d, Path::new(rel), max);
        assert!(matches!(below("link", 100), Err(DatasetError::Confined(ConfineError::Symlink { .. }))));
        assert!(matches!(open_regular(&d.join("link"), true), Err(DatasetError::Symlink { .. })));
        assert!(matches!(below("folder", 100), Err(DatasetError::Confined(ConfineError::NotRegular { .. }))));
        assert!(matches!(below("file", 0), Err(DatasetError::Confined(ConfineError::TooLarge { .. }))));
        assert_eq!(below("file", 1).expect("regular"), b"x");
        // A symlinked folder one level down is refused too, not only a symlinked last name.
        std::fs::write(d.join("folder/inner"), "sentinel").expect("write");
        assert!(matches!(below("folder-link/inner", 100), Err(DatasetError::Confined(ConfineError::Symlink { .. }))));
        assert_eq!(below("folder/inner", 100).expect("the real folder"), b"sentinel");
        assert!(matches!(entry_exists(&d.join("folder-link"), Kind::Folder), Err(DatasetError::Symlink { .. })));
        assert!(matches!(entry_exists(&d.join("file"), Kind::Folder), Err(DatasetError::NotRegular { .. })));
        assert!(!entry_exists(&d.join("absent"), Kind::File).expect("absent"));
        assert!(matches!(ensure_folder(&d.join("folder-link")), Err(DatasetError::Symlink { .. })));
        ensure_folder(&d.join("new")).expect("created");
        assert!(d.join("new").is_dir());

        // A write over a symlinked name replaces the link; the target is untouched.
        write_atomic(d, "link", b"new").expect("write");
        assert_eq!(std::fs::read_to_string(d.join("outside.txt")).expect("read"), "sentinel");
        assert!(!std::fs::symlink_metadata(d.join("link")).expect("lstat").file_type().is_symlink());
        // A planted temp symlink is removed, not written through.
        symlink(d.join("outside.txt"), d.join(".planted.tmp")).expect("symlink");
        write_atomic(d, "planted", b"new").expect("write");
        assert_eq!(std::fs::read_to_string(d.join("outside.txt")).expect("read"), "sentinel");
    }

    #[test]
    fn a_failed_write_leaves_no_temp_file() {
        let tmp = tempfile::tempdir().expect("temp dir");
        let e = write_atomic_with(tmp.path(), "poses.csv", |f| {
            f.write_all(b"partial")?;
            Err(std::io::Error::from_raw_os_error(libc::ENOSPC))
        })
        .expect_err("disk full");
        assert!(matches!(e, DatasetError::DiskFull { .. }), "{e}");
        let left: Vec<_> = std::fs::read_dir(tmp.path()).expect("list").collect();
        assert!(left.is_empty(), "{left:?}");
    }

    #[test]
    fn plain_names() {
        for ok in ["frame_0_0.png", "1_TacTip_3.png", "a b.png"] {
            assert!(is_plain_file_name(ok), "{ok}");
        }
        for bad in ["", ".", "..", "../x.png", "a/b.png", "/etc", "a\\b", "x\0y"] {
            assert!(!is_plain_file_name(bad), "{bad:?}");
        }
    }

    #[test]
    fn corrupt_and_oversized_images_are_errors() {
        assert!(decode_image(b"").is_err());
        assert!(decode_image(b"\x89PNG\r\n\x1a\n garbage").is_err());
        // A PNG header claiming 100000 x 100000 px: refused by the limits, not allocated.
        let mut png = Vec::new();
        image::RgbImage::new(2, 2).write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).expect("encode");
        png[16..20].copy_from_slice(&100_000u32.to_be_bytes());
        png[20..24].copy_from_slice(&100_000u32.to_be_bytes());
        assert!(decode_image(&png).is_err());
    }
}
