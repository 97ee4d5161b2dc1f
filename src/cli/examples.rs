//! The examples that end every subcommand's `--help` (and its man page). Each line that
//! starts with `rig ` is parsed by a test against the real argument definitions, so an
//! example cannot name a flag that does not exist. Paths are the repository's own
//! (`plans/`, `models/`, `datasets/`) or the files an earlier example writes.

/// `rig info`.
pub const INFO: &str = "\
Examples:
  rig info
  rig info --config rig.toml";

/// `rig collect`.
pub const COLLECT: &str = "\
Examples:
  rig collect --object sphere --plan plans/demo.toml --sensor all --out datasets --resume
  rig collect --object edge --poses 20 --seed 1 --sensor tactip,vitac --dry-run
  rig collect --config rig.toml --object edge --poses 5 --record run.rec";

/// `rig daemon`.
pub const DAEMON: &str = "\
Examples:
  rig daemon --listen 127.0.0.1:7700
  rig daemon --listen 127.0.0.1:7700 --sensor tactip --object edge
  rig collect --object edge --poses 6 --daemon http://127.0.0.1:7700";

/// `rig arm`.
pub const ARM: &str = "\
Examples:
  rig arm send --addr 192.168.1.6 \"RobotMode()\"
  rig arm send --addr 192.168.1.6 \"GetPose()\"
  rig arm send --addr 127.0.0.1 --port 41000 \"GetErrorID()\"";

/// `rig sim`.
pub const SIM: &str = "\
Examples:
  rig sim
  rig sim --port-base 41000 --time-scale 10";

/// `rig plan`.
pub const PLAN: &str = "\
Examples:
  rig plan show --plan plans/demo.toml --summary
  rig plan show --x -5:5:1 --y -5:5:1 --sampling lhs --n 50 --order optimised";

/// `rig dataset`.
pub const DATASET: &str = "\
Examples:
  rig dataset verify datasets/sphere/tactip
  rig dataset export datasets/sphere/tactip --format mds --out sphere-tactip.csv
  rig dataset merge --out datasets/sphere/tactip shard1 shard2";

/// `rig dataset verify`.
pub const DATASET_VERIFY: &str = "\
Examples:
  rig dataset verify datasets/sphere/tactip";

/// `rig dataset export`.
pub const DATASET_EXPORT: &str = "\
Examples:
  rig dataset export datasets/sphere/tactip --format mds --out sphere-tactip.csv --images-out mds-images
  rig dataset export datasets/sphere/vitac --format tactile-bench --out sphere-vitac.csv
  rig dataset export datasets/sphere --format lerobot --out lerobot/sphere";

/// `rig dataset import`.
pub const DATASET_IMPORT: &str = "\
Examples:
  rig dataset import example/csv/1.csv
  rig dataset import example/csv/1.csv --images example/tactile/1/TacTip/target --sensor tactip --stl example/stl/1.stl --out datasets/1/tactip";

/// `rig dataset merge`.
pub const DATASET_MERGE: &str = "\
Examples:
  rig dataset merge --out datasets/sphere/tactip shard1 shard2 shard3";

/// `rig sensor`.
pub const SENSOR: &str = "\
Examples:
  rig sensor render --kind vitactip --shape sphere --indent-mm 1 --out vitactip.png";

/// `rig sensor render`.
pub const SENSOR_RENDER: &str = "\
Examples:
  rig sensor render --kind tactip --shape none --out reference.png
  rig sensor render --kind vitactip --shape sphere --indent-mm 1 --out vitactip.png";

/// `rig synth`.
pub const SYNTH: &str = "\
Examples:
  rig synth --fill-missing --dataset datasets/sphere
  rig synth --fill-missing --dataset datasets/sphere/tactip --shard 1/4 --out shard1
  rig synth --poses-of test --out twins";

/// `rig synth one`.
pub const SYNTH_ONE: &str = "\
Examples:
  rig render --object edge --pose 0,0,1,30 --sensor control --size 128x128 --out control.png
  rig synth one --model models/default --control control.png --sensor TacTip --pose 0,0,1,30 --out tactip.png
  rig synth one --model mymodel --control hint.png --prompt hello --init-latents x_T.npy --dump-raw raw.npy --out one.png";

/// `rig synth bench`.
pub const SYNTH_BENCH: &str = "\
Examples:
  rig synth bench --model models/default --control hint.png --prompt tactile --guidance 9 --images 16 --batch 4";

/// `rig synth info`.
pub const SYNTH_INFO: &str = "\
Examples:
  rig synth info --model models/default";

/// `rig render`.
pub const RENDER: &str = "\
Examples:
  rig render --object edge --pose 0,0,1,30 --sensor control --out control.png
  rig render --stl part.stl --pose 1,-2,0.5,0 --sensor vitac --out vitac.png
  rig render --controls-of datasets/sphere/tactip --out controls";

/// `rig objects`.
pub const OBJECTS: &str = "\
Examples:
  rig objects generate
  rig objects contact-sheet --out sheet.png";

/// `rig objects generate`.
pub const OBJECTS_GENERATE: &str = "\
Examples:
  rig objects generate --out datasets/objects";

/// `rig objects contact-sheet`.
pub const OBJECTS_CONTACT_SHEET: &str = "\
Examples:
  rig objects contact-sheet --out sheet.png";

/// `rig calibrate`.
pub const CALIBRATE: &str = "\
Examples:
  rig calibrate --sensor tactip
  rig calibrate --sensor tactip --interactive --config rig.toml
  rig calibrate --sensor vitac --from-dataset datasets/sphere/vitac --out vitac.toml";

/// `rig compare-real`.
pub const COMPARE_REAL: &str = "\
Examples:
  rig compare-real --sample multidiffsense-example
  rig compare-real --sample multidiffsense-example --fit --out compare";

/// `rig eval`.
pub const EVAL: &str = "\
Examples:
  rig synth --poses-of test --out twins
  rig eval --real test --synthetic twins --collected datasets --markdown eval.md --json eval.json
  rig eval --downstream datasets --markdown downstream.md --json downstream.json";

/// `rig audit`.
pub const AUDIT: &str = "\
Examples:
  rig audit --dataset datasets/sphere/tactip
  rig audit --dataset datasets/sphere/tactip --fraction 0.2 --seed 3 --min-ssim 0.5";

/// `rig replay`.
pub const REPLAY: &str = "\
Examples:
  rig replay run.rec --info
  rig replay run.rec --out replayed";

/// `rig devices`.
pub const DEVICES: &str = "\
Examples:
  rig devices
  rig devices --config rig.toml";

/// `rig bench`.
pub const BENCH: &str = "\
Examples:
  rig bench --quick
  rig bench --only synthesis,control --out out/bench
  rig bench --only loops --python .rig/skimage/bin/python";

/// `rig generate`.
pub const GENERATE: &str = "\
Examples:
  rig generate man --out man
  rig generate completions bash --out completions";

/// `rig generate man`.
pub const GENERATE_MAN: &str = "\
Examples:
  rig generate man --out man";

/// `rig generate completions`.
pub const GENERATE_COMPLETIONS: &str = "\
Examples:
  rig generate completions bash
  rig generate completions zsh --out completions";

/// `rig plan show`.
pub const PLAN_SHOW: &str = "\
Examples:
  rig plan show --plan plans/demo.toml
  rig plan show --plan plans/default.toml --seed 7 --summary";
