//! The library without the command line: `cargo run --release -p pointray-io --example render --
//! CLOUD OUT.png` reads and prepares a cloud (or a scene file), builds its scene once and renders
//! it (the example of the README's "As a library").

use pointray::{Scene, Settings, render};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [input, output] = args.as_slice() else {
        return Err("usage: render CLOUD OUT.png".into());
    };
    let source = pointray_io::source::load(input.as_ref(), &Default::default(), &Default::default(), &|_| {})?;
    let settings = Settings { width: 640, height: 480, spp: 4, ..Settings::default() };
    let scene = Scene::build(source.parts, &settings)?;
    let frame = render(&scene, &settings)?; // frame.film: linear RGB; frame.stats: the work
    pointray_io::write_png(output.as_ref(), 640, 480, &frame.srgb8(settings.tone_map()))?;
    Ok(())
}
