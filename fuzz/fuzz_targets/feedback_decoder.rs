//! Fuzzes the feedback frame decoder and the resynchronising stream decoder.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/pose.rs"]
mod pose;
#[path = "../../src/arm/dobot/proto.rs"]
mod proto;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = proto::FeedbackFrame::decode(data);
    // Two valid frames glued after the input: the input's tail may fake a frame start that
    // swallows part of the first (indistinguishable on the wire), but resync must recover by
    // the second.
    let valid = proto::FeedbackFrame { robot_mode: 5, ..Default::default() };
    let mut decoder = proto::FeedbackDecoder::new();
    let step = data.first().map_or(1, |b| usize::from(*b).max(1));
    for chunk in data.chunks(step) {
        decoder.push(chunk);
        while decoder.next_frame().is_some() {}
    }
    decoder.push(&valid.encode());
    decoder.push(&valid.encode());
    let mut last = None;
    while let Some(f) = decoder.next_frame() {
        last = Some(f);
    }
    assert_eq!(last, Some(valid));
});
