//! The render loop: tiles over all cores, one ray tree per pixel sample, Whitted-style direct
//! light with hard shadows.
//!
//! Determinism: every pixel's value depends only on its coordinates, the scene and the seed
//! (a per-pixel RNG), never on which thread rendered it or when; statistics are integer sums.

use glam::Vec3;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::accel::{Accel, TraversalStats};
use crate::camera::{Camera, Region};
use crate::film::Film;
use crate::math::Ray;
use crate::shading::{Light, Material};
use crate::splat::scheme::{self, SurfaceScheme};
use crate::stats::RenderStats;

#[derive(Clone, Debug, serde::Serialize)]
pub struct RenderConfig {
    pub scheme: SurfaceScheme,
    pub light: Light,
    pub material: Material,
    pub shadows: bool,
    /// Shadow rays start this many splat radii off the surface, along the normal.
    pub shadow_offset: f32,
    /// Linear RGB behind the model.
    pub background: [f32; 3],
    /// Pixels to render; the rest of the film keeps the background.
    pub region: Region,
    /// Samples per pixel: 1 traces the pixel centre; more jitter within the pixel.
    pub samples: u32,
    pub seed: u64,
}

/// A finished tile: its pixels (radiance, nodes visited) in row order, and its counters.
type RenderedTile = (Region, Vec<([f32; 3], u32)>, RenderStats);

/// Pixels per tile edge: small enough to balance 2–64 threads, big enough for coherence.
const TILE: u32 = 16;

/// Renders `config.region` of the frame (the film covers just that region). `progress` is told how many pixels each finished
/// tile held.
pub fn render<A: Accel>(
    accel: &A,
    camera: &Camera,
    config: &RenderConfig,
    progress: &(dyn Fn(u64) + Sync),
) -> (Film, RenderStats) {
    let region = config.region.clamp_to(camera.width, camera.height);
    let mut film = Film::new(region);
    let tiles_x = region.width().div_ceil(TILE);
    let tiles_y = region.height().div_ceil(TILE);
    let tiles: Vec<Region> = (0..tiles_y)
        .flat_map(|ty| (0..tiles_x).map(move |tx| (tx, ty)))
        .map(|(tx, ty)| {
            let x0 = region.x0 + tx * TILE;
            let y0 = region.y0 + ty * TILE;
            Region { x0, y0, x1: (x0 + TILE).min(region.x1), y1: (y0 + TILE).min(region.y1) }
        })
        .collect();
    let rendered: Vec<RenderedTile> = tiles
        .into_par_iter()
        .map(|tile| {
            let mut stats = RenderStats::default();
            let mut pixels = Vec::with_capacity(tile.pixel_count() as usize);
            for y in tile.y0..tile.y1 {
                for x in tile.x0..tile.x1 {
                    pixels.push(render_pixel(accel, camera, config, x, y, &mut stats));
                }
            }
            progress(tile.pixel_count());
            (tile, pixels, stats)
        })
        .collect();
    let mut total = RenderStats::default();
    for (tile, pixels, stats) in rendered {
        total += stats;
        let mut it = pixels.into_iter();
        for y in tile.y0..tile.y1 {
            for x in tile.x0..tile.x1 {
                let (rgb, nodes) = it.next().expect("one value per pixel");
                let i = film.index(x, y);
                film.rgb[i] = rgb;
                film.nodes_visited[i] = nodes;
            }
        }
    }
    (film, total)
}

fn render_pixel<A: Accel>(
    accel: &A,
    camera: &Camera,
    config: &RenderConfig,
    x: u32,
    y: u32,
    stats: &mut RenderStats,
) -> ([f32; 3], u32) {
    let nodes_before = stats.traversal.nodes_visited;
    let mut sum = Vec3::ZERO;
    let samples = config.samples.max(1);
    let mut rng = (samples > 1).then(|| pixel_rng(config.seed, x, y));
    for _ in 0..samples {
        let (dx, dy) = match &mut rng {
            Some(r) => (r.random::<f32>(), r.random::<f32>()),
            None => (0.5, 0.5),
        };
        let ray = camera.ray(x as f32 + dx, y as f32 + dy);
        sum += Vec3::from(trace(accel, &ray, config, stats));
    }
    let nodes = (stats.traversal.nodes_visited - nodes_before).min(u32::MAX as u64) as u32;
    ((sum / samples as f32).to_array(), nodes)
}

/// A generator that depends only on the seed and the pixel.
fn pixel_rng(seed: u64, x: u32, y: u32) -> Pcg64Mcg {
    let key = seed ^ (u64::from(y) << 32 | u64::from(x)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    Pcg64Mcg::seed_from_u64(key)
}

/// Radiance along a primary ray.
fn trace<A: Accel>(accel: &A, ray: &Ray, config: &RenderConfig, stats: &mut RenderStats) -> [f32; 3] {
    stats.rays += 1;
    stats.primary_rays += 1;
    let mut ts = TraversalStats::default();
    let hit = scheme::intersect(accel, ray, &config.scheme, &mut ts);
    stats.traversal += ts;
    let Some(hit) = hit else { return config.background };
    stats.primary_hits += 1;
    stats.blended_splats += u64::from(hit.blended);
    let (to_light, light_dist, irradiance) = config.light.towards(hit.position);
    let faces_light = hit.normal.dot(to_light) > 0.0;
    let lit = faces_light && (!config.shadows || !in_shadow(accel, ray, &hit, to_light, light_dist, config, stats));
    config.material.shade(&hit, -ray.dir, to_light, irradiance, lit)
}

/// Shadow test from a hit. The ray starts `shadow_offset × r` off the surface, on the light's
/// side, and ignores crossings within one radius of its origin: the neighbouring disks of a
/// curved surface stand up to about r off each other's planes (SJ advise 1–3 r).
fn in_shadow<A: Accel>(
    accel: &A,
    primary: &Ray,
    hit: &scheme::SurfaceHit,
    to_light: Vec3,
    light_dist: f32,
    config: &RenderConfig,
    stats: &mut RenderStats,
) -> bool {
    stats.rays += 1;
    stats.shadow_rays += 1;
    let offset = config.shadow_offset * hit.radius;
    let origin = hit.position + hit.normal * offset;
    let footprint = primary.cone.width_at(hit.t);
    let ray =
        Ray::new(origin, to_light, crate::math::RayCone { width0: footprint, spread: 0.0 }).with_t_min(hit.radius);
    let mut ts = TraversalStats::default();
    let blocked = scheme::occluded(accel, &ray, light_dist, &mut ts);
    stats.traversal += ts;
    blocked
}
