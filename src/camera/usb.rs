//! USB identity of cameras and serial adapters, so a sensor is bound to its USB port or serial
//! number instead of a `/dev/videoN` number that changes across reboots.
//!
//! A [`UsbIdentity`] holds the port path (`1-2.3`: bus 1, root port 2, hub port 3; stable as
//! long as the cable stays in the same socket), the serial number when the device has one
//! (stable wherever it is plugged), and vendor/product ids. A [`DeviceSelector`] is what the
//! rig config writes (`port:1-2.3`, `serial:SN0042`, `id:046d:0825`, or a plain
//! `/dev/video0`), and [`resolve_video_device`] maps it to the `/dev/videoN` node today by
//! reading `/sys/class/video4linux/videoN/device`, whose parent chain leads to the USB device
//! directory (`/sys/bus/usb/devices/1-2.3`, named after the port path, holding `idVendor`,
//! `idProduct`, `serial`, `product`).
//!
//! [`list_usb_devices`] enumerates through libusb (`rusb`) with a private context; any libusb
//! failure (no USB in a container, no permission) means "no USB devices visible", never a panic.

use std::path::{Path, PathBuf};

/// The USB identity of one device.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct UsbIdentity {
    /// `bus-port.port...`, e.g. `1-2.3`.
    pub port_path: String,
    pub vendor_id: u16,
    pub product_id: u16,
    pub serial: Option<String>,
    pub manufacturer: Option<String>,
    pub product: Option<String>,
}

impl std::fmt::Display for UsbIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "usb port {} id {:04x}:{:04x}", self.port_path, self.vendor_id, self.product_id)?;
        if let Some(s) = &self.serial {
            write!(f, " serial {s}")?;
        }
        if let Some(p) = &self.product {
            write!(f, " ({p})")?;
        }
        Ok(())
    }
}

/// How the rig config names a device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceSelector {
    /// A device node, e.g. `/dev/video0` (not stable across reboots).
    Path(PathBuf),
    /// USB port path, e.g. `1-2.3`.
    Port(String),
    /// USB serial number.
    Serial(String),
    /// Vendor and product id; only unambiguous with one such device attached.
    VidPid { vendor_id: u16, product_id: u16 },
    /// A backend-specific index (nokhwa on macOS/Windows).
    Index(u32),
}

/// Why a selector could not be parsed or resolved.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UsbError {
    #[error("device {given:?}: expected /dev/..., port:1-2.3, serial:..., id:vvvv:pppp or index:N")]
    BadSelector { given: String },
    #[error("no video device matches {selector}")]
    NotFound { selector: String },
    #[error("{count} video devices match {selector}; use port: or serial: to pick one")]
    Ambiguous { selector: String, count: usize },
}

impl std::fmt::Display for DeviceSelector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceSelector::Path(p) => write!(f, "{}", p.display()),
            DeviceSelector::Port(p) => write!(f, "port:{p}"),
            DeviceSelector::Serial(s) => write!(f, "serial:{s}"),
            DeviceSelector::VidPid { vendor_id, product_id } => write!(f, "id:{vendor_id:04x}:{product_id:04x}"),
            DeviceSelector::Index(i) => write!(f, "index:{i}"),
        }
    }
}

impl DeviceSelector {
    /// Parses `/dev/video0`, `port:1-2.3` (or a bare `1-2.3`), `serial:SN`, `id:046d:0825`,
    /// `index:0`.
    pub fn parse(text: &str) -> Result<Self, UsbError> {
        let bad = || UsbError::BadSelector { given: text.to_string() };
        let text_trim = text.trim();
        if text_trim.starts_with('/') {
            return Ok(DeviceSelector::Path(PathBuf::from(text_trim)));
        }
        if let Some(p) = text_trim.strip_prefix("port:") {
            return if is_port_path(p) { Ok(DeviceSelector::Port(p.to_string())) } else { Err(bad()) };
        }
        if let Some(s) = text_trim.strip_prefix("serial:") {
            return if s.is_empty() { Err(bad()) } else { Ok(DeviceSelector::Serial(s.to_string())) };
        }
        if let Some(ids) = text_trim.strip_prefix("id:") {
            let (v, p) = ids.split_once(':').ok_or_else(bad)?;
            let vendor_id = u16::from_str_radix(v, 16).map_err(|_| bad())?;
            let product_id = u16::from_str_radix(p, 16).map_err(|_| bad())?;
            return Ok(DeviceSelector::VidPid { vendor_id, product_id });
        }
        if let Some(i) = text_trim.strip_prefix("index:") {
            return i.parse().map(DeviceSelector::Index).map_err(|_| bad());
        }
        if is_port_path(text_trim) {
            return Ok(DeviceSelector::Port(text_trim.to_string()));
        }
        Err(bad())
    }

