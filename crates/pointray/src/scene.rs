//! The library's front door: a prepared [`Scene`] (splats in a multiresolution accelerator,
//! with what lights and dresses them) and [`render`]`(&Scene, &Settings) -> Frame`. The
//! command line, the bench and the Python package are thin layers over these; the scene is
//! built once and rendered (or queried, [`Scene::intersect`]) as often as wanted, with any
//! settings its build allows.
//!
//! ```
//! use pointray::preprocess::{PreprocessConfig, preprocess};
//! use pointray::{Scene, Settings, render};
//!
//! let mut cloud = pointray::demo::demo_cloud(5_000, 1);
//! preprocess(&mut cloud, &PreprocessConfig::standard())?;
//! let settings = Settings { width: 64, height: 48, spp: 2, ..Settings::default() };
//! let scene = Scene::build(cloud.into(), &settings)?;
//! let frame = render(&scene, &settings)?;
//! let srgb = frame.srgb8(settings.tone_map()); // what `pointray render` writes to a PNG
//! assert_eq!(srgb.len(), 64 * 48 * 3);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::PointCloud;
use crate::accel::bvh::TwoLevel;
use crate::accel::stored::Stored;
use crate::accel::{Accel, BruteForce, Bvh, BvhParams, KdTree, KdTreeParams, NodeBounds};
use crate::camera::{Camera, Region};
use crate::clip::{ClipBox, ClipPlane};
use crate::color::srgb_to_linear;
use crate::color_by::{self, ColorBy};
use crate::culling::{backfacing_fraction, backfacing_fraction_in_view};
use crate::env_map::{EnvFrame, EnvMap};
use crate::film::Film;
use crate::frame::{Aov, Frame, FrameReport};
use crate::ground::{Checker, GroundPlane};
use crate::material::Material;
use crate::math::Aabb;
use crate::render::{Integrator, RenderConfig};
use crate::settings::{AccelKind, Cull, Projection, Settings, SettingsError};
use crate::shading::{Environment, Light};
use crate::splat::{DiskShape, splats_from_cloud};
use crate::stats::RenderStats;

/// `Cull::Auto` culls when at most this fraction of rays from around the model meets a back
/// face first. Closed scans measure 0.1–0.4 % (stray disks at silhouettes and creases), open
/// ones several percent and more.
const CULL_AUTO_MAX_BACKFACING: f64 = 0.01;

/// The prefilter's like bound, on the rendered view's rays: a few back faces first (thin
/// parts, stray disks) cost it a few pixels. Default views at 8 diagonals: the dragon 0.2 %,
/// Igea 0.5 %, the Happy Buddha (res3) 2.9 %, the Armadillo with its own normals 40 %, the
/// Autzen survey 28 % (its tree crowns); the bunny's range scan `bun000` from its scanner 0 %,
/// where rays from all around meet its back 42 % of the time.
const PREFILTER_MAX_BACKFACING: f64 = 0.05;

/// Camera rays of the prefilter's check.
const PREFILTER_CHECK_RAYS: usize = 1024;

/// Rays of the `Cull::Auto` check (a few milliseconds on the BVH).
const CULL_CHECK_RAYS: usize = 4096;

mod stored;
pub use stored::{PartMeta, PartRanges, SCENE_ARRAYS, SceneMeta, StoredScene, StoredSceneError, StreamedCloud};

/// What a scene file brings beside its points: then the settings' light, material, sky and
/// ground options, which dress a lone cloud, do not apply.
#[derive(Clone, Debug)]
pub struct SceneContent {
    pub lights: Vec<Light>,
    /// By index, as [`SceneParts::point_materials`] names them.
    pub materials: Vec<Material>,
    pub environment: Environment,
    /// What camera rays that leave the scene see instead of the environment (none: the
    /// environment), so that a sky can light a survey while its plan keeps a dark surround.
    pub background: Option<[f32; 3]>,
    pub ground: Option<GroundPlane>,
}

/// What a scene is built from.
#[derive(Clone, Debug, Default)]
pub struct SceneParts {
    /// Preprocessed: every point has a normal and a radius.
    pub cloud: PointCloud,
    /// Each point's index into the content's materials (none: all the first).
    pub point_materials: Option<Vec<u8>>,
    pub content: Option<SceneContent>,
    /// The view direction and distance (in bounding-box diagonals) when the settings name
    /// neither an eye nor their own (default: (0.4, 0.3, 1) at 1).
    pub view: Option<(Vec3, f32)>,
    /// The light when the settings name none (default: a headlight), at the settings'
    /// `light_intensity`: a survey's sun, the demo's light.
    pub light: Option<Light>,
    /// The data's up axis, where its format gives one (default: +y).
    pub up: Option<Vec3>,
    /// The light around a lone cloud when the settings name neither a sky nor a map (default:
    /// the dark background): a survey's sky, which bounced rays (the path tracer's, mirrors')
    /// see while camera rays still see the dark background.
    pub environment: Option<Environment>,
    /// A scene read from a scene file (`.prs`), built already: then the cloud is empty and
    /// the rest is the stored scene's.
    pub stored: Option<StoredScene>,
}

impl From<PointCloud> for SceneParts {
    fn from(cloud: PointCloud) -> Self {
        Self { cloud, ..Self::default() }
    }
}

/// Why a scene cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("{0} points is more than pointray can index ({1})")]
    TooManyPoints(usize, usize),
    #[error("the cloud is not prepared: every point needs a normal and a radius")]
    NotPrepared,
    #[error("the cloud has no points")]
    Empty,
    #[error("the points' material indices are not one a point")]
    MaterialCount,
    #[error("the cloud is inconsistent: {0}")]
    Inconsistent(String),
    /// A colour or class filter the cloud cannot give (no such attribute, no point left).
    #[error(transparent)]
    Settings(#[from] SettingsError),
    #[error(transparent)]
    TooLarge(#[from] crate::accel::bvh::TooLarge),
}

/// The accelerators a scene can be built on; the render loop is monomorphised for each.
enum Accelerator {
    Bvh(Bvh),
    /// A BVH of more than `BvhParams::part_splats` splats, in parts.
    TwoLevel(TwoLevel),
    KdTree(KdTree),
    Brute(BruteForce),
}

/// Calls `$body` with `$a` bound to whichever accelerator `$accel` holds.
macro_rules! on_accel {
    ($accel:expr, $a:ident => $body:expr) => {
        match $accel {
            Accelerator::Bvh($a) => $body,
            Accelerator::TwoLevel($a) => $body,
            Accelerator::KdTree($a) => $body,
            Accelerator::Brute($a) => $body,
        }
    };
}

/// How a scene was built: what settings it can render with.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Build {
    accel: AccelKind,
    node_bounds: NodeBounds,
    shape: DiskShape,
    color_by: ColorBy,
    classes: Option<Vec<u8>>,
    exclude_classes: Vec<u8>,
    clip_box: Option<ClipBox>,
    clip_planes: Vec<ClipPlane>,
    /// The axis the elevation colours follow (with `color_by` elevation): the settings' `up`,
    /// else the data's, which only `Scene::build` knows (`Build::of` leaves it `None`).
    elevation_up: Option<Vec3>,
}

