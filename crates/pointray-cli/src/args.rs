//! Command-line arguments (clap derive).

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, ValueEnum};
use pointray::color_by::ColorBy;
use pointray::film::ToneCurve;
use pointray::frame::Aov;
use pointray::render::{Filter, Integrator, Sampler};
use pointray::settings::{AccelKind, Cull, MaterialPreset, Projection, Settings};
use pointray::splat::scheme::SurfaceKind;

/// The settings' defaults, which the flags' defaults are.
static D: std::sync::LazyLock<Settings> = std::sync::LazyLock::new(Settings::default);

#[derive(Parser, Debug)]
#[command(name = "pointray", version, about = "Ray tracing of point clouds rendered directly as splats")]
#[command(after_help = "Examples:
  pointray render -o demo.png                         the built-in demo scene
  pointray render bunny.ply -o bunny.png --width 800 --height 800
  pointray render dragon.ply -o d.png --distance 4 --crop-to-model --stats d.json
  pointray prepare scan.ply -o scan_prepared.ply      compute normals and radii once
  pointray sample mesh.ply -n 5000000 -o dense.ply    a dense cloud from a mesh
  pointray info scan.ply

Exit status: 0 success, 1 bad or unreadable input, 2 bad command line, 3 output not writable,
130 interrupted (Ctrl-C). No output file is left half-written.")]
pub struct Cli {
    /// More log output (-v: info, -vv: debug, -vvv: trace).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    /// Only errors; no progress bars.
    #[arg(short, long, global = true)]
    pub quiet: bool,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Render a point cloud (or the built-in demo scene) to a PNG.
    #[command(after_help = "Examples:
  pointray render -o demo.png
  pointray render bun_zipper.ply -o bunny.png --surface sj --spp 4
  pointray render dragon.ply -o d.png --view-dir 0.4,0.3,1 --distance 16 --crop-to-model --stats s.json
  pointray render scan.ply -o s.png --eye 0,0.1,0.4 --look-at 0,0.1,0 --fov 40")]
    Render(Box<RenderArgs>),
    /// Compute what a cloud lacks (normals, orientation, radii), sort it, and write a binary PLY.
    #[command(after_help = "Example:
  pointray prepare bun_zipper.ply -o bunny_prepared.ply")]
    Prepare(PrepareArgs),
    /// Place N points uniformly over a triangle mesh's surface, with its smooth (or face) normals.
    #[command(after_help = "Example:
  pointray sample dragon_vrip_res2.binary_le.ply -n 20000000 -o dragon_20m.ply")]
    Sample(SampleArgs),
    /// Look at a cloud (or the demo, or a scene file) in the browser: a local web server whose
    /// page orbits, pans and zooms, refining each view while it rests.
    #[command(after_help = "Examples:
  pointray view bun_zipper.ply
  pointray view dragon.ply --port 8766 --no-open")]
    View(ViewArgs),
    /// Describe a point-cloud file: format, elements, properties, bounds.
    #[command(after_help = "Example:
  pointray info dragon.ply")]
    Info(InfoArgs),
    /// Compare two PNGs of the same size: PSNR, RMSE, largest channel difference, pixels that
    /// differ, and the perceptual difference (mean FLIP).
    #[command(after_help = "Examples:
  pointray compare bvh.png brute.png
  pointray compare new.png golden.png --json")]
    Compare(CompareArgs),
    /// Measure an experiment's matrix (models × accelerators × schemes × level of detail ×
    /// distance), beside Embree if it names Embree's bench; write JSON lines and CSV.
    #[command(after_help = "Examples:
  pointray bench experiments/thesis.toml --out results/thesis
  pointray bench experiments/thesis.toml --models bunny --dry-run")]
    #[cfg(feature = "bench")]
    Bench(BenchArgs),
    /// Write the Markdown report of a bench run, with its figures (SVG and PNG) and image pairs.
    #[command(after_help = "Example:
  pointray report results/thesis -o docs/RESULTS.md")]
    #[cfg(feature = "bench")]
    Report(ReportArgs),
}

/// How to read the input where its content does not say.
#[derive(Args, Clone, Debug, Default)]
pub struct ReadArgs {
    /// The input is text with these columns, in order (comma-separated: x,y,z, nx,ny,nz, r,g,b,
    /// a (alpha), i (intensity), c (class), return, t (GPS time), _ (a column to skip)), for a
    /// layout the first line cannot tell: e.g. --columns x,y,z,r,g,b,i.
    #[arg(long)]
    pub columns: Option<pointray_io::TextColumns>,
}

