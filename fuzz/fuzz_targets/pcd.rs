//! The PCD parser: the input follows the signature that selects it, so that every run
//! reaches the parser.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let mut file = b"VERSION .7\n".to_vec();
    file.extend_from_slice(data);
    let _ = pointray_io::parse_cloud(std::path::Path::new("/nonexistent/fuzz"), &file);
});