impl Build {
    /// What of `settings` a build takes (the rest is the render's).
    pub fn of(settings: &Settings) -> Self {
        // Only the BVH has bounding volumes to choose.
        let node_bounds = if settings.accel == AccelKind::Bvh { settings.sphere_from_level } else { NodeBounds::Boxes };
        Self {
            accel: settings.accel,
            node_bounds,
            shape: settings.surface.shape(),
            color_by: settings.color_by,
            classes: settings.classes.clone(),
            exclude_classes: settings.exclude_classes.clone(),
            clip_box: settings.clip_box,
            clip_planes: settings.clip_planes.clone(),
            elevation_up: None,
        }
    }

    /// The BVH's parameters this build asks for.
    pub fn bvh_params(&self) -> BvhParams {
        BvhParams { node_bounds: self.node_bounds, shape: self.shape, ..BvhParams::standard() }
    }

    /// What a build of a cloud whose up axis is `up` records of `settings`: [`Build::of`], and the
    /// axis elevation colours follow (the settings' up, else the cloud's).
    pub fn of_cloud(settings: &Settings, up: Vec3) -> Self {
        let elevation_up = (settings.color_by == ColorBy::Elevation).then_some(settings.up.unwrap_or(up));
        Self { elevation_up, ..Self::of(settings) }
    }
}

/// The most splats a BVH's build takes at a time (a chunk) and holds in one tree (a part):
/// `BvhParams::chunk_splats` and `part_splats`, whose defaults every front end takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BuildLimits {
    pub chunk_splats: usize,
    pub part_splats: usize,
}

impl Default for BuildLimits {
    fn default() -> Self {
        let p = BvhParams::standard();
        Self { chunk_splats: p.chunk_splats, part_splats: p.part_splats }
    }
}

/// Splats in an accelerator, with their lights, materials and surroundings: ready to render.
pub struct Scene {
    accel: Accelerator,
    build: Build,
    content: Option<SceneContent>,
    view: Option<(Vec3, f32)>,
    /// The data's up (unit).
    up: Vec3,
    light: Option<Light>,
    /// See [`SceneParts::environment`].
    environment: Option<Environment>,
    /// Added to the stored positions to give the file's coordinates (see [`PointCloud`]).
    origin: DVec3,
    /// What the camera frames and `crop_to_model` crops to: the points' bounds.
    bounds: Aabb,
    points: usize,
    mean_radius: f64,
    /// The accelerator's build alone (the splats made before it, the bounds after).
    build_seconds: f64,
    /// The input splat of each accelerator index where they differ (the BVH's blocks): a part's
    /// block lanes each (one for a lone BVH, or the points a filter kept).
    ids: Vec<Stored<u32>>,
    /// Read from a scene file (`.prs`): its build is the file's, and its ids' CRC is checked
    /// when a query first needs them.
    stored: Option<Arc<stored::IdsCheck>>,
    /// The `Cull::Auto` probe, run at the first render that asks.
    backfacing: OnceLock<Option<f64>>,
    /// The map `Settings::env_map` names, read from that file (see [`Scene::set_environment_map`]).
    environment_map: Option<(std::path::PathBuf, Arc<EnvMap>)>,
}

/// What a ray query met: the surface point `t` along the ray (its direction normalised), in
/// the file's coordinates, its shading normal (facing the ray) and the nearest splat's index
/// in the cloud the scene was built from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayHit {
    pub t: f32,
    pub position: DVec3,
    pub normal: Vec3,
    pub splat: u32,
}

impl Scene {
    /// Builds the accelerator the settings name (`accel`, `sphere_from_level`, and the disks
    /// `surface` tests) over the parts' cloud, which it consumes: the splats hold all the rest
    /// needs of the points, and the cloud is freed before the build's peak. The points are
    /// those of the settings' `classes` (less `exclude_classes`) inside their clip, coloured by
    /// `color_by`. A BVH over more than `accel::bvh::PART_SPLATS` is a scene in parts
    /// (`accel::bvh::TwoLevel`).
    pub fn build(parts: SceneParts, settings: &Settings) -> Result<Scene, SceneError> {
        Self::build_with_limits(parts, settings, BuildLimits::default())
    }

    /// [`Scene::build`] with a BVH's chunks and parts of at most `limits`' splats: for tests of
    /// builds made elsewhere (out of core) with small ones.
    #[doc(hidden)]
    pub fn build_with_limits(parts: SceneParts, settings: &Settings, limits: BuildLimits) -> Result<Scene, SceneError> {
        let SceneParts { mut cloud, mut point_materials, content, view, light, up, environment, stored } = parts;
        if let Some(stored) = stored {
            let scene = stored.scene();
            scene.check_build(settings)?;
            return Ok(scene);
        }
        cloud.check_lengths().map_err(SceneError::Inconsistent)?;
        if point_materials.as_ref().is_some_and(|m| m.len() != cloud.len()) {
            return Err(SceneError::MaterialCount);
        }
        let kept = select_points(&mut cloud, settings)?;
        if let (Some(kept), Some(materials)) = (&kept, &mut point_materials) {
            *materials = kept.iter().map(|&i| materials[i as usize]).collect();
        }
        let up = up.and_then(Vec3::try_normalize).unwrap_or(Vec3::Y);
        // The elevation colours' axis: the one `Self::up` gives the camera.
        let elevation_axis = settings.up.unwrap_or(up);
        color_by::apply(&mut cloud, settings.color_by, elevation_axis)?;
        if cloud.is_empty() {
            return Err(SceneError::Empty);
        }
        // A BVH in parts names its points in 32 bits; the others index 2²⁸ splats.
        let most = if settings.accel == AccelKind::Bvh { u32::MAX as usize } else { crate::accel::bvh::MAX_SPLATS };
        if cloud.len() > most {
            return Err(SceneError::TooManyPoints(cloud.len(), most));
        }
        let prepared = |v: Option<usize>| v == Some(cloud.len());
        if !prepared(cloud.normals.as_ref().map(Vec::len)) || !prepared(cloud.radii.as_ref().map(Vec::len)) {
            return Err(SceneError::NotPrepared);
        }
        let mut splats = splats_from_cloud(&cloud);
        if let Some(materials) = &point_materials {
            splats.iter_mut().zip(materials).for_each(|(s, &m)| s.set_material(m));
        }
        let mean_radius = splats.iter().map(|s| f64::from(s.radius)).sum::<f64>() / splats.len() as f64;
        let (origin, points, bounds) = (cloud.origin, cloud.len(), cloud.bounds());
        let residuals = cloud.residuals.take();
        drop(cloud);
        let build = Build::of_cloud(settings, up);
        let start = std::time::Instant::now();
        // The kd-tree and brute force keep the splats' order; the BVH says where each went.
        let mut ids = None;
        let params =
            BvhParams { chunk_splats: limits.chunk_splats, part_splats: limits.part_splats, ..build.bvh_params() };
        let accel = match build.accel {
            AccelKind::Bvh if splats.len() > params.part_splats => {
                let (scene, part_ids) = TwoLevel::try_build_with_ids(splats, residuals.as_deref(), &params)?;
                ids = Some(part_ids);
                scene.into_lone().map_or_else(Accelerator::TwoLevel, Accelerator::Bvh)
            }
            AccelKind::Bvh => {
                let (bvh, slot_ids) = Bvh::try_build_with_ids(splats, &params)?;
                ids = Some(vec![slot_ids]);
                Accelerator::Bvh(bvh)
            }
            AccelKind::Kdtree => Accelerator::KdTree(KdTree::build(
                splats,
                &KdTreeParams { shape: build.shape, ..KdTreeParams::standard() },
            )),
            AccelKind::Brute => Accelerator::Brute(BruteForce::new(splats)),
        };
        let build_seconds = start.elapsed().as_secs_f64();
        // Ids name the points as they came, before the class filter.
        let ids = match (ids, kept) {
            // (u32::MAX marks a block's empty slot.)
            (Some(parts), Some(kept)) => parts
                .iter()
                .map(|slots| slots.iter().map(|&s| if s == u32::MAX { s } else { kept[s as usize] }).collect())
                .collect(),
            (ids, kept) => ids.or(kept.map(|kept| vec![kept])).unwrap_or_default(),
        };
        let ids = ids.into_iter().map(Stored::from).collect();
        // The camera frames the points' bounds (the Embree bench's convention); a cloud of one
        // point, or of coincident points, has none, and then the disks' bounds serve.
        let bounds = if bounds.diagonal() > 0.0 { bounds } else { on_accel!(&accel, a => a.bounds()) };
        let bounds = if bounds.diagonal() > 0.0 {
            bounds
        } else {
            tracing::warn!("the model has no extent; framing a unit box around it");
            Aabb::new(bounds.center() - 0.5, bounds.center() + 0.5)
        };
        Ok(Scene {
            accel,
            build,
            content,
            view,
            up,
            light,
            environment,
            origin,
            bounds,
            points,
            mean_radius,
            build_seconds,
            ids,
            stored: None,
            backfacing: OnceLock::new(),
            environment_map: None,
        })
    }

