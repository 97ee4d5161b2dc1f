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

use std::fs::File;
use std::io::Write;
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
/// Most pixels decoded in one image: checked from the header before decoding, so an
/// 8192 x 8192 16-bit PNG is refused, not decoded. Kept with the configuration bounds, which
/// refuse a camera whose frames no reader would decode.
pub const MAX_IMAGE_PIXELS: u64 = crate::bounds::MAX_IMAGE_PIXELS;
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

/// Reads `rel` (a path a dataset's own files name, such as a row's `images/3.png`) below the
/// dataset folder `dir` through [`crate::confine`]: no symlink in any component (`images/`
/// included), a regular file, at most `max_bytes`.
pub fn read_below(dir: &Path, rel: &Path, max_bytes: u64) -> Result<Vec<u8>, DatasetError> {
    Ok(crate::confine::RootDir::open(dir)?.read(rel, max_bytes)?)
}

/// Decodes image bytes with bounds on the side, the pixel count and the memory the decoder may
/// take. A PNG (every image rig writes or reads in a dataset) goes to the `png` crate directly,
/// with its ancillary chunks bounded: the colour profile (`iCCP`) and text chunks (`tEXt`,
/// `zTXt`, `iTXt`) are skipped unread (rig uses neither, and an `iCCP` of 800 KB can inflate to
/// 800 MB, three million `tEXt` chunks would each be kept), and what the decoder allocates for
/// itself is capped at [`MAX_PNG_DECODER_BYTES`]. The pixel count is checked from the header
/// before anything else is read. Other formats (a JPEG control image) go through `image` with
/// the same side and memory bounds.
pub fn decode_image(bytes: &[u8]) -> Result<image::DynamicImage, String> {
    if bytes.starts_with(PNG_SIGNATURE) {
        return decode_png(bytes);
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE_PX);
    limits.max_image_height = Some(MAX_IMAGE_SIDE_PX);
    limits.max_alloc = Some(MAX_DECODE_BYTES);
    let reader = || {
        let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format().map_err(|e| e.to_string())?;
        reader.limits(limits.clone());
        Ok::<_, String>(reader)
    };
    // The header alone: the pixel count is bounded before anything is allocated for pixels.
    let (width, height) = reader()?.into_dimensions().map_err(|e| e.to_string())?;
    check_pixels(width, height)?;
    reader()?.decode().map_err(|e| e.to_string())
}

/// The eight bytes every PNG starts with.
const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

/// Most memory the PNG decoder may allocate for itself (line buffers, chunk data), beside the
/// pixels it decodes into.
pub const MAX_PNG_DECODER_BYTES: usize = 32 << 20;

fn check_pixels(width: u32, height: u32) -> Result<(), String> {
    if width > MAX_IMAGE_SIDE_PX || height > MAX_IMAGE_SIDE_PX || u64::from(width) * u64::from(height) > MAX_IMAGE_PIXELS {
        return Err(format!("{width}x{height} px is more than the {MAX_IMAGE_PIXELS} pixels ({MAX_IMAGE_SIDE_PX} px a side) rig decodes"));
    }
    Ok(())
}

/// [`decode_image`] for a PNG: see there for the bounds.
fn decode_png(bytes: &[u8]) -> Result<image::DynamicImage, String> {
    use image::{DynamicImage, ImageBuffer};
    use png::{BitDepth, ColorType};
    let mut options = png::DecodeOptions::default();
    options.set_ignore_iccp_chunk(true);
    options.set_ignore_text_chunk(true);
    let mut decoder = png::Decoder::new_with_options(std::io::Cursor::new(bytes), options);
    decoder.set_limits(png::Limits { bytes: MAX_PNG_DECODER_BYTES });
    // Palettes, bit depths under 8 and tRNS expanded: 8- or 16-bit grey, grey-alpha, RGB or RGBA.
    decoder.set_transformations(png::Transformations::EXPAND);
    let header = decoder.read_header_info().map_err(|e| e.to_string())?;
    check_pixels(header.width, header.height)?;
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let size = reader.output_buffer_size().filter(|&n| n as u64 <= MAX_DECODE_BYTES).ok_or("the decoded image is too large")?;
    let mut buf = vec![0u8; size];
    let frame = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    buf.truncate(frame.buffer_size());
    let (w, h) = (frame.width, frame.height);
    let wrong = || format!("{w}x{h} px in {:?} {:?} does not match its pixel data", frame.color_type, frame.bit_depth);
    let image = match frame.bit_depth {
        BitDepth::Sixteen => {
            // Samples are big-endian on the wire.
            let samples: Vec<u16> = buf.chunks_exact(2).map(|b| u16::from_be_bytes([b[0], b[1]])).collect();
            match frame.color_type {
                ColorType::Grayscale => ImageBuffer::from_raw(w, h, samples).map(DynamicImage::ImageLuma16),
                ColorType::GrayscaleAlpha => ImageBuffer::from_raw(w, h, samples).map(DynamicImage::ImageLumaA16),
                ColorType::Rgb => ImageBuffer::from_raw(w, h, samples).map(DynamicImage::ImageRgb16),
                ColorType::Rgba => ImageBuffer::from_raw(w, h, samples).map(DynamicImage::ImageRgba16),
                ColorType::Indexed => None,
            }
        }
        BitDepth::Eight => match frame.color_type {
            ColorType::Grayscale => ImageBuffer::from_raw(w, h, buf).map(DynamicImage::ImageLuma8),
            ColorType::GrayscaleAlpha => ImageBuffer::from_raw(w, h, buf).map(DynamicImage::ImageLumaA8),
            ColorType::Rgb => ImageBuffer::from_raw(w, h, buf).map(DynamicImage::ImageRgb8),
            ColorType::Rgba => ImageBuffer::from_raw(w, h, buf).map(DynamicImage::ImageRgba8),
            ColorType::Indexed => None,
        },
        _ => None,
    };
    image.ok_or_else(wrong)
}

