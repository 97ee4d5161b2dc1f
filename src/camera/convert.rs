//! Pixel-format conversion: the camera formats rig asks drivers for, to [`image::RgbImage`].
//!
//! USB (UVC) tactile-sensor cameras offer two formats worth using:
//!
//! | fourcc | layout | notes |
//! |---|---|---|
//! | `YUYV` (YUV 4:2:2) | per 2 pixels, 4 bytes: `Y0 U Y1 V` | uncompressed; bandwidth limits it to low rates at large sizes |
//! | `MJPG` (Motion-JPEG) | one baseline JPEG per frame | what reaches 25-30 fps at 640x480 and above over USB 2 |
//!
//! YUYV is converted with the ITU-R BT.601 limited-range ("studio swing", Y in 16..235,
//! Cb/Cr in 16..240) matrix that UVC cameras use by default, in integer arithmetic.
//! MJPEG frames are decoded with the `image` crate's JPEG decoder. Many UVC cameras leave the
//! Huffman tables (DHT) out of their MJPEG frames and rely on the standard tables of JPEG
//! Annex K.3; [`mjpeg_to_rgb`] inserts those before decoding when a frame has none.
//!
//! Every function takes untrusted bytes from a driver and returns an error (never panics) for
//! short, oversized or corrupt buffers.

use image::RgbImage;

/// Why a frame could not be converted.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ConvertError {
    #[error("YUYV frame of {width}x{height} needs {expected} bytes, got {got}")]
    ShortYuyv { width: u32, height: u32, expected: usize, got: usize },
    #[error("YUYV needs an even width, got {width}")]
    OddWidth { width: u32 },
    #[error("frame size {width}x{height} is not usable")]
    BadSize { width: u32, height: u32 },
    #[error("MJPEG frame is not a JPEG (starts {first_bytes:02x?})")]
    NotJpeg { first_bytes: Vec<u8> },
    #[error("MJPEG frame does not decode: {reason}")]
    Jpeg { reason: String },
    #[error("MJPEG frame decoded to {got_width}x{got_height}, expected {width}x{height}")]
    SizeMismatch { width: u32, height: u32, got_width: u32, got_height: u32 },
}

/// The pixel formats rig can convert.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    Yuyv,
    Mjpeg,
}

impl PixelFormat {
    /// The V4L2 fourcc code (`YUYV`, `MJPG`).
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Mjpeg => *b"MJPG",
        }
    }
    /// The format for a fourcc, if rig can convert it.
    pub fn from_fourcc(code: [u8; 4]) -> Option<Self> {
        match &code {
            b"YUYV" | b"YUY2" => Some(PixelFormat::Yuyv),
            b"MJPG" | b"JPEG" => Some(PixelFormat::Mjpeg),
            _ => None,
        }
    }
}

/// Converts one raw frame of `format` to RGB.
pub fn to_rgb(format: PixelFormat, bytes: &[u8], width: u32, height: u32) -> Result<RgbImage, ConvertError> {
    match format {
        PixelFormat::Yuyv => yuyv_to_rgb(bytes, width, height),
        PixelFormat::Mjpeg => {
            let image = mjpeg_to_rgb(bytes)?;
            if image.dimensions() != (width, height) {
                return Err(ConvertError::SizeMismatch { width, height, got_width: image.width(), got_height: image.height() });
            }
            Ok(image)
        }
    }
}

/// BT.601 limited range Y'CbCr to R'G'B', integer form (coefficients scaled by 2^8; the
/// classic table of ITU-R BT.601 with 298 = 255/219 * 256, 409 = 1.596 * 256 and so on).
#[inline]
pub fn ycbcr_to_rgb(y: u8, cb: u8, cr: u8) -> [u8; 3] {
    let c = i32::from(y) - 16;
    let d = i32::from(cb) - 128;
    let e = i32::from(cr) - 128;
    let clamp = |v: i32| ((v + 128) >> 8).clamp(0, 255) as u8;
    [clamp(298 * c + 409 * e), clamp(298 * c - 100 * d - 208 * e), clamp(298 * c + 516 * d)]
}