    /// The splats indexed.
    pub fn points(&self) -> usize {
        self.points
    }

    /// The parts of a two-level scene (`accel::bvh::TwoLevel`), or 1.
    pub fn parts(&self) -> usize {
        match &self.accel {
            Accelerator::TwoLevel(scene) => scene.parts().len(),
            _ => 1,
        }
    }

    /// The accelerator's name ("bvh", "kdtree", "brute").
    pub fn accel_name(&self) -> &'static str {
        on_accel!(&self.accel, a => a.name())
    }

    /// The accelerator's bytes, splats included.
    pub fn memory_bytes(&self) -> usize {
        on_accel!(&self.accel, a => a.memory_bytes())
    }

    /// What the camera frames, in the scene's stored coordinates (the file's less `origin`).
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    pub fn origin(&self) -> DVec3 {
        self.origin
    }

    pub fn mean_radius(&self) -> f64 {
        self.mean_radius
    }

    /// Seconds the accelerator's build took.
    pub fn build_seconds(&self) -> f64 {
        self.build_seconds
    }

    /// The first surface point along each ray (`origin` in the file's coordinates, `direction`
    /// of any length), at full detail, through the settings' surface scheme; rays in parallel.
    pub fn intersect(&self, rays: &[(DVec3, Vec3)], settings: &Settings) -> Result<Vec<Option<RayHit>>, RenderError> {
        settings.check()?;
        self.check_build(settings)?;
        if let Some(check) = &self.stored {
            check.check(&self.ids)?;
        }
        let scheme = settings.scheme();
        let cone = crate::math::RayCone { width0: 0.0, spread: 0.0 };
        let query = |&(origin, direction): &(DVec3, Vec3)| {
            let ray = crate::math::Ray::new(self.local(origin), direction, cone);
            let mut stats = crate::accel::TraversalStats::uncounted();
            let hit = on_accel!(&self.accel, a => crate::splat::scheme::intersect(a, &ray, &scheme, &mut stats))?;
            // Full detail: every hit is an input splat's, which the BVH's ids name.
            let splat = self.input_id(hit.splat);
            Some(RayHit { t: hit.t, position: self.origin + hit.position.as_dvec3(), normal: hit.normal, splat })
        };
        let hits = rays.par_iter().map(query).collect();
        self.check_whole()?;
        Ok(hits)
    }

    /// The input point of the accelerator's index `splat` (an input splat's).
    fn input_id(&self, splat: u32) -> u32 {
        match (&self.accel, &self.ids[..]) {
            (Accelerator::TwoLevel(scene), ids) => {
                let (part, local) = scene.locate(splat);
                ids[part][local as usize]
            }
            (_, [ids]) => ids[splat as usize],
            _ => splat,
        }
    }

    /// An error if a walk found part of a stored scene damaged (see [`Bvh::damage`]): what it
    /// drew or met is then incomplete.
    fn check_whole(&self) -> Result<(), RenderError> {
        let damage = match &self.accel {
            Accelerator::Bvh(bvh) => bvh.damage(),
            Accelerator::TwoLevel(scene) => scene.damage(),
            _ => None,
        };
        damage.map_or(Ok(()), |d| Err(RenderError::Stored(d.to_string())))
    }

    /// The settings resolved against this scene: the camera, the pixels and the render
    /// configuration, ready to render any number of frames.
    pub fn job(&self, settings: &Settings) -> Result<RenderJob<'_>, SettingsError> {
        settings.check()?;
        self.check_build(settings)?;
        let camera = self.camera(settings);
        let region = self.region(settings, &camera)?;
        let scheme = settings.scheme();
        // Level of detail lives in the BVH's and the kd-tree's nodes, normal cones in the BVH's
        // only; brute force traces at full detail. The report says what was used.
        let multires = matches!(self.build.accel, AccelKind::Bvh | AccelKind::Kdtree);
        // Ray-facing disks always face the ray: nothing to cull.
        let cones = self.build.accel == AccelKind::Bvh && scheme.kind.shape() == DiskShape::Oriented;
        let backfacing = (cones && settings.cull == Cull::Auto).then(|| self.backfacing_fraction()).flatten();
        let cull_backfaces = cones
            && match settings.cull {
                Cull::On => true,
                Cull::Off => false,
                Cull::Auto => backfacing.is_some_and(|f| f <= CULL_AUTO_MAX_BACKFACING),
            };
        // The prefilter keeps the disks facing the beam (`splat::footprint`): where this view
        // meets back faces first (normals pointing inwards) it would leave holes.
        let in_view = settings.prefilter.then(
            || on_accel!(&self.accel, a => backfacing_fraction_in_view(a, &camera, region, PREFILTER_CHECK_RAYS, 0)),
        );
        let in_view = in_view.flatten();
        tracing::info!("backface culling {cull_backfaces} (back faces first: {backfacing:?}, in view: {in_view:?})");
        let outward = in_view.is_some_and(|f| f <= PREFILTER_MAX_BACKFACING);
        if settings.prefilter && !outward {
            let share = in_view
                .map_or(String::new(), |f| format!(" ({:.1} % of this view's rays meet a back face first)", 100.0 * f));
            tracing::warn!("--prefilter needs normals that face the view{share}: rendering without it");
        }
        let map = self.environment_map(settings)?;
        let content = self.content.clone().unwrap_or_else(|| self.lone_cloud_content(settings, &camera, map));
        let config = RenderConfig {
            sampler: settings.sampler,
            filter: settings.filter,
            integrator: settings.integrator,
            ao_distance: settings.ao_distance.unwrap_or(0.1 * self.bounds.diagonal()),
            lod_threshold: if multires { settings.lod_threshold } else { 0.0 },
            prefilter: settings.prefilter && outward,
            cull_backfaces,
            scheme,
            lights: content.lights,
            materials: content.materials,
            shadows: settings.shadows,
            shadow_offset: settings.shadow_offset,
            environment: content.environment,
            background: content.background,
            ground: content.ground,
            max_depth: settings.max_depth,
            region,
            samples: settings.spp,
            sample_range: None,
            seed: settings.seed,
            diffuse_spread: settings.diffuse_spread,
            count_work: settings.count_work || settings.aovs.contains(&Aov::Nodes),
            first_hit_aovs: settings.aovs.iter().any(|aov| *aov != Aov::Nodes),
        };
        Ok(RenderJob { scene: self, settings: settings.clone(), camera, config, backfacing })
    }

    /// Whether the scene was built as `settings` ask (accelerator, disks, colours, classes,
    /// clips): else it must be built again for them (`job` refuses them, naming the option).
    pub fn built_for(&self, settings: &Settings) -> bool {
        self.check_build(settings).is_ok()
    }

    /// Refuses settings that need another build: another accelerator, other bounding volumes,
    /// or disks of another shape in the bounds.
    fn check_build(&self, settings: &Settings) -> Result<(), SettingsError> {
        let (built, asked) = (&self.build, Build::of(settings));
        let hint = if self.stored.is_some() {
            "render the cloud it was prepared from"
        } else {
            "prepare the scene with these settings"
        };
        let problem = |what: &str| format!("differs from the scene's build ({what}): {hint}");
        // (Does it differ, the option, what of the build it changes.)
        let checks = [
            (built.accel != asked.accel, "accel", self.accel_name()),
            (built.node_bounds != asked.node_bounds, "sphere_from_level", "its bounding volumes"),
            (built.shape != asked.shape, "surface", "the disks its bounds hold"),
            (built.color_by != asked.color_by, "color_by", "its splats' colours"),
            (built.classes != asked.classes, "classes", "the classes it holds"),
            (built.exclude_classes != asked.exclude_classes, "exclude_classes", "the classes it leaves out"),
            (built.clip_box != asked.clip_box, "clip_box", "the box its clip keeps"),
            (built.clip_planes != asked.clip_planes, "clip_planes", "the planes it is cut by"),
            (
                built.elevation_up.is_some_and(|axis| axis != self.up(settings)),
                "up",
                "the axis its elevation colours follow",
            ),
        ];
        match checks.into_iter().find(|(differs, ..)| *differs) {
            Some((_, option, what)) => Err(SettingsError::new(option, problem(what))),
            None => Ok(()),
        }
    }

    /// A turntable: the settings of `frames` views, the camera turned about the up axis by
    /// 360°·k/frames, k = 0, 1, … (frame 0 is the settings' own view): an eye and look-at turn
    /// about the look-at point, a view direction about the model's centre.
    pub fn turntable(&self, settings: &Settings, frames: u32) -> Vec<Settings> {
        (0..frames).map(|k| self.turned(settings, k, frames)).collect()
    }

    /// Frame `k` of [`Self::turntable`]'s `frames`.
    pub fn turned(&self, settings: &Settings, k: u32, frames: u32) -> Settings {
        let up = self.up(settings).normalize().as_dvec3();
        let turn = glam::DQuat::from_axis_angle(up, std::f64::consts::TAU * f64::from(k) / f64::from(frames));
        match (settings.eye, settings.look_at) {
            (Some(eye), Some(target)) => Settings { eye: Some(target + turn * (eye - target)), ..settings.clone() },
            _ => {
                let view = settings.view_dir.unwrap_or(self.default_view(settings).0);
                Settings { view_dir: Some((turn * view.as_dvec3()).as_vec3()), view: None, ..settings.clone() }
            }
        }
    }

    /// Positions the settings give are in the file's coordinates; the scene stores them
    /// relative to its origin.
    fn local(&self, p: DVec3) -> Vec3 {
        (p - self.origin).as_vec3()
    }

    /// The world's up for these settings: theirs, else the data's (what a viewer orbits about).
    pub fn up(&self, s: &Settings) -> Vec3 {
        s.up.unwrap_or(self.up)
    }

    /// The view direction and distance without an eye: a named view, else the scene's own,
    /// else (0.4, 0.3, 1) at one diagonal; the named and the default turned with the up axis
    /// (+y to +z: from the south, raised, for a survey).
    fn default_view(&self, s: &Settings) -> (Vec3, f32) {
        let turn = turn_from_y(self.up(s).normalize());
        match (s.view, self.view) {
            (Some(preset), own) => (turn * preset.direction_for_y_up(), own.map_or(1.0, |(_, d)| d)),
            (None, Some(own)) => own,
            (None, None) => (turn * Vec3::new(0.4, 0.3, 1.0), 1.0),
        }
    }

    fn camera(&self, s: &Settings) -> Camera {
        let up = self.up(s);
        let camera = match (s.eye, s.look_at) {
            (Some(eye), Some(target)) => {
                Camera::look_at(self.local(eye), self.local(target), up, s.fov, s.width, s.height)
            }
            _ => {
                let (view, distance) = self.default_view(s);
                let (view, distance) = (s.view_dir.unwrap_or(view), s.distance.unwrap_or(distance));
                Camera::orbit(&self.bounds, view, up, distance, s.fov, s.width, s.height)
            }
        };
        let camera = match s.projection {
            Projection::Perspective => camera,
            Projection::Orthographic => camera.into_orthographic(),
        };
        let focus = s.focus_distance.unwrap_or(camera.focus_distance);
        camera.with_lens(s.lens_radius, focus)
    }

    fn region(&self, s: &Settings, camera: &Camera) -> Result<Region, SettingsError> {
        if s.crop_to_model {
            let r = camera.region_of(&self.bounds);
            if r.pixel_count() == 0 {
                return Err(SettingsError::new("crop_to_model", "crops to nothing: the model lies outside the view"));
            }
            return Ok(r);
        }
        let Some(r) = s.region else { return Ok(Region::full(s.width, s.height)) };
        let clamped = r.clamp_to(s.width, s.height);
        if clamped.pixel_count() == 0 {
            let (w, h) = (s.width, s.height);
            let problem = format!("{},{},{},{} lies outside the {w}x{h} frame", r.x0, r.y0, r.x1, r.y1);
            return Err(SettingsError::new("region", problem));
        }
        Ok(clamped)
    }

    /// Gives the scene the environment map read from `path`, which settings whose `env_map`
    /// names that file render with (`None` takes it away).
    pub fn set_environment_map(&mut self, map: Option<(std::path::PathBuf, Arc<EnvMap>)>) {
        self.environment_map = map;
    }

    /// The map `settings.env_map` names, if it does; an error if the scene was not given it.
    fn environment_map(&self, settings: &Settings) -> Result<Option<Arc<EnvMap>>, SettingsError> {
        let Some(path) = &settings.env_map else { return Ok(None) };
        match &self.environment_map {
            Some((read, map)) if read == path => Ok(Some(map.clone())),
            _ => Err(SettingsError::new(
                "env_map",
                format!("{} was not read for this scene (pointray_io::source::environment_map)", path.display()),
            )),
        }
    }

    /// A lone cloud's lights, material, sky (or environment map) and ground, from the settings.
    fn lone_cloud_content(&self, s: &Settings, camera: &Camera, map: Option<Arc<EnvMap>>) -> SceneContent {
        let intensity = s.light_intensity;
        let light = match (s.light_pos, s.light_dir) {
            (Some(position), _) => match s.light_radius {
                Some(radius) => Some(Light::Sphere { center: self.local(position), radius, intensity }),
                None => Some(Light::Point { position: self.local(position), intensity }),
            },
            (None, Some(direction)) => Some(Light::Directional { direction, intensity }),
            // An environment map is the light: no headlight beside it.
            (None, None) if map.is_some() => None,
            // The data's own light (a survey's sun, the demo's), at the settings' intensity.
            (None, None) => {
                Some(self.light.map_or_else(|| Light::headlight(camera, intensity), |l| l.with_intensity(intensity)))
            }
        };
        let dark = Environment::BACKGROUND.flat_color();
        let (environment, background) = match (map, &self.environment) {
            (Some(map), _) => (Environment::Map { map, frame: EnvFrame::new(self.up(s), s.env_rotation) }, None),
            // The world's up (the camera's would tilt the horizon with the view).
            (None, _) if s.sky => (Environment::sky(self.up(s).normalize()), None),
            (None, Some(around)) => (around.clone(), Some(dark)),
            (None, None) => (Environment::BACKGROUND, None),
        };
        SceneContent {
            lights: light.into_iter().collect(),
            materials: vec![s.material.material(s.ior)],
            environment,
            background,
            ground: s.ground.then(|| floor_under(&self.bounds, self.up(s))),
        }
    }

    fn backfacing_fraction(&self) -> Option<f64> {
        // Only the BVH culls; the prefilter asks of every accelerator.
        *self.backfacing.get_or_init(|| on_accel!(&self.accel, a => backfacing_fraction(a, CULL_CHECK_RAYS, 0)))
    }

    /// Nodes, the nodes that test spheres, and bytes per node (none for brute force).
    fn node_summary(&self) -> (usize, usize, usize) {
        match &self.accel {
            Accelerator::Bvh(a) => (a.node_count(), a.sphere_node_count(), Bvh::NODE_BYTES),
            Accelerator::TwoLevel(a) => (a.node_count(), a.sphere_node_count(), Bvh::NODE_BYTES),
            Accelerator::KdTree(a) => (a.node_count(), 0, KdTree::NODE_BYTES),
            Accelerator::Brute(_) => (0, 0, 0),
        }
    }
}

