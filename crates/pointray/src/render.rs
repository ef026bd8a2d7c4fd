//! The render loop: tiles over all cores, one ray tree per pixel sample, Whitted ray tracing:
//! direct light with hard shadows on Phong surfaces, and recursive reflection and refraction
//! on mirrors and glass up to `max_depth` bounces.
//!
//! Determinism: every pixel's value depends only on its coordinates, the scene and the seed
//! (a per-pixel RNG), never on which thread rendered it or when; statistics are integer sums.

use std::sync::atomic::{AtomicBool, Ordering};

use glam::Vec3;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::accel::{Accel, TraversalStats};
use crate::camera::{Camera, Region};
use crate::film::Film;
use crate::ground::GroundPlane;
use crate::material::{self, Material, Phong};
use crate::math::{Ray, RayLanes};
use crate::shading::{Environment, Light};
use crate::splat::DiskShape;
use crate::splat::scheme::{self, SurfaceScheme};
use crate::stats::RenderStats;

mod footprint;

/// How light is carried from the lights to the eye.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Integrator {
    /// Whitted: Phong direct light with shadows, ambient for the rest; mirrors and glass
    /// followed by recursion, both branches of glass at every interface.
    Whitted,
    /// A path tracer (global illumination): diffuse surfaces (albedo/π) take each light's
    /// direct light by a shadow ray (next-event estimation; a light's intensity means what it
    /// means to Whitted's Phong, see [`Light`]) and the rest by one
    /// cosine-distributed bounce; glass picks reflection or refraction by its Fresnel
    /// reflectance. Russian roulette from the fourth bounce; unbiased but for `max_depth`.
    Path,
    /// Ambient occlusion: a diffuse surface shows its albedo times the fraction of
    /// cosine-distributed rays (one per sample) that meet nothing within
    /// [`RenderConfig::ao_distance`].
    Ao,
    /// Eye light: every hit shows its albedo times |N·D|, the cosine between its normal and
    /// the ray; no lights, shadows or bounces. The shading of Embree's tutorials and bench,
    /// so that a comparison with it measures the ray query, not the shading; and a quick
    /// preview.
    EyeLight,
}

/// Where in and around its pixel each sample's camera ray goes, and how its path draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Sampler {
    /// Independent uniform numbers.
    Random,
    /// The R2 low-discrepancy sequence (Roberts 2018), shifted per pixel: any number of
    /// samples spread evenly, so edges converge faster than with independent positions; the
    /// lens, lights and bounces draw from it too, in pairs.
    R2,
}

/// The pixel's reconstruction filter, applied by importance sampling (as pbrt-v4 does):
/// sample positions are drawn with the filter's density and averaged with equal weights.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Filter {
    /// The pixel's square.
    Box,
    /// A tent two pixels wide: smoother edges, a little softer.
    Tent,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct RenderConfig {
    pub sampler: Sampler,
    pub filter: Filter,
    pub integrator: Integrator,
    /// [`Integrator::Ao`]: how far a surface looks for what occludes it.
    pub ao_distance: f32,
    pub scheme: SurfaceScheme,
    /// Every light shines on Phong surfaces, each with its own shadow ray.
    pub lights: Vec<Light>,
    /// The materials that splats name by index ([`crate::splat::Splat::material`]); an index
    /// past the end takes the first.
    pub materials: Vec<Material>,
    pub shadows: bool,
    /// Shadow and secondary rays start this many splat radii off the surface, along the normal.
    pub shadow_offset: f32,
    /// What rays that leave the scene see.
    pub environment: Environment,
    /// What camera rays that leave the scene see instead (none: the environment).
    pub background: Option<[f32; 3]>,
    /// An analytic plane under the clouds, tested by every ray beside the accelerator.
    pub ground: Option<GroundPlane>,
    /// Bounces a path may take (Whitted: off mirrors and glass; the path tracer: any); the
    /// camera ray is bounce 0. A path that would go deeper contributes nothing more.
    pub max_depth: u32,
    /// Pixels to render; the rest of the film keeps the environment's flat colour.
    pub region: Region,
    /// Samples per pixel: 1 traces the pixel centre; more jitter within the pixel.
    pub samples: u32,
    /// Which of the pixel's `samples` this render traces (none: all), its film their mean: a
    /// pass of a progressive render. Each sample draws the same numbers and positions whatever
    /// the range, so passes over ranges that split `0..samples`, averaged by their lengths, make
    /// the image of all the samples at once (to the rounding of the sums).
    pub sample_range: Option<std::ops::Range<u32>>,
    pub seed: u64,
    /// Level-of-detail threshold τ in pixels for every ray (see `Ray::lod_threshold`); 0 = off.
    pub lod_threshold: f32,
    /// Camera rays whose footprint is wide enough for level of detail gather their pixel's
    /// footprint (`splat::footprint`, `render::footprint`): Whitted and eye light, Phong
    /// surfaces; others are traced as rays.
    pub prefilter: bool,
    /// Path tracer: the least spread (beam width per unit length) of a diffusely bounced ray's
    /// cone. Such rays go every which way, so their level of detail may be coarse (Christensen
    /// et al. 2003); 0 keeps the incoming ray's spread.
    pub diffuse_spread: f32,
    /// Cull back-facing subtrees for camera rays (only right for closed, consistently
    /// oriented surfaces; see `culling::backfacing_fraction`).
    pub cull_backfaces: bool,
    /// Count the traversal's work: [`RenderStats::traversal`] and the film's `nodes_visited`.
    /// Off, they stay zero and the BVH traverses without counting (see
    /// [`TraversalStats::uncounted`]): for frames whose statistics nobody reads.
    pub count_work: bool,
    /// Record the camera rays' first hits in the film: `Film::normal`, `albedo` and `depth`.
    /// Off, the render leaves those as they were and no sample adds to them (the dragon without
    /// them: first hits 761 → 749 instructions a pixel, SJ 1,033 → 1,021, callgrind).
    pub first_hit_aovs: bool,
}