impl ReadArgs {
    pub fn options(&self) -> pointray_io::ReadOptions {
        pointray_io::ReadOptions { columns: self.columns.clone() }
    }
}

#[derive(Args, Clone, Debug)]
pub struct PreprocessArgs {
    /// Neighbours for PCA normals.
    #[arg(long, default_value_t = pointray::preprocess::PreprocessConfig::standard().k_normals)]
    pub k_normals: usize,
    /// Neighbours for the splat radius.
    #[arg(long, default_value_t = pointray::preprocess::PreprocessConfig::standard().k_radius)]
    pub k_radius: usize,
    /// Scale applied to the computed radii.
    #[arg(long, default_value_t = pointray::preprocess::PreprocessConfig::standard().radius_scale)]
    pub radius_scale: f32,
    /// Points whose computed radius would exceed 8 times their neighbours' median (stray
    /// returns, no-return pixels stored at the origin): drop them, or clamp their radii.
    #[arg(long, value_enum, default_value_t = pointray::preprocess::PreprocessConfig::standard().strays)]
    pub strays: pointray::preprocess::Strays,
    /// Statistical outlier removal (as PCL's and Open3D's): drop the points whose mean distance
    /// to their --k-normals nearest neighbours exceeds the cloud's mean by this many standard
    /// deviations (1 to 2 is usual). Off by default.
    #[arg(long)]
    pub outlier_std: Option<f32>,
    /// Recompute normals and radii even when the file has them.
    #[arg(long)]
    pub recompute: bool,
}

#[derive(Args, Clone, Debug)]
pub struct RenderArgs {
    /// Point cloud (PLY, LAS/LAZ, E57, PCD, XYZ/PTS, the vertices of an OFF or OBJ mesh, or a Stanford scan set .conf; recognised by
    /// content), or a scene file (.toml: several clouds, materials, lights; see
    /// scenes/README.md); several clouds are the tiles of one survey, read as one; none
    /// renders the built-in demo scene.
    #[arg(value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
    /// Output image, written atomically: NAME.png (sRGB, tone-mapped, 8 or --bit-depth 16 bits)
    /// or NAME.exr (linear 32-bit float, with the --aov layers).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Image width in pixels.
    #[arg(long, default_value_t = D.width)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = D.height)]
    pub height: u32,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Acceleration structure: the multiresolution BVH; the SAH kd-tree with level of detail
    /// (no normal cones: culling and spheres apply to the BVH only); brute force, which tests every
    /// splat (the reference for tests).
    #[arg(long, value_enum, default_value_t = D.accel)]
    pub accel: AccelKind,
    #[command(flatten)]
    pub build: BuildArgs,
    /// SJ and RFD interpolation window, in radii of the first disk hit [default: 1 for SJ and
    /// PSS, 2 for RFD].
    #[arg(long)]
    pub sj_window: Option<f32>,
    /// SJ and RFD: least coverage Σ(1 − d/r) of the disks in a window for it to count as
    /// surface (lone disks crossed at their rims are skipped).
    #[arg(long, default_value_t = D.sj_min_coverage)]
    pub sj_min_coverage: f32,
    /// SJ and RFD: the same for a window whose disks face away from the viewer (seen past a
    /// silhouette or through a gap; a thin part seen from behind is covered and still shows,
    /// unless the near side lies just behind it: a crest's far side sticking out over it).
    #[arg(long, default_value_t = D.sj_min_coverage_facing_away)]
    pub sj_min_coverage_facing_away: f32,
    /// Samples per pixel (jittered, anti-aliasing).
    #[arg(long, default_value_t = D.spp)]
    pub spp: u32,
    /// Seed of the per-pixel random numbers (and of the demo scene's points).
    #[arg(long, default_value_t = D.seed)]
    pub seed: u64,

