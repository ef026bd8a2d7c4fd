//! The PLY mesh reader (vertices and face lists) behind `pointray sample`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let mut file = b"ply\n".to_vec();
    file.extend_from_slice(data);
    let _ = pointray_io::parse_mesh(std::path::Path::new("fuzz.ply"), &file);
});