/// Pixels per tile edge: small enough to balance 2–64 threads, big enough for coherence.
const TILE: u32 = 16;

/// Rows a band of `height` takes (see `render_into`): [`TILE`], or fewer where the region is
/// too short to give each of `threads` threads about sixteen bands. A distant model covers few
/// rows (the dragon at 16 diagonals, 41): in bands of 16 one of two threads took 25 rows and
/// the other 16; in bands of two, the last band still left a thread idle (bands of one row:
/// 16.8 → 17.6 M samples/s, two threads, alternating runs).
fn band_rows(height: u32, threads: usize) -> u32 {
    (height / (16 * threads as u32).max(1)).clamp(1, TILE)
}

/// Renders `config.region` of the frame (the film covers just that region). `progress` is told how many pixels each finished
/// tile held.
pub fn render<A: Accel>(
    accel: &A,
    camera: &Camera,
    config: &RenderConfig,
    progress: &(dyn Fn(u64) + Sync),
) -> (Film, RenderStats) {
    let mut film = film_for(camera, config);
    let stats = render_into(accel, camera, config, &mut film, progress);
    (film, stats)
}

/// A film of the region `config` renders, with the first hits' channels if it records them.
pub fn film_for(camera: &Camera, config: &RenderConfig) -> Film {
    let region = config.region.clamp_to(camera.width, camera.height);
    if config.first_hit_aovs { Film::with_first_hits(region) } else { Film::new(region) }
}

/// [`render`] into a film made before, which every pixel of is written (the first hits'
/// channels only with `config.first_hit_aovs`): frame after frame, one film serves (a fresh one
/// per frame, its pages faulted in anew, cost 7 % of a frame of the dragon at 1024², first hits).
///
/// # Panics
/// If the film's region is not `config.region` within the camera's frame, or the film has no
/// first-hit channels where `config.first_hit_aovs` asks for them ([`film_for`] makes one that
/// fits).
pub fn render_into<A: Accel>(
    accel: &A,
    camera: &Camera,
    config: &RenderConfig,
    film: &mut Film,
    progress: &(dyn Fn(u64) + Sync),
) -> RenderStats {
    let never = AtomicBool::new(false);
    render_into_until(accel, camera, config, film, progress, &never)
}

/// [`render_into`], stopping early once `cancel` is set: bands not yet begun are left as they
/// were (a band checks before it starts, so a frame stops within a band's time). The caller
/// knows a frame is whole when `cancel` is still clear afterwards.
pub fn render_into_until<A: Accel>(
    accel: &A,
    camera: &Camera,
    config: &RenderConfig,
    film: &mut Film,
    progress: &(dyn Fn(u64) + Sync),
    cancel: &AtomicBool,
) -> RenderStats {
    let region = config.region.clamp_to(camera.width, camera.height);
    assert_eq!(film.region, region, "a film for another region");
    let width = region.width() as usize;
    if width == 0 || region.height() == 0 {
        return RenderStats::default();
    }
    // One task per band of TILE rows (fewer for a short region), written straight into the
    // film; within a band, pixels go tile by tile (TILE wide) so that neighbouring rays share
    // nodes in cache. Pixels do not depend on the bands: the same image for any split.
    let rows_per_band = band_rows(region.height(), rayon::current_num_threads());
    let band = rows_per_band as usize * width;
    let primary = PrimaryRays::new(accel, camera, config);
    let render_band = |b: usize, rgb: &mut [[f32; 3]], nodes: &mut [u32], mut first_hits: Option<BandFirstHits>| {
        let mut stats = RenderStats::default();
        if cancel.load(Ordering::Relaxed) {
            return stats;
        }
        if !config.count_work {
            stats.traversal = TraversalStats::uncounted();
        }
        let y0 = region.y0 + b as u32 * rows_per_band;
        let rows = Rows { region, y0, width, primary: &primary };
        // The prefilter's frames in an instance of their own: a check per ray for it cost the
        // dragon's first hits 8 instructions a pixel, one per pixel choosing between two
        // instances of `render_pixel` 4 (callgrind).
        if primary.prefilter {
            render_rows::<A, true>(accel, camera, config, &rows, (rgb, nodes, &mut first_hits), &mut stats);
        } else {
            render_rows::<A, false>(accel, camera, config, &rows, (rgb, nodes, &mut first_hits), &mut stats);
        }
        progress(rgb.len() as u64);
        stats
    };
    let sum = |mut a: RenderStats, b: RenderStats| {
        a += b;
        a
    };
    // Every band a job of its own: left to itself, rayon ran a quarter of the bands as one
    // job, and a thread done early had nothing to steal (1M torus, two threads: 9.6 → 12.6
    // Mrays/s, first hits; frames 31–40 ms → 29–31 ms).
    let bands = film.rgb.par_chunks_mut(band).zip(film.nodes_visited.par_chunks_mut(band));
    let bands = bands.enumerate().with_max_len(1);
    match &mut film.first_hits {
        Some(c) if config.first_hit_aovs => {
            let channels = c.normal.par_chunks_mut(band).zip(c.albedo.par_chunks_mut(band));
            let channels = channels.zip(c.depth.par_chunks_mut(band)).zip(c.coverage.par_chunks_mut(band));
            bands
                .zip(channels)
                .map(|((b, (rgb, nodes)), (((normal, albedo), depth), coverage))| {
                    render_band(b, rgb, nodes, Some((normal, albedo, depth, coverage)))
                })
                .reduce(RenderStats::default, sum)
        }
        None if config.first_hit_aovs => panic!("a film without the first hits' channels (see `film_for`)"),
        _ => bands.map(|(b, (rgb, nodes))| render_band(b, rgb, nodes, None)).reduce(RenderStats::default, sum),
    }
}

