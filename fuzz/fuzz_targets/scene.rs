//! The scene-file reader (TOML) behind `pointray render scene.toml`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = pointray_io::scene::parse_scene(std::path::Path::new("fuzz.toml"), text);
    }
});
