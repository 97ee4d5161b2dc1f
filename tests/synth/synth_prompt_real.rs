//! The MultiDiffSense prompt for every filled row of the real example CSV
//! (`../shared/real-sample/multidiffsense-example/csv/1.csv`) equals what MultiDiffSense's own
//! Python produces: `str()` of the prompt dict after `round(np.float64(v), 2)` and a JSON round
//! trip. The expected lines (`tests/data/mds_prompts_object1_vitactip.txt`) were printed by that
//! Python code path.

use std::path::PathBuf;

use rig::pose::Pose;
use rig::synth::prompt::mds_prompt;

fn shared() -> PathBuf {
    let rel = std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string());
    let p = PathBuf::from(rel);
    if p.is_absolute() { p } else { PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(p) }
}

#[test]
fn prompts_for_the_real_csv_match_python() {
    let csv_path = shared().join("real-sample/multidiffsense-example/csv/1.csv");
    let mut reader =
        csv::Reader::from_path(&csv_path).unwrap_or_else(|e| panic!("{}: {e} (set RIG_SHARED to the shared/ folder)", csv_path.display()));
    let headers = reader.headers().unwrap().clone();
    let col = |name: &str| headers.iter().position(|h| h == name).unwrap();
    let (c1, c2, c3, c6) = (col("pose_1"), col("pose_2"), col("pose_3"), col("pose_6"));
    let mut got = Vec::new();
    for record in reader.records() {
        let record = record.unwrap();
        if record.get(c1).unwrap_or("").is_empty() {
            continue; // the template's unfilled rows
        }
        let v = |c: usize| record.get(c).unwrap().parse::<f64>().unwrap();
        got.push(mds_prompt(rig::sensor::SensorKind::ViTacTip, &Pose::new(v(c1), v(c2), v(c3), v(c6))));
    }
    let expected_path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/mds_prompts_object1_vitactip.txt");
    let expected: Vec<String> = std::fs::read_to_string(expected_path).unwrap().lines().map(str::to_string).collect();
    assert_eq!(got.len(), 11);
    assert_eq!(got, expected);
}