/// Where a band's pixels go: its first row and the region's.
struct Rows<'a> {
    region: Region,
    y0: u32,
    width: usize,
    primary: &'a PrimaryRays,
}

/// A band's pixels, tile by tile, into its rows of the film.
fn render_rows<A: Accel, const PREFILTER: bool>(
    accel: &A,
    camera: &Camera,
    config: &RenderConfig,
    rows_at: &Rows,
    (rgb, nodes, first_hits): (&mut [[f32; 3]], &mut [u32], &mut Option<BandFirstHits>),
    stats: &mut RenderStats,
) {
    let Rows { region, y0, width, primary } = *rows_at;
    let rows = (rgb.len() / width) as u32;
    let mut centres: Option<RayLanes<RAY_BATCH>> = None;
    for tx in (region.x0..region.x1).step_by(TILE as usize) {
        for y in y0..y0 + rows {
            for x in tx..(tx + TILE).min(region.x1) {
                let i = (y - y0) as usize * width + (x - region.x0) as usize;
                // One sample a pixel through a pinhole: the rays through the centres of
                // this pixel and the next made at once (`Camera::rays`; the dragon's first
                // hits 693 → 650 instructions a pixel, callgrind, and 10 % more rays a
                // second, the 1M torus 13 %, alternating runs).
                let lane = (x - tx) as usize % RAY_BATCH;
                if lane == 0 && primary.centre_rays {
                    let xs = std::array::from_fn(|i| (x + i as u32) as f32 + 0.5);
                    centres = Some(camera.rays(xs, [y as f32 + 0.5; RAY_BATCH]));
                }
                let centre = centres.as_ref().map(|rays| rays.ray(lane));
                let pixel = render_pixel::<A, PREFILTER>(accel, camera, config, primary, (x, y, centre), stats);
                (rgb[i], nodes[i]) = (pixel.rgb, pixel.nodes);
                if let Some((normal, albedo, depth, coverage)) = first_hits {
                    (normal[i], albedo[i], depth[i], coverage[i]) = pixel.first.means();
                }
            }
        }
    }
}

/// A band's rows of the first hits' normal, albedo, depth and coverage.
type BandFirstHits<'a> = (&'a mut [[f32; 3]], &'a mut [[f32; 3]], &'a mut [f32], &'a mut [f32]);

/// One pixel's values (see [`Film`]): its radiance, work and the sums of its first hits.
struct Pixel {
    rgb: [f32; 3],
    nodes: u32,
    first: FirstHits,
}

/// What a pixel's camera rays' first hits were, summed, for the film's AOVs.
#[derive(Default)]
struct FirstHits {
    normal: Vec3,
    albedo: Vec3,
    depth: f32,
    hits: u32,
    /// The share of the pixel each sample covered, summed: 1 a hit, or a footprint's coverage.
    covered: f32,
    samples: u32,
}

impl FirstHits {
    /// The mean normal and albedo over the samples (a miss counts as zero), the mean depth
    /// over the hits (∞ without one) and the share of the pixel covered: averaged only
    /// where the film records them.
    fn means(&self) -> ([f32; 3], [f32; 3], f32, f32) {
        let n = self.samples.max(1) as f32;
        let depth = if self.hits == 0 { f32::INFINITY } else { self.depth / self.hits as f32 };
        ((self.normal / n).to_array(), (self.albedo / n).to_array(), depth, self.covered / n)
    }
}

/// What every camera ray of a frame shares.
struct PrimaryRays {
    /// The rays' level-of-detail threshold: `config.lod_threshold`, or 0 where no camera ray
    /// could stop at a representative (a view close enough that every footprint stays
    /// narrower than the accelerator's `lod_floor`): the same hits, without a test per ray.
    tau: f32,
    /// Each of n samples stands for 1/n of the pixel, a beam 1/√n as wide (as pbrt scales its
    /// ray differentials): more samples resolve finer detail.
    footprint_scale: f32,
    /// Back faces culled: asked for, and the disks oriented (a ray-facing disk faces every ray).
    cull_backfaces: bool,
    /// One sample a pixel through a pinhole: each pixel's ray passes through its centre, and
    /// the rays of RAY_BATCH pixels in a row are made at once.
    centre_rays: bool,
    /// Many samples a pixel through a pinhole, at R2 points (which draw no numbers): a
    /// pixel's rays are made RAY_BATCH at a time.
    sample_batches: bool,
    /// The samples of each pixel traced (`RenderConfig::sample_range` within `0..samples`),
    /// found once a frame: per pixel, with the mean's divisor, it cost the dragon's first hits
    /// 702 → 699 instructions a pixel (callgrind).
    samples: std::ops::Range<u32>,
    /// The footprint prefilter: asked for, at a level of detail.
    prefilter: bool,
}

impl PrimaryRays {
    fn new<A: Accel>(accel: &A, camera: &Camera, config: &RenderConfig) -> Self {
        let footprint_scale = (config.samples.max(1) as f32).sqrt().recip();
        // Every camera ray's footprint, as `render_pixel` makes it.
        let mut cone = camera.ray(0.5, 0.5).cone;
        cone = cone.scaled(footprint_scale);
        // Thin-lens rays leave from across the lens: the bound is for one origin.
        let tau = if camera.lens_radius > 0.0
            || accel.may_stop_at_representatives_from(camera.eye, cone, config.lod_threshold)
        {
            config.lod_threshold
        } else {
            0.0
        };
        let cull_backfaces = config.cull_backfaces && config.scheme.kind.shape() == DiskShape::Oriented;
        // Rays made in lanes share the eye: a pinhole's, not a lens's or an orthographic film's.
        let pinhole = camera.lens_radius <= 0.0 && camera.orthographic.is_none();
        let centre_rays = pinhole && config.samples <= 1;
        let sample_batches = pinhole && config.samples > 1 && config.sampler == Sampler::R2;
        let n = config.samples.max(1);
        let samples = config.sample_range.as_ref().map_or(0..n, |r| r.start.min(n)..r.end.clamp(r.start.min(n), n));
        let prefilter = config.prefilter && tau > 0.0;
        Self { tau, footprint_scale, cull_backfaces, centre_rays, sample_batches, samples, prefilter }
    }

