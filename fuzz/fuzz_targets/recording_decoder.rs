//! Fuzzes the recording file decoder (`rig replay`): any bytes must decode or fail with an
//! error, never panic; whatever decodes must encode back to the same bytes.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/record/format.rs"]
mod format;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // Raw input, and the input behind a valid preamble so the record decoder is reached.
    let _ = format::decode(data);
    let mut framed = format::encode_preamble("{}");
    framed.extend_from_slice(data);
    if let Ok(r) = format::decode(&framed) {
        let mut again = format::encode_preamble(&r.header_json);
        for e in &r.events {
            again.extend(format::encode_event(e));
        }
        again.extend(format::encode_end(r.events.len() as u64));
        assert_eq!(again, framed);
    }
});
