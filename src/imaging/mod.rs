//! Image filters shared by calibration, the sensor simulator, eval and compare-real, written
//! once. Depends on nothing else in rig.
//!
//! Buffers are row-major. A scalar map is `&[f32]` with one value per pixel (`width * height`),
//! a mask `&[bool]` likewise, an image an [`image::RgbImage`].
//!
//! - [`blur`]: box blur of a scalar map; [`BoxBorder`] says what the window does at the edge
//!   (the two callers' numbers differ there, and each keeps its own); [`RowBand`], a map that
//!   is zero outside a band of rows, blurred at the cost of the band.
//! - [`morphology`]: grey dilation, erosion and closing of a map; square dilation of a mask.
//! - [`difference`]: luma, and how much an image changed from a reference (per-pixel maps and
//!   a thresholded mask).
//! - [`region`]: the connected region above a threshold (flood fill), and the overlap of two
//!   masks (intersection over union).
//! - [`stack`]: per-pixel statistics over a stack of frames: median, median over the frames a
//!   mask leaves free, mean.

pub mod blur;
pub mod difference;
pub mod morphology;
pub mod region;
pub mod stack;

pub use blur::{BoxBorder, RowBand, box_blur, box_blur_repeated};
pub use difference::{difference_mask, luma, luma_f64, max_channel_difference, summed_channel_difference};
pub use morphology::{close_values, dilate_mask, dilate_values, erode_values};
pub use region::{flood_fill, iou};
pub use stack::{MeanImage, mean_image, median_image, median_image_excluding};
