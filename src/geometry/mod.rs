//! Object geometry: STL meshes, the depth rasteriser and the control image.
//!
//! [`DepthMap`] is the hand-over between the rasteriser and its users (the control-image
//! pipeline and the simulated sensors): per pixel of the sensor image, the height of the
//! object's surface above the sensor's undeformed skin plane.
//!
//! Flow: [`stl`] loads a [`stl::Mesh`] (or [`objects`] finds a library object, built by
//! [`shapes`]); [`raster::render_depth`] projects it under the sensor at a pose through a
//! [`crate::calibration::model::Calibration`] into a [`DepthMap`]; [`control`] turns that into the
//! diffusion model's control image or a 16-bit depth PNG.

pub mod control;
pub mod objects;
pub mod raster;
pub mod shapes;
pub mod stl;

/// Per-pixel object height relative to the sensor's undeformed skin plane, in mm, row-major.
///
/// Positive: the object reaches past the skin plane there (the skin is pressed in by that much).
/// Negative: a gap between the skin and the object. [`DepthMap::BACKGROUND_MM`]: no object
/// under that pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    pub width: u32,
    pub height: u32,
    pub height_mm: Vec<f32>,
}

impl DepthMap {
    /// Value of pixels with no object under them.
    pub const BACKGROUND_MM: f32 = -1.0e3;

    /// A map with no object anywhere.
    pub fn empty(width: u32, height: u32) -> Self {
        Self { width, height, height_mm: vec![Self::BACKGROUND_MM; (width as usize) * (height as usize)] }
    }

    /// Height at pixel (x, y); `None` outside the map.
    pub fn get(&self, x: u32, y: u32) -> Option<f32> {
        if x < self.width && y < self.height {
            self.height_mm.get((y as usize) * (self.width as usize) + x as usize).copied()
        } else {
            None
        }
    }

    /// Largest indentation (positive height) in the map, 0 when nothing touches.
    pub fn max_indentation_mm(&self) -> f32 {
        self.height_mm.iter().copied().fold(0.0f32, f32::max)
    }
}
