//! The XYZ/PTS text parser: the `.xyz` extension selects it whatever the first line holds.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pointray_io::parse_cloud(std::path::Path::new("/nonexistent/fuzz.xyz"), data);
});