    /// perspective, or orthographic: parallel rays (plans, elevations, façades), at the scale
    /// the perspective view has at the point it looks at (--fov and --distance still frame it).
    #[arg(long, value_enum, default_value_t = D.projection)]
    pub projection: Projection,
    /// Camera position, in the file's coordinates (then --look-at is needed).
    #[arg(long, allow_hyphen_values = true, value_parser = parse_dvec3, requires = "look_at")]
    pub eye: Option<glam::DVec3>,
    /// The point the camera looks at, in the file's coordinates.
    #[arg(long, allow_hyphen_values = true, value_parser = parse_dvec3, requires = "eye")]
    pub look_at: Option<glam::DVec3>,
    /// Camera up vector, which the sky and the ground take too [default: the data's: +z for
    /// LAS and LAZ, else +y].
    #[arg(long, allow_hyphen_values = true, value_parser = parse_vec3)]
    pub up: Option<glam::Vec3>,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = D.fov)]
    pub fov: f32,
    /// Where a pixel's samples go: r2 (a low-discrepancy sequence) or random.
    #[arg(long, value_enum, default_value_t = D.sampler)]
    pub sampler: Sampler,
    /// Reconstruction filter: box (the pixel) or tent (two pixels wide, smoother edges); with
    /// --spp 1 the one sample goes through the pixel's centre.
    #[arg(long, value_enum, default_value_t = D.filter)]
    pub filter: Filter,
    /// How a PNG shows radiance: clamp (exactly, up to 1; brighter clips to white) or filmic
    /// (an ACES-like curve that rolls highlights off). EXR output is always linear.
    #[arg(long, value_enum, default_value_t = D.tonemap)]
    pub tonemap: ToneCurve,
    /// Exposure of a PNG in stops: radiance × 2^EXPOSURE before the tone map.
    #[arg(long, default_value_t = D.exposure, allow_hyphen_values = true)]
    pub exposure: f32,
    /// Depth of field: the lens radius, in the model's units (0: everything sharp).
    #[arg(long, default_value_t = D.lens_radius)]
    pub lens_radius: f32,
    /// Depth of field: the distance in focus (default: to the point looked at).
    #[arg(long)]
    pub focus_distance: Option<f32>,
    /// Direction from the model's centre to the camera, when no --eye [default: 0.4,0.3,1;
    /// the demo has its own].
    #[arg(long, allow_hyphen_values = true, value_parser = parse_vec3, conflicts_with = "eye")]
    pub view_dir: Option<glam::Vec3>,
    /// A named framing, turned with the data's up axis: top (a plan), front, side (elevations)
    /// or iso; with --projection orthographic, to scale.
    #[arg(long, value_enum, conflicts_with_all = ["eye", "view_dir"])]
    pub view: Option<pointray::settings::ViewPreset>,
    /// Camera distance from the model's centre, in bounding-box diagonals, when no --eye
    /// [default: 1; the demo has its own].
    #[arg(long, conflicts_with = "eye")]
    pub distance: Option<f32>,
    /// Render only this pixel rectangle of the frame: X0,Y0,X1,Y1 (X1, Y1 exclusive).
    #[arg(long, value_parser = parse_region, conflicts_with = "crop_to_model")]
    pub region: Option<pointray::camera::Region>,
    /// Render only the pixels inside the model's projected bounding box.
    #[arg(long)]
    pub crop_to_model: bool,

    /// Directional light: direction towards the light (default: from the camera, raised; a survey
    /// (LAS, LAZ) has a sun from the north-west at 45°; an --env-map lights alone).
    #[arg(long, allow_hyphen_values = true, value_parser = parse_vec3, conflicts_with = "light_pos")]
    pub light_dir: Option<glam::Vec3>,
    /// Point light position instead, in the file's coordinates.
    #[arg(long, allow_hyphen_values = true, value_parser = parse_dvec3)]
    pub light_pos: Option<glam::DVec3>,
    /// With --light-pos: a spherical light of this radius (file units) instead of a point,
    /// for soft shadows (noisy at low --spp; they converge as it grows).
    #[arg(long, requires = "light_pos")]
    pub light_radius: Option<f32>,
    /// Light intensity: the radiance a white Lambert surface facing the light shows, in every
    /// integrator (Whitted's Phong shows 1 − ambient of it); a point light's falls off with
    /// the squared distance from 1.
    #[arg(long, default_value_t = D.light_intensity)]
    pub light_intensity: f32,
    /// No shadow rays.
    #[arg(long)]
    pub no_shadows: bool,
    /// Shadow- and secondary-ray start offset, in splat radii.
    #[arg(long, default_value_t = D.shadow_offset)]
    pub shadow_offset: f32,
    /// What the points are made of: phong (lit by the light, with shadows), mirror, or glass
    /// (Fresnel reflection and refraction, --ior).
    #[arg(long, value_enum, default_value_t = D.material)]
    pub material: MaterialPreset,
    /// Index of refraction of --material glass.
    #[arg(long, default_value_t = D.ior)]
    pub ior: f32,
    /// whitted: direct light, shadows, reflection and refraction; path: a path tracer (global
    /// illumination: light bouncing between diffuse surfaces and from the sky; needs many --spp).
    #[arg(long, value_enum, default_value_t = D.integrator)]
    pub integrator: Integrator,
    /// --integrator ao: how far a surface looks for what occludes it (default: a tenth of the
    /// model's bounding-box diagonal).
    #[arg(long)]
    pub ao_distance: Option<f32>,
    /// --integrator path: the least spread of a diffusely bounced ray's cone (beam width per
    /// unit length), from which its level of detail follows; 0 keeps the camera ray's. The
    /// default, 0.1, renders a path-traced dragon 1.23-1.31x faster, 54 dB from full detail, where
    /// the Monte Carlo noise itself is 40 dB (docs/path-lod.md).
    #[arg(long, default_value_t = D.diffuse_spread)]
    pub diffuse_spread: f32,
    /// Bounces a path may take (off mirrors and glass; with --integrator path, any).
    #[arg(long, default_value_t = D.max_depth)]
    pub max_depth: u32,
    /// An analytic floor under the model: a checkered plane just below its bounding box
    /// along --up, which it stands on and shadows.
    #[arg(long)]
    pub ground: bool,
    /// A sky-blue gradient above a grey ground around the scene, instead of the dark
    /// background (what mirrors and glass show). A survey (LAS, LAZ) has this sky already for
    /// the light that bounces; --sky shows it behind the model too.
    #[arg(long)]
    pub sky: bool,
    /// An HDR panorama around the model (equirectangular Radiance .hdr or OpenEXR .exr, linear
    /// radiance): what rays that leave the scene see, and the light (the path tracer samples it;
    /// Whitted's Phong takes its light as the ambient term), with no headlight unless
    /// --light-dir or --light-pos adds a light. Row 0 is straight up (--up).
    #[arg(long, value_name = "FILE")]
    pub env_map: Option<PathBuf>,
    /// Degrees the --env-map turns about the up axis, anticlockwise seen from above.
    #[arg(long, default_value_t = D.env_rotation, allow_negative_numbers = true)]
    pub env_rotation: f32,
    /// Eye-dome lighting, the depth cue of Potree and CloudCompare: a pixel darkens where its
    /// neighbours are nearer, outlining the edges of nearer surfaces over farther ones, the
    /// model against the background, and creases; the strength (1 is Potree's default), 0 off.
    #[arg(long, default_value_t = D.edl)]
    pub edl: f32,

    /// Level of detail: a subtree narrower than this many pixels (its bounding sphere's
    /// radius against the ray's footprint) is drawn as its representative splat; 0 is full
    /// detail, as --lod off is.
    #[arg(long, default_value_t = D.lod_threshold)]
    pub lod_threshold: f32,
    /// Level of detail on or off (off: every ray descends to the input splats).
    #[arg(long, value_enum, default_value_t = Switch::On)]
    pub lod: Switch,
    /// Level of detail as a prefilter: where the pixel's footprint is wide enough for level
    /// of detail, the camera ray gathers what its pixel covers (partly covered pixels blended
    /// with what lies behind, rough patches shaded as such), so one ray a pixel looks like
    /// many. One sample a pixel, Whitted and eye-light, normals facing the view (a closed
    /// scan's outward, a range scan's or survey's seen from the side it was scanned from).
    #[arg(long)]
    pub prefilter: bool,
    /// Normal-cone backface culling for camera rays; auto turns it on when rays from around
    /// the model meet almost no back faces first (a closed, consistently oriented surface).
    /// Off by default: front-to-back traversal already skips what lies behind the first hit,
    /// and culling measured slower (docs/multires.md).
    #[arg(long, value_enum, default_value_t = D.cull)]
    pub cull: Cull,
    /// A PNG with alpha: the background transparent (the coverage as alpha, the colour with a
    /// flat background's share taken out), to composite over anything; an EXR gets an A layer.
    #[arg(long)]
    pub transparent: bool,
    /// Bits a channel of the PNG: 8, or 16 for grading and compositing without banding (the
    /// AOVs' PNGs stay 8-bit; an EXR is float).
    #[arg(long, default_value_t = 8, value_parser = parse_bit_depth)]
    pub bit_depth: u8,
    /// Extra images beside the output, OUTPUT.KIND.png (comma-separated or repeated).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub aov: Vec<Aov>,

    /// Write statistics (timings, rays, traversal work, memory) as JSON.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// A turntable: N frames with the camera turned about the up axis by 360/N degrees each,
    /// written as OUT_0000.png, OUT_0001.png, … (frame 0 is the view the other flags give).
    #[arg(long, default_value_t = 0, conflicts_with_all = ["stats", "aov", "bench_frames"])]
    pub turntable: u32,
    /// The frames of the animation (a scene file's [animation], or --turntable's) to render:
    /// A..B (A to B − 1) or K; all by default. Each is written as OUT_0007.png, or into the #s
    /// of -o out_####.png; -o out.mp4 encodes them with ffmpeg (the PNGs beside it without).
    #[arg(long, value_parser = crate::commands::animation::parse_frames)]
    pub frames: Option<std::ops::Range<u32>>,
    /// Frames a second of an -o .mp4 animation.
    #[arg(long, default_value_t = 30.0, value_parser = positive_fps)]
    pub fps: f32,
    /// Timed frames after one untimed warm-up frame (benchmarking; median and min reported).
    #[arg(long, default_value_t = 0)]
    pub bench_frames: u32,
    /// Builds of the accelerator, the last one kept, their median and min reported
    /// (benchmarking: the first build in a process pays for its fresh memory, as Embree's bench's
    /// first of its `--build-reps` does).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub bench_builds: u32,
    /// Points in the demo scene.
    #[arg(long, default_value_t = pointray::demo::DEMO_POINTS)]
    pub demo_points: usize,
    #[command(flatten)]
    pub read: ReadArgs,
    #[command(flatten)]
    pub preprocess: PreprocessArgs,
    /// The ids (field names) of the flags given on the command line, as opposed to defaults:
    /// a scene file's settings give way to these (`main` fills it in).
    #[arg(skip)]
    pub given: Vec<String>,
}

