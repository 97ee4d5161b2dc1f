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
            .map(|node| match v4l::Device::with_path(&node.path) {
                Ok(device) => match crate::camera::v4l2::enumerate_offers(&device) {
                    Ok(offers) => CameraEntry { node, offers, error: None },
                    Err(e) => CameraEntry { node, offers: Vec::new(), error: Some(e.to_string()) },
                },
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::convert::PixelFormat;

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