    /// A camera's `ray` with the frame's threshold, culling and footprint, counted.
    #[inline(always)]
    fn finish(&self, ray: Ray, stats: &mut RenderStats) -> Ray {
        let mut ray = ray.with_lod_threshold(self.tau).with_backface_culling(self.cull_backfaces);
        ray.cone = ray.cone.scaled(self.footprint_scale);
        stats.primary_rays += 1;
        ray
    }
}

/// Camera rays made at once: a pixel's samples through a pinhole, or the centres of as many
/// pixels in a row where each takes one.
const RAY_BATCH: usize = 8;

/// The pixel (`x`, `y`), given the ray through its centre where it takes one sample through
/// a pinhole (`PrimaryRays::centre_rays`); its camera rays through the footprint prefilter if
/// `PREFILTER`.
fn render_pixel<A: Accel, const PREFILTER: bool>(
    accel: &A,
    camera: &Camera,
    config: &RenderConfig,
    primary: &PrimaryRays,
    (x, y, centre): (u32, u32, Option<Ray>),
    stats: &mut RenderStats,
) -> Pixel {
    let nodes_before = stats.traversal.nodes_visited;
    let mut sum = Vec3::ZERO;
    let samples = config.samples.max(1);
    let range = primary.samples.clone();
    let traced = range.end - range.start;
    let mut first = FirstHits { samples: traced, ..FirstHits::default() };
    // The pixel's own shift of the R2 sequence (Cranley–Patterson rotation), drawn only
    // where it is used: seeding a generator costs ~60 instructions.
    let r2_samples = samples > 1 && config.sampler == Sampler::R2;
    let pixel_shift = if r2_samples {
        let mut rng = sample_rng(config.seed, x, y, u32::MAX);
        [rng.random::<f32>(), rng.random::<f32>()]
    } else {
        [0.0; 2]
    };
    // The numbers a sample's path draws (lens, lights, bounces) from a low-discrepancy
    // sequence too, with R2's pixel positions.
    let low_discrepancy = r2_samples.then(|| (sample_key(config.seed, x, y, u32::MAX), samples));
    // Where in the pixel a sample looks: the centre, a point of the R2 sequence, or two numbers
    // from the sample's own stream, which it then traces with (how many numbers a path draws,
    // roulette, total internal reflection, which disks it meets, never shifts another
    // sample's); filtered.
    let filtered = |u: [f32; 2]| match config.filter {
        Filter::Box => u,
        Filter::Tent => [0.5 + tent(u[0]), 0.5 + tent(u[1])],
    };
    if let Some(centre) = centre.filter(|_| !range.is_empty()) {
        // Apart from the loop below, which would make the same ray: folded into it, the
        // sample's offsets and the test cost the dragon's first hits 649 → 681 instructions a
        // pixel (callgrind).
        let rng = SampleRng::new(config.seed, x, y, 0, None);
        let ray = primary.finish(centre, stats);
        sum += Tracer { accel, config, rng, first: &mut first, stats: &mut *stats }.camera_radiance::<PREFILTER>(&ray);
    } else if primary.sample_batches {
        // Pinhole rays through the R2 points, which draw no numbers, made a batch at a time
        // and traced in order (`Camera::rays`: the dragon's distant samples, 64 a pixel, 1,233
        // → 1,165 instructions each, callgrind, and 7 % more a second, alternating runs).
        for start in range.clone().step_by(RAY_BATCH) {
            let (mut px, mut py) = ([0.0; RAY_BATCH], [0.0; RAY_BATCH]);
            for i in 0..RAY_BATCH {
                // Past the last sample too: those rays are made and never traced.
                let [dx, dy] = filtered(r2(start + i as u32, pixel_shift));
                (px[i], py[i]) = (x as f32 + dx, y as f32 + dy);
            }
            let rays = camera.rays(px, py);
            for i in 0..(range.end - start).min(RAY_BATCH as u32) {
                let rng = SampleRng::new(config.seed, x, y, start + i, low_discrepancy);
                let ray = primary.finish(rays.ray(i as usize), stats);
                sum += Tracer { accel, config, rng, first: &mut first, stats: &mut *stats }
                    .camera_radiance::<PREFILTER>(&ray);
            }
        }
    } else {
        for sample in range.clone() {
            let mut rng = SampleRng::new(config.seed, x, y, sample, low_discrepancy);
            let [dx, dy] = match config.sampler {
                _ if samples == 1 => [0.5, 0.5],
                Sampler::Random => filtered([rng.next(), rng.next()]),
                Sampler::R2 => filtered(r2(sample, pixel_shift)),
            };
            let lens = if camera.lens_radius > 0.0 { [rng.next(), rng.next()] } else { [0.5; 2] };
            let ray = primary.finish(camera.lens_ray(x as f32 + dx, y as f32 + dy, lens), stats);
            sum +=
                Tracer { accel, config, rng, first: &mut first, stats: &mut *stats }.camera_radiance::<PREFILTER>(&ray);
        }
    }
    let nodes = (stats.traversal.nodes_visited - nodes_before).min(u32::MAX as u64) as u32;
    Pixel { rgb: (sum / traced.max(1) as f32).to_array(), nodes, first }
}

