//! Fuzzes the rig configuration reader (`rig.toml`, both stages): any text gives a resolved
//! configuration or an error naming the file.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/pose.rs"]
mod pose;
#[path = "../../src/config.rs"]
mod config;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    match config::RigConfig::parse(text, std::path::Path::new("fuzz.toml")) {
        Ok(c) => {
            let _ = (c.describe(), c.faults.describe());
        }
        Err(e) => assert!(e.to_string().contains("fuzz.toml"), "error without the file name: {e}"),
    }
});