/// `ground`: a checkered grey plane just under the model's bounding box (along `up`), with
/// squares an eighth of the box's diagonal. It lies a thousandth of the diagonal below the
/// box, so that a floor of points in the model (the demo's) shows instead of fighting it.
fn floor_under(bounds: &Aabb, up: Vec3) -> GroundPlane {
    let up = up.normalize();
    let lowest = bounds.corners().iter().map(|c| c.dot(up)).fold(f32::INFINITY, f32::min);
    let height = lowest - 1e-3 * bounds.diagonal();
    let grey = |c: f32| [srgb_to_linear(c); 3];
    GroundPlane {
        up,
        height,
        color: grey(0.8),
        checker: Some(Checker { color: grey(0.6), tile: bounds.diagonal() / 8.0 }),
        material: Material::standard(),
    }
}

/// Settings resolved against a scene: render it frame after frame.
#[derive(Clone)]
pub struct RenderJob<'s> {
    scene: &'s Scene,
    settings: Settings,
    pub camera: Camera,
    pub config: RenderConfig,
    /// The `Cull::Auto` probe's fraction of back faces met first, if it ran.
    backfacing: Option<f64>,
}

impl RenderJob<'_> {
    /// One frame. `progress` is told how many pixels each finished band held. An error where
    /// the frame met a damaged part of a stored scene (the frame is then incomplete).
    pub fn render(&self, progress: &(dyn Fn(u64) + Sync)) -> Result<Frame, RenderError> {
        let frame = self.render_until(progress, &AtomicBool::new(false))?;
        Ok(frame.expect("a render nobody cancels is whole"))
    }

    /// [`Self::render`], given up (`None`) once `cancel` is set: a band checks before it starts.
    pub fn render_until(
        &self,
        progress: &(dyn Fn(u64) + Sync),
        cancel: &AtomicBool,
    ) -> Result<Option<Frame>, RenderError> {
        let mut film = self.film();
        let (camera, config) = (&self.camera, &self.config);
        let stats = on_accel!(&self.scene.accel, a => crate::render::render_into_until(a, camera, config, &mut film, progress, cancel));
        if cancel.load(Ordering::Relaxed) {
            return Ok(None);
        }
        self.shade_eye_dome(&mut film);
        self.scene.check_whole()?;
        let (width, height) = (self.settings.width, self.settings.height);
        Ok(Some(Frame { film, stats, width, height, background: self.background() }))
    }

    /// Eye-dome lighting over the film's pixels, where the settings ask for it.
    fn shade_eye_dome(&self, film: &mut Film) {
        let strength = self.settings.edl;
        if strength <= 0.0 {
            return;
        }
        let (camera, config) = (&self.camera, &self.config);
        // Twice as far as the model's farthest corner can be.
        let bounds = &self.scene.bounds;
        let background_depth = 2.0 * (camera.eye.distance(bounds.center()) + bounds.diagonal());
        let rays = crate::eye_dome::DepthRays {
            lod_threshold: config.lod_threshold,
            cull_backfaces: config.cull_backfaces && config.scheme.kind.shape() == DiskShape::Oriented,
            background_depth,
        };
        let shades = on_accel!(&self.scene.accel, a => crate::eye_dome::shades(a, camera, &config.scheme, rays, config.region, strength));
        for (rgb, shade) in film.rgb.iter_mut().zip(shades) {
            *rgb = rgb.map(|c| c * shade);
        }
    }

    /// The same job counting no work (for timed frames whose statistics nobody reads).
    pub fn uncounted(&self) -> Self {
        let mut job = self.clone();
        job.config.count_work = false;
        job
    }

    /// A film for this job's pixels and channels, for [`Self::render_into`].
    pub fn film(&self) -> Film {
        crate::render::film_for(&self.camera, &self.config)
    }

    /// A frame into a film made before (frame after frame, one film serves: a fresh one per
    /// frame, its pages faulted in anew, cost 7 % of a frame of the dragon at 1024²).
    pub fn render_into(&self, film: &mut Film, progress: &(dyn Fn(u64) + Sync)) -> RenderStats {
        let (camera, config, never) = (&self.camera, &self.config, AtomicBool::new(false));
        let stats = on_accel!(&self.scene.accel, a => crate::render::render_into_until(a, camera, config, film, progress, &never));
        self.shade_eye_dome(film);
        stats
    }

    /// The camera's ray (without its lens) through the centre of pixel (`x`, `y`): its origin in
    /// the file's coordinates and its direction, not normalised (what [`Scene::intersect`] takes,
    /// which then meets what the render's ray met).
    pub fn camera_ray(&self, x: u32, y: u32) -> (DVec3, Vec3) {
        let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
        (self.scene.origin + self.camera.origin(fx, fy).as_dvec3(), self.camera.direction(fx, fy))
    }

    /// What rays that leave the scene see, flat: the colour outside the rendered region.
    pub fn background(&self) -> [f32; 3] {
        self.config.background.unwrap_or_else(|| self.config.environment.flat_color())
    }

    /// What was rendered and how: the settings as resolved, the scene, the work counted.
    pub fn report(&self, frame: &Frame) -> FrameReport {
        let (scene, config, stats) = (self.scene, &self.config, &frame.stats);
        let (nodes, sphere_nodes, bytes_per_node) = scene.node_summary();
        let per_ray = |n: u64| if stats.rays == 0 { 0.0 } else { n as f64 / stats.rays as f64 };
        let per_hit = |n: u64| if stats.primary_hits == 0 { 0.0 } else { n as f64 / stats.primary_hits as f64 };
        let s = &self.settings;
        FrameReport {
            points: scene.points,
            width: s.width,
            height: s.height,
            region: config.region,
            accel: scene.accel_name(),
            surface: config.scheme.kind.name(),
            integrator: config.integrator,
            ao_distance: (config.integrator == Integrator::Ao).then_some(config.ao_distance),
            materials: config.materials.iter().map(Material::name).collect(),
            ground: config.ground.map(|g| g.material.name()),
            color_by: scene.build.color_by,
            classes: scene.build.classes.clone(),
            exclude_classes: scene.build.exclude_classes.clone(),
            edl: s.edl,
            clip_box: scene.build.clip_box,
            clip_planes: scene.build.clip_planes.clone(),
            samples_per_pixel: s.spp,
            rays: stats.rays,
            primary_rays: stats.primary_rays,
            secondary_rays: stats.secondary_rays,
            shadow_rays: stats.shadow_rays,
            hit_fraction: stats.hit_fraction(),
            nodes_visited_per_ray: stats.nodes_visited_per_ray(),
            splat_tests_per_ray: stats.splat_tests_per_ray(),
            box_tests_per_ray: per_ray(stats.traversal.box_tests),
            sphere_tests_per_ray: per_ray(stats.traversal.sphere_tests),
            lod_stops_per_ray: per_ray(stats.traversal.lod_stops),
            culled_per_ray: per_ray(stats.traversal.culled),
            blended_splats_per_hit: per_hit(stats.blended_splats),
            pss_steps_per_hit: per_hit(stats.traversal.pss_steps),
            pss_fallback_fraction: per_hit(stats.traversal.pss_fallbacks),
            lod_threshold: (config.lod_threshold > 0.0).then_some(config.lod_threshold),
            prefilter: config.prefilter,
            culling: crate::frame::CullingReport {
                mode: s.cull,
                enabled: config.cull_backfaces,
                backfacing_fraction: self.backfacing,
            },
            node_bounds: scene.build.node_bounds,
            nodes,
            sphere_nodes,
            bytes_per_node,
            nodes_visited_max_per_pixel: frame.nodes_max(),
            accel_bytes: scene.memory_bytes(),
            bytes_per_splat: scene.memory_bytes() as f64 / scene.points as f64,
            mean_radius: scene.mean_radius,
            bounds_diagonal: scene.bounds.diagonal(),
            camera_distance: s
                .eye
                .is_none()
                .then(|| s.distance.unwrap_or(scene.default_view(s).1) * scene.bounds.diagonal()),
            up: scene.up(s).to_array(),
            view: s.view,
            isa: crate::accel::isa::active(),
            counters: *stats,
        }
    }
}