impl RenderArgs {
    /// Whether the flag of field `id` was given on the command line.
    pub fn given(&self, id: &str) -> bool {
        self.given.iter().any(|g| g == id)
    }

    /// The render settings these flags give.
    pub fn settings(&self) -> Settings {
        Settings {
            width: self.width,
            height: self.height,
            accel: self.accel,
            sphere_from_level: self.build.sphere_from_level,
            surface: self.build.surface,
            sj_window: self.sj_window,
            sj_min_coverage: self.sj_min_coverage,
            sj_min_coverage_facing_away: self.sj_min_coverage_facing_away,
            spp: self.spp,
            seed: self.seed,
            sampler: self.sampler,
            filter: self.filter,
            tonemap: self.tonemap,
            exposure: self.exposure,
            projection: self.projection,
            eye: self.eye,
            look_at: self.look_at,
            up: self.up,
            fov: self.fov,
            lens_radius: self.lens_radius,
            focus_distance: self.focus_distance,
            view_dir: self.view_dir,
            view: self.view,
            distance: self.distance,
            region: self.region,
            crop_to_model: self.crop_to_model,
            light_dir: self.light_dir,
            light_pos: self.light_pos,
            light_radius: self.light_radius,
            light_intensity: self.light_intensity,
            material: self.material,
            ior: self.ior,
            sky: self.sky,
            env_map: self.env_map.clone(),
            env_rotation: self.env_rotation,
            ground: self.ground,
            color_by: self.build.color_by,
            classes: self.build.classes.clone(),
            exclude_classes: self.build.exclude_classes.clone(),
            edl: self.edl,
            clip_box: self.build.clip_box,
            clip_planes: self.build.clip_plane.clone(),
            integrator: self.integrator,
            ao_distance: self.ao_distance,
            diffuse_spread: self.diffuse_spread,
            max_depth: self.max_depth,
            shadows: !self.no_shadows,
            shadow_offset: self.shadow_offset,
            lod_threshold: if self.lod == Switch::On { self.lod_threshold } else { 0.0 },
            prefilter: self.prefilter,
            cull: self.cull,
            // The alpha of --transparent is the coverage AOV.
            aovs: self.aov.iter().copied().chain(self.transparent.then_some(Aov::Alpha)).collect(),
            count_work: self.stats.is_some(),
        }
    }
}