/// Point `i` of the R2 sequence, shifted by `shift` (modulo 1): α = (1/g, 1/g²), g the
/// plastic number, the root of x³ = x + 1.
fn r2(i: u32, shift: [f32; 2]) -> [f32; 2] {
    const G: f64 = 1.324_717_957_244_746;
    let t = f64::from(i);
    // `fract` of a value in [0, 2³³): the cast truncates as `trunc` does, which the x86-64
    // baseline has no instruction for (a libm call, 38 instructions a sample, callgrind).
    // Through i64, not u64, which x86-64 converts in one instruction each way (45 instructions
    // a sample fewer; the dragon at distance 16, 64 samples: 1.7 % more rays a second).
    let fract = |x: f64| x - (x as i64) as f64;
    [fract(f64::from(shift[0]) + t / G) as f32, fract(f64::from(shift[1]) + t / (G * G)) as f32]
}

/// The offset from the pixel's centre, in pixels, that a uniform `u` in [0, 1) maps to under
/// a tent filter of radius 1 (inverse of its distribution function).
fn tent(u: f32) -> f32 {
    if u < 0.5 { (2.0 * u).sqrt() - 1.0 } else { 1.0 - (2.0 - 2.0 * u).sqrt() }
}

/// A generator that depends only on the seed, the pixel and the sample.
fn sample_rng(seed: u64, x: u32, y: u32, sample: u32) -> Pcg64Mcg {
    Pcg64Mcg::seed_from_u64(sample_key(seed, x, y, sample))
}

fn sample_key(seed: u64, x: u32, y: u32, sample: u32) -> u64 {
    let pixel = (u64::from(y) << 32 | u64::from(x)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    seed ^ pixel ^ u64::from(sample).wrapping_mul(0xd1b5_4a32_d192_ed03)
}

/// A sample's numbers: when the pixel's samples take R2 positions, its first [`LD_DIMS`] in
/// pairs, each pair a point of R2 shifted per pixel (Cranley–Patterson) at the sample's index
/// permuted per pixel and pair, so that every pair spreads as the pixel positions do while the
/// pairs stay independent of one another (one R_d sequence over all the dimensions lined its
/// low pairs up at 64 samples: 38 of 64 cells empty where independent numbers leave 23). The
/// rest, and all with one sample or the random sampler, from [`sample_rng`], seeded on its
/// first draw: a camera ray of one sample a pixel under Whitted's point lights draws nothing,
/// and seeding cost 62 instructions a ray (callgrind, dragon). The same numbers as seeding at
/// once.
struct SampleRng {
    key: u64,
    rng: Option<Pcg64Mcg>,
    low_discrepancy: Option<LowDiscrepancy>,
    dim: usize,
    /// The second number of the pair the last even dimension drew.
    pending: f32,
}

/// The pixel's key, the sample's index and the pixel's number of samples.
#[derive(Clone, Copy)]
struct LowDiscrepancy {
    pixel: u64,
    index: u32,
    count: u32,
}

/// Dimensions a sample draws in low-discrepancy pairs: a lens, then the path's lights,
/// directions, roulette and glass (the demo path traced under its sky, against 1,024 samples a
/// pixel: the error at 64 samples 18 % below independent numbers', 0.00465 against 0.00565).
const LD_DIMS: usize = 12;

impl SampleRng {
    fn new(seed: u64, x: u32, y: u32, sample: u32, low_discrepancy: Option<(u64, u32)>) -> Self {
        let low_discrepancy = low_discrepancy.map(|(pixel, count)| LowDiscrepancy { pixel, index: sample, count });
        Self { key: sample_key(seed, x, y, sample), rng: None, low_discrepancy, dim: 0, pending: 0.0 }
    }

    fn get(&mut self) -> &mut Pcg64Mcg {
        let key = self.key;
        self.rng.get_or_insert_with(|| Pcg64Mcg::seed_from_u64(key))
    }

    /// The sample's next number in [0, 1).
    fn next(&mut self) -> f32 {
        let dim = self.dim;
        match self.low_discrepancy {
            Some(ld) if dim < LD_DIMS => {
                self.dim += 1;
                if dim % 2 == 1 {
                    return self.pending;
                }
                let key = splitmix(ld.pixel ^ (dim as u64 + 1).wrapping_mul(0x9e37_79b9));
                let shift =
                    [(key >> 40) as f32 / (1 << 24) as f32, ((key >> 16) & 0xff_ffff) as f32 / (1 << 24) as f32];
                let [u, v] = r2(permute(ld.index, ld.count, key), shift);
                self.pending = v;
                u
            }
            _ => self.get().random(),
        }
    }
}

/// Index `i` of `0..n` permuted by `key`: a four-round Feistel network over the least power of
/// four at least `n`, walking on past indices beyond `n` (a bijection of that range, so the
/// walk ends; less than three quarters of the range lies past `n`).
fn permute(i: u32, n: u32, key: u64) -> u32 {
    let bits = (u32::BITS - n.saturating_sub(1).leading_zeros()).max(2).next_multiple_of(2);
    let (half, mask) = (bits / 2, (1u32 << (bits / 2)) - 1);
    let mut x = i;
    loop {
        let (mut left, mut right) = (x >> half, x & mask);
        for round in 0..4u64 {
            let f = splitmix(key ^ (round << 40) ^ u64::from(right)) as u32 & mask;
            (left, right) = (right, left ^ f);
        }
        x = (left << half) | right;
        if x < n {
            return x;
        }
    }
}

/// A 64-bit mix (SplitMix64's finaliser): a well-spread number from a key.
fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// One sample's tracing: the scene, the sample's random stream, and what it adds up.
struct Tracer<'a, A> {
    accel: &'a A,
    config: &'a RenderConfig,
    rng: SampleRng,
    /// The camera ray's hit, for the film's AOVs.
    first: &'a mut FirstHits,
    stats: &'a mut RenderStats,
}

