//! `rig bench` report generation on a very small configuration (one or two poses, the tiny
//! model package, 64 px maps and frames): the report and one SVG per knob are written, and
//! every table has the rows the configuration asks for, with finite numbers. No timing is
//! asserted. Needs ONNX Runtime (`.rig/onnxruntime/`, as the synthesis tests do).

use std::path::Path;

use rig::bench::scale::Stage;
use rig::bench::{BenchConfig, Knob, run, sensor::render_stages, write_report};
use rig::sensor::SensorKind;
use rig::synth::SchedulerKind;

fn tiny_config() -> BenchConfig {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    BenchConfig {
        label: "test".into(),
        knobs: Knob::ALL.to_vec(),
        synth_model: root.join("tests/data/tiny-package"),
        synth_poses: 1,
        synth_steps: vec![2, 4],
        synth_schedulers: vec![SchedulerKind::Ddim, SchedulerKind::DpmSolverPp2m],
        synth_guidance: 1.0,
        image_px: 64,
        control_supersample: vec![1, 2],
        control_reference_supersample: 4,
        control_objects: vec!["pacman".into()],
        control_poses: 1,
        collect_poses: 1,
        collect_settle_s: vec![0.0, 0.2],
        collect_frames: vec![1, 2],
        sim_time_scale: 20.0,
        // The contact detector is tuned for 512 px frames; the calibration keeps that size.
        calib_image_px: 512,
        calib_grids: vec![(2, 2), (3, 2)],
        plan_poses: 40,
        plan_seeds: vec![0],
        sensor_frames: 1,
        loop_repeats: 1,
        // The peer's row is left out: a developer's $RIG_PYTHON must not change the table.
        peer_python: None,
        scale_plan_poses: vec![100, 200, 400],
        scale_frames: vec![3, 6, 12],
        scale_image_px: 32,
        rig_exe: Some(env!("CARGO_BIN_EXE_rig").into()),
        adaptive_seeds_per_pose: vec![2],
        adaptive_steps: 1,
    }
}

#[test]
#[cfg_attr(not(feature = "synth"), ignore = "every knob, synthesis too: needs the synth feature")]
fn tiny_bench_writes_the_report_with_every_table_and_plot() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("report");
    let config = tiny_config();
    let runtime = tokio::runtime::Runtime::new().expect("runtime");
    let report = runtime.block_on(run(&config, &dir.path().join("work"), |_| {}));
    let failed: Vec<String> = report.failed.iter().map(|(k, e)| format!("{k}: {e}")).collect();
    assert!(failed.is_empty(), "{failed:?}");
    assert!(!dir.path().join("work").exists(), "the scratch folder is removed");

    let sensor_rows: usize = SensorKind::ALL.iter().map(|k| 2 * render_stages(*k).len() + 1).sum();
    let expected = [
        (Knob::Synthesis, 2 * 2),
        (Knob::Control, 2 + 1),
        (Knob::Collection, 2 + 2),
        (Knob::Calibration, 2),
        (Knob::PlanOrder, 2),
        (Knob::Sensor, sensor_rows),
        // SSIM and control maps: rig and the previous code; synthesis: rig (no peer here).
        (Knob::Loops, 2 + 2 + 1),
        (Knob::Scale, Stage::ALL.iter().filter(|s| s.built()).count()),
        // Rounds 2 and 3 of the one setting.
        (Knob::Adaptive, 2),
        // The choosing arithmetic at the three plan sizes.
        (Knob::AdaptiveScale, 3),
    ];
    assert_eq!(report.knobs.iter().map(|k| k.knob).collect::<Vec<_>>(), expected.map(|(k, _)| k).to_vec());
    for (knob, (want_knob, rows)) in report.knobs.iter().zip(expected) {
        assert_eq!(knob.knob, want_knob);
        assert_eq!(knob.rows.len(), rows, "{want_knob}: {:?}", knob.rows);
        for row in &knob.rows {
            assert_eq!(row.values.len(), knob.columns.len(), "{want_knob} {}", row.label);
            assert!(row.values.iter().all(|v| v.is_finite()), "{want_knob} {}: {:?}", row.label, row.values);
        }
        assert!(knob.plot.series.iter().map(|s| s.points.len()).sum::<usize>() > 0, "{want_knob}: empty plot");
    }

    let written = write_report(&report, &out).expect("report");
    assert_eq!(written.len(), 1 + Knob::ALL.len());
    let md = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(md.contains("- machine: ") && md.contains("- date: ") && md.contains("total run time"), "{md}");
    for knob in &report.knobs {
        let svg = std::fs::read_to_string(out.join(format!("{}.svg", knob.knob.name()))).expect("svg");
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"), "{}", knob.knob);
        assert!(md.contains(&format!("![{}]({}.svg)", knob.title, knob.knob.name())));
        // Every row is in the Markdown table, with as many cells as columns.
        for row in &knob.rows {
            let line = md.lines().find(|l| l.starts_with(&format!("| {} |", row.label))).expect("row in the report");
            assert_eq!(line.matches('|').count(), knob.columns.len() + 2, "{line}");
            assert!(!line.contains("n/a"), "{line}");
        }
    }
    // Sanity of the numbers, not their speed: the reference rows match themselves exactly.
    let control = &report.knobs[1];
    assert_eq!(control.rows.last().map(|r| r.values[1]), Some(0.0));
    let loops = &report.knobs[6];
    assert!(loops.rows[1].values[2] < 1e-12, "SSIM agrees with the code it replaced: {:?}", loops.rows[1]);
    assert_eq!(loops.rows[3].values[2], 0.0, "control maps equal the previous renderer's: {:?}", loops.rows[3]);
    let synth = &report.knobs[0];
    assert!(synth.rows.iter().filter(|r| r.values[0] == 4.0).all(|r| r.values[1] == 1.0));
}