/// The inverse of [`ycbcr_to_rgb`] (used to build synthetic test frames and by the simulator
/// tests): R'G'B' to BT.601 limited range.
pub fn rgb_to_ycbcr(rgb: [u8; 3]) -> [u8; 3] {
    let [r, g, b] = rgb.map(i32::from);
    let y = ((66 * r + 129 * g + 25 * b + 128) >> 8) + 16;
    let cb = ((-38 * r - 74 * g + 112 * b + 128) >> 8) + 128;
    let cr = ((112 * r - 94 * g - 18 * b + 128) >> 8) + 128;
    [y.clamp(0, 255) as u8, cb.clamp(0, 255) as u8, cr.clamp(0, 255) as u8]
}

/// YUYV (`Y0 U Y1 V` per pixel pair, rows packed with no padding) to RGB. A buffer longer
/// than needed is accepted (drivers round `bytesused` up); a shorter one is an error.
pub fn yuyv_to_rgb(bytes: &[u8], width: u32, height: u32) -> Result<RgbImage, ConvertError> {
    if width == 0 || height == 0 || width > 16384 || height > 16384 {
        return Err(ConvertError::BadSize { width, height });
    }
    if !width.is_multiple_of(2) {
        return Err(ConvertError::OddWidth { width });
    }
    let expected = width as usize * height as usize * 2;
    if bytes.len() < expected {
        return Err(ConvertError::ShortYuyv { width, height, expected, got: bytes.len() });
    }
    let mut out = vec![0u8; width as usize * height as usize * 3];
    for (quad, rgb) in bytes[..expected].chunks_exact(4).zip(out.chunks_exact_mut(6)) {
        let (y0, u, y1, v) = (quad[0], quad[1], quad[2], quad[3]);
        rgb[..3].copy_from_slice(&ycbcr_to_rgb(y0, u, v));
        rgb[3..].copy_from_slice(&ycbcr_to_rgb(y1, u, v));
    }
    RgbImage::from_raw(width, height, out).ok_or(ConvertError::BadSize { width, height })
}

/// RGB to YUYV, averaging the chroma of each pixel pair: builds synthetic camera frames.
pub fn rgb_to_yuyv(image: &RgbImage) -> Vec<u8> {
    let mut out = Vec::with_capacity(image.width() as usize * image.height() as usize * 2);
    for row in image.rows() {
        let pixels: Vec<[u8; 3]> = row.map(|p| rgb_to_ycbcr(p.0)).collect();
        for pair in pixels.chunks(2) {
            let a = pair[0];
            let b = *pair.get(1).unwrap_or(&a);
            let avg = |i: usize| (u16::from(a[i]) + u16::from(b[i])).div_ceil(2) as u8;
            out.extend_from_slice(&[a[0], avg(1), b[0], avg(2)]);
        }
    }
    out
}

/// Decodes one MJPEG frame, inserting the standard Huffman tables when the frame has none.
pub fn mjpeg_to_rgb(bytes: &[u8]) -> Result<RgbImage, ConvertError> {
    if bytes.len() < 4 || bytes[0] != 0xFF || bytes[1] != 0xD8 {
        return Err(ConvertError::NotJpeg { first_bytes: bytes.iter().take(4).copied().collect() });
    }
    let with_tables;
    let jpeg = if has_huffman_tables(bytes) {
        bytes
    } else {
        with_tables = insert_default_huffman_tables(bytes);
        &with_tables[..]
    };
    let decoded =
        image::load_from_memory_with_format(jpeg, image::ImageFormat::Jpeg).map_err(|e| ConvertError::Jpeg { reason: e.to_string() })?;
    Ok(decoded.to_rgb8())
}

