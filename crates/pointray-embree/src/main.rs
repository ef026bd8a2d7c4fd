//! `pointray-embree`: Embree 3's point primitives on a cloud that pointray prepared, traced
//! through pointray's own camera, pixels and shading, so that `pointray bench` can put
//! Embree's speed beside every point it measures and the two images can be compared pixel by
//! pixel. It answers the command line of `shared/bench/embree`'s bench (the options `pointray
//! bench` passes) and prints one JSON line per distance with the same keys.
//!
//! Oriented discs (`--geom oriented`, `RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT`) are the
//! classic splat, beside pointray's SJ, PSS and first-hit; ray-facing discs (`--geom disc`,
//! `RTC_GEOMETRY_TYPE_DISC_POINT`) are the RFD's primitive.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, ensure};
use clap::{Parser, ValueEnum};
use embree3::{
    BufferUsage, Device, DeviceProperty, Format, GeometryKind, INVALID_ID, IntersectContext, Ray, RayHit, Scene,
};
use glam::Vec3;
use pointray::camera::{Camera, Region};
use pointray::material::Phong;
use pointray::shading::{Environment, Light};
use pointray::splat::scheme::SurfaceHit;
use pointray::splat::{Splat, splats_from_cloud};
use rayon::prelude::*;

#[derive(Parser)]
#[command(
    name = "pointray-embree",
    version,
    about = "Embree 3's point primitives through pointray's camera and pixels"
)]
struct Args {
    /// A cloud with normals and radii (`pointray prepare`, or the one `pointray bench` writes).
    cloud: PathBuf,
    #[arg(long, value_enum, default_value_t = Geom::Oriented)]
    geom: Geom,
    /// Build and render threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Camera distances in bounding-box diagonals, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1")]
    dist: Vec<f32>,
    /// Frame size, WxH.
    #[arg(long, default_value = "1024x1024")]
    size: String,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = 60.0)]
    fov: f32,
    /// Direction from the model's centre towards the camera.
    #[arg(long, default_value = "0.4,0.3,1", allow_hyphen_values = true)]
    view: String,
    #[arg(long, default_value = "0,1,0", allow_hyphen_values = true)]
    up: String,
    /// Timed frames per distance (the median is reported).
    #[arg(long, default_value_t = 5)]
    reps: u32,
    /// Timed builds (the median is reported).
    #[arg(long, default_value_t = 3)]
    build_reps: u32,
    /// Trace only the pixels of the model's projected bounding box, as `pointray render
    /// --crop-to-model` does.
    #[arg(long)]
    crop: bool,
    /// Write each distance's image here, shaded as pointray shades a first hit (the whole
    /// frame, as `pointray render` writes it, to compare with `pointray compare`).
    #[arg(long)]
    images: Option<PathBuf>,
    /// Trace a shadow ray from each hit towards the headlight, as pointray does with shadows
    /// on, so that frames with shadows are timed against the same work.
    #[arg(long)]
    shadows: bool,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Geom {
    Oriented,
    Disc,
}

fn main() {
    if let Err(e) = run(&Args::parse()) {
        eprintln!("pointray-embree: error: {e:#}");
        std::process::exit(1);
    }
}

fn vec3(text: &str) -> anyhow::Result<Vec3> {
    let v: Vec<f32> = text.split(',').map(|c| c.trim().parse()).collect::<Result<_, _>>()?;
    ensure!(v.len() == 3, "{text:?}: three numbers, comma-separated");
    Ok(Vec3::new(v[0], v[1], v[2]))
}