/// The turn taking +y to unit `up`. +y to −y is a half turn about x, which keeps a depth
/// frame's front (+z, its sensor's side −z) where it is seen from: glam's arc picks another
/// axis, which turned it to the back.
fn turn_from_y(up: Vec3) -> glam::Quat {
    if up.dot(Vec3::Y) < -0.9999 {
        glam::Quat::from_rotation_x(std::f32::consts::PI)
    } else {
        glam::Quat::from_rotation_arc(Vec3::Y, up)
    }
}

/// Leaves in `cloud` the points the settings draw (their `classes`, inside their clip); returns
/// the kept points' indices in the cloud as it came (`None`: all kept).
fn select_points(cloud: &mut PointCloud, settings: &Settings) -> Result<Option<Vec<u32>>, SettingsError> {
    let by_class = color_by::filter_classes(cloud, settings.classes.as_deref(), &settings.exclude_classes)?;
    let clipped = crate::clip::clip(cloud, settings.clip_box.as_ref(), &settings.clip_planes)?;
    Ok(match (by_class, clipped) {
        (Some(first), Some(then)) => Some(then.iter().map(|&i| first[i as usize]).collect()),
        (first, then) => first.or(then),
    })
}

/// Renders `scene` with `settings`: the one call a program needs.
pub fn render(scene: &Scene, settings: &Settings) -> Result<Frame, RenderError> {
    scene.job(settings)?.render(&|_| {})
}