impl<A: Accel> Tracer<'_, A> {
    /// Radiance arriving along a camera ray: through the footprint prefilter where the frame
    /// asks for it (`PREFILTER`, [`PrimaryRays::prefilter`]) and the ray's footprint is wide
    /// enough for level of detail.
    #[inline(always)]
    fn camera_radiance<const PREFILTER: bool>(&mut self, ray: &Ray) -> Vec3 {
        if PREFILTER
            && self.accel.may_stop_at_representatives(ray)
            && let Some(radiance) = self.footprint_radiance(ray)
        {
            return radiance;
        }
        self.radiance(ray, 0, false)
    }

    /// Radiance arriving along `ray`, which has bounced `depth` times and travels inside a
    /// glass object when `inside`.
    #[inline(always)]
    fn radiance(&mut self, ray: &Ray, depth: u32, inside: bool) -> Vec3 {
        self.radiance_drawn(ray, depth, inside, 0.0)
    }

    /// [`Self::radiance`] along a ray the path tracer's diffuse bounce drew with density
    /// `bounce_pdf` (per steradian; 0 for any other ray): an environment map it then sees is
    /// weighed against the map's own samples.
    fn radiance_drawn(&mut self, ray: &Ray, depth: u32, inside: bool, bounce_pdf: f32) -> Vec3 {
        let config = self.config;
        self.stats.rays += 1;
        if depth > 0 {
            self.stats.secondary_rays += 1;
        }
        let Some((hit, material)) = self.closest(ray, depth == 0) else {
            return self.missed(ray, depth, bounce_pdf);
        };
        if depth == 0 && config.first_hit_aovs {
            self.first.normal += hit.normal;
            self.first.albedo += Vec3::from(hit.color);
            self.first.depth += hit.t;
            self.first.hits += 1;
            self.first.covered += 1.0;
        }
        self.shade(ray, &hit, material, depth, inside)
    }

    /// The radiance `hit` (of `material`) sends back along `ray` after `depth` bounces.
    #[inline(always)]
    fn shade(&mut self, ray: &Ray, hit: &scheme::SurfaceHit, material: Material, depth: u32, inside: bool) -> Vec3 {
        let config = self.config;
        if config.integrator == Integrator::EyeLight {
            return Vec3::from(hit.color) * hit.normal.dot(ray.dir).abs();
        }
        let bounce = |direction: Vec3| secondary(ray, hit, direction, config);
        match material {
            Material::Phong(phong) if config.integrator == Integrator::Path => {
                self.diffuse(ray, hit, &phong, depth, inside)
            }
            Material::Phong(_) if config.integrator == Integrator::Ao => {
                let direction = cosine_direction(hit.normal, [self.rng.next(), self.rng.next()]);
                let probe = secondary(ray, hit, direction, config);
                self.stats.secondary_rays += 1;
                self.stats.rays += 1;
                let open = !self.occluded(&probe, config.ao_distance);
                Vec3::from(hit.color) * f32::from(u8::from(open))
            }
            Material::Phong(phong) => {
                let mut color = self.ambient(&phong, hit);
                self.visible_lights(ray, hit, |to_light, irradiance| {
                    color += phong.direct(hit, -ray.dir, to_light, irradiance);
                });
                color
            }
            _ if depth >= config.max_depth => Vec3::ZERO,
            Material::Mirror { tint } => {
                Vec3::from(tint) * self.radiance(&bounce(material::reflect(ray.dir, hit.normal)), depth + 1, inside)
            }
            Material::Glass { ior, tint } => {
                // The normal faces the incoming ray; `inside` says which medium it comes from.
                let eta = if inside { ior } else { ior.recip() };
                let reflectance = material::fresnel_dielectric(-ray.dir.dot(hit.normal), eta);
                let reflected = bounce(material::reflect(ray.dir, hit.normal));
                let refracted = material::refract(ray.dir, hit.normal, eta).filter(|_| reflectance < 1.0).map(bounce);
                let tint = Vec3::from(tint);
                match (config.integrator, refracted) {
                    (_, None) => self.radiance(&reflected, depth + 1, inside),
                    // One branch, chosen with the probability of its Fresnel weight, which it
                    // then cancels.
                    (Integrator::Path | Integrator::Ao, Some(refracted)) => {
                        if self.rng.next() < reflectance {
                            self.radiance(&reflected, depth + 1, inside)
                        } else {
                            tint * self.radiance(&refracted, depth + 1, !inside)
                        }
                    }
                    // Whitted: both, weighted. (An eye-light render returned before.)
                    (Integrator::Whitted | Integrator::EyeLight, Some(refracted)) => {
                        reflectance * self.radiance(&reflected, depth + 1, inside)
                            + (1.0 - reflectance) * tint * self.radiance(&refracted, depth + 1, !inside)
                    }
                }
            }
        }
    }

    /// Phong's ambient term at `hit`: an environment map's light, unshadowed, or the ambient.
    #[inline(always)]
    fn ambient(&self, phong: &Phong, hit: &scheme::SurfaceHit) -> Vec3 {
        match &self.config.environment {
            Environment::Map { map, frame } => {
                Vec3::from(hit.color) * map.irradiance(frame, hit.normal) / std::f32::consts::PI
            }
            _ => phong.ambient(hit),
        }
    }

    /// What `ray`, which left the scene after `depth` bounces (drawn with `bounce_pdf` by a
    /// diffuse bounce, else 0), sees: the environment, or the background for a camera ray.
    fn missed(&self, ray: &Ray, depth: u32, bounce_pdf: f32) -> Vec3 {
        let config = self.config;
        if let (0, Some(background)) = (depth, &config.background) {
            return Vec3::from(*background);
        }
        match &config.environment {
            // Met by a diffuse bounce, which the map's own samples could have drawn too.
            Environment::Map { map, frame } if bounce_pdf > 0.0 => {
                map.radiance(frame, ray.dir) * power_heuristic(bounce_pdf, map.pdf(frame, ray.dir))
            }
            environment => environment.radiance(ray.dir),
        }
    }

    /// The nearest surface along `ray`, a splat or the ground in front of it, and its material.
    /// Camera rays (`primary`) that meet a splat are counted.
    fn closest(&mut self, ray: &Ray, primary: bool) -> Option<(scheme::SurfaceHit, Material)> {
        let config = self.config;
        let splat = scheme::intersect(self.accel, ray, &config.scheme, &mut self.stats.traversal);
        let t_max = splat.map_or(f32::INFINITY, |hit| hit.t);
        if let Some(ground) = &config.ground
            && let Some(hit) = ground.intersect(ray, t_max)
        {
            return Some((hit, ground.material));
        }
        let hit = splat?;
        if primary {
            self.stats.primary_hits += 1;
            self.stats.blended_splats += u64::from(hit.blended);
        }
        let index = usize::from(self.accel.splat(hit.splat).material());
        let material = config.materials.get(index).or(config.materials.first()).copied();
        Some((hit, material.unwrap_or(Material::standard())))
    }

    /// Whether anything, a splat or the ground, meets `ray` before `t_max`.
    fn occluded(&mut self, ray: &Ray, t_max: f32) -> bool {
        self.config.ground.is_some_and(|ground| ground.blocks(ray, t_max))
            || scheme::occluded(self.accel, ray, t_max, &self.config.scheme, &mut self.stats.traversal)
    }

    /// Calls `lit` with the direction towards each light that `hit` faces and sees (one
    /// shadow ray each, aimed at a random point of an area light), and its irradiance there.
    fn visible_lights(&mut self, ray: &Ray, hit: &scheme::SurfaceHit, mut lit: impl FnMut(Vec3, f32)) {
        let config = self.config;
        for light in &config.lights {
            let (to_light, _, irradiance) = light.towards(hit.position);
            if hit.normal.dot(to_light) <= 0.0 {
                continue;
            }
            let visible = !config.shadows || {
                let u = if light.is_area() { [self.rng.next(), self.rng.next()] } else { [0.5; 2] };
                let (direction, distance) = light.shadow_target(hit.position, u);
                !self.in_shadow(ray, hit, direction, distance)
            };
            if visible {
                lit(to_light, irradiance);
            }
        }
    }

    /// The path tracer at a diffuse hit: each light's direct light (albedo × irradiance ×
    /// cos θ if the shadow ray is free, which is the albedo/π BRDF under the light's
    /// radiometric irradiance, π times its scale; see [`Light`]) and its highlight (`phong`'s
    /// lobe, as Whitted draws it), plus the light one cosine-distributed bounce brings, which
    /// for that distribution weighs exactly the albedo.
    fn diffuse(&mut self, ray: &Ray, hit: &scheme::SurfaceHit, phong: &Phong, depth: u32, inside: bool) -> Vec3 {
        let albedo = Vec3::from(hit.color);
        let mut color = Vec3::ZERO;
        self.visible_lights(ray, hit, |to_light, irradiance| {
            color += albedo * (irradiance * hit.normal.dot(to_light));
            color += phong.glossy(hit.normal, -ray.dir, to_light, irradiance);
        });
        color += albedo * self.environment_sample(ray, hit);
        if depth >= self.config.max_depth {
            return color;
        }
        // Russian roulette after three bounces: stop dim paths early, weigh the survivors up.
        let survive = if depth < 3 { 1.0 } else { albedo.max_element().clamp(0.05, 0.95) };
        if self.rng.next() >= survive {
            return color;
        }
        let direction = cosine_direction(hit.normal, [self.rng.next(), self.rng.next()]);
        let mut next = secondary(ray, hit, direction, self.config);
        next.cone.spread = next.cone.spread.max(self.config.diffuse_spread);
        let pdf = direction.dot(hit.normal).max(0.0) / std::f32::consts::PI;
        color + albedo * self.radiance_drawn(&next, depth + 1, inside, pdf) / survive
    }

    /// The path tracer's sample of an environment map at a diffuse hit: the light of one
    /// direction drawn from the map (by its luminance) that the hit faces and sees, times the
    /// Lambert BRDF's 1/π and the cosine over the sample's density, weighed against the bounce
    /// that may meet the same light (the power heuristic; Veach 1997). Zero without a map.
    fn environment_sample(&mut self, ray: &Ray, hit: &scheme::SurfaceHit) -> Vec3 {
        let Environment::Map { map, frame } = &self.config.environment else { return Vec3::ZERO };
        let Some(sample) = map.sample(frame, [self.rng.next(), self.rng.next()]) else { return Vec3::ZERO };
        let cos = hit.normal.dot(sample.dir);
        if cos <= 0.0 || (self.config.shadows && self.in_shadow(ray, hit, sample.dir, f32::INFINITY)) {
            return Vec3::ZERO;
        }
        let bsdf_pdf = cos / std::f32::consts::PI;
        sample.radiance * (bsdf_pdf / sample.pdf * power_heuristic(sample.pdf, bsdf_pdf))
    }

    /// Shadow test from a hit. The ray starts `shadow_offset × k·r` off the surface, on the
    /// light's side, and ignores crossings within k·r of its origin, k the scheme's
    /// `self_hit_radii`: the neighbouring disks of a curved surface stand up to about r off
    /// each other's planes, and a neighbour's ray-facing disk is met wherever the ray passes
    /// near its centre (SJ advise 1–3 r).
    fn in_shadow(&mut self, incoming: &Ray, hit: &scheme::SurfaceHit, to_light: Vec3, light_dist: f32) -> bool {
        self.stats.rays += 1;
        self.stats.shadow_rays += 1;
        // The shadow ray's beam starts as wide as the footprint at the hit (a directional
        // light keeps it that wide), and takes its level of detail from it.
        let mut ray = secondary(incoming, hit, to_light, self.config);
        ray.cone.spread = 0.0;
        self.occluded(&ray, light_dist)
    }
}