    /// Whether a device with this node and identity is the one selected.
    pub fn matches(&self, node: &Path, usb: Option<&UsbIdentity>) -> bool {
        match self {
            DeviceSelector::Path(p) => p == node,
            DeviceSelector::Port(p) => usb.is_some_and(|u| &u.port_path == p),
            DeviceSelector::Serial(s) => usb.is_some_and(|u| u.serial.as_deref() == Some(s.as_str())),
            DeviceSelector::VidPid { vendor_id, product_id } => {
                usb.is_some_and(|u| u.vendor_id == *vendor_id && u.product_id == *product_id)
            }
            DeviceSelector::Index(i) => node.file_name().is_some_and(|n| n.to_string_lossy() == format!("video{i}")),
        }
    }
}

/// `1-2`, `1-2.3`, `3-1.4.2`: bus number, dash, dot-separated port numbers.
fn is_port_path(text: &str) -> bool {
    let Some((bus, ports)) = text.split_once('-') else { return false };
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    digits(bus) && ports.split('.').all(digits)
}

/// The USB identity of the device that a sysfs device directory belongs to: follows the
/// directory's real path upwards to the first directory holding `idVendor`.
pub fn usb_identity_of_sysfs_device(device_dir: &Path) -> Option<UsbIdentity> {
    let real = std::fs::canonicalize(device_dir).ok()?;
    let usb_dir = real.ancestors().find(|d| d.join("idVendor").is_file())?;
    read_usb_dir(usb_dir)
}

/// Reads `idVendor`, `idProduct`, `serial`, `manufacturer`, `product` of a sysfs USB device
/// directory named after its port path.
pub fn read_usb_dir(dir: &Path) -> Option<UsbIdentity> {
    let text = |name: &str| std::fs::read_to_string(dir.join(name)).ok().map(|s| s.trim().to_string()).filter(|s| !s.is_empty());
    let hex = |name: &str| text(name).and_then(|s| u16::from_str_radix(&s, 16).ok());
    Some(UsbIdentity {
        port_path: dir.file_name()?.to_string_lossy().into_owned(),
        vendor_id: hex("idVendor")?,
        product_id: hex("idProduct")?,
        serial: text("serial"),
        manufacturer: text("manufacturer"),
        product: text("product"),
    })
}

/// A V4L2 device node and what sysfs says about it.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoNode {
    /// `/dev/videoN`.
    pub path: PathBuf,
    /// The driver's name for it (`/sys/class/video4linux/videoN/name`).
    pub name: String,
    /// The node's index among its device's nodes; 0 is the capture node, UVC cameras add a
    /// metadata node with index 1.
    pub index: u32,
    pub usb: Option<UsbIdentity>,
}

/// Video nodes listed under `/sys/class/video4linux`, sorted by node number.
pub fn list_video_nodes() -> Vec<VideoNode> {
    list_video_nodes_in(Path::new("/sys/class/video4linux"), Path::new("/dev"))
}

/// [`list_video_nodes`] over other roots (tests build fake trees).
pub fn list_video_nodes_in(sys_v4l: &Path, dev: &Path) -> Vec<VideoNode> {
    let Ok(entries) = std::fs::read_dir(sys_v4l) else { return Vec::new() };
    let mut nodes: Vec<(u32, VideoNode)> = entries
        .flatten()
        .filter_map(|e| {
            let file_name = e.file_name().to_string_lossy().into_owned();
            let number: u32 = file_name.strip_prefix("video")?.parse().ok()?;
            let dir = e.path();
            let read = |n: &str| std::fs::read_to_string(dir.join(n)).ok().map(|s| s.trim().to_string());
            Some((
                number,
                VideoNode {
                    path: dev.join(&file_name),
                    name: read("name").unwrap_or_default(),
                    index: read("index").and_then(|s| s.parse().ok()).unwrap_or(0),
                    usb: usb_identity_of_sysfs_device(&dir.join("device")),
                },
            ))
        })
        .collect();
    nodes.sort_by_key(|(n, _)| *n);
    nodes.into_iter().map(|(_, node)| node).collect()
}

/// The capture node selected by `selector` among `nodes`: exactly one device must match
/// (a camera's metadata nodes, index > 0, are not candidates).
pub fn select_video_node<'a>(nodes: &'a [VideoNode], selector: &DeviceSelector) -> Result<&'a VideoNode, UsbError> {
    let matching: Vec<&VideoNode> = nodes.iter().filter(|n| n.index == 0 && selector.matches(&n.path, n.usb.as_ref())).collect();
    match matching.as_slice() {
        [one] => Ok(one),
        [] => Err(UsbError::NotFound { selector: selector.to_string() }),
        many => Err(UsbError::Ambiguous { selector: selector.to_string(), count: many.len() }),
    }
}

