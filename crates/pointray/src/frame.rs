//! A rendered frame ([`crate::scene::render`]'s result): the film of the rendered region, the
//! work counted, and the images a program writes from it (the 8-bit sRGB frame, the AOVs as
//! images or as float channels), the same for every front end.

use serde::Serialize;

use crate::accel::NodeBounds;
use crate::camera::Region;
use crate::color::linear_to_srgb;
use crate::film::{Film, FirstHitChannels, ToneMap};
use crate::render::Integrator;
use crate::settings::Cull;
use crate::stats::RenderStats;

/// Arbitrary output variables: channels recorded beside the radiance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Aov {
    /// A heat map of the accelerator nodes visited per pixel.
    Nodes,
    /// The camera rays' shading normals, as RGB = (n + 1) / 2.
    Normal,
    /// The distance to the first hit, nearest white, farthest dark, misses black.
    Depth,
    /// The surface colour, unlit.
    Albedo,
    /// The coverage: the fraction of the pixel's camera samples that hit something (the
    /// alpha of a PNG with `--transparent`, the `A` layer of an EXR).
    Alpha,
}

impl Aov {
    pub fn name(self) -> &'static str {
        match self {
            Aov::Nodes => "nodes",
            Aov::Normal => "normal",
            Aov::Depth => "depth",
            Aov::Albedo => "albedo",
            Aov::Alpha => "alpha",
        }
    }
}

/// One rendered frame.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The rendered region's pixels.
    pub film: Film,
    pub stats: RenderStats,
    /// The whole frame's size, of which the film covers `film.region`.
    pub width: u32,
    pub height: u32,
    /// The flat colour outside the region (linear).
    pub background: [f32; 3],
}

impl Frame {
    /// The whole frame as 8-bit sRGB through `tone` (what a PNG stores).
    pub fn srgb8(&self, tone: ToneMap) -> Vec<u8> {
        self.film.frame_srgb8(self.width, self.height, self.background, tone)
    }

    /// The whole frame's linear radiance, row-major, top row first (the background outside
    /// the region): what [`Self::srgb8`] encodes.
    pub fn linear_rgb(&self) -> Vec<[f32; 3]> {
        self.whole(self.background, |i| self.film.rgb[i])
    }

    /// The whole frame, row-major: `fill` outside the film's region, `value(i)` at the region's
    /// pixel `i`.
    fn whole<T: Copy>(&self, fill: T, value: impl Fn(usize) -> T) -> Vec<T> {
        let mut out = vec![fill; self.width as usize * self.height as usize];
        let r = self.film.region;
        let width = r.width() as usize;
        for (row, y) in (r.y0..r.y1).enumerate() {
            let start = y as usize * self.width as usize + r.x0 as usize;
            for (col, px) in out[start..start + width].iter_mut().enumerate() {
                *px = value(row * width + col);
            }
        }
        out
    }

    /// The whole frame as 8-bit sRGB with alpha (RGBA): the coverage as alpha, and the colour
    /// with the background's share taken out (exact for a flat background, which each missed
    /// sample adds), so that the image composites over any other. Needs the alpha AOV.
    ///
    /// # Panics
    /// If the render did not record the first hits (`Settings::aovs` with `Aov::Alpha`).
    pub fn srgba8(&self, tone: ToneMap) -> Vec<u8> {
        self.srgba(tone.encoder(), |alpha| (alpha * 255.0 + 0.5) as u8)
    }

    /// [`Self::srgb8`] at 16 bits a channel (a 16-bit PNG's samples).
    pub fn srgb16(&self, tone: ToneMap) -> Vec<u16> {
        let encode = tone.encoder16();
        let (rgb, background) = (&self.film.rgb, self.background.map(&encode));
        self.whole(background, |i| rgb[i].map(&encode)).into_iter().flatten().collect()
    }

    /// [`Self::srgba8`] at 16 bits a channel.
    ///
    /// # Panics
    /// As [`Self::srgba8`].
    pub fn srgba16(&self, tone: ToneMap) -> Vec<u16> {
        self.srgba(tone.encoder16(), |alpha| (alpha * 65535.0 + 0.5) as u16)
    }

