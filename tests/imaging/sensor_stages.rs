//! The stage pipeline: a scene runs exactly the stages it lists, and each stage does what it
//! says.

use crate::sensor_support::{central, radii, spots};
use rig::geometry::DepthMap;
use rig::sensor::SensorKind;
use rig::sim::sensor::{MotionState, SKIN_PARAMETERS, Scene, SensorSim, SkinModel, Stage, shapes};

const PX_PER_MM: f32 = 8.5;

fn sim(kind: SensorKind, stages: &[Stage]) -> SensorSim {
    SensorSim::new(kind, Scene::with_stages("test", stages), 256, 256, PX_PER_MM / 2.0, 7)
}

fn pressed(w: u32, h: u32, k: f32) -> DepthMap {
    shapes::sphere(w, h, k, 1.0, -0.5, 6.0, 1.2)
}

fn moving() -> MotionState {
    MotionState { speed_px_per_s: 600.0, direction_rad: 0.3, exposure_s: 0.016 }
}

#[test]
fn a_scene_without_a_stage_never_runs_it() {
    let frames = 3u64;
    for kind in SensorKind::ALL {
        for left_out in Stage::ALL {
            let stages: Vec<Stage> = Stage::ALL.into_iter().filter(|s| *s != left_out).collect();
            let s = sim(kind, &stages);
            let depth = pressed(256, 256, PX_PER_MM / 2.0);
            for key in 0..frames {
                s.render(&depth, &moving(), key);
            }
            let counts = s.stage_counts();
            assert_eq!(counts.get(left_out), 0, "{kind}: {left_out} left out but ran ({counts})");
            for st in Stage::ALL {
                // Stale frames are a camera effect; render never runs them.
                let expected = if st == left_out || !st.applies_to(kind) || st == Stage::StaleFrame { 0 } else { frames };
                assert_eq!(counts.get(st), expected, "{kind}: {st} ({counts})");
            }
        }
    }
}

#[test]
fn a_scene_with_one_stage_runs_only_that_stage() {
    for kind in SensorKind::ALL {
        for only in Stage::ALL.into_iter().filter(|s| *s != Stage::StaleFrame) {
            let s = sim(kind, &[only]);
            s.render(&pressed(256, 256, PX_PER_MM / 2.0), &moving(), 1);
            let counts = s.stage_counts();
            let expected = u64::from(only.applies_to(kind));
            assert_eq!(counts.get(only), expected, "{kind}: {only}");
            assert_eq!(counts.total(), expected, "{kind}: only {only} should run ({counts})");
        }
        let none = SensorSim::new(kind, Scene::preset("none").unwrap(), 128, 128, 4.0, 1);
        none.render(&pressed(128, 128, 4.0), &moving(), 1);
        none.reference();
        assert_eq!(none.stage_counts().total(), 0);
    }
}

/// Stage timing is off unless asked for, and then times every stage that runs (and only
/// those), without changing the frame.
#[test]
fn stage_timing_times_the_stages_that_run() {
    let depth = pressed(256, 256, PX_PER_MM / 2.0);
    let plain = sim(SensorKind::ViTacTip, &Stage::ALL);
    let timed = sim(SensorKind::ViTacTip, &Stage::ALL).with_stage_timing();
    for key in 0..3 {
        assert_eq!(plain.render(&depth, &moving(), key), timed.render(&depth, &moving(), key));
    }
    let (p, t) = (plain.stage_counts(), timed.stage_counts());
    for st in Stage::ALL {
        assert_eq!(p.mean_ms(st), 0.0, "{st} timed without stage timing");
        assert_eq!(p.get(st), t.get(st), "{st}");
        if st == Stage::StaleFrame {
            assert_eq!(t.mean_ms(st), 0.0);
        } else {
            assert!(t.mean_ms(st) > 0.0, "{st} ran ({}) but took no time", t.get(st));
        }
    }
}