/// `/dev/videoN` for a selector on this machine. A `/dev/...` path is taken as given.
pub fn resolve_video_device(selector: &DeviceSelector) -> Result<PathBuf, UsbError> {
    if let DeviceSelector::Path(p) = selector {
        return Ok(p.clone());
    }
    select_video_node(&list_video_nodes(), selector).map(|n| n.path.clone())
}

/// [`resolve_video_device`] with the USB identity sysfs gives for the node (what the manifest
/// records: serial, vendor and product id, port). A `/dev/...` path is taken as given and its
/// identity looked up; the identity is `None` for a node that is not a USB device or that
/// sysfs does not list.
pub fn resolve_video_node(selector: &DeviceSelector) -> Result<(PathBuf, Option<UsbIdentity>), UsbError> {
    video_node_of(&list_video_nodes(), selector)
}

/// [`resolve_video_node`] among `nodes` (tests build them from fake trees).
pub fn video_node_of(nodes: &[VideoNode], selector: &DeviceSelector) -> Result<(PathBuf, Option<UsbIdentity>), UsbError> {
    if let DeviceSelector::Path(p) = selector {
        // `/dev/v4l/by-id/...` links name a node too.
        let real = std::fs::canonicalize(p).ok();
        let usb = nodes.iter().find(|n| &n.path == p || real.as_ref() == Some(&n.path)).and_then(|n| n.usb.clone());
        return Ok((p.clone(), usb));
    }
    select_video_node(nodes, selector).map(|n| (n.path.clone(), n.usb.clone()))
}

/// Always empty: libusb is built on Linux only, where USB identities bind cameras to sensors;
/// nokhwa on macOS and Windows picks cameras by index.
#[cfg(not(target_os = "linux"))]
pub fn list_usb_devices() -> Vec<UsbIdentity> {
    Vec::new()
}

