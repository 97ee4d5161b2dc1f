//! Depth-rasteriser timing per library object: `cargo bench --bench raster`.
//!
//! Prints a table of milliseconds per 512 x 512 render, without and with 2 x 2 supersampling,
//! and the ratio between them. The sensor simulator calls `render_depth` once per frame.

use std::time::Instant;

use rig::calibration::Calibration;
use rig::geometry::objects::{load_object, object_names};
use rig::geometry::raster::render_depth;
use rig::pose::Pose;

fn time_ms(reps: u32, mut f: impl FnMut()) -> f64 {
    f();
    let t = Instant::now();
    for _ in 0..reps {
        f();
    }
    t.elapsed().as_secs_f64() * 1e3 / reps as f64
}

fn main() {
    let calib = Calibration::default_for(512, 512);
    let pose = Pose::new(0.8, -0.6, 1.5, 25.0);
    println!("{:<16} {:>9} {:>12} {:>12} {:>7}", "object", "triangles", "ss1 ms", "ss2 ms", "ratio");
    for name in object_names() {
        let Ok(mesh) = load_object(name) else { continue };
        let reps = 20;
        let a = time_ms(reps, || {
            std::hint::black_box(render_depth(&mesh, &pose, &calib, 512, 512, 1));
        });
        let b = time_ms(reps, || {
            std::hint::black_box(render_depth(&mesh, &pose, &calib, 512, 512, 2));
        });
        println!("{:<16} {:>9} {:>12.2} {:>12.2} {:>7.2}", name, mesh.triangles.len(), a, b, b / a);
    }
}