#[test]
fn presets_run_what_they_list() {
    let s = SensorSim::new(SensorKind::ViTacTip, Scene::preset("fast").unwrap(), 128, 128, 4.0, 1);
    s.render(&pressed(128, 128, 4.0), &moving(), 1);
    let c = s.stage_counts();
    for st in [Stage::ContactDeformation, Stage::MarkerDisplacement, Stage::SeeThrough, Stage::Vignetting] {
        assert_eq!(c.get(st), 1, "{st}");
    }
    for st in [Stage::Shading, Stage::Noise, Stage::MotionBlur, Stage::StaleFrame] {
        assert_eq!(c.get(st), 0, "{st}");
    }
}

#[test]
fn rendering_is_deterministic_for_a_seed_and_key() {
    let full = Scene::preset("full").unwrap();
    let a = SensorSim::new(SensorKind::ViTacTip, full.clone(), 200, 150, 4.0, 11);
    let b = SensorSim::new(SensorKind::ViTacTip, full.clone(), 200, 150, 4.0, 11);
    let d = pressed(200, 150, 4.0);
    assert_eq!(a.render(&d, &moving(), 5), b.render(&d, &moving(), 5));
    assert_ne!(a.render(&d, &moving(), 5), a.render(&d, &moving(), 6), "noise follows the frame key");
    let c = SensorSim::new(SensorKind::ViTacTip, full, 200, 150, 4.0, 12);
    assert_ne!(a.render(&d, &moving(), 5), c.render(&d, &moving(), 5), "noise follows the seed");
    // Without noise nothing is random: the key does not matter.
    let quiet = SensorSim::new(SensorKind::ViTacTip, Scene::preset("fast").unwrap(), 200, 150, 4.0, 11);
    assert_eq!(quiet.render(&d, &moving(), 5), quiet.render(&d, &moving(), 6));
}

/// Mean absolute difference between two images, levels.
fn mad(a: &image::RgbImage, b: &image::RgbImage) -> f32 {
    a.as_raw().iter().zip(b.as_raw()).map(|(x, y)| (*x as f32 - *y as f32).abs()).sum::<f32>() / a.as_raw().len() as f32
}

#[test]
fn marker_displacement_pushes_pins_away_from_the_indenter() {
    let k = 8.5;
    let depth = shapes::sphere(512, 512, k, 0.0, 0.0, 8.0, 1.5);
    let with = SensorSim::new(
        SensorKind::TacTip,
        Scene::with_stages("t", &[Stage::ContactDeformation, Stage::MarkerDisplacement]),
        512,
        512,
        k,
        3,
    );
    let without = SensorSim::new(SensorKind::TacTip, Scene::with_stages("t", &[Stage::ContactDeformation]), 512, 512, k, 3);
    let find = |img: &image::RgbImage| central(spots(img, false, 40.0, 20.0, 400.0), 512, 512, 200.0);
    let rest = find(&without.render(&depth, &MotionState::STILL, 0));
    let moved = find(&with.render(&depth, &MotionState::STILL, 0));
    assert_eq!(rest.len(), 137);
    assert_eq!(moved.len(), 137, "pins must stay separate spots");
    let (r0, r1) = (radii(&rest), radii(&moved));
    // The ring at ~50 px sits on the flank of the dent: pushed outwards, at most by the
    // skin's longest travel (0.15 mm, 1.3 px here, as measured on the real TacTip).
    let ring = |r: &[f32]| r.iter().filter(|v| **v > 40.0 && **v < 65.0).sum::<f32>();
    let (a, b) = (ring(&r0), ring(&r1));
    assert!(b > a + 16.0 * 0.5, "ring 2 should move out by >0.5 px per pin: {a} -> {b}");
    assert!(b < a + 16.0 * 1.5, "ring 2 should move out by <1.5 px per pin: {a} -> {b}");
    // Far from the contact nothing moves.
    let outer = |r: &[f32]| r.iter().rev().take(32).sum::<f32>() / 32.0;
    assert!((outer(&r0) - outer(&r1)).abs() < 1.0);
}

