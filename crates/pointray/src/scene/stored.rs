//! A scene as a scene file keeps it (`pointray_io::prs`, `docs/prs.md`): the BVH's arrays and
//! the input's ids as bytes, and everything else as [`SceneMeta`]; and the scene back from
//! bytes that stay mapped, rendering the same image as the scene it was.
//!
//! Only what a lone cloud makes is stored: a BVH (the accelerator whose level of detail the
//! file serves), or the parts of a two-level scene, each its arrays, with the cloud's up axis,
//! view, sun and sky. A scene file's lights and materials, and an environment map, are refused
//! when storing.

use std::borrow::Cow;
use std::ops::Range;
use std::sync::{Arc, OnceLock};

use glam::{DVec3, Vec3};

use super::{Accelerator, Build, Scene};
use crate::accel::bvh::{ARRAYS, BvhMeta, BvhStoredError, TwoLevel};
use crate::accel::stored::{StableBytes, Stored, StoredError};
use crate::accel::{Bvh, block};
use crate::math::Aabb;
use crate::settings::AccelKind;
use crate::shading::{Environment, Light};

/// The arrays of a stored scene's part, in the order [`Scene::stored`] gives them and
/// [`Scene::from_stored`] takes them: the BVH's, then the input's id of each splat slot.
pub const SCENE_ARRAYS: [&str; 7] = [ARRAYS[0], ARRAYS[1], ARRAYS[2], ARRAYS[3], ARRAYS[4], ARRAYS[5], "ids"];

/// A stored scene's part's arrays' bytes, named as [`SCENE_ARRAYS`].
pub type SceneArrays<'a> = [Cow<'a, [u8]>; 7];

/// Where a part's arrays lie in the stored bytes.
pub type PartRanges = [Range<usize>; 7];

/// A part of a stored scene: a BVH, one alone or one of a two-level scene's
/// (`accel::bvh::TwoLevel`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PartMeta {
    /// Where its positions' origin lies from the scene's (zero for a lone part).
    pub offset: [f32; 3],
    pub bvh: BvhMeta,
    /// CRC-32 of its ids, checked when a query first needs them.
    pub ids_crc: u32,
}

/// Everything of a stored scene but its arrays.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SceneMeta {
    pub points: usize,
    /// Added to the stored positions to give the input's coordinates.
    pub origin: [f64; 3],
    /// What the camera frames: minimum, maximum.
    pub bounds: [[f32; 3]; 2],
    pub mean_radius: f64,
    pub up: [f32; 3],
    pub view: Option<([f32; 3], f32)>,
    pub light: Option<Light>,
    pub environment: Option<Environment>,
    /// The settings the accelerator was built with, which a render must ask for too.
    pub build: Build,
    /// One BVH, or a two-level scene's parts in the order of their index spaces.
    pub parts: Vec<PartMeta>,
}

/// What [`SceneMeta::streamed`] needs of a cloud whose BVH was built out of core
/// (`accel::bvh::StreamedBvh`), as [`Scene::build`] finds it of the cloud in memory.
#[derive(Clone, Copy, Debug)]
pub struct StreamedCloud {
    pub points: usize,
    pub origin: DVec3,
    /// Of the positions, taken in the order of the splats.
    pub bounds: Aabb,
    /// Of the radii, summed in the order of the splats.
    pub mean_radius: f64,
}

impl SceneMeta {
    /// What [`Scene::stored`] gives of the scene [`Scene::build`] makes with `settings` of a
    /// lone cloud with `scene`'s view, light, up axis and environment, whose BVH (or parts,
    /// `parts`) was built out of core.
    pub fn streamed(
        settings: &crate::Settings,
        scene: &super::SceneParts,
        cloud: &StreamedCloud,
        parts: Vec<PartMeta>,
    ) -> SceneMeta {
        let up = scene.up.and_then(Vec3::try_normalize).unwrap_or(Vec3::Y);
        let disks = parts.iter().fold(Aabb::EMPTY, |b, p| {
            let ([lo, hi], offset) = (p.bvh.bounds, Vec3::from(p.offset));
            b.union(Aabb::new(Vec3::from(lo) + offset, Vec3::from(hi) + offset))
        });
        let bounds = if cloud.bounds.diagonal() > 0.0 { cloud.bounds } else { disks };
        let bounds =
            if bounds.diagonal() > 0.0 { bounds } else { Aabb::new(bounds.center() - 0.5, bounds.center() + 0.5) };
        SceneMeta {
            points: cloud.points,
            origin: cloud.origin.to_array(),
            bounds: [bounds.min.to_array(), bounds.max.to_array()],
            mean_radius: cloud.mean_radius,
            up: up.to_array(),
            view: scene.view.map(|(dir, distance)| (dir.to_array(), distance)),
            light: scene.light,
            environment: scene.environment.clone(),
            build: Build::of_cloud(settings, up),
            parts,
        }
    }
}

