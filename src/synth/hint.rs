//! The control image a caller hands `rig synth one`, checked against the package's
//! `hint_encoding` and `control_colour_map` before anything is loaded.
//!
//! Both encodings rig knows (`rgb01`, `rgb11`, [`HintEncoding`]) read an 8-bit, 3-channel
//! control image; they differ only in how the bytes are scaled (to [0, 1] or [-1, 1]). Anything
//! else decodes, but conditions the model on something it was never trained on and gives a
//! wrong image with exit 0, so it is refused, saying which `rig render` makes the right one:
//!
//! | image | why it is refused |
//! |---|---|
//! | 16-bit (grey or colour) | a depth map (`rig render --sensor depth` writes 16-bit grey) |
//! | floating point | not a PNG the control renderer writes |
//! | RGBA with any pixel not opaque | transparency has no meaning in a control image |
//!
//! A package that declares its control colour-mapped (`control_colour_map = "viridis"`: the
//! depth map rendered from the STL, inverted and colour-mapped with viridis, as
//! MultiDiffSense trains on it and `rig render --sensor control` and `rig synth --fill-missing`
//! make it; rig's own packages and its MultiDiffSense exports declare it) also refuses:
//!
//! | image | why it is refused |
//! |---|---|
//! | 1 or 2 channels (8-bit grey) | no colour map: a depth map or a photo saved as grey |
//! | RGB whose every pixel is grey (R = G = B) | viridis has no grey: a grey depth map saved as RGB |
//!
//! A package that declares none reads any 8-bit RGB control image, as diffusers' ControlNet
//! pipelines do (its depth and edge ControlNets are conditioned on grey images): an 8-bit grey
//! image is read as RGB with R = G = B. An opaque RGBA image is read as its RGB.

use std::path::Path;

use image::{DynamicImage, RgbImage};

use super::SynthError;
use super::package::{ControlColourMap, HintEncoding};

/// The `rig render` command that makes a control image for `hint_encoding`.
pub fn render_command(encoding: HintEncoding) -> &'static str {
    match encoding {
        // Both encodings read the same image; only the scaling differs.
        HintEncoding::Rgb01 | HintEncoding::Rgb11 => {
            "rig render --sensor control (--object NAME | --stl FILE) --pose x,y,z,yaw --size WxH --out control.png"
        }
    }
}

/// The name of `encoding` as `model.toml` writes it.
fn encoding_name(encoding: HintEncoding) -> &'static str {
    match encoding {
        HintEncoding::Rgb01 => "rgb01",
        HintEncoding::Rgb11 => "rgb11",
    }
}