#[test]
fn contact_deformation_spreads_the_dent_beyond_the_footprint() {
    let k = 8.5;
    // A small sphere: without the elastic spread only pins right on it would move.
    let depth = shapes::sphere(512, 512, k, 0.0, 0.0, 2.0, 1.0);
    let spread = SensorSim::new(
        SensorKind::TacTip,
        Scene::with_stages("t", &[Stage::ContactDeformation, Stage::MarkerDisplacement]),
        512,
        512,
        k,
        3,
    );
    let local = SensorSim::new(SensorKind::TacTip, Scene::with_stages("t", &[Stage::MarkerDisplacement]), 512, 512, k, 3);
    let still = MotionState::STILL;
    let reference = spread.reference();
    // Pixels changed at 30..60 px from the centre (outside the 17 px footprint).
    let changed = |img: &image::RgbImage| {
        img.enumerate_pixels()
            .filter(|(x, y, p)| {
                let r = ((*x as f32 - 256.0).powi(2) + (*y as f32 - 256.0).powi(2)).sqrt();
                r > 30.0 && r < 60.0 && **p != *reference.get_pixel(*x, *y)
            })
            .count()
    };
    let (a, b) = (changed(&local.render(&depth, &still, 0)), changed(&spread.render(&depth, &still, 0)));
    assert!(b > a + 200, "spread {b} vs local {a}");
}

#[test]
fn see_through_shows_the_pressed_object_bright() {
    let k = 4.25;
    let depth = shapes::bar(256, 256, k, 0.0, 0.0, 0.0, 33.0, 4.0, 1.0);
    let on = sim(SensorKind::ViTac, &[Stage::SeeThrough]);
    let off = sim(SensorKind::ViTac, &[]);
    let img = on.render(&depth, &MotionState::STILL, 0);
    let centre = img.get_pixel(128, 128);
    assert!(centre.0.iter().all(|&c| c > 230), "object under the skin is white: {centre:?}");
    // Off: the object does not show at all.
    assert_eq!(off.render(&depth, &MotionState::STILL, 0), off.reference());
    // The glow lights the skin beside the bar but fades with distance.
    let r = on.reference();
    let l = |p: &image::Rgb<u8>| p.0.iter().map(|&c| c as f32).sum::<f32>();
    let near = l(img.get_pixel(128, 128 + 14)) - l(r.get_pixel(128, 128 + 14));
    let far = l(img.get_pixel(128, 128 + 60)) - l(r.get_pixel(128, 128 + 60));
    assert!(near > far && far >= 0.0 && near > 20.0, "near {near} far {far}");
}

#[test]
fn shading_changes_only_the_deformed_skin() {
    let k = 4.25;
    let depth = shapes::straight_edge(256, 256, k, 0.0, 0.0, 1.0);
    let on = sim(SensorKind::ViTac, &[Stage::ContactDeformation, Stage::Shading]);
    let off = sim(SensorKind::ViTac, &[Stage::ContactDeformation]);
    let (a, b) = (on.render(&depth, &MotionState::STILL, 0), off.render(&depth, &MotionState::STILL, 0));
    // Near the edge (x = 128) the slope changes the brightness; far from it nothing changes.
    let diff = |x: u32| (0..256).map(|y| (a.get_pixel(x, y)[0] as i32 - b.get_pixel(x, y)[0] as i32).abs()).sum::<i32>();
    assert!(diff(124) > 100, "{}", diff(124));
    assert_eq!(diff(20), 0);
    assert_eq!(diff(236), 0);
}

#[test]
fn vignetting_darkens_the_rim_more_than_the_centre() {
    let on = sim(SensorKind::ViTac, &[Stage::Vignetting]);
    let off = sim(SensorKind::ViTac, &[]);
    let (a, b) = (on.reference(), off.reference());
    let ratio = |x: u32, y: u32| a.get_pixel(x, y)[0] as f32 / b.get_pixel(x, y)[0].max(1) as f32;
    let (centre, rim) = (ratio(128, 128), ratio(128, 128 + 110));
    assert!(centre > 0.97 && rim < 0.8 && rim > 0.6, "centre {centre} rim {rim}");
}

