//! Any bytes as an environment map (Radiance .hdr or OpenEXR, by content).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pointray_io::env_map::parse_env_map(std::path::Path::new("fuzz.hdr"), data);
});