/// `image` as the 8-bit RGB control image a package with `encoding` and `colour_map` reads, or
/// a [`SynthError::BadRequest`] on field `control` saying what the image is and which
/// `rig render` makes the right one. `path` is the file it was read from, for the message.
pub fn control_for(
    image: &DynamicImage,
    encoding: HintEncoding,
    colour_map: Option<ControlColourMap>,
    path: &Path,
) -> Result<RgbImage, SynthError> {
    let refuse = |what: String| SynthError::BadRequest {
        field: "control",
        value: path.display().to_string(),
        reason: match colour_map {
            Some(ControlColourMap::Viridis) => format!(
                "it is {what}; this package (hint_encoding = \"{}\", control_colour_map = \"viridis\") is conditioned on the 8-bit \
                 RGB colour-mapped control image: make it with `{}`",
                encoding_name(encoding),
                render_command(encoding)
            ),
            None => format!(
                "it is {what}; this package (hint_encoding = \"{}\") reads an 8-bit RGB (or grey) control image, such as `{}` makes",
                encoding_name(encoding),
                render_command(encoding)
            ),
        },
    };
    let colour_mapped = colour_map.is_some();
    let rgb = match image {
        DynamicImage::ImageRgb8(rgb) => rgb.clone(),
        DynamicImage::ImageRgba8(rgba) => {
            if rgba.pixels().any(|p| p.0[3] != u8::MAX) {
                return Err(refuse("an RGBA image with transparent pixels".to_string()));
            }
            image.to_rgb8()
        }
        DynamicImage::ImageLuma16(_) | DynamicImage::ImageLumaA16(_) => {
            return Err(refuse("a 16-bit grey image (a depth map, as `rig render --sensor depth` writes)".to_string()));
        }
        DynamicImage::ImageRgb16(_) | DynamicImage::ImageRgba16(_) => return Err(refuse("a 16-bit colour image".to_string())),
        DynamicImage::ImageLuma8(_) | DynamicImage::ImageLumaA8(_) if colour_mapped => {
            return Err(refuse("an 8-bit grey image (one channel, no colour map)".to_string()));
        }
        DynamicImage::ImageLumaA8(grey) if grey.pixels().any(|p| p.0[1] != u8::MAX) => {
            return Err(refuse("a grey image with transparent pixels".to_string()));
        }
        // Read as diffusers reads it (PIL's convert("RGB")): R = G = B.
        DynamicImage::ImageLuma8(_) | DynamicImage::ImageLumaA8(_) => image.to_rgb8(),
        other => return Err(refuse(format!("an image of {:?} pixels", other.color()))),
    };
    if colour_mapped && rgb.pixels().all(|p| p.0[0] == p.0[1] && p.0[1] == p.0[2]) {
        return Err(refuse("an RGB image whose every pixel is grey (viridis has no grey: a depth map saved as RGB?)".to_string()));
    }
    Ok(rgb)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::control::{control_image, depth_png16};

    fn depth() -> crate::geometry::DepthMap {
        let mesh = crate::geometry::objects::load_object("sphere").expect("library sphere");
        let calib = crate::calibration::Calibration::default_for(32, 32);
        crate::geometry::raster::render_depth(&mesh, &crate::pose::Pose::new(0.0, 0.0, 1.0, 0.0), &calib, 32, 32, 1)
    }

    /// The two images `rig render` writes: `--sensor control` passes, `--sensor depth` is refused
    /// naming the command that makes the right one.
    #[test]
    fn the_control_render_passes_and_the_depth_render_is_refused() {
        let depth = depth();
        for encoding in [HintEncoding::Rgb01, HintEncoding::Rgb11] {
            let control = DynamicImage::ImageRgb8(control_image(&depth));
            assert_eq!(control_for(&control, encoding, VIRIDIS, Path::new("c.png")).expect("a control image"), control.to_rgb8());
            let err = control_for(&DynamicImage::ImageLuma16(depth_png16(&depth)), encoding, VIRIDIS, Path::new("depth.png"))
                .expect_err("a 16-bit depth map");
            let text = err.to_string();
            assert!(text.contains("depth.png") && text.contains("16-bit grey"), "{text}");
            assert!(text.contains("rig render --sensor control"), "{text}");
            assert!(text.contains(encoding_name(encoding)), "{text}");
        }
    }

    const VIRIDIS: Option<ControlColourMap> = Some(ControlColourMap::Viridis);

    #[test]
    fn grey_alpha_and_deep_images_are_refused_opaque_rgba_is_read() {
        let refuse = |image: DynamicImage, phrase: &str| {
            let err = control_for(&image, HintEncoding::Rgb01, VIRIDIS, Path::new("x.png")).expect_err(phrase);
            assert!(err.to_string().contains(phrase), "{err}");
        };
        let grey8 = image::GrayImage::from_fn(4, 4, |x, _| image::Luma([x as u8 * 40]));
        refuse(DynamicImage::ImageLuma8(grey8.clone()), "8-bit grey");
        refuse(DynamicImage::ImageRgb8(DynamicImage::ImageLuma8(grey8).to_rgb8()), "every pixel is grey");
        refuse(DynamicImage::ImageRgb16(image::ImageBuffer::from_pixel(4, 4, image::Rgb([1u16, 2, 3]))), "16-bit colour");
        let colour = image::RgbaImage::from_fn(4, 4, |x, y| image::Rgba([x as u8, y as u8, 9, 255]));
        let opaque =
            control_for(&DynamicImage::ImageRgba8(colour.clone()), HintEncoding::Rgb01, VIRIDIS, Path::new("x.png")).expect("opaque");
        assert_eq!(opaque.get_pixel(3, 2).0, [3, 2, 9]);
        let mut see_through = colour;
        see_through.put_pixel(0, 0, image::Rgba([1, 2, 3, 0]));
        refuse(DynamicImage::ImageRgba8(see_through), "transparent");
    }

    /// A package that declares no colour map (a diffusers depth or edge ControlNet) reads grey
    /// control images, as RGB or as one channel; 16-bit and transparent ones stay refused.
    #[test]
    fn a_package_without_a_colour_map_reads_grey_control_images() {
        let grey8 = image::GrayImage::from_fn(4, 4, |x, y| image::Luma([(x * 40 + y) as u8]));
        let as_rgb = DynamicImage::ImageLuma8(grey8.clone()).to_rgb8();
        for image in [DynamicImage::ImageLuma8(grey8.clone()), DynamicImage::ImageRgb8(as_rgb.clone())] {
            assert_eq!(control_for(&image, HintEncoding::Rgb01, None, Path::new("edges.png")).expect("a grey control"), as_rgb);
            let e = control_for(&image, HintEncoding::Rgb01, VIRIDIS, Path::new("edges.png")).expect_err("refused by a viridis package");
            assert!(e.to_string().contains("control_colour_map"), "{e}");
        }
        let deep = DynamicImage::ImageLuma16(image::ImageBuffer::from_pixel(4, 4, image::Luma([9u16])));
        assert!(control_for(&deep, HintEncoding::Rgb01, None, Path::new("d.png")).is_err());
        let see_through = image::GrayAlphaImage::from_pixel(4, 4, image::LumaA([7, 0]));
        assert!(control_for(&DynamicImage::ImageLumaA8(see_through), HintEncoding::Rgb01, None, Path::new("t.png")).is_err());
    }
}