/// The weight of a sample drawn with density `pdf` where another strategy would have drawn
/// it with density `other`: pdf² / (pdf² + other²).
fn power_heuristic(pdf: f32, other: f32) -> f32 {
    let (a, b) = (pdf * pdf, other * other);
    if a + b > 0.0 { a / (a + b) } else { 0.0 }
}

/// A direction about unit `normal` distributed as cos θ / π (Malley: uniform on the disk,
/// lifted to the hemisphere), from two uniform numbers.
fn cosine_direction(normal: Vec3, u: [f32; 2]) -> Vec3 {
    let (a, b) = crate::math::orthonormal_basis(normal);
    let (r, phi) = (u[0].sqrt(), std::f32::consts::TAU * u[1]);
    (a * (r * phi.cos()) + b * (r * phi.sin()) + normal * (1.0 - u[0]).max(0.0).sqrt()).normalize()
}

/// A reflected, refracted or shadow ray from `hit`: it starts `shadow_offset × k·r` off the
/// surface on its own side and ignores crossings within k·r of its origin (k the scheme's
/// `self_hit_radii`), and its beam starts as wide as the incoming ray's footprint and keeps
/// spreading at its rate (a flat interface's).
fn secondary(incoming: &Ray, hit: &scheme::SurfaceHit, direction: Vec3, config: &RenderConfig) -> Ray {
    let reach = config.scheme.self_hit_radii() * hit.radius;
    let side = if direction.dot(hit.normal) >= 0.0 { 1.0 } else { -1.0 };
    let origin = hit.position + hit.normal * (side * config.shadow_offset * reach);
    let cone = crate::math::RayCone { width0: incoming.cone.width_at(hit.t), spread: incoming.cone.spread };
    Ray::new(origin, direction, cone).with_t_min(reach).with_lod_threshold(config.lod_threshold)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Full frames keep bands of a tile's height; a short region gets bands enough for every
    /// thread to take several (`determinism.rs` checks that the image does not change).
    #[test]
    fn short_regions_get_thin_bands() {
        assert_eq!(band_rows(1024, 2), TILE);
        assert_eq!(band_rows(41, 2), 1);
        assert_eq!(band_rows(41, 1), 2);
        assert_eq!(band_rows(3, 64), 1);
        assert_eq!(band_rows(0, 0), 1);
    }

    #[test]
    fn the_tent_filter_maps_uniform_numbers_to_its_density() {
        // Symmetric, within one pixel, and |offset| averages 1/3 under a tent of radius 1.
        let n = 100_000;
        let offsets: Vec<f32> = (0..n).map(|i| tent((i as f32 + 0.5) / n as f32)).collect();
        assert!(offsets.iter().all(|o| o.abs() <= 1.0));
        assert!(offsets.iter().sum::<f32>().abs() < 1e-2);
        assert!((offsets.iter().map(|o| o.abs()).sum::<f32>() / n as f32 - 1.0 / 3.0).abs() < 1e-3);
    }

    #[test]
    fn r2_points_fill_the_square_evenly() {
        // 64 points in an 8 × 8 grid: R2 puts at most 2 in a cell and leaves 10 empty
        // (measured); independent points leave about 23 empty (64 × (63/64)^64).
        let count = |points: &mut dyn Iterator<Item = [f32; 2]>| {
            let mut cells = [0u32; 64];
            points.for_each(|[u, v]| cells[(u * 8.0) as usize * 8 + (v * 8.0) as usize] += 1);
            (cells.iter().filter(|&&c| c == 0).count(), *cells.iter().max().unwrap())
        };
        let (empty, most) = count(&mut (0..64).map(|i| r2(i, [0.3, 0.7])));
        let mut rng = sample_rng(1, 2, 3, 4);
        let (random_empty, random_most) = count(&mut (0..64).map(|_| [rng.random(), rng.random()]));
        assert!(most <= 2 && empty <= 12, "R2: {empty} empty cells, at most {most} in one");
        assert!(random_empty > empty && random_most > most, "independent: {random_empty} empty, {random_most} in one");
    }

    #[test]
    fn a_pixels_samples_spread_evenly_in_each_pair_of_dimensions_then_go_on_at_random() {
        // 64 samples of one pixel, each drawing LD_DIMS + 2 numbers, in an 8 × 8 grid: each pair
        // spreads as R2 does (at most 12 empty cells), pairs of numbers from two pairs as
        // independent ones do (about 23), and so do the two past LD_DIMS.
        let draws: Vec<Vec<f32>> = (0..64)
            .map(|i| {
                let mut rng = SampleRng::new(1, 5, 6, i, Some((sample_key(1, 5, 6, u32::MAX), 64)));
                (0..LD_DIMS + 2).map(|_| rng.next()).collect()
            })
            .collect();
        let empty = |a: usize, b: usize| {
            let mut cells = [0u32; 64];
            draws.iter().for_each(|d| cells[(d[a] * 8.0) as usize * 8 + (d[b] * 8.0) as usize] += 1);
            cells.iter().filter(|&&c| c == 0).count()
        };
        for a in 0..LD_DIMS {
            for b in a + 1..LD_DIMS {
                let (e, paired) = (empty(a, b), a % 2 == 0 && b == a + 1);
                assert!(if paired { e <= 12 } else { (12..=34).contains(&e) }, "dimensions {a} and {b}: {e} empty");
            }
        }
        assert!(empty(LD_DIMS, LD_DIMS + 1) > 12, "{}", empty(LD_DIMS, LD_DIMS + 1));
        assert!(draws.iter().flatten().all(|u| (0.0..1.0).contains(u)));
    }

    #[test]
    fn permutations_are_bijections() {
        for n in [1, 2, 3, 5, 16, 17, 100, 1000] {
            let mut seen: Vec<u32> = (0..n).map(|i| permute(i, n, 42 + u64::from(n))).collect();
            seen.sort_unstable();
            assert_eq!(seen, (0..n).collect::<Vec<_>>(), "n = {n}");
        }
    }
}