fn run(a: &Args) -> anyhow::Result<()> {
    let (width, height) = a.size.split_once('x').context("--size: WxH")?;
    let (width, height): (u32, u32) = (width.parse()?, height.parse()?);
    let (view, up) = (vec3(&a.view).context("--view")?, vec3(&a.up).context("--up")?);
    ensure!(a.reps > 0 && a.build_reps > 0, "--reps and --build-reps must be at least 1");
    let threads = if a.threads == 0 { std::thread::available_parallelism().map_or(1, |n| n.get()) } else { a.threads };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;

    let cloud = pointray_io::read_cloud(&a.cloud)?.cloud;
    ensure!(
        cloud.normals.is_some() && cloud.radii.is_some(),
        "{}: no normals or radii: run `pointray prepare` first",
        a.cloud.display()
    );
    let splats = splats_from_cloud(&cloud);
    let bounds = cloud.bounds();

    let device = Device::with_config(embree3::Config { threads: threads as u32, ..Default::default() })
        .map_err(|e| anyhow::anyhow!("Embree: cannot create a device: {e:?}"))?;
    // Embree reports its version as one number, major × 10000 + minor × 100 + patch.
    let version = device
        .get_property(DeviceProperty::VERSION)
        .ok()
        .map(|v| format!("{}.{}.{}", v / 10_000, v / 100 % 100, v % 100));
    let mut build_times = Vec::new();
    let mut scene = None;
    for _ in 0..a.build_reps {
        let (built, seconds) = build(&device, &splats, a.geom)?;
        build_times.push(seconds);
        scene = Some(built);
    }
    let scene = scene.expect("one build at least");
    build_times.sort_by(f64::total_cmp);

    for &distance in &a.dist {
        let camera = Camera::orbit(&bounds, view, up, distance, a.fov, width, height);
        let region = if a.crop { camera.region_of(&bounds) } else { Region::full(width, height) };
        let (image, hits) = pool.install(|| trace(&scene, &splats, &camera, region, a.shadows));
        let mut times: Vec<f64> = (0..a.reps)
            .map(|_| {
                let t = Instant::now();
                let _ = pool.install(|| trace(&scene, &splats, &camera, region, a.shadows));
                t.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        let rays = region.pixel_count();
        let render_s = pointray::stats::median(&times);
        if let Some(folder) = &a.images {
            let stem = a.cloud.file_stem().map_or("cloud".into(), |s| s.to_string_lossy().into_owned());
            let geom = if a.geom == Geom::Oriented { "oriented" } else { "disc" };
            let path = folder.join(format!("{stem}_{geom}_k{distance}.png"));
            // The whole frame, the background outside the region, as `pointray render` writes it.
            let mut film = pointray::film::Film::new(region);
            film.rgb = image;
            let background = Environment::BACKGROUND.flat_color();
            pointray_io::write_png(
                &path,
                width,
                height,
                &film.frame_srgb8(width, height, background, pointray::film::ToneMap::CLAMP),
            )?;
        }
        let line = serde_json::json!({
            "bench": "pointray-embree",
            "embree_version": version,
            "input": a.cloud.display().to_string(),
            "points": splats.len(),
            "geom": if a.geom == Geom::Oriented { "oriented_disc" } else { "disc" },
            "threads": threads,
            "width": width,
            "height": height,
            "crop": a.crop,
            "shadows": a.shadows,
            "rays": rays,
            "fov_deg": a.fov,
            "k": distance,
            "build_s": pointray::stats::median(&build_times),
            "build_s_min": build_times[0],
            "render_s": render_s,
            "render_s_min": times[0],
            "mrays_s": rays as f64 / render_s / 1e6,
            "hit_frac": hits as f64 / rays.max(1) as f64,
            "reps": a.reps,
        });
        println!("{line}");
    }
    Ok(())
}

/// Embree's scene of the splats as `geom` points (centre and radius; the normal for oriented
/// discs), and how long its commit (the BVH build) took.
fn build<'a>(device: &Device, splats: &[Splat], geom: Geom) -> anyhow::Result<(Scene<'a>, f64)> {
    let kind = match geom {
        Geom::Oriented => GeometryKind::ORIENTED_DISC_POINT,
        Geom::Disc => GeometryKind::DISC_POINT,
    };
    fn embree_error(what: &'static str) -> impl Fn(embree3::Error) -> anyhow::Error {
        move |e| anyhow::anyhow!("Embree: {what}: {e:?}")
    }
    let mut points = device.create_geometry(kind).map_err(embree_error("cannot create the geometry"))?;
    let n = splats.len();
    points
        .set_new_buffer::<[f32; 4]>(BufferUsage::VERTEX, 0, Format::FLOAT4, 16, n)
        .map_err(embree_error("vertex buffer"))?
        .iter_mut()
        .zip(splats)
        .for_each(|(v, s)| *v = [s.center.x, s.center.y, s.center.z, s.radius]);
    if geom == Geom::Oriented {
        points
            .set_new_buffer::<[f32; 3]>(BufferUsage::NORMAL, 0, Format::FLOAT3, 12, n)
            .map_err(embree_error("normal buffer"))?
            .iter_mut()
            .zip(splats)
            .for_each(|(v, s)| *v = s.normal.to_array());
    }
    let points = points.commit();
    let mut scene = device.create_scene().map_err(embree_error("cannot create the scene"))?;
    scene.attach_geometry(&points);
    let t = Instant::now();
    scene.commit();
    Ok((scene, t.elapsed().as_secs_f64()))
}

/// One frame of `region`, shaded as pointray shades a first hit (standard Phong under the
/// headlight, the splat's colour, the default background; with `shadows`, the headlight seen
/// through a shadow ray): linear RGB, as pointray's film holds it, and the hit count.
fn trace(scene: &Scene, splats: &[Splat], camera: &Camera, region: Region, shadows: bool) -> (Vec<[f32; 3]>, u64) {
    let phong = Phong::standard();
    let light = Light::headlight(camera, 1.0);
    let background = Vec3::from(Environment::BACKGROUND.flat_color());
    let rows: Vec<(Vec<[f32; 3]>, u64)> = (region.y0..region.y1)
        .into_par_iter()
        .map(|y| {
            let mut context = IntersectContext::incoherent();
            let mut row = Vec::with_capacity(region.width() as usize);
            let mut hits = 0;
            for x in region.x0..region.x1 {
                let ray = camera.ray(x as f32 + 0.5, y as f32 + 0.5);
                let mut query =
                    RayHit::from_ray(Ray::segment(ray.origin.to_array(), ray.dir.to_array(), 0.0, f32::INFINITY));
                scene.intersect(&mut context, &mut query);
                let color = if query.hit.geomID == INVALID_ID {
                    background
                } else {
                    hits += 1;
                    let t = query.ray.tfar;
                    let normal = Vec3::new(query.hit.Ng_x, query.hit.Ng_y, query.hit.Ng_z).normalize_or(Vec3::Z);
                    let normal = if normal.dot(ray.dir) > 0.0 { -normal } else { normal };
                    let splat = &splats[query.hit.primID as usize];
                    let hit = SurfaceHit {
                        t,
                        position: ray.at(t),
                        normal,
                        color: splat.color_linear(),
                        radius: splat.radius,
                        splat: query.hit.primID,
                        blended: 1,
                    };
                    let (to_light, _, irradiance) = light.towards(hit.position);
                    let lit = !shadows || !occluded(scene, &mut context, &hit, to_light);
                    let direct = if lit { phong.direct(&hit, -ray.dir, to_light, irradiance) } else { Vec3::ZERO };
                    phong.ambient(&hit) + direct
                };
                row.push(color.to_array());
            }
            (row, hits)
        })
        .collect();
    let hits = rows.iter().map(|(_, h)| h).sum();
    (rows.into_iter().flat_map(|(row, _)| row).collect(), hits)
}

/// Whether the light along `to_light` is hidden from `hit`: a shadow ray as pointray starts
/// one from an oriented disc (one radius off the surface on the light's side, crossings within
/// a radius of its origin ignored).
fn occluded(scene: &Scene, context: &mut IntersectContext, hit: &SurfaceHit, to_light: Vec3) -> bool {
    if hit.normal.dot(to_light) <= 0.0 {
        return true;
    }
    let origin = hit.position + hit.normal * hit.radius;
    let mut ray = Ray::segment(origin.to_array(), to_light.to_array(), hit.radius, f32::INFINITY);
    scene.occluded(context, &mut ray)
}