/// `rig bench --only scale`'s report: one row per stage this build has, each measured at the
/// three sizes asked for (increasing), wall time and peak memory positive, the exponents
/// finite; the table and the log-log plot in `report.md` and `scale.svg`. No timing is
/// asserted. The stages run the real `rig` binary as child processes.
#[test]
fn scale_report_has_a_row_per_stage_at_three_sizes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = BenchConfig { knobs: vec![Knob::Scale], ..tiny_config() };
    let runtime = tokio::runtime::Runtime::new().expect("runtime");
    let report = runtime.block_on(run(&config, &dir.path().join("work"), |_| {}));
    let failed: Vec<String> = report.failed.iter().map(|(k, e)| format!("{k}: {e}")).collect();
    assert!(failed.is_empty(), "{failed:?}");
    let [scale] = &report.knobs[..] else { panic!("one knob: {:?}", report.knobs.len()) };
    let stages: Vec<Stage> = Stage::ALL.into_iter().filter(|s| s.built()).collect();
    assert_eq!(scale.rows.iter().map(|r| r.label.as_str()).collect::<Vec<_>>(), stages.iter().map(|s| s.label()).collect::<Vec<_>>());
    assert_eq!(scale.columns.len(), 12);
    for row in &scale.rows {
        let v = &row.values;
        assert_eq!(v.len(), 12, "{}", row.label);
        assert!(v.iter().all(|x| x.is_finite()), "{}: {v:?}", row.label);
        let sizes = if row.label == Stage::Ordering.label() { &config.scale_plan_poses } else { &config.scale_frames };
        assert_eq!(v[..3].to_vec(), sizes.iter().map(|&n| n as f64).collect::<Vec<_>>(), "{}", row.label);
        assert!(v[3..6].iter().all(|&t| t > 0.0), "{}: wall times {v:?}", row.label);
        assert!((v[7] - v[5] * 1e3 / v[2]).abs() < 1e-9, "{}: ms per item {v:?}", row.label);
        // A rig process holds a few MB at least; its peak is its own, not the bench's.
        assert!(v[8..11].iter().all(|&mb| (1.0..4096.0).contains(&mb)), "{}: peaks {v:?}", row.label);
    }
    assert_eq!(scale.plot.series.len(), scale.rows.len());
    assert!(scale.plot.series.iter().all(|s| s.points.len() == 3));
    let out = dir.path().join("report");
    write_report(&report, &out).expect("report");
    let md = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(
        md.contains("| stage | N1 | N2 | N3 | wall N1 [s] |") && md.contains("time exponent") && md.contains("memory exponent"),
        "{md}"
    );
    assert!(md.contains("![Scale: what the work costs as it grows](scale.svg)"), "{md}");
    assert!(std::fs::read_to_string(out.join("scale.svg")).expect("svg").starts_with("<svg"));
    assert!(!dir.path().join("work").exists(), "the scratch folder is removed");
}