#[test]
fn motion_blur_smears_the_contact_along_the_motion_only() {
    let k = 4.25;
    let on = sim(SensorKind::ViTacTip, &[Stage::SeeThrough, Stage::MotionBlur]);
    let depth = shapes::sphere(256, 256, k, 0.0, 0.0, 5.0, 1.0);
    let horizontal = MotionState { speed_px_per_s: 500.0, direction_rad: 0.0, exposure_s: 0.02 };
    let still = on.render(&depth, &MotionState::STILL, 0);
    let blurred = on.render(&depth, &horizontal, 0);
    let reference = on.reference();
    // Gradient energy of the contact's imprint (the change from the no-contact frame).
    let energy = |img: &image::RgbImage, dx: u32, dy: u32| {
        let delta = |x: u32, y: u32| img.get_pixel(x, y)[1] as f64 - reference.get_pixel(x, y)[1] as f64;
        let mut e = 0.0f64;
        for y in 0..255 {
            for x in 0..255 {
                e += (delta(x + dx, y + dy) - delta(x, y)).powi(2);
            }
        }
        e
    };
    let (hx0, hx1) = (energy(&still, 1, 0), energy(&blurred, 1, 0));
    let (vy0, vy1) = (energy(&still, 0, 1), energy(&blurred, 0, 1));
    assert!(hx1 < 0.5 * hx0, "horizontal detail must fall: {hx0} -> {hx1}");
    assert!(hx1 / hx0 < 0.7 * (vy1 / vy0), "vertical detail falls less: h {} v {}", hx1 / hx0, vy1 / vy0);
    // The sensor moves with the arm: without contact nothing streaks.
    assert_eq!(on.render(&DepthMap::empty(256, 256), &horizontal, 0), reference);
    // Zero exposure: no streak.
    let none = MotionState { exposure_s: 0.0, ..horizontal };
    assert_eq!(on.render(&depth, &none, 0), still);
}

#[test]
fn noise_has_the_scene_sigma() {
    let mut scene = Scene::with_stages("n", &[Stage::Noise]);
    scene.noise_sigma_levels = 4.0;
    let on = SensorSim::new(SensorKind::ViTac, scene, 256, 256, PX_PER_MM / 2.0, 7); // same static look as `off`
    let off = sim(SensorKind::ViTac, &[]);
    let (a, b) = (on.render(&DepthMap::empty(256, 256), &MotionState::STILL, 9), off.reference());
    // Inside the field of view (no clipping), the residual's spread is a few levels.
    let mut d = Vec::new();
    for y in 100..156 {
        for x in 100..156 {
            d.push(a.get_pixel(x, y)[1] as f32 - b.get_pixel(x, y)[1] as f32);
        }
    }
    let n = d.len() as f32;
    let mean = d.iter().sum::<f32>() / n;
    let sd = (d.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / n).sqrt();
    assert!(mean.abs() < 0.5, "mean {mean}");
    assert!(sd > 4.0 && sd < 9.0, "sd {sd}");
    assert!(mad(&a, &b) > 1.0);
}

#[test]
fn any_size_and_any_depth_values_render_without_panicking() {
    let s = SensorSim::new(SensorKind::ViTacTip, Scene::preset("full").unwrap(), 33, 17, 1.0, 0);
    let mut d = DepthMap::empty(33, 17);
    for (i, v) in d.height_mm.iter_mut().enumerate() {
        *v = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e30, -1e30, 0.5][i % 6];
    }
    let img = s.render(&d, &MotionState { speed_px_per_s: f32::NAN, direction_rad: f32::INFINITY, exposure_s: 1.0 }, 0);
    assert_eq!(img.dimensions(), (33, 17));
    let tiny = SensorSim::new(SensorKind::TacTip, Scene::preset("full").unwrap(), 1, 1, f32::NAN, 0);
    assert_eq!(tiny.render(&DepthMap::empty(0, 0), &MotionState::STILL, 0).dimensions(), (1, 1));
}

/// A synthetic "measured" no-contact frame: grey skin with dark pins on the simulator lattice.
fn measured_reference(w: u32, h: u32) -> image::RgbImage {
    let lattice = rig::sim::sensor::look::marker_lattice(w, h);
    let s = rig::sim::sensor::look::scale(w, h);
    image::RgbImage::from_fn(w, h, |x, y| {
        let on_pin = lattice.iter().any(|m| (m[0] - x as f32 - 0.5).powi(2) + (m[1] - y as f32 - 0.5).powi(2) < (4.5 * s).powi(2));
        if on_pin { image::Rgb([30, 30, 30]) } else { image::Rgb([140, 130, 110]) }
    })
}

