//! What hardware this machine offers: cameras (V4L2 nodes with their formats and USB
//! identities), serial ports, USB devices. Behind `rig devices`.
//!
//! [`DeviceReport::scan`] reads sysfs, opens each capture node to list its formats, and asks
//! libusb; every step that fails (no sysfs, no permission, no libusb) just contributes nothing.
//! [`DeviceReport::render`] says plainly when a kind of device was not found, with the likely
//! reason, so an empty machine gives a useful answer rather than silence.

use std::fmt::Write as _;

use crate::camera::usb::{UsbIdentity, VideoNode};
use crate::camera::v4l2::FormatOffer;
use crate::io::serial::SerialPortInfo;

/// One camera node and what it offers.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraEntry {
    pub node: VideoNode,
    /// YUYV/MJPEG modes; empty when the node could not be opened.
    pub offers: Vec<FormatOffer>,
    /// Why the formats could not be read, if they could not.
    pub error: Option<String>,
}

/// Everything `rig devices` lists.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DeviceReport {
    pub cameras: Vec<CameraEntry>,
    pub serial_ports: Vec<SerialPortInfo>,
    pub usb_devices: Vec<UsbIdentity>,
}

impl DeviceReport {
    /// Scans this machine.
    pub fn scan() -> Self {
        let cameras = crate::camera::usb::list_video_nodes()
            .into_iter()
            // Metadata nodes (index > 0) carry no images.
            .filter(|n| n.index == 0)
            .map(|node| match crate::camera::v4l2::offers_at(&node.path) {
                Ok(offers) => CameraEntry { node, offers, error: None },
                Err(e) => CameraEntry { node, offers: Vec::new(), error: Some(e.to_string()) },
            })
            .collect();
        Self { cameras, serial_ports: crate::io::serial::list_serial_ports(), usb_devices: crate::camera::usb::list_usb_devices() }
    }

    /// The human-readable listing.
    pub fn render(&self) -> String {
        let mut out = String::new();
        if self.cameras.is_empty() {
            out.push_str("cameras: none found (no /sys/class/video4linux/video* nodes; is a camera plugged in, and is the uvcvideo driver loaded?)\n");
        } else {
            let _ = writeln!(out, "cameras: {}", self.cameras.len());
            for c in &self.cameras {
                let _ = writeln!(out, "  {}  {}", c.node.path.display(), c.node.name);
                match &c.node.usb {
                    Some(u) => {
                        let _ = writeln!(out, "    {u}");
                        let _ = writeln!(
                            out,
                            "    config: device = \"port:{}\"{}",
                            u.port_path,
                            u.serial.as_ref().map(|s| format!("  or  device = \"serial:{s}\"")).unwrap_or_default()
                        );
                    }
                    None => out.push_str("    not a USB device\n"),
                }
                if let Some(e) = &c.error {
                    let _ = writeln!(out, "    formats: cannot open ({e})");
                } else if c.offers.is_empty() {
                    out.push_str("    formats: no YUYV or MJPEG modes\n");
                } else {
                    for o in &c.offers {
                        let _ = writeln!(out, "    {:?} {}x{} up to {:.1} fps", o.format, o.width, o.height, o.max_fps);
                    }
                }
            }
        }
        if self.serial_ports.is_empty() {
            out.push_str("serial ports: none found (no /dev/ttyUSB*, /dev/ttyACM* or device-backed ttys)\n");
        } else {
            let _ = writeln!(out, "serial ports: {}", self.serial_ports.len());
            for p in &self.serial_ports {
                match &p.usb {
                    Some(u) => {
                        let _ = writeln!(out, "  {}  {u}", p.path.display());
                    }
                    None => {
                        let _ = writeln!(out, "  {}", p.path.display());
                    }
                }
            }
        }
        if self.usb_devices.is_empty() {
            out.push_str("usb devices: none visible (no USB bus here, or libusb cannot read it)\n");
        } else {
            let _ = writeln!(out, "usb devices: {}", self.usb_devices.len());
            for u in &self.usb_devices {
                let _ = writeln!(out, "  {u}");
            }
        }
        out
    }
}