    /// RGBA with the colour un-composited from the background (see [`Self::srgba8`]), each
    /// colour channel by `encode`, the coverage (clamped to [0, 1]) by `alpha`.
    fn srgba<T: Copy + Default>(&self, encode: impl Fn(f32) -> T, alpha_of: impl Fn(f32) -> T) -> Vec<T> {
        let coverage = &self.first_hits().coverage;
        let pixel = |i: usize| {
            let alpha = coverage[i];
            if alpha <= 0.0 {
                return [T::default(); 4];
            }
            let [r, g, b] =
                std::array::from_fn(|c| encode((self.film.rgb[i][c] - (1.0 - alpha) * self.background[c]) / alpha));
            [r, g, b, alpha_of(alpha.clamp(0.0, 1.0))]
        };
        self.whole([T::default(); 4], pixel).into_iter().flatten().collect()
    }

    /// Most nodes visited by one pixel (the top of the node heat map's scale).
    pub fn nodes_max(&self) -> u32 {
        self.film.nodes_visited.iter().copied().max().unwrap_or(0)
    }

    /// An AOV as the whole frame in 8-bit RGB, black outside the region.
    ///
    /// # Panics
    /// If the AOV is a first hit's and the render did not record them (`Settings::aovs`).
    pub fn aov_rgb8(&self, aov: Aov) -> Vec<u8> {
        let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
        let region: Vec<u8> = match aov {
            Aov::Nodes => crate::metrics::heat_map_rgb8(&self.film.nodes_visited, self.nodes_max()),
            Aov::Normal => self.first_hits().normal.iter().flat_map(|n| n.map(|c| byte(0.5 * c + 0.5))).collect(),
            Aov::Albedo => {
                let linear = &self.first_hits().albedo;
                linear.iter().flat_map(|c| c.map(|v| byte(linear_to_srgb(v)))).collect()
            }
            Aov::Alpha => self.first_hits().coverage.iter().flat_map(|&a| [byte(a); 3]).collect(),
            Aov::Depth => {
                let depth = &self.first_hits().depth;
                let finite = depth.iter().copied().filter(|d| d.is_finite());
                let (near, far) = finite.fold((f32::INFINITY, 0.0f32), |(lo, hi), d| (lo.min(d), hi.max(d)));
                let range = (far - near).max(f32::MIN_POSITIVE);
                let shade = |d: f32| if d.is_finite() { byte(1.0 - 0.8 * (d - near) / range) } else { 0 };
                depth.iter().flat_map(|&d| [shade(d); 3]).collect()
            }
        };
        self.whole([0; 3], |i| [region[3 * i], region[3 * i + 1], region[3 * i + 2]]).into_iter().flatten().collect()
    }

    /// The linear radiance as channels `R`, `G`, `B` (the background outside the region) and
    /// each AOV as named float channels (`depth.Z`, `normal.X`, …), each the whole frame: the
    /// layers of an EXR.
    pub fn float_channels(&self, aovs: &[Aov]) -> Vec<(String, Vec<f32>)> {
        let film = &self.film;
        let whole = |value: &dyn Fn(usize) -> f32, fill: f32| self.whole(fill, value);
        let mut channels: Vec<(String, Vec<f32>)> = ["R", "G", "B"]
            .iter()
            .enumerate()
            .map(|(c, name)| (name.to_string(), whole(&|i| film.rgb[i][c], self.background[c])))
            .collect();
        let mut add = |name: String, value: &dyn Fn(usize) -> f32, fill: f32| {
            if !channels.iter().any(|(n, _)| *n == name) {
                channels.push((name, whole(value, fill)));
            }
        };
        for aov in aovs {
            match aov {
                Aov::Nodes => add("nodes.Y".into(), &|i| film.nodes_visited[i] as f32, 0.0),
                Aov::Alpha => add("A".into(), &|i| self.first_hits().coverage[i], 0.0),
                Aov::Depth => add("depth.Z".into(), &|i| self.first_hits().depth[i], f32::INFINITY),
                Aov::Normal => {
                    for (c, axis) in ["X", "Y", "Z"].iter().enumerate() {
                        add(format!("normal.{axis}"), &|i| self.first_hits().normal[i][c], 0.0);
                    }
                }
                Aov::Albedo => {
                    for (c, name) in ["R", "G", "B"].iter().enumerate() {
                        add(format!("albedo.{name}"), &|i| self.first_hits().albedo[i][c], 0.0);
                    }
                }
            }
        }
        channels
    }

