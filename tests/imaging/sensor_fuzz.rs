//! Hostile inputs: scene files and depth maps of any content never panic.

use proptest::prelude::*;
use rig::geometry::DepthMap;
use rig::sensor::SensorKind;
use rig::sim::sensor::{MotionState, Scene, SensorSim};

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn scene_parsing_never_panics(text in "\\PC{0,200}") {
        let _ = Scene::from_toml(&text);
    }

    #[test]
    fn scene_like_toml_never_panics(
        stages in prop::collection::vec("[a-z_]{0,20}", 0..6),
        sigma in any::<f32>(),
    ) {
        let list: Vec<String> = stages.iter().map(|s| format!("{s:?}")).collect();
        let text = format!("stages = [{}]\nnoise_sigma_levels = {sigma:?}\n", list.join(", "));
        if let Ok(scene) = Scene::from_toml(&text) {
            prop_assert!(scene.noise_sigma_levels.is_finite() && scene.noise_sigma_levels >= 0.0);
        }
    }

    #[test]
    fn any_depth_map_renders(
        w in 1u32..24, h in 1u32..24,
        dw in 0u32..30, dh in 0u32..30,
        values in prop::collection::vec(any::<f32>(), 0..900),
        speed in any::<f32>(), dir in any::<f32>(), exposure in any::<f32>(),
        kind in 0usize..3, key in any::<u64>(),
    ) {
        let sim = SensorSim::new(SensorKind::ALL[kind], Scene::preset("full").unwrap(), w, h, 2.0, 3);
        let depth = DepthMap { width: dw, height: dh, height_mm: values };
        let img = sim.render(&depth, &MotionState { speed_px_per_s: speed, direction_rad: dir, exposure_s: exposure }, key);
        prop_assert_eq!(img.dimensions(), (w, h));
    }
}