impl PreprocessArgs {
    pub fn config(&self) -> pointray::preprocess::PreprocessConfig {
        pointray::preprocess::PreprocessConfig {
            k_normals: self.k_normals,
            k_radius: self.k_radius,
            radius_scale: self.radius_scale,
            recompute: self.recompute,
            strays: self.strays,
            outlier_std: self.outlier_std,
            ..pointray::preprocess::PreprocessConfig::standard()
        }
    }
}

/// What a scene's accelerator holds: the render's flags that a `.prs` scene file keeps.
#[derive(Args, Debug, Clone)]
pub struct BuildArgs {
    /// How the disks a ray crosses become a surface point.
    #[arg(long, value_enum, default_value_t = D.surface)]
    pub surface: SurfaceKind,
    /// What the points' colours show: auto (the file's colours, else the material's), rgb,
    /// intensity (viridis), classification (the ASPRS class colours), elevation (viridis along
    /// --up) or normal.
    #[arg(long, value_enum, default_value_t = D.color_by)]
    pub color_by: ColorBy,
    /// Draw only the points of these ASPRS classes (comma-separated codes: 2 ground, 6
    /// building, 3-5 vegetation, 9 water, 7 and 18 noise).
    #[arg(long, value_delimiter = ',')]
    pub classes: Option<Vec<u8>>,
    /// Leave out the points of these classes (e.g. 7,18: noise).
    #[arg(long, value_delimiter = ',')]
    pub exclude_classes: Vec<u8>,
    /// Keep only the points inside this box, in the file's coordinates: X0,Y0,Z0,X1,Y1,Z1.
    #[arg(long, allow_hyphen_values = true, value_parser = parse_clip_box)]
    pub clip_box: Option<pointray::clip::ClipBox>,
    /// A section: keep only the points with NX·x + NY·y + NZ·z <= D (file coordinates; the
    /// normal points to the side cut away): NX,NY,NZ,D. May be given several times.
    #[arg(long, allow_hyphen_values = true, value_parser = parse_clip_plane)]
    pub clip_plane: Vec<pointray::clip::ClipPlane>,
    /// Bounding volumes: boxes above this level of the tree (the root is 0), spheres from it
    /// down; "never" for boxes only, "auto" to choose per node by surface area.
    #[arg(long, value_parser = parse_sphere_level, default_value = "never")]
    pub sphere_from_level: pointray::accel::NodeBounds,
}