/// Why a scene cannot be stored, or stored bytes are not a scene.
#[derive(Debug, thiserror::Error)]
pub enum StoredSceneError {
    #[error("only a BVH is stored (this scene's accelerator is the {0})")]
    NotBvh(&'static str),
    #[error("a scene file's lights and materials are not stored: store its clouds")]
    Content,
    #[error("an environment map is not stored")]
    EnvironmentMap,
    #[error(transparent)]
    Bvh(#[from] BvhStoredError),
    #[error("the ids array: {0}")]
    Ids(StoredError),
    #[error("{0} ids for {1} splat slots")]
    IdCount(usize, usize),
    #[error("{0} parts' arrays for {1} parts")]
    PartCount(usize, usize),
    #[error(transparent)]
    TooLarge(#[from] crate::accel::bvh::TooLarge),
    #[error("{0}")]
    Meta(String),
    /// A stored scene stored again, read whole: a part of it failed its check or its fetch.
    #[error("the scene file it was opened from: {0}")]
    Unread(String),
}

/// The ids' CRCs (a part's each), checked once, when a query first names a point (the ids
/// fetched first where the file's bytes arrive as read: a failed fetch fails that query alone).
pub(super) struct IdsCheck {
    crcs: Vec<u32>,
    whole: OnceLock<bool>,
}

/// The most bytes of ids asked for at once, where they are fetched.
const IDS_FETCH: usize = 64 << 20;

impl IdsCheck {
    pub(super) fn check(&self, ids: &[Stored<u32>]) -> Result<(), super::RenderError> {
        if self.whole.get().is_none() {
            ids.iter()
                .try_for_each(fetch_ids)
                .map_err(|e| super::RenderError::Stored(format!("the ids array could not be read: {e}")))?;
        }
        let whole = *self.whole.get_or_init(|| {
            ids.len() == self.crcs.len()
                && ids.iter().zip(&self.crcs).all(|(ids, &crc)| crc32fast::hash(ids.as_bytes()) == crc)
        });
        let damaged = || super::RenderError::Stored("the ids array is damaged (CRC mismatch)".into());
        whole.then_some(()).ok_or_else(damaged)
    }
}

/// A part's ids fetched, where its file's bytes are, a few megabytes at a time.
fn fetch_ids(ids: &Stored<u32>) -> Result<(), String> {
    let (Some(bytes), Some(all)) = (ids.owner(), ids.byte_range(0..ids.len())) else { return Ok(()) };
    (all.start..all.end)
        .step_by(IDS_FETCH)
        .try_for_each(|at| bytes.fetch(std::slice::from_ref(&(at..(at + IDS_FETCH).min(all.end)))))
}

/// A stored scene, checked as far as opening checks it (see [`Scene::from_stored`]): what
/// [`Scene::build`] makes the scene from when [`super::SceneParts::stored`] holds one, as often
/// as asked, sharing its arrays and the checks made so far.
pub struct StoredScene {
    meta: SceneMeta,
    /// A lone part's BVH, or the parts.
    accel: StoredAccel,
    ids: Vec<Stored<u32>>,
    ids_check: Arc<IdsCheck>,
}

enum StoredAccel {
    Bvh(Box<Bvh>),
    TwoLevel(TwoLevel),
}

impl StoredAccel {
    fn share(&self) -> StoredAccel {
        match self {
            StoredAccel::Bvh(bvh) => StoredAccel::Bvh(Box::new(bvh.share())),
            StoredAccel::TwoLevel(scene) => StoredAccel::TwoLevel(scene.share()),
        }
    }

    fn accelerator(&self) -> Accelerator {
        match self.share() {
            StoredAccel::Bvh(bvh) => Accelerator::Bvh(*bvh),
            StoredAccel::TwoLevel(scene) => Accelerator::TwoLevel(scene),
        }
    }
}

impl StoredScene {
    /// The scene in `ranges` of `bytes`, with `meta`, as [`Scene::from_stored`] takes it; the
    /// same errors.
    pub fn new(
        meta: SceneMeta,
        bytes: Arc<dyn StableBytes>,
        ranges: Vec<PartRanges>,
    ) -> Result<Self, StoredSceneError> {
        check_meta(&meta).map_err(StoredSceneError::Meta)?;
        if ranges.len() != meta.parts.len() {
            return Err(StoredSceneError::PartCount(ranges.len(), meta.parts.len()));
        }
        let (mut parts, mut all_ids) = (Vec::new(), Vec::new());
        for (part, ranges) in meta.parts.iter().zip(ranges) {
            let [nodes, lod, blocks, representatives, aggregates, treelets, ids] = ranges;
            let ids = Stored::<u32>::from_bytes(Arc::clone(&bytes), ids).map_err(StoredSceneError::Ids)?;
            let arrays = [nodes, lod, blocks, representatives, aggregates, treelets];
            let bvh = Bvh::from_stored(part.bvh.clone(), Arc::clone(&bytes), arrays)?;
            let slots = bvh.blocks.len() * block::BLOCK;
            if ids.len() != slots {
                return Err(StoredSceneError::IdCount(ids.len(), slots));
            }
            parts.push((bvh, Vec3::from(part.offset)));
            all_ids.push(ids);
        }
        let accel = match parts.len() {
            1 => StoredAccel::Bvh(Box::new(parts.pop().expect("one part").0)),
            _ => StoredAccel::TwoLevel(TwoLevel::new(parts)?),
        };
        let ids_check =
            Arc::new(IdsCheck { crcs: meta.parts.iter().map(|p| p.ids_crc).collect(), whole: OnceLock::new() });
        Ok(Self { meta, accel, ids: all_ids, ids_check })
    }

    pub fn meta(&self) -> &SceneMeta {
        &self.meta
    }

    /// The scene, sharing this one's arrays.
    pub(super) fn scene(&self) -> Scene {
        let meta = self.meta.clone();
        let [lo, hi] = meta.bounds;
        Scene {
            accel: self.accel.accelerator(),
            build: meta.build,
            content: None,
            view: meta.view.map(|(dir, distance)| (Vec3::from(dir), distance)),
            up: Vec3::from(meta.up),
            light: meta.light,
            environment: meta.environment,
            origin: DVec3::from(meta.origin),
            bounds: Aabb::new(lo.into(), hi.into()),
            points: meta.points,
            mean_radius: meta.mean_radius,
            build_seconds: 0.0,
            ids: self.ids.clone(),
            stored: Some(Arc::clone(&self.ids_check)),
            backfacing: OnceLock::new(),
            environment_map: None,
        }
    }
}

impl Clone for StoredScene {
    fn clone(&self) -> Self {
        let (meta, accel, ids, ids_check) =
            (self.meta.clone(), self.accel.share(), self.ids.clone(), Arc::clone(&self.ids_check));
        Self { meta, accel, ids, ids_check }
    }
}

impl std::fmt::Debug for StoredScene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StoredScene").field("meta", &self.meta).finish_non_exhaustive()
    }
}

impl Scene {
    /// What a scene file stores of this scene: each part's arrays' bytes (named as
    /// [`SCENE_ARRAYS`]) and the rest.
    pub fn stored(&self) -> Result<(Vec<SceneArrays<'_>>, SceneMeta), StoredSceneError> {
        let bvhs: Vec<(&Bvh, Vec3)> = match &self.accel {
            Accelerator::Bvh(bvh) => vec![(bvh, Vec3::ZERO)],
            Accelerator::TwoLevel(scene) => scene.parts().iter().map(|p| (&p.bvh, p.offset)).collect(),
            _ => return Err(StoredSceneError::NotBvh(self.accel_name())),
        };
        if self.content.is_some() {
            return Err(StoredSceneError::Content);
        }
        if matches!(self.environment, Some(Environment::Map { .. })) {
            return Err(StoredSceneError::EnvironmentMap);
        }
        // Stored again, a stored scene is read whole: every treelet and the ids checked first, and
        // fetched where its file is fetched by ranges (which holds only what was read so far).
        for (bvh, _) in &bvhs {
            bvh.check_all().map_err(StoredSceneError::Unread)?;
        }
        if let Some(check) = &self.stored {
            check.check(&self.ids).map_err(|e| match e {
                super::RenderError::Stored(why) => StoredSceneError::Unread(why),
                e => StoredSceneError::Unread(e.to_string()),
            })?;
        }
        let (mut arrays, mut parts) = (Vec::new(), Vec::new());
        for ((bvh, offset), ids) in bvhs.into_iter().zip(&self.ids) {
            let ([nodes, lod, blocks, representatives, aggregates, treelets], bvh_meta) = bvh.arrays();
            let ids = ids.as_bytes();
            parts.push(PartMeta { offset: offset.to_array(), bvh: bvh_meta, ids_crc: crc32fast::hash(ids) });
            arrays.push([nodes, lod, blocks, representatives, aggregates, treelets, Cow::Borrowed(ids)]);
        }
        let b = self.bounds;
        let meta = SceneMeta {
            points: self.points,
            origin: self.origin.to_array(),
            bounds: [b.min.to_array(), b.max.to_array()],
            mean_radius: self.mean_radius,
            up: self.up.to_array(),
            view: self.view.map(|(dir, distance)| (dir.to_array(), distance)),
            light: self.light,
            environment: self.environment.clone(),
            build: self.build.clone(),
            parts,
        };
        Ok((arrays, meta))
    }