#[test]
fn a_measured_reference_is_the_no_contact_frame() {
    let reference = measured_reference(256, 256);
    let sim = SensorSim::new(SensorKind::ViTacTip, Scene::preset("fast").unwrap(), 256, 256, PX_PER_MM / 2.0, 7)
        .with_reference(&reference)
        .unwrap();
    // The measured frame already holds the sensor's vignetting: nothing is added.
    let got = sim.reference();
    let worst = got.as_raw().iter().zip(reference.as_raw()).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
    assert!(worst <= 1, "worst difference {worst}");
    let wrong = image::RgbImage::new(100, 256);
    let err = SensorSim::new(SensorKind::ViTac, Scene::preset("fast").unwrap(), 256, 256, 4.0, 7).with_reference(&wrong).unwrap_err();
    assert_eq!((err.width, err.height, err.expected_width, err.expected_height), (100, 256, 256, 256));
}

#[test]
fn on_a_measured_reference_pins_move_and_stay_in_front_of_the_object() {
    let (w, h) = (256, 256);
    let reference = measured_reference(w, h);
    let k = PX_PER_MM / 2.0;
    let depth = shapes::sphere(w, h, k, 0.0, 0.0, 8.0, 1.5);
    let make = |stages: &[Stage]| {
        SensorSim::new(SensorKind::ViTacTip, Scene::with_stages("t", stages), w, h, k, 3).with_reference(&reference).unwrap()
    };
    // Displacement alone: the skin (and its pins) moves near the contact, not far from it.
    let moved = make(&[Stage::ContactDeformation, Stage::MarkerDisplacement]).render(&depth, &MotionState::STILL, 0);
    let changed = |r0: f32, r1: f32| {
        moved
            .enumerate_pixels()
            .filter(|(x, y, p)| {
                let r = ((*x as f32 - 128.0).powi(2) + (*y as f32 - 128.0).powi(2)).sqrt();
                r >= r0 && r < r1 && p.0.iter().zip(reference.get_pixel(*x, *y).0).any(|(a, b)| a.abs_diff(b) > 8)
            })
            .count()
    };
    assert!(changed(10.0, 60.0) > 100, "pins near the contact must move");
    assert_eq!(changed(80.0, 200.0), 0, "far from the contact nothing moves");
    // See-through: the object shows bright, and the central pin stays dark in front of it.
    let seen = make(&[Stage::SeeThrough]).render(&depth, &MotionState::STILL, 0);
    let centre = rig::sim::sensor::look::marker_lattice(w, h)[0];
    let pin = seen.get_pixel(centre[0] as u32, centre[1] as u32).0;
    let beside = seen.get_pixel(centre[0] as u32 + 8, centre[1] as u32 + 3).0;
    assert!(beside.iter().all(|&v| v > 200), "object seen through: {beside:?}");
    assert!(pin.iter().all(|&v| v < 120), "pin in front of the object: {pin:?}");
}

#[test]
fn skin_parameters_read_write_and_clamp() {
    let mut s = SkinModel::of(SensorKind::ViTac);
    for p in SKIN_PARAMETERS {
        let mid = 0.5 * (p.min + p.max);
        p.set(&mut s, mid);
        assert_eq!(p.get(&s), mid, "{}", p.name);
        p.set(&mut s, p.max * 10.0 + 1.0);
        assert_eq!(p.get(&s), p.max, "{}", p.name);
        p.set(&mut s, f32::NAN);
        assert_eq!(p.get(&s), p.min, "{}", p.name);
    }
    for kind in SensorKind::ALL {
        assert!(!SkinModel::fitted_parameters(kind).is_empty());
        assert_eq!(SkinModel::of(kind).clamped(), SkinModel::of(kind), "{kind}: the fitted skin lies in the ranges");
    }
}