impl BuildArgs {
    /// Default settings but for what these flags say.
    pub fn settings(&self) -> Settings {
        let b = self.clone();
        let (color_by, classes, exclude_classes) = (b.color_by, b.classes, b.exclude_classes);
        let (clip_box, clip_planes, sphere_from_level) = (b.clip_box, b.clip_plane, b.sphere_from_level);
        Settings {
            surface: b.surface,
            color_by,
            classes,
            exclude_classes,
            clip_box,
            clip_planes,
            sphere_from_level,
            ..Settings::default()
        }
    }
}

#[derive(Args, Debug)]
pub struct PrepareArgs {
    /// Point cloud (PLY, LAS/LAZ, E57, PCD, XYZ/PTS, the vertices of an OFF or OBJ mesh, or a
    /// Stanford scan set .conf); several: the tiles of one survey, prepared as one cloud.
    #[arg(required = true, value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
    /// Output PLY (binary, with normals, radii and any colours; written atomically), or a
    /// scene file (`.prs`: the BVH a default render builds, memory-mapped by `render`).
    #[arg(short, long)]
    pub output: PathBuf,
    #[command(flatten)]
    pub read: ReadArgs,
    #[command(flatten)]
    pub preprocess: PreprocessArgs,
    /// To a `.prs` output: what its BVH holds (a render must ask for the same).
    #[command(flatten)]
    pub build: BuildArgs,
    /// To a `.prs` output: prepare within about this much memory (e.g. 1GiB, 512MiB; K, M, G
    /// are powers of 1024; default: half this machine's): a cloud that would need more in
    /// memory (some 90 bytes a point) is read in passes and built a chunk at a time, with
    /// temporary files beside the output, normals and radii computed a cell at a time: the same
    /// file either way. For now out of core reads binary PLY, LAS/LAZ and E57 files (or
    /// tiles of them); other formats are refused when a budget is asked for, and prepared in memory by
    /// default.
    #[arg(long, value_parser = parse_bytes, value_name = "SIZE")]
    pub memory_budget: Option<u64>,
}