/// Bytes per second a USB 2.0 high-speed bus gives periodic (isochronous) transfers, which UVC
/// video streams use: at most 80% of each 125 us microframe (USB 2.0 specification, section
/// 5.6.4), 0.8 x 480 Mbit/s = 48 MB/s, shared by every camera on the bus.
pub const USB2_PERIODIC_BYTES_PER_S: f64 = 0.8 * 480e6 / 8.0;

/// A configured camera's stream as it would run: the format `choose_format` picks for its
/// configured size and rate, and the USB bus it sits on.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfiguredStream {
    pub sensor: String,
    /// The bus number, the part of the USB port path before `-` (`1` for `1-2.3`).
    pub bus: String,
    pub format: crate::camera::convert::PixelFormat,
    pub width: u32,
    pub height: u32,
    pub fps: u32,
}

impl ConfiguredStream {
    /// Uncompressed bytes per second (YUYV: 2 bytes a pixel); `None` for MJPEG, whose size
    /// depends on the scene.
    pub fn raw_bytes_per_s(&self) -> Option<f64> {
        match self.format {
            crate::camera::convert::PixelFormat::Yuyv => Some(2.0 * f64::from(self.width) * f64::from(self.height) * f64::from(self.fps)),
            _ => None,
        }
    }
}

/// One warning per USB bus whose YUYV streams together need more than a USB 2.0 bus carries
/// ([`USB2_PERIODIC_BYTES_PER_S`]), suggesting MJPEG. MJPEG streams are not counted.
pub fn usb_bandwidth_warnings(streams: &[ConfiguredStream]) -> Vec<String> {
    let mut buses: std::collections::BTreeMap<&str, Vec<&ConfiguredStream>> = std::collections::BTreeMap::new();
    for s in streams {
        buses.entry(s.bus.as_str()).or_default().push(s);
    }
    let mut out = Vec::new();
    for (bus, on_bus) in buses {
        let yuyv: Vec<&&ConfiguredStream> = on_bus.iter().filter(|s| s.raw_bytes_per_s().is_some()).collect();
        let total: f64 = yuyv.iter().filter_map(|s| s.raw_bytes_per_s()).sum();
        if total > USB2_PERIODIC_BYTES_PER_S {
            let names: Vec<String> = yuyv.iter().map(|s| format!("{} ({}x{} at {} fps)", s.sensor, s.width, s.height, s.fps)).collect();
            out.push(format!(
                "warning: USB bus {bus}: YUYV streams of {} need {:.1} MB/s, more than a USB 2.0 bus carries for video ({:.0} MB/s); \
                 set pixel_format = \"mjpeg\" for some of them, or move a camera to another bus",
                names.join(", "),
                total / 1e6,
                USB2_PERIODIC_BYTES_PER_S / 1e6
            ));
        }
    }
    out
}