/// Whether a JPEG carries a DHT (0xFFC4) segment before its scan. Walks the marker segments
/// up to SOS; anything malformed counts as "has tables" so the decoder reports the real error.
pub fn has_huffman_tables(bytes: &[u8]) -> bool {
    let mut i = 2;
    while i + 4 <= bytes.len() {
        if bytes[i] != 0xFF {
            return true;
        }
        let marker = bytes[i + 1];
        if marker == 0xC4 {
            return true;
        }
        if marker == 0xDA {
            return false;
        }
        let len = usize::from(u16::from_be_bytes([bytes[i + 2], bytes[i + 3]]));
        if len < 2 {
            return true;
        }
        i += 2 + len;
    }
    true
}

/// The frame with the DHT segment of JPEG Annex K.3 (the tables the UVC MJPEG payload spec
/// tells decoders to assume) inserted right after SOI.
fn insert_default_huffman_tables(bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(bytes.len() + DEFAULT_DHT.len());
    out.extend_from_slice(&bytes[..2]);
    out.extend_from_slice(&DEFAULT_DHT);
    out.extend_from_slice(&bytes[2..]);
    out
}

/// DHT segment holding the four standard tables (ITU-T T.81 Annex K.3, tables K.3-K.6):
/// DC luminance, AC luminance, DC chrominance, AC chrominance.
#[rustfmt::skip]
const DEFAULT_DHT: [u8; 420] = [
    0xFF, 0xC4, 0x01, 0xA2,
    // DC luminance (class 0, id 0)
    0x00, 0x00, 0x01, 0x05, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0B,
    // DC chrominance (class 0, id 1)
    0x01, 0x00, 0x03, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0B,
    // AC luminance (class 1, id 0)
    0x10, 0x00, 0x02, 0x01, 0x03, 0x03, 0x02, 0x04, 0x03, 0x05, 0x05, 0x04, 0x04, 0x00, 0x00, 0x01, 0x7D,
    0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61, 0x07,
    0x22, 0x71, 0x14, 0x32, 0x81, 0x91, 0xA1, 0x08, 0x23, 0x42, 0xB1, 0xC1, 0x15, 0x52, 0xD1, 0xF0,
    0x24, 0x33, 0x62, 0x72, 0x82, 0x09, 0x0A, 0x16, 0x17, 0x18, 0x19, 0x1A, 0x25, 0x26, 0x27, 0x28,
    0x29, 0x2A, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49,
    0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69,
    0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89,
    0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9A, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7,
    0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4, 0xB5, 0xB6, 0xB7, 0xB8, 0xB9, 0xBA, 0xC2, 0xC3, 0xC4, 0xC5,
    0xC6, 0xC7, 0xC8, 0xC9, 0xCA, 0xD2, 0xD3, 0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9, 0xDA, 0xE1, 0xE2,
    0xE3, 0xE4, 0xE5, 0xE6, 0xE7, 0xE8, 0xE9, 0xEA, 0xF1, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7, 0xF8,
    0xF9, 0xFA,
    // AC chrominance (class 1, id 1)
    0x11, 0x00, 0x02, 0x01, 0x02, 0x04, 0x04, 0x03, 0x04, 0x07, 0x05, 0x04, 0x04, 0x00, 0x01, 0x02, 0x77,
    0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61, 0x71,
    0x13, 0x22, 0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xA1, 0xB1, 0xC1, 0x09, 0x23, 0x33, 0x52, 0xF0,
    0x15, 0x62, 0x72, 0xD1, 0x0A, 0x16, 0x24, 0x34, 0xE1, 0x25, 0xF1, 0x17, 0x18, 0x19, 0x1A, 0x26,
    0x27, 0x28, 0x29, 0x2A, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48,
    0x49, 0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68,
    0x69, 0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A, 0x82, 0x83, 0x84, 0x85, 0x86, 0x87,
    0x88, 0x89, 0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9A, 0xA2, 0xA3, 0xA4, 0xA5,
    0xA6, 0xA7, 0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4, 0xB5, 0xB6, 0xB7, 0xB8, 0xB9, 0xBA, 0xC2, 0xC3,
    0xC4, 0xC5, 0xC6, 0xC7, 0xC8, 0xC9, 0xCA, 0xD2, 0xD3, 0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9, 0xDA,
    0xE2, 0xE3, 0xE4, 0xE5, 0xE6, 0xE7, 0xE8, 0xE9, 0xEA, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7, 0xF8,
    0xF9, 0xFA,
];

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    /// A synthetic frame: horizontal colour gradient, vertical brightness ramp.
    fn test_pattern(width: u32, height: u32) -> RgbImage {
        RgbImage::from_fn(width, height, |x, y| Rgb([(x * 255 / width.max(1)) as u8, (y * 255 / height.max(1)) as u8, 128]))
    }

    fn encode_jpeg(image: &RgbImage, quality: u8) -> Vec<u8> {
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality).encode_image(image).unwrap();
        out
    }

    /// Removes every DHT segment before SOS, as tableless MJPEG cameras send.
    fn strip_dht(jpeg: &[u8]) -> Vec<u8> {
        let mut out = jpeg[..2].to_vec();
        let mut i = 2;
        loop {
            let marker = jpeg[i + 1];
            if marker == 0xDA {
                out.extend_from_slice(&jpeg[i..]);
                return out;
            }
            let len = usize::from(u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]));
            if marker != 0xC4 {
                out.extend_from_slice(&jpeg[i..i + 2 + len]);
            }
            i += 2 + len;
        }
    }

    #[test]
    fn bt601_reference_colours() {
        // Limited-range reference points: black, white, and the 75% colour bars of BT.601.
        assert_eq!(ycbcr_to_rgb(16, 128, 128), [0, 0, 0]);
        assert_eq!(ycbcr_to_rgb(235, 128, 128), [255, 255, 255]);
        assert_eq!(ycbcr_to_rgb(126, 128, 128), [128, 128, 128]);
        // 100% red is Y'=81, Cb=90, Cr=240 in BT.601 limited range.
        let [r, g, b] = ycbcr_to_rgb(81, 90, 240);
        assert!(r >= 253 && g <= 2 && b <= 2, "red came out {r},{g},{b}");
        // Out-of-range values clamp instead of wrapping.
        assert_eq!(ycbcr_to_rgb(0, 128, 128), [0, 0, 0]);
        assert_eq!(ycbcr_to_rgb(255, 128, 128), [255, 255, 255]);
    }

    #[test]
    fn yuyv_literal_bytes() {
        // Two pixels: black and white sharing neutral chroma; then two mid-greys.
        let bytes = [16, 128, 235, 128, 126, 128, 126, 128];
        let rgb = yuyv_to_rgb(&bytes, 2, 2).unwrap();
        assert_eq!(rgb.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(rgb.get_pixel(1, 0).0, [255, 255, 255]);
        assert_eq!(rgb.get_pixel(0, 1).0, [128, 128, 128]);
        assert_eq!(rgb.get_pixel(1, 1).0, [128, 128, 128]);
    }

    #[test]
    fn yuyv_round_trip_is_close() {
        let image = test_pattern(64, 48);
        let yuyv = rgb_to_yuyv(&image);
        assert_eq!(yuyv.len(), 64 * 48 * 2);
        let back = yuyv_to_rgb(&yuyv, 64, 48).unwrap();
        // Chroma is shared by pixel pairs, so neighbouring pixels differ by up to one
        // gradient step in colour; luma quantisation adds about 1 level.
        let worst = image
            .pixels()
            .zip(back.pixels())
            .flat_map(|(a, b)| (0..3).map(move |c| (i32::from(a[c]) - i32::from(b[c])).abs()))
            .max()
            .unwrap();
        assert!(worst <= 6, "worst channel error {worst}");
    }

    #[test]
    fn yuyv_rejects_bad_buffers() {
        assert_eq!(yuyv_to_rgb(&[0; 7], 2, 2), Err(ConvertError::ShortYuyv { width: 2, height: 2, expected: 8, got: 7 }));
        assert_eq!(yuyv_to_rgb(&[0; 12], 3, 2), Err(ConvertError::OddWidth { width: 3 }));
        assert_eq!(yuyv_to_rgb(&[], 0, 2), Err(ConvertError::BadSize { width: 0, height: 2 }));
        // A longer buffer (bytesused rounded up) is fine.
        assert!(yuyv_to_rgb(&[128; 20], 2, 2).is_ok());
    }

    #[test]
    fn mjpeg_decodes_synthetic_frames() {
        let image = test_pattern(80, 60);
        let jpeg = encode_jpeg(&image, 95);
        let back = to_rgb(PixelFormat::Mjpeg, &jpeg, 80, 60).unwrap();
        let mean_err: f64 = image
            .pixels()
            .zip(back.pixels())
            .flat_map(|(a, b)| (0..3).map(move |c| (f64::from(a[c]) - f64::from(b[c])).abs()))
            .sum::<f64>()
            / (80.0 * 60.0 * 3.0);
        assert!(mean_err < 4.0, "mean error {mean_err}");
        assert!(matches!(
            to_rgb(PixelFormat::Mjpeg, &jpeg, 640, 480),
            Err(ConvertError::SizeMismatch { got_width: 80, got_height: 60, .. })
        ));
    }

    #[test]
    fn mjpeg_without_huffman_tables_gets_the_standard_ones() {
        let image = test_pattern(32, 32);
        // The encoder writes the Annex K tables, so stripping them leaves a frame exactly like
        // a tableless UVC camera's.
        let jpeg = encode_jpeg(&image, 90);
        assert!(has_huffman_tables(&jpeg));
        let stripped = strip_dht(&jpeg);
        assert!(!has_huffman_tables(&stripped));
        assert!(stripped.len() < jpeg.len());
        let full = mjpeg_to_rgb(&jpeg).unwrap();
        let fixed = mjpeg_to_rgb(&stripped).unwrap();
        assert_eq!(full, fixed);
    }

    #[test]
    fn mjpeg_rejects_garbage() {
        assert!(matches!(mjpeg_to_rgb(b"\x00\x01"), Err(ConvertError::NotJpeg { .. })));
        assert!(matches!(mjpeg_to_rgb(&[0xFF, 0xD8, 0xFF, 0xDA, 0, 2, 1, 2, 3]), Err(ConvertError::Jpeg { .. })));
        // A frame cut short (a USB packet lost mid-frame) must come back as a value, not a
        // panic; the decoder may fill the missing rows or refuse, either is fine here.
        let jpeg = encode_jpeg(&test_pattern(16, 16), 80);
        let _ = mjpeg_to_rgb(&jpeg[..jpeg.len() / 3]);
        assert!(mjpeg_to_rgb(&jpeg[..3]).is_err());
    }

    #[test]
    fn fourcc_mapping() {
        assert_eq!(PixelFormat::from_fourcc(*b"YUYV"), Some(PixelFormat::Yuyv));
        assert_eq!(PixelFormat::from_fourcc(*b"MJPG"), Some(PixelFormat::Mjpeg));
        assert_eq!(PixelFormat::from_fourcc(*b"NV12"), None);
        assert_eq!(PixelFormat::Mjpeg.fourcc(), *b"MJPG");
    }

    proptest::proptest! {
        #[test]
        fn converters_never_panic(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..2048), w in 0u32..64, h in 0u32..64) {
            let _ = yuyv_to_rgb(&bytes, w, h);
            let mut jpeg = vec![0xFF, 0xD8];
            jpeg.extend_from_slice(&bytes);
            let _ = mjpeg_to_rgb(&jpeg);
            let _ = has_huffman_tables(&jpeg);
        }
    }
}
