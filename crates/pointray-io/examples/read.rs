//! Reads point-cloud files and prints what was found and how long it took:
//! `cargo run --release -p pointray-io --example read -- FILE...`
//! Each file is read `REPEAT` times (default 5) and the fastest time reported, since one
//! cold or contended read says little.

use std::path::Path;
use std::time::Instant;

fn main() {
    let repeat: usize = std::env::var("REPEAT").ok().and_then(|r| r.parse().ok()).unwrap_or(5).max(1);
    for argument in std::env::args().skip(1) {
        let path = Path::new(&argument);
        let mut fastest = f64::INFINITY;
        let mut result = None;
        for _ in 0..repeat {
            let start = Instant::now();
            result = Some(pointray_io::read_cloud(path));
            fastest = fastest.min(start.elapsed().as_secs_f64());
        }
        match result.expect("repeat is at least one") {
            Ok(loaded) => {
                let cloud = &loaded.cloud;
                println!(
                    "{}: {} points in {:.1} ms; {}; elements {:?}; normals {}, radii {}, colours {}; origin {:.3}",
                    path.display(),
                    cloud.len(),
                    fastest * 1e3,
                    loaded.info.format,
                    loaded.info.elements,
                    cloud.normals.is_some(),
                    cloud.radii.is_some(),
                    cloud.colors.is_some(),
                    cloud.origin,
                );
            }
            Err(error) => println!("{error}"),
        }
    }
}
