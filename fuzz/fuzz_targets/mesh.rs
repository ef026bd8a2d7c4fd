//! The mesh readers (PLY, OFF and OBJ: vertices and faces) behind `pointray sample`; the first
//! byte picks the format's opening, so that each gets its share of the inputs.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else { return };
    let opening: &[u8] = match pick % 3 {
        0 => b"ply\n",
        1 => b"OFF\n",
        _ => b"v ",
    };
    let file = [opening, rest].concat();
    let _ = pointray_io::parse_mesh(std::path::Path::new("fuzz.mesh"), &file);
});