    /// The scene whose parts' arrays lie in `ranges` (each in [`SCENE_ARRAYS`]' order) of
    /// `bytes`, as [`Self::stored`] gave them, with the rest in `meta`: read where they lie,
    /// never copied.
    pub fn from_stored(
        meta: SceneMeta,
        bytes: Arc<dyn StableBytes>,
        ranges: Vec<PartRanges>,
    ) -> Result<Scene, StoredSceneError> {
        Ok(StoredScene::new(meta, bytes, ranges)?.scene())
    }
}

/// The values of `meta` the renderer divides by or frames with: finite, and bounds that hold
/// a box.
fn check_meta(meta: &SceneMeta) -> Result<(), String> {
    let [lo, hi] = meta.bounds;
    let finite = lo.iter().chain(&hi).all(|v| v.is_finite()) && meta.origin.iter().all(|v| v.is_finite());
    if !finite || lo.iter().zip(&hi).any(|(l, h)| l > h) {
        return Err(format!("the scene's bounds {lo:?}..{hi:?} (origin {:?}) are no box", meta.origin));
    }
    if Vec3::from(meta.up).try_normalize().is_none() {
        return Err(format!("the up axis {:?} is no direction", meta.up));
    }
    if meta.build.accel != AccelKind::Bvh {
        return Err(format!("the build names the {:?} accelerator, but a BVH is stored", meta.build.accel));
    }
    match &meta.parts[..] {
        [] => return Err("it holds no part".into()),
        [lone] if lone.offset != [0.0; 3] => return Err(format!("its lone part lies at {:?}", lone.offset)),
        parts if parts.iter().any(|p| !p.offset.iter().all(|v| v.is_finite())) => {
            return Err("a part's offset is not finite".into());
        }
        _ => {}
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::stored::AlignedBytes;
    use crate::preprocess::{PreprocessConfig, preprocess};
    use crate::{Settings, render};

    fn laid_out(parts: &[SceneArrays<'_>]) -> (Arc<dyn StableBytes>, Vec<PartRanges>) {
        let mut bytes = Vec::new();
        let mut part = |arrays: &SceneArrays<'_>| {
            arrays.each_ref().map(|a| {
                bytes.resize(bytes.len().next_multiple_of(crate::accel::bvh::ARRAY_ALIGN), 0);
                let start = bytes.len();
                bytes.extend_from_slice(a);
                start..bytes.len()
            })
        };
        let ranges = parts.iter().map(&mut part).collect();
        (Arc::new(AlignedBytes::copy_of(&bytes)), ranges)
    }

    #[test]
    fn a_stored_scene_renders_the_image_of_the_scene_it_was() {
        let mut cloud = crate::demo::demo_cloud(4_000, 3);
        preprocess(&mut cloud, &PreprocessConfig::standard()).unwrap();
        let settings = Settings { width: 48, height: 40, spp: 2, ..Settings::default() };
        let scene = Scene::build(crate::demo::demo_scene_parts(cloud), &settings).unwrap();
        let (arrays, meta) = scene.stored().expect("a BVH from a cloud");
        // Through JSON, as a file keeps it.
        let meta: SceneMeta = serde_json::from_str(&serde_json::to_string(&meta).unwrap()).unwrap();
        let (bytes, ranges) = laid_out(&arrays);
        let back = Scene::from_stored(meta, bytes, ranges).expect("its own arrays");
        let image = |s: &Scene| render(s, &settings).unwrap().srgb8(settings.tone_map());
        assert_eq!(image(&back), image(&scene));
        let prefiltered = Settings { prefilter: true, lod_threshold: 1.0, spp: 1, ..settings.clone() };
        let image = |s: &Scene| render(s, &prefiltered).unwrap().srgb8(settings.tone_map());
        assert_eq!(image(&back), image(&scene));
        // A query names the input's points through the stored ids.
        let (center, size) = (scene.bounds().center().as_dvec3(), scene.bounds().diagonal() as f64);
        let rays: Vec<(DVec3, Vec3)> = (0..100)
            .map(|i| {
                // From above the demo's floor (y up), down.
                let across = DVec3::new((i % 10) as f64 - 4.5, 10.0, (i / 10) as f64 - 4.5) * (0.1 * size);
                (scene.origin() + center + across, -Vec3::Y)
            })
            .collect();
        let hits = |s: &Scene| s.intersect(&rays, &settings).unwrap();
        assert!(hits(&scene).iter().flatten().count() > 10);
        assert_eq!(hits(&back), hits(&scene));
    }

    #[test]
    fn a_stored_scene_refuses_settings_its_build_does_not_allow() {
        let mut cloud = crate::demo::demo_cloud(2_000, 4);
        preprocess(&mut cloud, &PreprocessConfig::standard()).unwrap();
        let settings = Settings { width: 16, height: 16, ..Settings::default() };
        let scene = Scene::build(cloud.into(), &settings).unwrap();
        let (arrays, meta) = scene.stored().unwrap();
        let (bytes, ranges) = laid_out(&arrays);
        let back = Scene::from_stored(meta.clone(), bytes, ranges.clone()).unwrap();
        let kd = Settings { accel: AccelKind::Kdtree, ..settings.clone() };
        assert!(render(&back, &kd).is_err_and(|e| e.to_string().contains("accel")));
        // Damaged values the renderer would divide by or frame with.
        let (bytes, _) = laid_out(&arrays);
        let bad = SceneMeta { bounds: [[0.0, f32::NAN, 0.0], [1.0; 3]], ..meta.clone() };
        assert!(Scene::from_stored(bad, Arc::clone(&bytes), ranges.clone()).is_err());
        let bad = SceneMeta { up: [0.0; 3], ..meta.clone() };
        assert!(Scene::from_stored(bad, Arc::clone(&bytes), ranges.clone()).is_err());
        let mut short = ranges.clone();
        short[0][6].end -= 4;
        assert!(Scene::from_stored(meta, bytes, short).is_err_and(|e| e.to_string().contains("ids")));
    }

    #[test]
    fn only_a_bvh_is_stored() {
        let mut cloud = crate::demo::demo_cloud(1_000, 5);
        preprocess(&mut cloud, &PreprocessConfig::standard()).unwrap();
        let settings = Settings { accel: AccelKind::Kdtree, ..Settings::default() };
        let scene = Scene::build(cloud.into(), &settings).unwrap();
        assert!(matches!(scene.stored(), Err(StoredSceneError::NotBvh("kdtree"))));
    }
}