/// Writes `dir/name` atomically and durably (see the module docs).
pub fn write_atomic(dir: &Path, name: &str, bytes: &[u8]) -> Result<(), DatasetError> {
    write_atomic_with(dir, name, |f| f.write_all(bytes))
}

/// [`write_atomic`] with the content written by `fill` (a test can make it fail). Goes
/// through the held folder ([`crate::confine::RootDir::write_atomic_with`]): the temp file is
/// created and renamed relative to one descriptor of `dir`.
pub(crate) fn write_atomic_with(dir: &Path, name: &str, fill: impl FnOnce(&mut File) -> std::io::Result<()>) -> Result<(), DatasetError> {
    let folder = crate::confine::RootDir::open(dir).map_err(dataset_error)?;
    folder.write_atomic_with(name, fill).map_err(dataset_error)
}

/// A confined operation's error as the dataset module says it: a symlink is
/// [`DatasetError::Symlink`], a failed write keeps its "disk full" reading.
pub(crate) fn dataset_error(e: crate::confine::ConfineError) -> DatasetError {
    use crate::confine::ConfineError;
    match e {
        ConfineError::Symlink { path, .. } => DatasetError::Symlink { path },
        ConfineError::Io { op, path, source } => DatasetError::io(op, path)(source),
        other => DatasetError::Confined(other),
    }
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

    /// The PNG decoder gives what `image` gives for every colour type and depth rig may meet
    /// (8- and 16-bit grey, grey-alpha, RGB, RGBA, and a palette expanded to RGB), and skips
    /// text and colour-profile chunks without changing the pixels.
    #[test]
    fn pngs_of_every_colour_type_decode_as_image_decodes_them() {
        use image::DynamicImage as D;
        let rgb = image::RgbImage::from_fn(5, 3, |x, y| image::Rgb([x as u8 * 40, y as u8 * 70, 200]));
        let rgb16 = image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(5, 3, |x, y| image::Rgb([x as u16 * 9000, y as u16 * 300, 65535]));
        for original in [
            D::ImageRgb8(rgb.clone()),
            D::ImageRgba8(D::ImageRgb8(rgb.clone()).to_rgba8()),
            D::ImageLuma8(D::ImageRgb8(rgb.clone()).to_luma8()),
            D::ImageLumaA8(D::ImageRgb8(rgb.clone()).to_luma_alpha8()),
            D::ImageRgb16(rgb16.clone()),
            D::ImageLuma16(D::ImageRgb16(rgb16).to_luma16()),
        ] {
            let mut png = Vec::new();
            original.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).expect("encode");
            assert_eq!(decode_image(&png).expect("decode"), original, "{:?}", original.color());
            // A text chunk and a colour profile after the header change nothing.
            let mut with = png[..33].to_vec();
            for (kind, data) in [(&b"tEXt"[..], &b"Comment\0hello"[..]), (b"iCCP", b"p\0\0\x78\x01\x03\x00\x00\x00\x00\x01")] {
                with.extend_from_slice(&(data.len() as u32).to_be_bytes());
                let start = with.len();
                with.extend_from_slice(kind);
                with.extend_from_slice(data);
                let crc = crc32(&with[start..]);
                with.extend_from_slice(&crc.to_be_bytes());
            }
            with.extend_from_slice(&png[33..]);
            assert_eq!(decode_image(&with).expect("decode"), original, "{:?} with ancillary chunks", original.color());
        }
        // A palette image (2 bits an index) comes out as 8-bit RGB.
        let mut png = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut png, 4, 1);
            encoder.set_color(png::ColorType::Indexed);
            encoder.set_depth(png::BitDepth::Two);
            encoder.set_palette(vec![0, 0, 0, 255, 0, 0, 0, 255, 0, 0, 0, 255]);
            let mut writer = encoder.write_header().expect("header");
            writer.write_image_data(&[0b0001_1011]).expect("data");
        }
        let decoded = decode_image(&png).expect("palette").to_rgb8();
        let pixels: Vec<[u8; 3]> = decoded.pixels().map(|p| p.0).collect();
        assert_eq!(pixels, vec![[0, 0, 0], [255, 0, 0], [0, 255, 0], [0, 0, 255]]);
    }

    /// CRC-32 (IEEE), as PNG chunks use.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = 0xFFFF_FFFFu32;
        for &b in bytes {
            c ^= u32::from(b);
            for _ in 0..8 {
                c = if c & 1 != 0 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
            }
        }
        c ^ 0xFFFF_FFFF
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
