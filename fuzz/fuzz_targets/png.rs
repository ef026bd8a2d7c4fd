//! The PNG reader behind `pointray compare`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pointray_io::decode_png(std::path::Path::new("fuzz.png"), data);
});
