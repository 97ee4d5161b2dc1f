//! The simulated look against the real images of the MultiDiffSense sample (512x512):
//! marker count and ring layout, skin colours by radius, the field of view and the dark
//! outside. Measured the same way on both. Needs `$RIG_SHARED/real-sample` (default
//! `../shared` from the repository root).

use crate::sensor_support::{central, radii, real_image, ring_mean, spots};
use rig::sensor::SensorKind;
use rig::sim::sensor::{MotionState, Scene, SensorSim, shapes};

const K: f32 = 8.5;

fn sim(kind: SensorKind) -> SensorSim {
    SensorSim::new(kind, Scene::preset("full").unwrap(), 512, 512, K, 1)
}

/// The bar of object 1 pressed below the centre, roughly as in real frame 0.
fn bar_frame(kind: SensorKind) -> image::RgbImage {
    let depth = shapes::bar(512, 512, K, 0.5, 1.6, 0.0, 33.0, 4.0, 0.8);
    sim(kind).render(&depth, &MotionState::STILL, 1)
}

fn luma(c: [f32; 3]) -> f32 {
    (c[0] + c[1] + c[2]) / 3.0
}

/// Radius where the ring-mean brightness first falls below `level`, px.
fn fov_edge(img: &image::RgbImage, level: f32) -> f32 {
    let mut r = 150.0;
    while r < 300.0 && luma(ring_mean(img, r, r + 2.0)) >= level {
        r += 2.0;
    }
    r
}

#[test]
fn tactip_pins_match_in_count_and_rings() {
    let find = |img: &image::RgbImage| central(spots(img, false, 40.0, 12.0, 400.0), 512, 512, 190.0);
    let real = find(&real_image("TacTip", 0));
    let simulated = find(&sim(SensorKind::TacTip).reference());
    eprintln!("pins: real {} sim {}", real.len(), simulated.len());
    assert!((130..=140).contains(&real.len()), "detector sanity on the real image: {}", real.len());
    assert!(real.len().abs_diff(simulated.len()) <= 2, "real {} sim {}", real.len(), simulated.len());
    let (rr, rs) = (radii(&real), radii(&simulated));
    let n = rr.len().min(rs.len());
    let err = (0..n).map(|i| (rr[i] - rs[i]).abs()).sum::<f32>() / n as f32;
    eprintln!("mean ring-radius error {err:.2} px");
    assert!(err < 2.5, "ring radii differ by {err} px on average");
    let area = |s: &[crate::sensor_support::Spot]| s.iter().map(|p| p.area).sum::<f32>() / s.len() as f32;
    eprintln!("pin area: real {:.1} sim {:.1}", area(&real), area(&simulated));
    assert!((area(&real) - area(&simulated)).abs() < 0.25 * area(&real));
}

#[test]
fn vitactip_markers_match_in_count() {
    let find = |img: &image::RgbImage| central(spots(img, true, 25.0, 12.0, 400.0), 512, 512, 190.0);
    let real = find(&real_image("ViTacTip", 1));
    let simulated = find(&bar_frame(SensorKind::ViTacTip));
    eprintln!("markers: real {} sim {}", real.len(), simulated.len());
    assert!((130..=140).contains(&real.len()), "detector sanity on the real image: {}", real.len());
    assert!(real.len().abs_diff(simulated.len()) <= 3, "real {} sim {}", real.len(), simulated.len());
}

#[test]
fn skin_colours_by_radius_match() {
    for (kind, frame, tol) in [(SensorKind::ViTac, 0, 10.0), (SensorKind::ViTacTip, 1, 10.0), (SensorKind::TacTip, 0, 6.0)] {
        let real = real_image(kind.label(), frame);
        let simulated = bar_frame(kind);
        for (r0, r1) in [(60.0, 140.0), (160.0, 200.0), (200.0, 235.0), (270.0, 360.0)] {
            let (a, b) = (ring_mean(&real, r0, r1), ring_mean(&simulated, r0, r1));
            eprintln!("{kind} r {r0}..{r1}: real {a:.0?} sim {b:.0?}");
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() < tol, "{kind} ring {r0}..{r1} channel {c}: real {a:?} sim {b:?}");
            }
        }
        // Warm skin: red above blue inside the field of view of the see-through sensors.
        if kind != SensorKind::TacTip {
            let m = ring_mean(&simulated, 120.0, 220.0);
            assert!(m[0] > m[2] + 15.0, "{kind} skin is warm: {m:?}");
        }
    }
}

#[test]
fn field_of_view_is_a_circle_of_the_real_size() {
    for (kind, frame) in [(SensorKind::ViTac, 0), (SensorKind::ViTacTip, 1)] {
        let (a, b) = (fov_edge(&real_image(kind.label(), frame), 40.0), fov_edge(&bar_frame(kind), 40.0));
        eprintln!("{kind} field-of-view edge: real {a} sim {b}");
        assert!((a - b).abs() <= 8.0, "{kind}: real edge {a} px, sim {b} px");
    }
    // Dark outside for every kind: the corners.
    for kind in SensorKind::ALL {
        let img = bar_frame(kind);
        let corner = ring_mean(&img, 330.0, 400.0);
        assert!(luma(corner) < 20.0, "{kind} corners {corner:?}");
    }
}
