//! The nokhwa backend where this build has none (Linux, or without the `nokhwa` feature):
//! [`NokhwaCamera::open`](crate::camera::nokhwa_backend::NokhwaCamera::open) refuses with
//! [`CameraError::NotBuilt`](crate::camera::CameraError::NotBuilt).

use super::usb::DeviceSelector;
use super::v4l2::CameraSettings;

super::absent_camera!(
    NokhwaCamera,
    "nokhwa",
    "nokhwa is built on macOS and Windows only, with the `nokhwa` feature (on by default); on Linux use backend = \"v4l2\"",
    DeviceSelector,
    CameraSettings
);