    fn first_hits(&self) -> &FirstHitChannels {
        self.film.first_hits.as_ref().expect("the render records the first hits whenever their AOVs are asked for")
    }
}

/// What a frame rendered and how: the resolved settings, the scene's accelerator, the work
/// counted (zero unless `Settings::count_work`). `pointray render --stats` writes it.
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub points: usize,
    pub width: u32,
    pub height: u32,
    pub region: Region,
    pub accel: &'static str,
    pub surface: &'static str,
    pub integrator: Integrator,
    /// Ambient occlusion's reach, with `integrator` "ao".
    pub ao_distance: Option<f32>,
    /// The materials, by index (one per cloud of a scene).
    pub materials: Vec<&'static str>,
    /// The analytic ground plane's material, if there is one.
    pub ground: Option<&'static str>,
    /// What the points' colours show, and the class filter (the classes drawn, all if null,
    /// less those left out).
    pub color_by: crate::color_by::ColorBy,
    pub classes: Option<Vec<u8>>,
    pub exclude_classes: Vec<u8>,
    /// Eye-dome lighting's strength; 0 off.
    pub edl: f32,
    /// The clip: the box and half-spaces kept (file coordinates).
    pub clip_box: Option<crate::clip::ClipBox>,
    pub clip_planes: Vec<crate::clip::ClipPlane>,
    pub samples_per_pixel: u32,
    pub rays: u64,
    pub primary_rays: u64,
    /// Reflected and refracted rays (mirrors and glass).
    pub secondary_rays: u64,
    pub shadow_rays: u64,
    pub hit_fraction: f64,
    pub nodes_visited_per_ray: f64,
    pub splat_tests_per_ray: f64,
    pub box_tests_per_ray: f64,
    pub sphere_tests_per_ray: f64,
    pub lod_stops_per_ray: f64,
    pub culled_per_ray: f64,
    pub blended_splats_per_hit: f64,
    /// PSS projection steps per camera-ray hit (0 for the other schemes).
    pub pss_steps_per_hit: f64,
    /// Fraction of PSS hits that kept the SJ seed (the projection did not converge).
    pub pss_fallback_fraction: f64,
    /// Level-of-detail threshold in pixels; null at full detail.
    pub lod_threshold: Option<f32>,
    /// Whether camera rays went through the footprint prefilter: asked for, and the normals
    /// face the view (else it warns and renders without).
    pub prefilter: bool,
    pub culling: CullingReport,
    pub node_bounds: NodeBounds,
    pub nodes: usize,
    pub sphere_nodes: usize,
    pub bytes_per_node: usize,
    /// Most nodes visited by one pixel (the top of the `nodes` AOV's scale).
    pub nodes_visited_max_per_pixel: u32,
    pub accel_bytes: usize,
    /// The accelerator with its splats, per splat.
    pub bytes_per_splat: f64,
    pub mean_radius: f64,
    pub bounds_diagonal: f32,
    pub camera_distance: Option<f32>,
    /// The camera's up: the settings', else the data's (+z for LAS, LAZ and E57, −y for an
    /// organised depth frame, a prepared PLY's own), else +y.
    pub up: [f32; 3],
    /// The named framing, if one was asked for.
    pub view: Option<crate::settings::ViewPreset>,
    /// The instruction-set path the kernels ran on (`pointray::accel::isa`).
    pub isa: crate::accel::isa::Isa,
    pub counters: RenderStats,
}

#[derive(Clone, Debug, Serialize)]
pub struct CullingReport {
    pub mode: Cull,
    pub enabled: bool,
    /// Fraction of rays from around the model whose first disk faces away (the auto check).
    pub backfacing_fraction: Option<f64>,
}