/// The configured V4L2 cameras (sensor name, `device` selector, settings) found among
/// `cameras`, each with the format rig would pick. Cameras that are absent, not on USB, or
/// offer no matching mode are left out (`rig collect` reports those when it opens them).
pub fn configured_streams<'a>(
    sensors: impl IntoIterator<Item = (&'a str, &'a str, &'a crate::camera::v4l2::CameraSettings)>,
    cameras: &[CameraEntry],
) -> Vec<ConfiguredStream> {
    let nodes: Vec<crate::camera::usb::VideoNode> = cameras.iter().map(|c| c.node.clone()).collect();
    sensors
        .into_iter()
        .filter_map(|(sensor, device, settings)| {
            let selector = crate::camera::usb::DeviceSelector::parse(device).ok()?;
            let (path, usb) = crate::camera::usb::video_node_of(&nodes, &selector).ok()?;
            let entry = cameras.iter().find(|c| c.node.path == path)?;
            let choice = crate::camera::v4l2::choose_format(&entry.offers, settings).ok()?;
            let bus = usb?.port_path.split('-').next()?.to_string();
            Some(ConfiguredStream {
                sensor: sensor.to_string(),
                bus,
                format: choice.format,
                width: choice.width,
                height: choice.height,
                fps: choice.fps,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::convert::PixelFormat;

    fn stream(sensor: &str, bus: &str, format: PixelFormat) -> ConfiguredStream {
        ConfiguredStream { sensor: sensor.into(), bus: bus.into(), format, width: 640, height: 480, fps: 30 }
    }

    #[test]
    fn three_yuyv_cameras_on_one_bus_are_too_many() {
        // 640 x 480 x 2 bytes x 30 fps = 18.4 MB/s each; three need 55.3 MB/s of 48.
        let three =
            [stream("tactip", "1", PixelFormat::Yuyv), stream("vitac", "1", PixelFormat::Yuyv), stream("digit", "1", PixelFormat::Yuyv)];
        let w = usb_bandwidth_warnings(&three);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].contains("USB bus 1") && w[0].contains("55.3 MB/s") && w[0].contains("mjpeg"), "{w:?}");
        // One of them in MJPEG, or one on another bus: within the bus's share.
        let mut mixed = three.clone();
        mixed[2].format = PixelFormat::Mjpeg;
        assert!(usb_bandwidth_warnings(&mixed).is_empty());
        let mut spread = three.clone();
        spread[2].bus = "3".into();
        assert!(usb_bandwidth_warnings(&spread).is_empty());
    }

    #[test]
    fn configured_cameras_are_matched_to_their_nodes_and_formats() {
        let usb = |port: &str| crate::camera::usb::UsbIdentity {
            port_path: port.into(),
            vendor_id: 0x0c45,
            product_id: 0x6366,
            serial: None,
            manufacturer: None,
            product: None,
        };
        let offer = |format| crate::camera::v4l2::FormatOffer { format, width: 640, height: 480, max_fps: 30.0 };
        let cameras: Vec<CameraEntry> = (0..3)
            .map(|k| CameraEntry {
                node: crate::camera::usb::VideoNode {
                    path: format!("/dev/video{}", 2 * k).into(),
                    name: "cam".into(),
                    index: 0,
                    usb: Some(usb(&format!("1-{}", k + 1))),
                },
                offers: vec![offer(PixelFormat::Yuyv), offer(PixelFormat::Mjpeg)],
                error: None,
            })
            .collect();
        let settings = crate::camera::v4l2::CameraSettings { width: 640, height: 480, fps: 30, ..Default::default() };
        let configured =
            [("s0", "port:1-1", &settings), ("s1", "port:1-2", &settings), ("s2", "port:1-3", &settings), ("gone", "port:2-9", &settings)];
        let streams = configured_streams(configured, &cameras);
        assert_eq!(streams.len(), 3, "{streams:?}");
        assert!(streams.iter().all(|s| s.bus == "1" && s.format == PixelFormat::Yuyv), "{streams:?}");
        assert_eq!(usb_bandwidth_warnings(&streams).len(), 1);
    }

    #[test]
    fn empty_machine_says_none_found() {
        let text = DeviceReport::default().render();
        assert!(text.contains("cameras: none found"), "{text}");
        assert!(text.contains("serial ports: none found"), "{text}");
        assert!(text.contains("usb devices: none visible"), "{text}");
    }

    #[test]
    fn cameras_show_formats_and_the_config_line() {
        let usb = UsbIdentity {
            port_path: "1-2.3".into(),
            vendor_id: 0x0c45,
            product_id: 0x6366,
            serial: Some("TT1".into()),
            ..UsbIdentity::default()
        };
        let report = DeviceReport {
            cameras: vec![CameraEntry {
                node: VideoNode { path: "/dev/video2".into(), name: "TacTip".into(), index: 0, usb: Some(usb) },
                offers: vec![FormatOffer { format: PixelFormat::Mjpeg, width: 640, height: 480, max_fps: 30.0 }],
                error: None,
            }],
            ..DeviceReport::default()
        };
        let text = report.render();
        assert!(text.contains("cameras: 1"), "{text}");
        assert!(text.contains("usb port 1-2.3 id 0c45:6366 serial TT1"), "{text}");
        assert!(text.contains("device = \"port:1-2.3\"  or  device = \"serial:TT1\""), "{text}");
        assert!(text.contains("Mjpeg 640x480 up to 30.0 fps"), "{text}");
    }
}
