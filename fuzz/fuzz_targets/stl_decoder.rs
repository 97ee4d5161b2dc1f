//! Fuzzes the STL decoder (binary and ASCII): any bytes give a mesh or an error, and a mesh
//! that decodes survives the binary round trip.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/geometry/stl.rs"]
mod stl;
#[path = "../../src/untrusted.rs"]
mod untrusted;
#[path = "../../src/confine.rs"]
mod confine;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(mesh) = stl::Mesh::from_bytes(data) {
        let _ = (mesh.bounds(), mesh.top_z_mm());
        let again = stl::Mesh::from_bytes(&mesh.to_binary_bytes("fuzz"));
        assert!(again.is_ok(), "a decoded mesh must re-encode to a valid STL: {:?}", again.err());
    }
});