/// USB devices libusb can see; empty when libusb cannot run here. Strings (serial, product)
/// need the device opened, which may be refused without permissions; they are then `None`.
#[cfg(target_os = "linux")]
pub fn list_usb_devices() -> Vec<UsbIdentity> {
    use rusb::UsbContext;
    let Ok(context) = rusb::Context::new() else { return Vec::new() };
    let Ok(devices) = context.devices() else { return Vec::new() };
    let timeout = std::time::Duration::from_millis(200);
    let mut out = Vec::new();
    for device in devices.iter() {
        let Ok(desc) = device.device_descriptor() else { continue };
        let ports = device.port_numbers().unwrap_or_default();
        let port_path = if ports.is_empty() {
            // Root hubs have no port numbers; sysfs names them usbN.
            format!("usb{}", device.bus_number())
        } else {
            let joined: Vec<String> = ports.iter().map(u8::to_string).collect();
            format!("{}-{}", device.bus_number(), joined.join("."))
        };
        let mut identity = UsbIdentity { port_path, vendor_id: desc.vendor_id(), product_id: desc.product_id(), ..UsbIdentity::default() };
        if let Ok(handle) = device.open()
            && let Ok(languages) = handle.read_languages(timeout)
            && let Some(lang) = languages.first()
        {
            identity.serial = handle.read_serial_number_string(*lang, &desc, timeout).ok();
            identity.manufacturer = handle.read_manufacturer_string(*lang, &desc, timeout).ok();
            identity.product = handle.read_product_string(*lang, &desc, timeout).ok();
        }
        out.push(identity);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selectors_parse() {
        assert_eq!(DeviceSelector::parse("/dev/video2").unwrap(), DeviceSelector::Path("/dev/video2".into()));
        assert_eq!(DeviceSelector::parse("port:1-2.3").unwrap(), DeviceSelector::Port("1-2.3".into()));
        assert_eq!(DeviceSelector::parse("3-1").unwrap(), DeviceSelector::Port("3-1".into()));
        assert_eq!(DeviceSelector::parse("serial:TT-0042").unwrap(), DeviceSelector::Serial("TT-0042".into()));
        assert_eq!(DeviceSelector::parse("id:046d:0825").unwrap(), DeviceSelector::VidPid { vendor_id: 0x046d, product_id: 0x0825 });
        assert_eq!(DeviceSelector::parse("index:1").unwrap(), DeviceSelector::Index(1));
        for bad in ["", "video0", "port:1-", "port:x-2", "serial:", "id:zz:01", "id:046d", "1.2-3"] {
            assert!(DeviceSelector::parse(bad).is_err(), "{bad:?} parsed");
        }
        // Display round-trips.
        for text in ["port:1-2.3", "serial:A", "id:046d:0825", "index:0"] {
            assert_eq!(DeviceSelector::parse(text).unwrap().to_string(), text);
        }
    }

    /// A sysfs-like tree: two cameras on a hub, one with a metadata node, the numbering
    /// swapped from what their ports suggest.
    fn fake_sysfs(root: &Path) -> (PathBuf, PathBuf) {
        let usb = root.join("sys/devices/pci0000:00/usb1");
        let cameras =
            [("1-2.3", "0c45", "6366", Some("TT-0042"), &[(0u32, 2u32), (1, 3)][..]), ("1-2.1", "0c45", "6366", None, &[(0, 0)][..])];
        let v4l = root.join("sys/class/video4linux");
        std::fs::create_dir_all(&v4l).unwrap();
        for (port, vid, pid, serial, nodes) in cameras {
            let dev = usb.join(port);
            std::fs::create_dir_all(&dev).unwrap();
            std::fs::write(dev.join("idVendor"), format!("{vid}\n")).unwrap();
            std::fs::write(dev.join("idProduct"), format!("{pid}\n")).unwrap();
            std::fs::write(dev.join("product"), "USB Camera\n").unwrap();
            if let Some(s) = serial {
                std::fs::write(dev.join("serial"), format!("{s}\n")).unwrap();
            }
            for (index, number) in nodes {
                // The interface directory below the device, then the video4linux entry.
                let iface = dev.join(format!("{port}:1.0"));
                let node_dir = iface.join(format!("video4linux/video{number}"));
                std::fs::create_dir_all(&node_dir).unwrap();
                std::fs::write(node_dir.join("name"), "USB Camera: USB Camera\n").unwrap();
                std::fs::write(node_dir.join("index"), format!("{index}\n")).unwrap();
                let class_dir = v4l.join(format!("video{number}"));
                std::fs::create_dir_all(&class_dir).unwrap();
                std::fs::write(class_dir.join("index"), format!("{index}\n")).unwrap();
                std::os::unix::fs::symlink(&iface, class_dir.join("device")).unwrap();
            }
        }
        (v4l, root.join("dev"))
    }

    #[test]
    fn usb_identity_maps_to_the_right_video_node() {
        let dir = tempfile::tempdir().unwrap();
        let (v4l, dev) = fake_sysfs(dir.path());
        let nodes = list_video_nodes_in(&v4l, &dev);
        assert_eq!(nodes.len(), 3);
        let by_port = select_video_node(&nodes, &DeviceSelector::Port("1-2.3".into())).unwrap();
        assert_eq!(by_port.path, dev.join("video2"));
        let id = by_port.usb.as_ref().unwrap();
        assert_eq!((id.vendor_id, id.product_id, id.serial.as_deref()), (0x0c45, 0x6366, Some("TT-0042")));
        let by_serial = select_video_node(&nodes, &DeviceSelector::Serial("TT-0042".into())).unwrap();
        assert_eq!(by_serial.path, dev.join("video2"));
        assert_eq!(select_video_node(&nodes, &DeviceSelector::Port("1-2.1".into())).unwrap().path, dev.join("video0"));
        // Same vendor/product twice: ambiguous, and a missing port is not found.
        assert!(matches!(
            select_video_node(&nodes, &DeviceSelector::VidPid { vendor_id: 0x0c45, product_id: 0x6366 }),
            Err(UsbError::Ambiguous { count: 2, .. })
        ));
        assert!(matches!(select_video_node(&nodes, &DeviceSelector::Port("2-1".into())), Err(UsbError::NotFound { .. })));
        // The metadata node video3 is never picked, even by its own index.
        assert!(select_video_node(&nodes, &DeviceSelector::Index(3)).is_err());

        // The identity goes with the node, however it was selected; a node without a serial
        // has none, and a path sysfs does not list has no identity.
        let (path, usb) = video_node_of(&nodes, &DeviceSelector::Serial("TT-0042".into())).unwrap();
        assert_eq!((path, usb.and_then(|u| u.serial)), (dev.join("video2"), Some("TT-0042".to_string())));
        let (_, usb) = video_node_of(&nodes, &DeviceSelector::Path(dev.join("video0"))).unwrap();
        let usb = usb.expect("video0 is a USB camera");
        assert_eq!((usb.port_path.as_str(), usb.vendor_id, usb.serial), ("1-2.1", 0x0c45, None));
        assert_eq!(video_node_of(&nodes, &DeviceSelector::Path(dev.join("video9"))).unwrap(), (dev.join("video9"), None));
        assert!(matches!(video_node_of(&nodes, &DeviceSelector::Port("2-1".into())), Err(UsbError::NotFound { .. })));
    }

    #[test]
    fn no_sysfs_means_no_nodes_and_libusb_trouble_means_no_devices() {
        assert!(list_video_nodes_in(Path::new("/nonexistent/v4l"), Path::new("/dev")).is_empty());
        // Must return (possibly empty), never panic, whatever USB support this machine has.
        let _ = list_usb_devices();
    }
}