/// A size in bytes: a number, then optionally K, M, G or T (powers of 1024; `KiB`, `KB` alike).
fn parse_bytes(s: &str) -> Result<u64, String> {
    let digits = s.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(s.len());
    let (number, unit) = s.split_at(digits);
    let number: f64 = number.parse().map_err(|_| format!("{s:?}: a size is a number and a unit, as 1GiB"))?;
    let shift = match unit.trim().to_ascii_lowercase().trim_end_matches("ib").trim_end_matches('b') {
        "" => 0,
        "k" => 10,
        "m" => 20,
        "g" => 30,
        "t" => 40,
        other => return Err(format!("{s:?}: unknown unit {other:?} (K, M, G or T)")),
    };
    Ok((number * (1u64 << shift) as f64) as u64)
}

#[derive(Args, Debug)]
pub struct SampleArgs {
    /// Triangle mesh: PLY with a 'face' element, OFF or OBJ (recognised by content).
    pub input: PathBuf,
    /// Points to place on the surface.
    #[arg(short = 'n', long)]
    pub points: u64,
    /// Output PLY (binary, with normals; written atomically).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Random seed: the same seed gives the same points.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// smooth: the vertex normals interpolated (smooth shading; disks near sharp edges lean off
    /// their faces); face: each triangle's own normal (disks lie in their faces, facets show).
    #[arg(long, value_enum, default_value_t = NormalsArg::Smooth)]
    pub normals: NormalsArg,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum NormalsArg {
    Smooth,
    Face,
}

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// Point cloud or scene file, as for `render`; none views the built-in demo scene.
    pub input: Option<PathBuf>,
    /// Port to listen on (0: any free one; the address is printed).
    #[arg(long, default_value_t = 8765)]
    pub port: u16,
    /// Address to listen on: this machine only unless told otherwise.
    #[arg(long, default_value = "127.0.0.1")]
    pub bind: String,
    /// Do not open the page in a browser.
    #[arg(long)]
    pub no_open: bool,
    /// The view's width in pixels at full resolution.
    #[arg(long, default_value_t = 800)]
    pub width: u32,
    /// The view's height in pixels at full resolution.
    #[arg(long, default_value_t = 600)]
    pub height: u32,
    /// Samples a pixel a view at rest refines to (the page can change it).
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// What the points' colours show, as for `render` (the scene is built with it) [default: a
    /// scene file's, else auto].
    #[arg(long, value_enum)]
    pub color_by: Option<ColorBy>,
    #[command(flatten)]
    pub read: ReadArgs,
    #[command(flatten)]
    pub preprocess: PreprocessArgs,
}

#[derive(Args, Debug)]
pub struct InfoArgs {
    /// Point cloud (PLY, LAS/LAZ, E57, PCD, XYZ/PTS, the vertices of an OFF or OBJ mesh, or a Stanford scan set .conf).
    pub input: PathBuf,
    #[command(flatten)]
    pub read: ReadArgs,
}

#[cfg(feature = "bench")]
#[derive(Args, Debug)]
pub struct BenchArgs {
    /// The experiment (TOML; experiments/README.md documents it).
    pub experiment: PathBuf,
    /// Folder for results.jsonl, results.csv and the images.
    #[arg(long, default_value = "results")]
    pub out: PathBuf,
    /// Only these models (comma-separated names).
    #[arg(long, value_delimiter = ',')]
    pub models: Vec<String>,
    /// List the points that would be measured, and measure nothing.
    #[arg(long)]
    pub dry_run: bool,
    /// Worker threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Then write the report (Markdown) of the run here, as `pointray report` does.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Folder for the report's figures and images [default: results/ beside the report].
    #[arg(long, requires = "report")]
    pub figures: Option<PathBuf>,
    #[command(flatten)]
    pub preprocess: PreprocessArgs,
}