/// Why a render or a query has no result.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// A stored scene's part failed its check, or could not be fetched, when first read.
    #[error("the scene file: {0}")]
    Stored(String),
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The option a render refused.
    fn refused_option(result: Result<Frame, RenderError>) -> &'static str {
        match result {
            Err(RenderError::Settings(e)) => e.option,
            other => panic!("not refused for an option: {:?}", other.err()),
        }
    }

    fn sphere_scene(settings: &Settings) -> Scene {
        let mut cloud = crate::demo::demo_cloud(3000, 1);
        crate::preprocess::preprocess(&mut cloud, &crate::preprocess::PreprocessConfig::standard()).unwrap();
        Scene::build(cloud.into(), settings).unwrap()
    }

    #[test]
    fn a_scene_renders_with_settings_its_build_allows_and_refuses_others() {
        let small = Settings { width: 32, height: 24, ..Settings::default() };
        let scene = sphere_scene(&small);
        let frame = render(&scene, &small).unwrap();
        assert_eq!(frame.film.rgb.len(), 32 * 24);
        let first_hit = Settings { surface: crate::splat::scheme::SurfaceKind::FirstHit, ..small.clone() };
        assert!(render(&scene, &first_hit).is_ok(), "oriented disks both");
        let rfd = Settings { surface: crate::splat::scheme::SurfaceKind::Rfd, ..small.clone() };
        assert_eq!(refused_option(render(&scene, &rfd)), "surface");
        let kd = Settings { accel: AccelKind::Kdtree, ..small };
        assert_eq!(refused_option(render(&scene, &kd)), "accel");
    }

    /// A scene in parts (of at most 1,000 splats here) renders the lone tree's image up to the
    /// rounding of its parts' frames, at full detail, with level of detail and prefiltered, and
    /// its queries name the same points.
    #[test]
    fn a_scene_in_parts_renders_the_lone_scenes_image() {
        let mut cloud = crate::demo::demo_cloud(8_000, 2);
        crate::preprocess::preprocess(&mut cloud, &crate::preprocess::PreprocessConfig::standard()).unwrap();
        let parts = || SceneParts::from(cloud.clone());
        let lone = Scene::build(parts(), &Settings::default()).unwrap();
        let limits = BuildLimits { chunk_splats: 500, part_splats: 1_000 };
        let split = Scene::build_with_limits(parts(), &Settings::default(), limits).unwrap();
        assert!(split.parts() >= 6, "{} parts", split.parts());
        let small =
            Settings { width: 96, height: 72, spp: 2, count_work: true, lod_threshold: 0.0, ..Settings::default() };
        // From afar, where level of detail stops in the parts' tops.
        let lod = Settings { lod_threshold: 1.0, distance: Some(6.0), ..small.clone() };
        let prefilter = Settings { prefilter: true, spp: 1, ..lod.clone() };
        for settings in [small, lod, prefilter] {
            let render = |s: &Scene| render(s, &settings).unwrap();
            let (a, b) = (render(&lone), render(&split));
            let stops = |f: &crate::Frame| f.stats.traversal.lod_stops;
            assert_eq!(stops(&a) > 0, settings.lod_threshold > 0.0, "{:?}", stops(&a));
            let diff = crate::metrics::compare_rgb8(&a.srgb8(settings.tone_map()), &b.srgb8(settings.tone_map()));
            if settings.lod_threshold == 0.0 {
                assert!(diff.psnr_db.is_none_or(|db| db > 60.0), "{diff:?} at full detail");
            } else {
                // No stop above a part (here 1,000 splats, a few pixels across): where the lone
                // tree stops over several parts, the parts stop at their own roots' children.
                assert!(diff.differing_pixels * 100 <= diff.pixels, "{diff:?} at τ = 1");
            }
        }
        let rays = rays_at(&lone, 500);
        let (a, b) = (
            lone.intersect(&rays, &Settings::default()).unwrap(),
            split.intersect(&rays, &Settings::default()).unwrap(),
        );
        let same = a.iter().zip(&b).filter(|(a, b)| a.map(|h| h.splat) == b.map(|h| h.splat)).count();
        assert!(a.iter().flatten().count() > 100 && same >= 495, "{same} of 500 rays name the same point");
    }

    #[test]
    fn a_class_filter_keeps_its_points_whose_ids_name_them_as_given() {
        let mut cloud = crate::demo::demo_cloud(3000, 1);
        crate::preprocess::preprocess(&mut cloud, &crate::preprocess::PreprocessConfig::standard()).unwrap();
        // Even points class 2, odd ones class 6.
        cloud.scan.classification = Some((0..cloud.len()).map(|i| if i % 2 == 0 { 2 } else { 6 }).collect());
        for accel in [AccelKind::Bvh, AccelKind::Kdtree, AccelKind::Brute] {
            let s =
                Settings { accel, classes: Some(vec![6]), color_by: ColorBy::Classification, ..Settings::default() };
            let scene = Scene::build(cloud.clone().into(), &s).unwrap();
            assert_eq!(scene.points(), cloud.len() / 2);
            let hits = scene.intersect(&rays_at(&scene, 500), &s).unwrap();
            assert!(hits.iter().flatten().count() > 100, "{accel:?}");
            assert!(hits.iter().flatten().all(|h| h.splat % 2 == 1), "{accel:?}: only class 6, by the input's ids");
            // Settings that need another build are refused.
            let other = Settings { classes: None, ..s.clone() };
            assert_eq!(refused_option(render(&scene, &other)), "classes");
            let other = Settings { color_by: ColorBy::Auto, ..s };
            assert_eq!(refused_option(render(&scene, &other)), "color_by");
        }
    }

    #[test]
    fn eye_dome_lighting_darkens_behind_silhouettes_alike_in_any_region() {
        let s = Settings { width: 256, height: 192, ..Settings::default() };
        let scene = sphere_scene(&s);
        let plain = render(&scene, &s).unwrap();
        let edl = Settings { edl: 1.0, ..s.clone() };
        let shaded = render(&scene, &edl).unwrap();
        let lit = plain.film.rgb.iter().zip(&shaded.film.rgb).filter(|(p, _)| p[1] > 0.05);
        let ratios: Vec<f32> = lit.map(|(p, q)| q[1] / p[1]).collect();
        assert!(ratios.iter().all(|&r| r <= 1.0 + 1e-6), "eye-dome lighting only darkens");
        let (dark, kept) = (ratios.iter().filter(|&&r| r < 0.5).count(), ratios.iter().filter(|&&r| r > 0.99).count());
        assert!(dark > 20 && kept > ratios.len() / 2, "{dark} outlined, {kept} of {} kept", ratios.len());
        // The model's outline, drawn on the background next to it.
        let background = plain.background;
        let outline =
            plain.film.rgb.iter().zip(&shaded.film.rgb).filter(|(p, q)| **p == background && q[2] < 0.5 * p[2]);
        assert!(outline.count() > 50);
        // A tile's shading is the frame's: its margin's depths are traced too.
        let region = Region { x0: 100, y0: 70, x1: 160, y1: 130 };
        let tile = render(&scene, &Settings { region: Some(region), ..edl }).unwrap();
        let frame = shaded.linear_rgb();
        let crop: Vec<[f32; 3]> = (region.y0..region.y1)
            .flat_map(|y| (region.x0..region.x1).map(move |x| (x, y)))
            .map(|(x, y)| frame[(y * 256 + x) as usize])
            .collect();
        assert_eq!(tile.film.rgb, crop);
    }

    #[test]
    fn elevation_colours_refuse_another_up_axis() {
        let s = Settings { width: 8, height: 8, color_by: ColorBy::Elevation, ..Settings::default() };
        let scene = sphere_scene(&s);
        assert!(render(&scene, &Settings { up: Some(Vec3::Y), ..s.clone() }).is_ok(), "the data's up, named");
        assert_eq!(refused_option(render(&scene, &Settings { up: Some(Vec3::Z), ..s })), "up");
    }

    #[test]
    fn an_unprepared_or_empty_cloud_is_refused() {
        let raw = crate::demo::demo_cloud(100, 1);
        assert!(matches!(Scene::build(raw.into(), &Settings::default()), Err(SceneError::NotPrepared)));
        let empty = PointCloud::default();
        assert!(matches!(Scene::build(empty.into(), &Settings::default()), Err(SceneError::Empty)));
    }

    /// Random rays from around the model towards it.
    fn rays_at(scene: &Scene, n: usize) -> Vec<(DVec3, Vec3)> {
        let (c, r) = (scene.bounds().center(), scene.bounds().diagonal());
        let mut rng = 12345u64;
        let mut unit = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        (0..n)
            .map(|_| {
                let from = c + Vec3::new(unit(), unit(), unit()).normalize_or(Vec3::X) * r;
                let to = c + Vec3::new(unit(), unit(), unit()) * 0.5 * r;
                (scene.origin() + from.as_dvec3(), to - from)
            })
            .collect()
    }

    #[test]
    fn ray_queries_name_the_same_splats_on_every_accelerator() {
        for surface in [crate::splat::scheme::SurfaceKind::FirstHit, crate::splat::scheme::SurfaceKind::Sj] {
            let hits = |accel| {
                let s = Settings { accel, surface, ..Settings::default() };
                let scene = sphere_scene(&s);
                scene.intersect(&rays_at(&scene, 2000), &s).unwrap()
            };
            let oracle = hits(AccelKind::Brute);
            assert!(oracle.iter().flatten().count() > 500, "most rays meet the model");
            assert_eq!(hits(AccelKind::Bvh), oracle, "{surface:?}");
            assert_eq!(hits(AccelKind::Kdtree), oracle, "{surface:?}");
        }
    }

    #[test]
    fn ray_queries_meet_the_camera_rays_first_hits() {
        let s = Settings { width: 40, height: 30, lod_threshold: 0.0, aovs: vec![Aov::Depth], ..Settings::default() };
        let scene = sphere_scene(&s);
        let job = scene.job(&s).unwrap();
        let frame = job.render(&|_| {}).unwrap();
        let rays: Vec<_> =
            (0..30).flat_map(|y| (0..40).map(move |x| (x, y))).map(|(x, y)| job.camera_ray(x, y)).collect();
        let hits = scene.intersect(&rays, &s).unwrap();
        let depth = &frame.film.first_hits.as_ref().unwrap().depth;
        assert!(hits.iter().flatten().count() > 150, "{}", hits.iter().flatten().count());
        for (hit, &d) in hits.iter().zip(depth) {
            assert_eq!(hit.map_or(f32::INFINITY, |h| h.t), d);
        }
    }

    #[test]
    fn the_data_s_up_axis_turns_the_default_view_and_the_settings_win() {
        let mut cloud = crate::demo::demo_cloud(3000, 1);
        crate::preprocess::preprocess(&mut cloud, &crate::preprocess::PreprocessConfig::standard()).unwrap();
        let s = Settings { width: 16, height: 16, ..Settings::default() };
        let scene = Scene::build(SceneParts { up: Some(Vec3::Z), ..cloud.into() }, &s).unwrap();
        let job = scene.job(&s).unwrap();
        let centre = scene.bounds().center();
        // (0.4, 0.3, 1) turned from +y to +z: (0.4, −1, 0.3), raised along z, from −y.
        let from = (job.camera.eye - centre).normalize();
        assert!((from - Vec3::new(0.4, -1.0, 0.3).normalize()).length() < 1e-5, "{from}");
        assert_eq!(job.report(&job.render(&|_| {}).unwrap()).up, [0.0, 0.0, 1.0]);
        let told = Settings { up: Some(Vec3::Y), ..s };
        assert_eq!(scene.job(&told).unwrap().report(&job.render(&|_| {}).unwrap()).up, [0.0, 1.0, 0.0]);
    }

    #[test]
    fn named_views_turn_with_the_up_axis() {
        use crate::settings::ViewPreset;
        let mut cloud = crate::demo::demo_cloud(3000, 1);
        crate::preprocess::preprocess(&mut cloud, &crate::preprocess::PreprocessConfig::standard()).unwrap();
        let s = Settings { width: 16, height: 16, ..Settings::default() };
        let z_up = Scene::build(SceneParts { up: Some(Vec3::Z), ..cloud.clone().into() }, &s).unwrap();
        let y_down = Scene::build(SceneParts { up: Some(Vec3::NEG_Y), ..cloud.clone().into() }, &s).unwrap();
        let y_up = Scene::build(cloud.into(), &s).unwrap();
        let from = |scene: &Scene, view| {
            let job = scene.job(&Settings { view: Some(view), ..s.clone() }).unwrap();
            ((job.camera.eye - scene.bounds().center()).normalize(), job.camera.up())
        };
        let close = |a: Vec3, b: Vec3| (a - b).length() < 1e-5;
        // A survey: the front from the south, the side from the east, the plan with north up.
        assert!(close(from(&z_up, ViewPreset::Front).0, Vec3::NEG_Y));
        assert!(close(from(&z_up, ViewPreset::Side).0, Vec3::X));
        let (top, up) = from(&z_up, ViewPreset::Top);
        assert!(close(top, Vec3::Z) && close(up, Vec3::Y), "{top} {up}");
        // A y-up model: its front (+z) at the foot of its plan.
        let (top, up) = from(&y_up, ViewPreset::Top);
        assert!(close(top, Vec3::Y) && close(up, Vec3::NEG_Z), "{top} {up}");
        assert!(close(from(&y_up, ViewPreset::Iso).0, Vec3::ONE.normalize()));
        // A depth frame (y down, its sensor at −z): its front is seen from the sensor's side.
        assert!(close(from(&y_down, ViewPreset::Front).0, Vec3::NEG_Z));
        let both = Settings { view: Some(ViewPreset::Top), view_dir: Some(Vec3::X), ..s };
        assert_eq!(y_up.job(&both).err().map(|e| e.option), Some("view"));
    }

    #[test]
    fn a_turntable_turns_the_camera_about_the_up_axis() {
        let s = Settings { width: 16, height: 16, ..Settings::default() };
        let scene = sphere_scene(&s);
        let eyes: Vec<Vec3> =
            scene.turntable(&s, 4).iter().map(|t| scene.job(t).unwrap().camera.eye - scene.bounds().center()).collect();
        assert_eq!(eyes[0], scene.job(&s).unwrap().camera.eye - scene.bounds().center(), "frame 0 is the view");
        for (k, eye) in eyes.iter().enumerate() {
            // A quarter turn about +y each frame: the height and the distance stay.
            let expected = glam::Quat::from_rotation_y(std::f32::consts::FRAC_PI_2 * k as f32) * eyes[0];
            assert!((*eye - expected).length() < 1e-4 * eyes[0].length(), "{k}: {eye} {expected}");
        }
        let fixed = Settings { eye: Some(DVec3::new(0.0, 1.0, 4.0)), look_at: Some(DVec3::new(0.0, 1.0, 0.0)), ..s };
        let turned = scene.turntable(&fixed, 2);
        assert!((turned[1].eye.unwrap() - DVec3::new(0.0, 1.0, -4.0)).length() < 1e-9);
    }

    #[test]
    fn an_orthographic_camera_shows_a_sphere_at_its_true_size_and_its_rays_meet_the_depths() {
        // 20,000 points on the unit sphere (a Fibonacci spiral), normals outward.
        let n = 20_000;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let world: Vec<DVec3> = (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let (s, phi) = ((1.0 - z * z).sqrt(), golden * i as f64);
                DVec3::new(s * phi.cos(), s * phi.sin(), z)
            })
            .collect();
        let mut cloud = PointCloud::from_world_positions(&world);
        cloud.normals = Some(world.iter().map(|p| p.as_vec3()).collect());
        crate::preprocess::preprocess(&mut cloud, &crate::preprocess::PreprocessConfig::standard()).unwrap();
        let s = Settings {
            width: 64,
            height: 64,
            projection: Projection::Orthographic,
            view_dir: Some(Vec3::Z),
            lod_threshold: 0.0,
            aovs: vec![Aov::Depth],
            ..Settings::default()
        };
        let scene = Scene::build(cloud.into(), &s).unwrap();
        let job = scene.job(&s).unwrap();
        let frame = job.render(&|_| {}).unwrap();
        // The frame is 2·tan 30° · 2√3 = 4 units high: the unit disk covers π/16 of it.
        let depth = &frame.film.first_hits.as_ref().unwrap().depth;
        let covered = depth.iter().filter(|d| d.is_finite()).count() as f64 / depth.len() as f64;
        assert!((covered - std::f64::consts::PI / 16.0).abs() < 0.01, "{covered}");
        // Parallel rays: the nearest point of the sphere is as far as the eye from the plane z = 1.
        let nearest = depth.iter().copied().fold(f32::INFINITY, f32::min);
        let eye_height = job.camera.eye.z - scene.bounds().center().z;
        assert!((nearest - (eye_height - 1.0)).abs() < 0.02, "{nearest} {eye_height}");
        let rays: Vec<_> =
            (0..64).flat_map(|y| (0..64).map(move |x| (x, y))).map(|(x, y)| job.camera_ray(x, y)).collect();
        let hits = scene.intersect(&rays, &s).unwrap();
        for (hit, &d) in hits.iter().zip(depth) {
            assert_eq!(hit.map_or(f32::INFINITY, |h| h.t), d);
        }
        let lens = Settings { lens_radius: 0.1, ..s };
        assert_eq!(scene.job(&lens).err().map(|e| e.option), Some("lens_radius"));
    }

    #[test]
    fn a_region_outside_the_frame_is_named() {
        let s = Settings {
            width: 16,
            height: 16,
            region: Some(Region { x0: 20, y0: 0, x1: 30, y1: 8 }),
            ..Settings::default()
        };
        let scene = sphere_scene(&s);
        let e = render(&scene, &s).unwrap_err();
        assert_eq!(e.to_string(), "region 20,0,30,8 lies outside the 16x16 frame");
    }
}
