//! Opt-in checks against a real USB camera through V4L2 (Linux). Run with
//! `RIG_HW_CAMERA=port:1-2.1 cargo test --test rig hw_camera:: -- --ignored --nocapture`
//! (any `device =` value of the rig config works: `/dev/video0`, `serial:...`).
//! Optional: `RIG_HW_CAMERA_SIZE=640x480`, `RIG_HW_CAMERA_FPS=30`, `RIG_HW_CAMERA_EXPOSURE=156`.

use std::sync::Arc;

use rig::camera::Camera;
use rig::camera::usb::{DeviceSelector, resolve_video_device};
use rig::camera::v4l2::{CameraSettings, V4l2Camera};
use rig::clock::{Clock, MonotonicClock};

fn selector() -> DeviceSelector {
    let text = std::env::var("RIG_HW_CAMERA").unwrap_or_else(|_| panic!("set RIG_HW_CAMERA to a camera (port:1-2.1, /dev/video0)"));
    DeviceSelector::parse(&text).expect("RIG_HW_CAMERA parses as a device selector")
}

fn settings() -> CameraSettings {
    let mut s = CameraSettings::default();
    if let Ok(size) = std::env::var("RIG_HW_CAMERA_SIZE") {
        let (w, h) = size.split_once('x').expect("RIG_HW_CAMERA_SIZE is WxH");
        s.width = w.parse().expect("width");
        s.height = h.parse().expect("height");
    }
    if let Ok(fps) = std::env::var("RIG_HW_CAMERA_FPS") {
        s.fps = fps.parse().expect("fps");
    }
    s.exposure_100us = std::env::var("RIG_HW_CAMERA_EXPOSURE").ok().map(|e| e.parse().expect("exposure"));
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs a USB camera named by RIG_HW_CAMERA"]
async fn real_camera_streams_fresh_frames_in_order() {
    let selector = selector();
    let path = resolve_video_device(&selector).expect("the selector matches one camera");
    println!("{selector} is {}", path.display());
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let s = settings();
    let mut camera = V4l2Camera::open("hw", &selector, &s, Arc::clone(&clock)).expect("opens and streams");
    println!("format {:?}", camera.format());
    let mut last = None::<(f64, u64)>;
    let start_s = clock.now_s();
    let n: u32 = 60;
    for _ in 0..n {
        let asked_s = clock.now_s();
        let frame = camera.frame_after(asked_s).await.expect("a frame");
        assert_eq!(frame.image.dimensions(), (s.width, s.height));
        // Never a frame exposed before it was asked for (the stale-buffer bug).
        assert!(frame.t_capture_s >= asked_s, "frame at {} s older than request at {asked_s} s", frame.t_capture_s);
        if let Some((t, seq)) = last {
            assert!(frame.t_capture_s > t && frame.seq > seq, "frames out of order");
        }
        last = Some((frame.t_capture_s, frame.seq));
    }
    // Reported, not asserted: rates depend on the camera and the USB bus.
    let elapsed_s = clock.now_s() - start_s;
    println!("{n} fresh frames in {elapsed_s:.2} s ({:.1} requests/s; each waits for a new exposure)", f64::from(n) / elapsed_s);
    // The stream delivered at least the frames handed out, and its rate was measured.
    let stats = camera.stream_stats().expect("V4L2 counts its stream");
    assert!(stats.frames_received >= u64::from(n), "{stats:?}");
    let fps = stats.measured_fps().expect("a measured rate");
    println!("stream: {} frames received, {} dropped by the driver, {fps:.2} fps delivered", stats.frames_received, stats.frames_dropped);
    println!("usb identity: {:?}", camera.usb());
}