#[cfg(feature = "bench")]
#[derive(Args, Debug)]
pub struct ReportArgs {
    /// A bench run's folder (its results.jsonl and images).
    pub results: PathBuf,
    /// The report (Markdown; its `## Discussion` section, if any, is kept).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Folder for the figures and images [default: results/ beside the report].
    #[arg(long)]
    pub figures: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct CompareArgs {
    /// First PNG (any colour type; alpha is ignored).
    pub a: PathBuf,
    /// Second PNG, of the same size.
    pub b: PathBuf,
    /// Print the result as one JSON object (`psnr_db` is null for identical images).
    #[arg(long)]
    pub json: bool,
    /// Compare only this pixel rectangle: X0,Y0,X1,Y1 (X1, Y1 exclusive), e.g. the `region`
    /// of a `--crop-to-model` render's stats, so that background does not inflate the PSNR.
    #[arg(long, value_parser = parse_region)]
    pub region: Option<pointray::camera::Region>,
    /// Also count the first image's isolated dark speckles (pixels 60 levels of luma darker
    /// than each of their four neighbours), how many of them the second lacks at the same
    /// place, and of those how many it shows no trace of (darker than around it by less than
    /// 1/32 of the dot's depth, in linear light). The foreground is this PNG's non-black
    /// pixels: the first render's depth AOV (`--aov depth`).
    #[arg(long, value_name = "FOREGROUND.png")]
    pub speckles: Option<PathBuf>,
}

#[derive(Copy, Clone, Debug, PartialEq, Eq, ValueEnum)]
pub enum Switch {
    On,
    Off,
}

fn parse_sphere_level(s: &str) -> Result<pointray::accel::NodeBounds, String> {
    use pointray::accel::NodeBounds;
    match s {
        "never" => Ok(NodeBounds::Boxes),
        "auto" => Ok(NodeBounds::Auto),
        level => level
            .parse()
            .map(NodeBounds::SpheresFrom)
            .map_err(|_| format!("{level:?}: expected a level (0, 1, 2, …), \"never\" or \"auto\"")),
    }
}

/// Parses `N` comma-separated finite numbers, in f64 (file coordinates may be large).
fn parse_floats<const N: usize>(s: &str) -> Result<[f64; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!("expected {N} comma-separated numbers, got {:?}", s));
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(parts) {
        *o = p.parse::<f64>().map_err(|_| format!("{p:?} is not a number"))?;
        if !o.is_finite() {
            return Err(format!("{p:?} is not finite"));
        }
    }
    Ok(out)
}

fn parse_vec3(s: &str) -> Result<glam::Vec3, String> {
    parse_floats::<3>(s).map(|v| glam::DVec3::from(v).as_vec3())
}

/// A position in the file's coordinates: kept in f64 until the cloud's origin is subtracted.
fn parse_dvec3(s: &str) -> Result<glam::DVec3, String> {
    parse_floats::<3>(s).map(glam::DVec3::from)
}

fn positive_fps(s: &str) -> Result<f32, String> {
    s.parse::<f32>().ok().filter(|f| *f > 0.0 && *f <= 1000.0).ok_or_else(|| format!("{s:?}: between 0 and 1000"))
}

fn parse_bit_depth(s: &str) -> Result<u8, String> {
    match s {
        "8" => Ok(8),
        "16" => Ok(16),
        _ => Err(format!("{s:?}: a PNG has 8 or 16 bits a channel")),
    }
}

fn parse_clip_box(s: &str) -> Result<pointray::clip::ClipBox, String> {
    let [x0, y0, z0, x1, y1, z1] = parse_floats::<6>(s)?;
    Ok(pointray::clip::ClipBox { min: glam::DVec3::new(x0, y0, z0), max: glam::DVec3::new(x1, y1, z1) })
}

fn parse_clip_plane(s: &str) -> Result<pointray::clip::ClipPlane, String> {
    let [x, y, z, offset] = parse_floats::<4>(s)?;
    Ok(pointray::clip::ClipPlane { normal: glam::DVec3::new(x, y, z), offset })
}

fn parse_region(s: &str) -> Result<pointray::camera::Region, String> {
    let v = parse_floats::<4>(s)?;
    if v.iter().any(|x| *x < 0.0 || x.fract() != 0.0) {
        return Err("region bounds must be non-negative integers".into());
    }
    let [x0, y0, x1, y1] = v.map(|x| x as u32);
    if x1 <= x0 || y1 <= y0 {
        return Err(format!("empty region {x0},{y0},{x1},{y1}: need X0 < X1 and Y0 < Y1"));
    }
    Ok(pointray::camera::Region { x0, y0, x1, y1 })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_vectors_and_regions() {
        assert_eq!(parse_vec3("0.4, 0.3,1").unwrap(), glam::Vec3::new(0.4, 0.3, 1.0));
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,x,2").is_err());
        assert!(parse_region("10,10,5,20").is_err());
        assert_eq!(parse_region("1,2,3,4").unwrap(), pointray::camera::Region { x0: 1, y0: 2, x1: 3, y1: 4 });
    }

    #[test]
    fn clap_definition_is_consistent() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }
}