/// Mean luminance change from the reference over pixels at `r0..r1` px from the centre.
fn change_in_ring(img: &image::RgbImage, reference: &image::RgbImage, r0: f32, r1: f32) -> f32 {
    let (cx, cy) = (img.width() as f32 / 2.0, img.height() as f32 / 2.0);
    let (mut sum, mut n) = (0.0f32, 0usize);
    for (x, y, p) in img.enumerate_pixels() {
        let r = ((x as f32 + 0.5 - cx).powi(2) + (y as f32 + 0.5 - cy).powi(2)).sqrt();
        if r >= r0 && r < r1 {
            let q = reference.get_pixel(x, y);
            sum += (0..3).map(|c| (p.0[c] as f32 - q.0[c] as f32).abs()).sum::<f32>();
            n += 1;
        }
    }
    sum / n.max(1) as f32
}

/// A deeper press moves the pins further, and over a wider field: on the default rig's scale,
/// pins ring by ring move out more at 2 mm than at 1 mm (before the skin model, the travel was
/// capped at 0.25 mm, reached at any press, and the two frames were the same).
#[test]
fn a_deeper_press_moves_the_pins_further_out() {
    let k = 8.5;
    let sim = SensorSim::new(
        SensorKind::TacTip,
        Scene::with_stages("t", &[Stage::ContactDeformation, Stage::MarkerDisplacement]),
        512,
        512,
        k,
        3,
    );
    let find = |img: &image::RgbImage| central(spots(img, false, 40.0, 20.0, 400.0), 512, 512, 200.0);
    let rest = radii(&find(&sim.reference()));
    let ring_sum = |r: &[f32], lo: f32, hi: f32| r.iter().filter(|v| **v > lo && **v < hi).sum::<f32>();
    let out_by = |indent_mm: f32| {
        let moved = find(&sim.render(&shapes::sphere(512, 512, k, 0.0, 0.0, 8.0, indent_mm), &MotionState::STILL, 0));
        assert_eq!(moved.len(), 137, "pins must stay separate spots at {indent_mm} mm");
        // Rings 2 and 3 (16 pins each, about 50 and 75 px out).
        let r = radii(&moved);
        (ring_sum(&r, 40.0, 65.0) - ring_sum(&rest, 40.0, 65.0), ring_sum(&r, 65.0, 90.0) - ring_sum(&rest, 65.0, 90.0))
    };
    let ((a2, a3), (b2, b3)) = (out_by(1.0), out_by(2.0));
    assert!(a2 > 0.0 && a3 >= 0.0, "pins move outward: ring 2 {a2}, ring 3 {a3} px in all");
    assert!(b2 > 1.3 * a2, "ring 2 moves further at 2 mm: {a2} -> {b2} px in all");
    assert!(b3 > a3 + 16.0 * 0.2, "ring 3 moves further at 2 mm: {a3} -> {b3} px in all");
}

/// A deeper press shows more through a transparent skin: the object brighter where it presses
/// and the glow around it wider (before the skin model, visibility and glow were saturated at
/// 0.2 mm and a 1 mm and a 2 mm press looked the same).
#[test]
fn a_deeper_press_shows_more_through_the_skin() {
    let k = 4.25;
    for kind in [SensorKind::ViTac, SensorKind::ViTacTip] {
        let sim = SensorSim::new(kind, Scene::with_stages("t", &[Stage::ContactDeformation, Stage::SeeThrough]), 256, 256, k, 7);
        let reference = sim.reference();
        let at = |indent_mm: f32| sim.render(&shapes::sphere(256, 256, k, 0.0, 0.0, 12.0, indent_mm), &MotionState::STILL, 0);
        let (shallow, deep) = (at(0.5), at(2.0));
        // The glow beyond the contact (a 12 mm sphere pressed 2 mm touches out to 6.6 mm, 28 px).
        let (g0, g1) = (change_in_ring(&shallow, &reference, 40.0, 70.0), change_in_ring(&deep, &reference, 40.0, 70.0));
        assert!(g1 > g0 + 1.0, "{kind}: the glow grows with depth: {g0} -> {g1} levels");
        let (c0, c1) = (change_in_ring(&shallow, &reference, 0.0, 8.0), change_in_ring(&deep, &reference, 0.0, 8.0));
        assert!(c1 > c0, "{kind}: the contact shows more at depth: {c0} -> {c1} levels");
    }
}
