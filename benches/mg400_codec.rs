//! Throughput of the MG400 codec and kinematics: `cargo bench --bench mg400_codec` prints a
//! table. Under `cargo test` (no `--bench` argument) it runs a few iterations only, as a smoke
//! check that the benchmark still works.

use std::hint::black_box;
use std::time::Instant;

use rig::arm::dobot::proto::{FeedbackDecoder, FeedbackFrame, ReplyFramer};
use rig::arm::profile::FirmwareProfile;
use rig::pose::Pose;

fn measure(name: &str, unit: &str, n: u64, mut f: impl FnMut() -> u64) {
    let start = Instant::now();
    let done = f();
    let s = start.elapsed().as_secs_f64();
    assert_eq!(done, n, "{name}: processed {done} of {n}");
    println!("| {name:<42} | {n:>9} {unit:<8} | {:>10.3} ms | {:>14.0} {unit}/s |", s * 1e3, n as f64 / s);
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let scale = if full { 1 } else { 1000 };
    println!("| what                                       | count              | time          | rate                  |");
    println!("|--------------------------------------------|--------------------|---------------|-----------------------|");

    let frames = 20_000 / scale;
    let frame = FeedbackFrame { robot_mode: 5, tool_vector_actual: [300.0, 1.0, -20.0, 5.0, 0.0, 0.0], ..Default::default() };
    let mut stream = Vec::new();
    for _ in 0..frames {
        stream.extend_from_slice(&frame.encode());
        stream.extend_from_slice(b"junk");
    }
    measure("feedback frames, 1000-byte reads + resync", "frames", frames, || {
        let mut d = FeedbackDecoder::new();
        let mut n = 0;
        for chunk in stream.chunks(1000) {
            d.push(chunk);
            while let Some(f) = d.next_frame() {
                black_box(f);
                n += 1;
            }
        }
        n
    });

    let replies = 200_000 / scale;
    let text = "0,{300.000000,1.000000,-20.000000,5.000000,0.000000,0.000000},GetPose();".repeat(replies as usize);
    measure("replies, 4096-byte reads, parsed as poses", "replies", replies, || {
        let mut r = ReplyFramer::new();
        let mut n = 0;
        for chunk in text.as_bytes().chunks(4096) {
            r.push(chunk);
            while let Ok(Some(reply)) = r.next_reply() {
                black_box(reply.pose().ok());
                n += 1;
            }
        }
        n
    });

    let profile = FirmwareProfile::default_mg400();
    let solves = 1_000_000 / scale;
    measure("check_reachable (IK + limits)", "poses", solves, || {
        (0..solves)
            .filter(|i| {
                let f = (*i % 1000) as f64;
                profile.check_reachable(&Pose::new(250.0 + f * 0.1, -50.0 + f * 0.1, -30.0, f * 0.05)).is_ok()
            })
            .count() as u64
    });
    measure("motion_time_s (plan optimiser cost)", "pairs", solves, || {
        let a = Pose::new(300.0, 0.0, -20.0, 0.0);
        (0..solves)
            .map(|i| {
                let f = (i % 1000) as f64;
                black_box(profile.motion_time_s(&a, &Pose::new(250.0 + f * 0.1, -50.0 + f * 0.1, -30.0, f * 0.05)))
            })
            .filter(|t| t.is_finite())
            .count() as u64
    });
}
