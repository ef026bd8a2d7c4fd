//! Any bytes through the format detection and whichever parser it picks.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    // A folder that does not exist: a scan set's scans are never found.
    let _ = pointray_io::parse_cloud(std::path::Path::new("/nonexistent/fuzz"), data);
});
