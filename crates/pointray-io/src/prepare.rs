//! Preparing a scene file (`pointray prepare IN... -o OUT.prs`, `pointray.prepare_file`):
//! [`prepare_scene_file`] builds the scene in memory and stores it, or where that would take more
//! than the memory budget, prepares it out of core ([`prepare_out_of_core`]): the cloud read in
//! passes, never whole; its points routed by Morton cell to temporary files,
//! each cell then sorted and cleaned as preprocessing does in memory (repeated positions
//! dropped, statistical outliers on request, the given normals turned outward where they point
//! in), the missing normals and radii computed a cell at a time with a halo, and the BVH built
//! a chunk at a time ([`StreamedBvh`]) straight into the file. The file holds the same bytes as
//! preparing the cloud in memory writes (`tests`), so it renders the same images.
//!
//! What it takes, for now: binary PLY, LAS/LAZ and E57 files (read as streams, [`VertexStream`],
//! [`LasStream`], [`E57Stream`]; several are the tiles of one survey, `crate::tiles`), sorted, and a BVH's
//! build settings (class and clip filters, colours, bounding volumes). Anything else is refused,
//! naming what to do.

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use bytemuck::Zeroable;
use glam::{DVec3, Vec3};
use pointray::Settings;
use pointray::accel::Bvh;
use pointray::accel::bvh::{BvhMeta, BvhParams, ChunkPlan, Sink, Spill, Spilled, StreamedBvh, part_offset};
use pointray::accel::stored::StableBytes;
use pointray::cloud::{WorldBounds, moved_precisely, residual};
use pointray::color_by::{self, ColorBy, UnitScale};
use pointray::math::{Aabb, morton};
use pointray::preprocess::{PreprocessConfig, outliers};
use pointray::scene::{BuildLimits, PartMeta, PartRanges, SceneMeta, SceneParts, StreamedCloud};
use pointray::splat::footprint::{coverage_counts, density_of};
use pointray::splat::{DEFAULT_COLOR, Splat, pack_color};

use crate::IoError;
use crate::builder::{PointRecord, ScanFields};
use crate::e57::E57Stream;
use crate::las::LasStream;
use crate::ply::VertexStream;

/// What [`prepare_scene_file`] takes besides the files.
#[derive(Clone, Debug, Default)]
pub struct SceneFileOptions {
    pub preprocess: PreprocessConfig,
    pub read: crate::ReadOptions,
    /// The build settings the file holds (a render of it must ask for the same).
    pub settings: Settings,
    /// Prepare within about this much memory: out of core where preparing in memory would take
    /// more ([`BYTES_A_POINT`]), refused where that cannot be done. `None`: half this machine's
    /// memory, out of core only where it can be done (in memory otherwise, with a warning).
    pub memory_budget: Option<u64>,
}

/// Bytes a point takes preparing a cloud with normals and radii in memory (the 30-million-point
/// torus peaked at 2.35 GB: 78 a point).
pub const BYTES_A_POINT: u64 = 90;

/// What [`prepare_scene_file`] did.
#[derive(Clone, Debug)]
pub struct SceneFileSummary {
    /// The points stored.
    pub points: usize,
    /// Out of core: the build's chunks (`None`: prepared in memory).
    pub chunks: Option<usize>,
    /// The parts of a two-level scene (`pointray::accel::bvh::TwoLevel`), or 1.
    pub parts: usize,
    /// The file's size.
    pub bytes: u64,
}

/// Why [`prepare_scene_file`] failed.
#[derive(Debug, thiserror::Error)]
pub enum SceneFileError {
    /// A setting is out of range, or cannot be had out of core.
    #[error("{}: {}", .0.option, .0.problem)]
    Settings(pointray::settings::SettingsError),
    /// A setting the cloud cannot meet: an attribute it lacks, a filter that leaves no point.
    #[error("{}: {}", .0.option, .0.problem)]
    Unmet(pointray::settings::SettingsError),
    /// An input could not be read or prepared.
    #[error(transparent)]
    Input(IoError),
    /// The output could not be written.
    #[error(transparent)]
    Output(IoError),
}

/// Prepares the cloud at `inputs` (a file, or a survey's tiles) into the scene file `output`, in
/// memory or out of core as `options.memory_budget` says; `progress` is told each stage (with
/// its points done and in all where they are counted, out of core).
pub fn prepare_scene_file(
    inputs: &[PathBuf],
    output: &Path,
    options: &SceneFileOptions,
    progress: &dyn Fn(&Progress),
) -> Result<SceneFileSummary, SceneFileError> {
    options.preprocess.check().map_err(SceneFileError::Settings)?;
    options.settings.check().map_err(SceneFileError::Settings)?;
    // The points the headers give, or as many as fit the files at 28 bytes (a binary PLY's least).
    let size: u64 = inputs.iter().map(|i| std::fs::metadata(i).map_or(0, |m| m.len())).sum();
    let need = points_in(inputs).map_or(size / 28, |n| n as u64) * BYTES_A_POINT;
    let out_of_core = match options.memory_budget {
        Some(budget) => need > budget,
        None if need > default_budget() => match out_of_core_refusal(inputs, &options.preprocess, &options.settings) {
            None => true,
            Some(why) => {
                let name = crate::set_name(inputs);
                tracing::warn!(
                    "{}: preparing it takes more than half this machine's memory; it is prepared in memory ({why})",
                    name.display()
                );
                false
            }
        },
        None => false,
    };
    if out_of_core {
        let cell_points = OutOfCore::cells_within(options.memory_budget.unwrap_or_else(default_budget));
        let settings = options.settings.clone();
        let config = OutOfCore { preprocess: options.preprocess, settings, cell_points, ..Default::default() };
        let done = prepare_out_of_core(inputs, output, &config, progress)?;
        let bytes = std::fs::metadata(output).map_or(0, |m| m.len());
        return Ok(SceneFileSummary { points: done.points, chunks: Some(done.chunks), parts: done.parts, bytes });
    }
    let stage = |stage: &str| progress(&Progress { stage, done: 0, total: 0 });
    let source =
        crate::source::load_tiles(inputs, &options.preprocess, &options.read, &stage).map_err(SceneFileError::Input)?;
    stage("build");
    let scene = pointray::Scene::build(source.parts, &options.settings).map_err(|e| match e {
        pointray::scene::SceneError::Settings(e) => SceneFileError::Unmet(e),
        e => SceneFileError::Input(IoError::invalid(&crate::set_name(inputs), e.to_string())),
    })?;
    stage("write");
    crate::prs::write_prs(output, &scene).map_err(SceneFileError::Output)?;
    let bytes = std::fs::metadata(output).map_or(0, |m| m.len());
    Ok(SceneFileSummary { points: scene.points(), chunks: None, parts: scene.parts(), bytes })
}

/// The memory budget by default: half the physical memory (unbounded where the system does not
/// say).
fn default_budget() -> u64 {
    let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
    let total_kb = meminfo
        .lines()
        .find_map(|l| l.strip_prefix("MemTotal:")?.trim().strip_suffix("kB")?.trim().parse::<u64>().ok());
    total_kb.map_or(u64::MAX, |kb| kb * 1024 / 2)
}

/// One point as the passes keep it in their temporary files.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Record {
    code: u64,
    /// Its place in the file, which orders points of one code as the in-memory sort does.
    index: u32,
    position: [f32; 3],
    normal: [f32; 3],
    radius: f32,
    /// Packed, or the intensity's bits where the colours will show it.
    color: u32,
    /// [`GIVEN_NORMAL`], [`GIVEN_RADIUS`]: which are valid (given by the file, or computed);
    /// the class from [`CLASS_SHIFT`] on, the viewpoint from [`VIEWPOINT_SHIFT`].
    flags: u32,
    /// What `position` rounded off the file's coordinates, for a cloud that keeps it
    /// (`PointCloud::residuals`; zeros otherwise).
    residual: [f32; 3],
    _unused: u32,
}

const GIVEN_NORMAL: u32 = 1;
const GIVEN_RADIUS: u32 = 2;
const GIVEN: u32 = GIVEN_NORMAL | GIVEN_RADIUS;
/// Where a record's `flags` keep its point's class (ASPRS code; 0 without).
const CLASS_SHIFT: u32 = 8;
/// Where a record's `flags` keep which of the file's viewpoints saw its point.
const VIEWPOINT_SHIFT: u32 = 16;

impl Record {
    fn given(&self) -> bool {
        self.flags & GIVEN == GIVEN
    }

    fn class(&self) -> u8 {
        (self.flags >> CLASS_SHIFT) as u8
    }

    fn viewpoint(&self) -> u16 {
        (self.flags >> VIEWPOINT_SHIFT) as u16
    }
}

/// What preparing out of core did.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub points_read: usize,
    pub points: usize,
    pub chunks: usize,
    /// The parts of a two-level scene (`pointray::accel::bvh::TwoLevel`), or 1.
    pub parts: usize,
    pub dropped_non_finite: usize,
    pub dropped_duplicates: usize,
    /// Statistical outliers dropped (`PreprocessConfig::outlier_std`).
    pub dropped_outliers: usize,
    /// Points whose computed radius made them strays, dropped.
    pub dropped_strays: usize,
    pub turned_outward: bool,
}

impl Prepared {
    /// The warnings preprocessing in memory gives of what it dropped or turned, naming `input`.
    fn warn_repairs(&self, input: &Path) {
        let stats = pointray::preprocess::PreprocessStats {
            dropped_non_finite: self.dropped_non_finite,
            dropped_duplicates: self.dropped_duplicates,
            dropped_outliers: self.dropped_outliers,
            dropped_strays: self.dropped_strays,
            turned_outward: self.turned_outward,
            ..Default::default()
        };
        stats.warn_repairs(&input.display().to_string());
    }
}

/// How far a pass of [`prepare_out_of_core`] is: `done` of its `total` points.
#[derive(Clone, Copy, Debug)]
pub struct Progress<'a> {
    pub stage: &'a str,
    pub done: usize,
    pub total: usize,
}

/// Counts a pass's points for its [`Progress`], told every 2¹⁸ points.
struct Ticker<'a> {
    report: &'a dyn Fn(&Progress),
    stage: &'static str,
    done: usize,
    total: usize,
}

impl<'a> Ticker<'a> {
    fn new(report: &'a dyn Fn(&Progress), stage: &'static str, total: usize) -> Self {
        report(&Progress { stage, done: 0, total });
        Self { report, stage, done: 0, total }
    }

    fn tick(&mut self, points: usize) {
        let before = self.done >> 18;
        self.done += points;
        if self.done >> 18 != before {
            (self.report)(&Progress { stage: self.stage, done: self.done.min(self.total), total: self.total });
        }
    }
}

/// A cloud file read in passes: a binary PLY's vertices, a LAS/LAZ file's points, an E57 file's
/// scans.
enum Stream {
    Ply(Box<VertexStream>),
    Las(LasStream),
    E57(E57Stream),
}

impl Stream {
    fn open(path: &Path) -> Result<Self, IoError> {
        let mut start = [0; 8];
        let read = File::open(path).and_then(|mut f| f.read_exact(&mut start));
        if read.is_ok() && crate::las::looks_like_las(&start) {
            return LasStream::open(path).map(Stream::Las);
        }
        if read.is_ok() && crate::e57::looks_like_e57(&start) {
            return E57Stream::open(path).map(Stream::E57);
        }
        VertexStream::open(path).map(|s| Stream::Ply(Box::new(s)))
    }

    fn count(&self) -> usize {
        match self {
            Stream::Ply(s) => s.count,
            Stream::Las(s) => s.count,
            Stream::E57(s) => s.count,
        }
    }

    fn info(&self) -> &crate::FileInfo {
        match self {
            Stream::Ply(s) => &s.info,
            Stream::Las(s) => &s.info,
            Stream::E57(s) => &s.info,
        }
    }

    /// Whether the points have normals, and radii.
    fn given(&self) -> [bool; 2] {
        match self {
            Stream::Ply(s) => [s.attributes().normals, s.attributes().radii],
            Stream::Las(_) | Stream::E57(_) => [false; 2],
        }
    }

    /// Whether the points have colours (a LAS file's known after a pass).
    fn has_colors(&self) -> bool {
        match self {
            Stream::Ply(s) => s.attributes().colors,
            Stream::Las(s) => s.has_colors(),
            Stream::E57(s) => s.colors,
        }
    }

    /// Which scan attributes the points have.
    fn scan(&self) -> ScanFields {
        match self {
            Stream::Ply(s) => s.attributes().scan,
            Stream::Las(_) => ScanFields { intensity: true, classification: true, ..ScanFields::default() },
            Stream::E57(s) => s.fields,
        }
    }

    /// The sensors that saw the points, in the file's coordinates (a point's `viewpoint` names
    /// its own where there are several).
    fn viewpoints(&self) -> Vec<DVec3> {
        match self {
            Stream::Ply(s) => s.viewpoint.map(DVec3::from).into_iter().collect(),
            Stream::Las(_) => Vec::new(),
            Stream::E57(s) => s.scanners.clone(),
        }
    }

    fn for_each(&mut self, visit: impl FnMut(&PointRecord)) -> Result<(), IoError> {
        match self {
            Stream::Ply(s) => s.for_each(visit),
            Stream::Las(s) => s.for_each(visit),
            Stream::E57(s) => s.for_each(visit),
        }
    }
}

/// The input read in passes: a cloud file, or the tiles of a survey ([`crate::tiles`]), each
/// point placed and given what reading the tiles in memory gives it.
struct Input {
    streams: Vec<Stream>,
    /// With several tiles, each one's bounds, once [`Input::find_tile_bounds`] has found them.
    tile_bounds: Vec<WorldBounds>,
}

impl Input {
    fn open(paths: &[PathBuf]) -> Result<Self, IoError> {
        let streams = paths.iter().map(|p| Stream::open(p)).collect::<Result<Vec<_>, _>>()?;
        if streams.is_empty() {
            return Err(IoError::invalid(Path::new(""), "no input file"));
        }
        Ok(Self { streams, tile_bounds: Vec::new() })
    }

    fn count(&self) -> usize {
        self.streams.iter().map(Stream::count).sum()
    }

    /// The up axis and sun every tile gives alike.
    fn up_and_sun(&self) -> (Option<Vec3>, Option<Vec3>) {
        let up = crate::tiles::agreed(self.streams.iter().map(|s| s.info().up));
        let sun = crate::tiles::agreed(self.streams.iter().map(|s| s.info().sun));
        (up.map(Vec3::from), sun.map(Vec3::from))
    }

    /// The sensors a lone file names (see [`Stream::viewpoints`]; a survey's tiles have none).
    fn viewpoints(&self) -> Vec<DVec3> {
        match self.streams.as_slice() {
            [stream] => stream.viewpoints(),
            _ => Vec::new(),
        }
    }

    /// Whether every tile has colours (known after a pass).
    fn has_colors(&self) -> bool {
        self.streams.iter().all(Stream::has_colors)
    }

    /// Whether some tile has intensities, and classes (the others' points take 0, as in memory).
    fn scan(&self) -> [bool; 2] {
        let any = |f: fn(&ScanFields) -> bool| self.streams.iter().any(|s| f(&s.scan()));
        [any(|s| s.intensity), any(|s| s.classification)]
    }

    /// With several tiles, a pass finding each one's bounds (its origin, whether it keeps its
    /// residuals), as reading it alone would.
    fn find_tile_bounds(&mut self, ticker: &mut Ticker) -> Result<(), IoError> {
        if self.streams.len() > 1 {
            ticker.total += self.count();
            self.tile_bounds = Vec::with_capacity(self.streams.len());
            for stream in &mut self.streams {
                self.tile_bounds.push(world_bounds(stream, ticker)?);
            }
        }
        Ok(())
    }

    /// Calls `visit` with every point in file order, tile after tile (a tile's point placed,
    /// and without a normal or radius some other tile lacks).
    fn for_each(&mut self, mut visit: impl FnMut(&PointRecord)) -> Result<(), IoError> {
        // Normals and radii where every tile gives them.
        let given = self.streams.iter().map(Stream::given);
        let [normals, radii] = given.fold([true; 2], |all, g| [all[0] && g[0], all[1] && g[1]]);
        for (k, stream) in self.streams.iter_mut().enumerate() {
            let tile = self.tile_bounds.get(k);
            stream.for_each(|r| match tile {
                None => visit(r),
                Some(tile) => visit(&PointRecord {
                    position: crate::tiles::placed(r.position, tile),
                    normal: if normals { r.normal } else { Vec3::ZERO },
                    radius: if radii { r.radius } else { 0.0 },
                    ..*r
                }),
            })?;
        }
        Ok(())
    }
}

/// The bounds of `stream`'s points as one cloud read in memory finds them.
fn world_bounds(stream: &mut Stream, ticker: &mut Ticker) -> Result<WorldBounds, IoError> {
    let mut bounds = WorldBounds::default();
    stream.for_each(|r| {
        ticker.tick(1);
        bounds = bounds.with(r.position);
    })?;
    Ok(bounds)
}

/// The points of `inputs` if their headers say (a binary PLY's, a LAS file's), for estimating
/// what preparing them takes.
pub fn points_in(inputs: &[PathBuf]) -> Option<usize> {
    Input::open(inputs).ok().map(|s| s.count())
}

/// Why [`prepare_out_of_core`] would refuse `inputs` with `config` and `settings` from their
/// headers alone (none if it would not).
pub fn out_of_core_refusal(inputs: &[PathBuf], config: &PreprocessConfig, settings: &Settings) -> Option<String> {
    let refusal = || -> Result<(), SceneFileError> {
        check_config(&crate::set_name(inputs), config).map_err(SceneFileError::Input)?;
        check_settings(settings).map_err(SceneFileError::Settings)?;
        Input::open(inputs).map(|_| ()).map_err(SceneFileError::Input)
    };
    refusal().err().map(|e| e.to_string())
}

/// Out of core, the BVH alone is built.
fn check_settings(settings: &Settings) -> Result<(), pointray::settings::SettingsError> {
    settings.check()?;
    match settings.accel {
        pointray::settings::AccelKind::Bvh => Ok(()),
        _ => Err(pointray::settings::SettingsError::new("accel", "out of core, only the BVH is built")),
    }
}

fn check_config(input: &Path, config: &PreprocessConfig) -> Result<(), IoError> {
    config.check().map_err(|e| IoError::invalid(input, e.to_string()))?;
    if !config.sort {
        return Err(IoError::invalid(input, "out of core, points are always sorted"));
    }
    Ok(())
}

/// What [`prepare_out_of_core`] takes besides the files.
#[derive(Clone, Debug)]
pub struct OutOfCore {
    pub preprocess: PreprocessConfig,
    /// The build settings (a BVH's): which points are drawn, their colours, the bounding volumes.
    pub settings: Settings,
    /// The build's chunks and parts (`BvhParams::chunk_splats`, `part_splats`). The default's
    /// tree is the one a build in memory makes (`Scene::build_with_limits` for others).
    pub limits: BuildLimits,
    /// The most points in a cell whose outliers, normals and radii are found together (with a
    /// halo round each): at most `chunk_splats`, whose cells they divide.
    pub cell_points: usize,
}

/// Bytes a point of a cell takes while its normals and radii are computed (with its halo and
/// 16 neighbours each): the 30-million-point torus's cells of 3.75 million points peaked at
/// 1.11 GB (297 a point), with a margin.
const CELL_BYTES_A_POINT: u64 = 320;

impl OutOfCore {
    /// The cells' size for a memory budget: what a cell's normals take within it, at most a
    /// chunk, at least 2¹⁸ points (84 MB: a smaller budget is no real one, and would cut a
    /// small cloud's normals into cells apart). (The build's chunk of 2²² splats takes some
    /// 400 MB itself.)
    pub fn cells_within(budget: u64) -> usize {
        let chunk = BvhParams::standard().chunk_splats;
        usize::try_from(budget / CELL_BYTES_A_POINT).unwrap_or(chunk).clamp(1 << 18, chunk)
    }
}

impl Default for OutOfCore {
    fn default() -> Self {
        Self {
            preprocess: PreprocessConfig::standard(),
            settings: Settings::default(),
            limits: BuildLimits::default(),
            cell_points: BvhParams::standard().chunk_splats,
        }
    }
}

/// Prepares the cloud at `inputs` (a file, or a survey's tiles) into the scene file `output`
/// out of core (see the module); `progress` is told how far each pass is.
pub fn prepare_out_of_core(
    inputs: &[PathBuf],
    output: &Path,
    options: &OutOfCore,
    progress: &dyn Fn(&Progress),
) -> Result<Prepared, SceneFileError> {
    let (config, settings) = (&options.preprocess, &options.settings);
    let input = &crate::set_name(inputs);
    check_config(input, config).map_err(SceneFileError::Input)?;
    check_settings(settings).map_err(SceneFileError::Settings)?;
    let io = SceneFileError::Input;
    let mut stream = Input::open(inputs).map_err(io)?;
    let points_read = stream.count();
    let ticker = |stage, total| Ticker::new(progress, stage, total);
    let world = world_bounds_of(&mut stream, &mut ticker("read: origin", points_read)).map_err(io)?;
    let origin = world.origin();
    let (bounds, kept) = local_bounds(&mut stream, origin, &mut ticker("read: bounds", points_read)).map_err(io)?;
    if kept == 0 {
        return Err(io(IoError::invalid(input, "no point with finite coordinates")));
    }
    let BuildLimits { chunk_splats, part_splats } = options.limits;
    let params = BvhParams { chunk_splats, part_splats, ..pointray::scene::Build::of(settings).bvh_params() };
    let dir = crate::ScratchDir::beside(output).map_err(io)?;
    let cell_points = options.cell_points.min(params.chunk_splats);
    let provisional = plan(&mut stream, origin, bounds, kept, cell_points, &mut ticker("read: cells", 0));
    let provisional = provisional.map_err(io)?;
    let route_ticker = &mut ticker("read: route", points_read);
    let intensity = settings.color_by == ColorBy::Intensity;
    let routing = Routing { origin, residuals: world.keeps_residuals(), recompute: config.recompute, intensity };
    let mut buckets = route(&mut stream, &routing, &provisional, dir.path(), route_ticker).map_err(io)?;
    let sensors: Vec<Vec3> = stream.viewpoints().iter().map(|v| (*v - origin).as_vec3()).collect();
    let done = preprocess_cells(&mut buckets, config, &sensors, progress, kept).map_err(io)?;
    if done.dropped() == kept {
        return Err(io(IoError::invalid(input, "preprocessing: no points left")));
    }
    let (file_up, sun) = stream.up_and_sun();
    let [intensity, classes] = stream.scan();
    let scan = ScanFields { intensity, classification: classes, ..ScanFields::default() };
    let selected = select(&buckets, settings, origin, scan.classification, &mut ticker("select", kept))?;
    let count = kept - done.dropped() - selected.dropped;
    let up = file_up.and_then(Vec3::try_normalize).unwrap_or(Vec3::Y);
    let style = Style::new(&buckets, settings, up, scan, stream.has_colors())?;
    // The build's chunks: the cells, or the chunks they divide (each cell inside one).
    let plan = match done.dropped() + selected.dropped {
        0 if cell_points == params.chunk_splats => provisional,
        _ => final_plan(&mut buckets, bounds, count, params.chunk_splats, dir.path()).map_err(io)?,
    };
    let chunks = plan.chunks().len();
    let preprocessed = selected.preprocessed;
    // The view from a lone sensor framing the points preprocessing left (as in memory, before
    // the build's filters).
    let scene = |cloud: &StreamedCloud| {
        let view = match sensors[..] {
            [sensor] => crate::source::sensor_view_of(sensor, preprocessed.unwrap_or(cloud.bounds)),
            _ => None,
        };
        SceneParts { view, ..crate::source::lone_cloud_parts(file_up, sun) }
    };
    let build =
        Build { plan, params, buckets: &buckets, origin, style: &style, named: selected.named, dir: dir.path() };
    let (cloud, parts) = write(output, &build, settings, scene, &mut ticker("build", count)).map_err(io)?;
    let done = Prepared {
        points_read,
        points: cloud.points,
        chunks,
        parts,
        dropped_non_finite: points_read - kept,
        dropped_duplicates: done.duplicates,
        dropped_outliers: done.outliers,
        dropped_strays: done.strays,
        turned_outward: done.inward,
    };
    done.warn_repairs(input);
    Ok(done)
}

/// What preprocessing the cells did.
struct CellsDone {
    duplicates: usize,
    outliers: usize,
    strays: usize,
    inward: bool,
}

impl CellsDone {
    fn dropped(&self) -> usize {
        self.duplicates + self.outliers + self.strays
    }
}

/// Preprocesses the cells as preprocessing does a cloud in memory: sorted and cleaned, the
/// outliers dropped (on request), the given normals turned outward where they point in, the
/// missing normals and radii computed.
fn preprocess_cells(
    buckets: &mut [Bucket],
    config: &PreprocessConfig,
    sensors: &[Vec3],
    progress: &dyn Fn(&Progress),
    kept: usize,
) -> Result<CellsDone, IoError> {
    let ticker = |stage, total| Ticker::new(progress, stage, total);
    let cleaned = clean(buckets, &mut ticker("sort cells", kept))?;
    let outliers = match config.outlier_std {
        Some(ratio) if kept - cleaned.duplicates > 1 => {
            drop_outliers(buckets, config.k_normals, ratio, &mut ticker("outliers", kept))?
        }
        _ => 0,
    };
    let (all, given): (Vec<&Bucket>, _) = (buckets.iter().collect(), |r: &Record| r.flags & GIVEN_NORMAL != 0);
    let inward = pointing_in(&all, given, &mut ticker("orient", kept))?;
    if inward {
        turn(&all, given, &mut ticker("turn normals", kept))?;
    }
    let strays =
        if cleaned.missing == 0 { 0 } else { fill(buckets, config, sensors, &mut ticker("normals, radii", kept))? };
    Ok(CellsDone { duplicates: cleaned.duplicates, outliers, strays, inward })
}

/// The points the build draws (`Scene::build`'s class filter and clips), the others dropped from
/// the cells; where some are, each point kept is named by its place in the cloud preprocessed
/// (the ids a build in memory gives them), in its record's `index`.
struct Selected {
    dropped: usize,
    named: bool,
    /// Where points were dropped, the bounds of all preprocessing left.
    preprocessed: Option<Aabb>,
}

fn select(
    buckets: &[Bucket],
    settings: &Settings,
    origin: DVec3,
    has_classes: bool,
    ticker: &mut Ticker,
) -> Result<Selected, SceneFileError> {
    let (keep, exclude) = (settings.classes.as_deref(), &settings.exclude_classes[..]);
    let (by_class, clipped) = (keep.is_some() || !exclude.is_empty(), settings.clip_box.is_some());
    let clipped = clipped || !settings.clip_planes.is_empty();
    if !by_class && !clipped {
        return Ok(Selected { dropped: 0, named: false, preprocessed: None });
    }
    if by_class && !has_classes {
        let option = if keep.is_some() { "classes" } else { "exclude_classes" };
        let why = "needs classified points; the cloud has no classification";
        return Err(SceneFileError::Unmet(pointray::settings::SettingsError::new(option, why)));
    }
    let (mut rank, mut drawn, mut kept, mut present) = (0u32, 0usize, 0usize, [false; 256]);
    let mut preprocessed = Aabb::EMPTY;
    for b in buckets {
        let mut records = read_bucket(b).map_err(SceneFileError::Input)?;
        ticker.tick(records.len());
        records.retain_mut(|r| {
            (r.index, rank) = (rank, rank + 1);
            present[usize::from(r.class())] = true;
            preprocessed = preprocessed.union(Aabb::new(r.position.into(), r.position.into()));
            let in_class = color_by::drawn(r.class(), keep, exclude);
            let p = origin + Vec3::from(r.position).as_dvec3();
            let inside = in_class && pointray::clip::keeps(p, settings.clip_box.as_ref(), &settings.clip_planes);
            (drawn, kept) = (drawn + usize::from(in_class), kept + usize::from(inside));
            inside
        });
        write_bucket(b, &records).map_err(SceneFileError::Input)?;
    }
    if drawn == 0 {
        let option = if keep.is_some() { "classes" } else { "exclude_classes" };
        let classes = (0..=255u8).filter(|&c| present[usize::from(c)]);
        return Err(SceneFileError::Unmet(color_by::none_drawn(option, classes)));
    }
    if kept == 0 {
        return Err(SceneFileError::Unmet(pointray::clip::none_kept(&settings.clip_planes)));
    }
    Ok(Selected { dropped: rank as usize - kept, named: true, preprocessed: Some(preprocessed) })
}

/// The colours the build gives the points (`color_by::apply`'s, a point at a time): the scale of
/// intensities or heights found in passes over the cells.
struct Style {
    by: ColorBy,
    /// The elevation colours' axis.
    up: Vec3,
    scale: UnitScale,
}

impl Style {
    fn new(
        buckets: &[Bucket],
        settings: &Settings,
        up: Vec3,
        scan: ScanFields,
        has_colors: bool,
    ) -> Result<Self, SceneFileError> {
        let by = settings.color_by;
        let missing = |what: &str| {
            let why = format!("{}: the cloud has no {what}", by.name());
            SceneFileError::Unmet(pointray::settings::SettingsError::new("color_by", why))
        };
        let up = settings.up.unwrap_or(up);
        let value: fn(&Record, Vec3) -> f32 = match by {
            ColorBy::Rgb if !has_colors => return Err(missing("colours")),
            ColorBy::Intensity if !scan.intensity => return Err(missing("intensity")),
            ColorBy::Classification if !scan.classification => return Err(missing("classification")),
            ColorBy::Intensity => |r, _| f32::from_bits(r.color),
            ColorBy::Elevation => |r, up| color_by::height(Vec3::from(r.position), up),
            _ => return Ok(Self { by, up, scale: UnitScale::between(0.0, 0.0) }),
        };
        let scale = percentiles(buckets, |r| value(r, up)).map_err(SceneFileError::Input)?;
        Ok(Self { by, up, scale })
    }

    /// A point's colour, packed.
    fn color(&self, r: &Record) -> u32 {
        match self.by {
            ColorBy::Auto | ColorBy::Rgb => r.color,
            ColorBy::Intensity => pack_color(color_by::viridis(self.scale.unit(f32::from_bits(r.color)))),
            ColorBy::Classification => pack_color(color_by::classification_color(r.class())),
            ColorBy::Elevation => {
                pack_color(color_by::viridis(self.scale.unit(color_by::height(Vec3::from(r.position), self.up))))
            }
            ColorBy::Normal => pack_color(color_by::normal_color(Vec3::from(r.normal))),
        }
    }
}

/// [`UnitScale::of`] the `value` of every record: its finite values' percentiles, selected in
/// passes over the cells (`math::select::select_in_passes`).
fn percentiles(buckets: &[Bucket], value: impl Fn(&Record) -> f32) -> Result<UnitScale, IoError> {
    let each = |f: &mut dyn FnMut(f32)| -> Result<(), IoError> {
        for b in buckets {
            for_each_record(b, |r| Some(value(r)).filter(|v| v.is_finite()).into_iter().for_each(&mut *f))?;
        }
        Ok(())
    };
    let selected = pointray::math::select::select_in_passes(color_by::percentile_ranks, each)?;
    Ok(selected.map_or(UnitScale::between(0.0, 0.0), |[lo, hi]| UnitScale::between(lo, hi)))
}

/// The bounds reading the cloud in memory finds (`PointCloud::from_world_positions`): their
/// centre is its origin, and they say whether it keeps its residuals.
fn world_bounds_of(stream: &mut Input, ticker: &mut Ticker) -> Result<WorldBounds, IoError> {
    stream.find_tile_bounds(ticker)?;
    let mut bounds = WorldBounds::default();
    stream.for_each(|r| {
        ticker.tick(1);
        bounds = bounds.with(r.position);
    })?;
    Ok(bounds)
}

/// A point's position as the cloud in memory holds it (`None`: dropped as non-finite).
fn local(position: DVec3, origin: DVec3) -> Option<Vec3> {
    Some((position - origin).as_vec3()).filter(|p| p.is_finite())
}

/// The bounds of the points kept and how many.
fn local_bounds(stream: &mut Input, origin: DVec3, ticker: &mut Ticker) -> Result<(Aabb, usize), IoError> {
    let (mut bounds, mut kept) = (Aabb::EMPTY, 0usize);
    stream.for_each(|r| {
        ticker.tick(1);
        if let Some(p) = local(r.position, origin) {
            bounds = bounds.union(Aabb::new(p, p));
            kept += 1;
        }
    })?;
    Ok((bounds, kept))
}

/// The chunks of the kept points, repeats counted (they cannot be told apart before routing).
fn plan(
    stream: &mut Input,
    origin: DVec3,
    bounds: Aabb,
    kept: usize,
    most: usize,
    ticker: &mut Ticker,
) -> Result<ChunkPlan, IoError> {
    let mut failed = None;
    let plan = ChunkPlan::new(bounds, kept, most, |f| {
        // A pass for each level of cells split: the total grows as they are made.
        ticker.total += stream.count();
        let pass = stream.for_each(|r| {
            ticker.tick(1);
            if let Some(p) = local(r.position, origin) {
                f(morton::encode(p, &bounds));
            }
        });
        failed = failed.take().or(pass.err());
    });
    failed.map_or(Ok(plan), Err)
}

/// The chunks of the `count` points the buckets hold once cleaned (fewer than the plan they were
/// routed by counted: each new chunk is one or more of the buckets, which are finer).
fn replan(buckets: &[Bucket], bounds: Aabb, count: usize, most: usize) -> Result<ChunkPlan, IoError> {
    let mut failed = None;
    let plan = ChunkPlan::new(bounds, count, most, |f| {
        for b in buckets {
            if let Err(e) = for_each_record(b, |r| f(r.code)) {
                failed = failed.take().or(Some(e));
            }
        }
    });
    failed.map_or(Ok(plan), Err)
}

/// A chunk's points in a temporary file, and the least Morton code of its cell.
struct Bucket {
    path: PathBuf,
    first_code: u64,
    /// Of its points' positions, once cleaned.
    bounds: Aabb,
}

/// The buckets of a plan's cells being written, a record at a time.
struct Cells<'a> {
    plan: &'a ChunkPlan,
    buckets: Vec<Bucket>,
    writers: Vec<BufWriter<File>>,
    failed: Option<IoError>,
}

/// Files a preparation holds open beside its cells': the input, the spill, the output, the
/// standard streams, with a margin.
const OTHER_FILES: u64 = 64;

/// Raises the soft limit on open files to what `cells` files written at once take (a cloud of
/// 10⁹ points under a 1 GiB budget routes to some 300, past the usual soft limit of 1,024 by
/// 3·10⁹), or says which limit stands in the way.
fn open_files_for(cells: usize, dir: &Path) -> Result<(), IoError> {
    let needed = cells as u64 + OTHER_FILES;
    let limit = rlimit::increase_nofile_limit(needed).map_err(|e| IoError::io(dir, e))?;
    if limit < needed {
        return Err(IoError::invalid(
            dir,
            format!(
                "preparing out of core writes {cells} cells' files at once, and this process may open {limit} files: \
                 raise the limit (`ulimit -n`) or the memory budget"
            ),
        ));
    }
    Ok(())
}

impl<'a> Cells<'a> {
    /// A file in `dir` for each of `plan`'s cells, named `name` and the cell's number.
    fn create(plan: &'a ChunkPlan, dir: &Path, name: &str) -> Result<Self, IoError> {
        let cells = plan.chunks().iter().enumerate();
        let buckets: Vec<Bucket> = cells
            .map(|(c, cell)| Bucket {
                path: dir.join(format!("{name}{c}")),
                first_code: cell.first_code(),
                bounds: Aabb::EMPTY,
            })
            .collect();
        open_files_for(buckets.len(), dir)?;
        let mut writers = Vec::with_capacity(buckets.len());
        for b in &buckets {
            writers
                .push(BufWriter::with_capacity(1 << 16, File::create(&b.path).map_err(|e| IoError::io(&b.path, e))?));
        }
        Ok(Self { plan, buckets, writers, failed: None })
    }

    /// Appends `record` to its cell's file (the first failure kept for [`Cells::finish`]).
    fn write(&mut self, record: &Record) {
        let c = self.plan.chunk_of(record.code);
        let p = Vec3::from(record.position);
        self.buckets[c].bounds = self.buckets[c].bounds.union(Aabb::new(p, p));
        if let Err(e) = self.writers[c].write_all(bytemuck::bytes_of(record)) {
            self.failed = self.failed.take().or(Some(IoError::io(&self.buckets[c].path, e)));
        }
    }

    fn finish(self) -> Result<Vec<Bucket>, IoError> {
        if let Some(e) = self.failed {
            return Err(e);
        }
        for (w, b) in self.writers.into_iter().zip(&self.buckets) {
            w.into_inner().map_err(|e| IoError::io(&b.path, e.into_error()))?;
        }
        Ok(self.buckets)
    }
}

/// How [`route`] makes records of the points read.
struct Routing {
    /// Where the cloud's positions are from.
    origin: DVec3,
    /// Whether the records keep what their positions rounded off.
    residuals: bool,
    /// Normals and radii ignored, to be computed.
    recompute: bool,
    /// The intensity kept in place of the colour, which will show it.
    intensity: bool,
}

/// Every kept point written to its chunk's file, in file order.
fn route(
    stream: &mut Input,
    routing: &Routing,
    plan: &ChunkPlan,
    dir: &Path,
    ticker: &mut Ticker,
) -> Result<Vec<Bucket>, IoError> {
    let mut cells = Cells::create(plan, dir, "chunk")?;
    let mut index = 0u32;
    let colors = stream.has_colors();
    let recompute = routing.recompute;
    stream.for_each(|r| {
        ticker.tick(1);
        if let Some(p) = local(r.position, routing.origin) {
            // Normalised as preprocessing normalises the given normals; invalid ones, and
            // invalid radii, are missing (a file without them gives zeros).
            let normal = r.normal.try_normalize().filter(|_| !recompute);
            let radius = Some(r.radius).filter(|r| r.is_finite() && *r > 0.0 && !recompute);
            let given = (u32::from(normal.is_some()) * GIVEN_NORMAL) | (u32::from(radius.is_some()) * GIVEN_RADIUS);
            cells.write(&Record {
                code: plan.code(p),
                index,
                position: p.to_array(),
                normal: normal.unwrap_or(Vec3::Z).to_array(),
                radius: radius.unwrap_or(0.0),
                color: match routing.intensity {
                    true => r.intensity.to_bits(),
                    false => pack_color(if colors { r.color } else { DEFAULT_COLOR }),
                },
                flags: given | u32::from(r.classification) << CLASS_SHIFT | u32::from(r.viewpoint) << VIEWPOINT_SHIFT,
                residual: match routing.residuals {
                    true => residual(r.position, routing.origin, p).to_array(),
                    false => [0.0; 3],
                },
                _unused: 0,
            });
        }
        index += 1;
    })?;
    cells.finish()
}

/// The chunks of the points left after some were dropped, as the build in memory plans them
/// over their bounds: the cells' codes stand where the bounds did not change; otherwise every
/// point's code is found again over the new bounds and the points routed again to the new
/// plan's cells (in order: the cloud's order stays).
fn final_plan(
    buckets: &mut Vec<Bucket>,
    bounds: Aabb,
    count: usize,
    most: usize,
    dir: &Path,
) -> Result<ChunkPlan, IoError> {
    let mut left = Aabb::EMPTY;
    for b in buckets.iter() {
        for_each_record(b, |r| left = left.union(Aabb::new(r.position.into(), r.position.into())))?;
    }
    if left == bounds {
        return replan(buckets, bounds, count, most);
    }
    let code = |r: &Record| morton::encode(Vec3::from(r.position), &left);
    let mut failed = None;
    let plan = ChunkPlan::new(left, count, most, |f| {
        for b in buckets.iter() {
            if let Err(e) = for_each_record(b, |r| f(code(r))) {
                failed = failed.take().or(Some(e));
            }
        }
    });
    if let Some(e) = failed {
        return Err(e);
    }
    let mut cells = Cells::create(&plan, dir, "final")?;
    for b in buckets.iter() {
        for_each_record(b, |r| cells.write(&Record { code: code(r), ..*r }))?;
        std::fs::remove_file(&b.path).map_err(|e| IoError::io(&b.path, e))?;
    }
    *buckets = cells.finish()?;
    Ok(plan)
}

/// Calls `visit` with every record of `bucket`, in order.
fn for_each_record(bucket: &Bucket, mut visit: impl FnMut(&Record)) -> Result<(), IoError> {
    let io = |e| IoError::io(&bucket.path, e);
    let mut file = std::io::BufReader::with_capacity(1 << 20, File::open(&bucket.path).map_err(io)?);
    let mut record = Record::zeroed();
    loop {
        match file.read_exact(bytemuck::bytes_of_mut(&mut record)) {
            Ok(()) => visit(&record),
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(io(e)),
        }
    }
}

/// Rewrites `bucket` to hold `records`.
fn write_bucket(bucket: &Bucket, records: &[Record]) -> Result<(), IoError> {
    std::fs::write(&bucket.path, bytemuck::cast_slice(records)).map_err(|e| IoError::io(&bucket.path, e))
}

fn read_bucket(bucket: &Bucket) -> Result<Vec<Record>, IoError> {
    let mut records = Vec::new();
    for_each_record(bucket, |r| records.push(*r))?;
    Ok(records)
}

/// What cleaning the buckets found: repeats dropped, and the centre of the points kept.
struct Cleaned {
    duplicates: usize,
    /// Points missing a normal or a radius.
    missing: usize,
}

/// Sorts each bucket as the in-memory Morton sort orders its points, drops every point whose
/// position repeats an earlier one's (preprocessing's `drop_duplicates`: repeats share a code,
/// so a bucket), and sums the positions with given normals as `orient::turn_given_outward`
/// does, in blocks of the sorted order; notes each bucket's bounds.
fn clean(buckets: &mut [Bucket], ticker: &mut Ticker) -> Result<Cleaned, IoError> {
    let (mut duplicates, mut missing) = (0, 0);
    for b in buckets {
        let mut records = read_bucket(b)?;
        ticker.tick(records.len());
        records.sort_unstable_by_key(|r| (r.code, r.index));
        let before = records.len();
        records = without_repeats(records);
        duplicates += before - records.len();
        for r in &records {
            let p = Vec3::from(r.position);
            missing += usize::from(!r.given());
            b.bounds = b.bounds.union(Aabb::new(p, p));
        }
        write_bucket(b, &records)?;
    }
    Ok(Cleaned { duplicates, missing })
}

/// `records` (sorted by code) without those whose position (bit for bit, −0 as +0) an earlier
/// one in the file has: only points of one code can share a position.
fn without_repeats(records: Vec<Record>) -> Vec<Record> {
    let bits = |r: &Record| (Vec3::from(r.position) + Vec3::ZERO).to_array().map(f32::to_bits);
    let mut repeat = vec![false; records.len()];
    let mut start = 0;
    while start < records.len() {
        let end = start + records[start..].iter().take_while(|r| r.code == records[start].code).count();
        if end - start > 1 {
            let mut run: Vec<([u32; 3], u32, usize)> =
                (start..end).map(|i| (bits(&records[i]), records[i].index, i)).collect();
            run.sort_unstable();
            for pair in run.windows(2).filter(|w| w[0].0 == w[1].0) {
                repeat[pair[1].2] = true;
            }
        }
        start = end;
    }
    records.into_iter().zip(repeat).filter(|(_, r)| !r).map(|(r, _)| r).collect()
}

/// Sums of four terms over points in the sorted order, as `orient`'s `given_sums` adds them:
/// in blocks of 2¹⁶ points, then block by block.
#[derive(Default)]
struct BlockSums {
    block: [f64; 4],
    in_block: usize,
    total: [f64; 4],
}

impl BlockSums {
    const BLOCK: usize = pointray::preprocess::orient::SUM_BLOCK;

    /// The next point's term (`None`: a point not summed, which still counts to its block).
    fn add(&mut self, term: Option<[f64; 4]>) {
        if let Some(term) = term {
            self.block = std::array::from_fn(|k| self.block[k] + term[k]);
        }
        self.in_block += 1;
        if self.in_block == Self::BLOCK {
            self.flush();
        }
    }

    fn flush(&mut self) {
        self.total = std::array::from_fn(|k| self.total[k] + self.block[k]);
        (self.block, self.in_block) = ([0.0; 4], 0);
    }

    fn total(mut self) -> [f64; 4] {
        if self.in_block > 0 {
            self.flush();
        }
        self.total
    }
}

/// Drops the statistical outliers as preprocessing does ([`outliers`]), a bucket at a time: each
/// point's mean distance to its `k` nearest neighbours, found with the halo they reach and kept
/// beside the bucket; the limit from two passes over those in the sorted order; then each bucket
/// rewritten without the points beyond it. Returns how many were dropped.
fn drop_outliers(buckets: &[Bucket], k: usize, std_ratio: f32, ticker: &mut Ticker) -> Result<usize, IoError> {
    let distances = |b: &Bucket| b.path.with_extension("distances");
    let read_distances = |b: &Bucket| {
        let bytes = std::fs::read(distances(b)).map_err(|e| IoError::io(&distances(b), e))?;
        Ok::<Vec<f64>, IoError>(bytes.chunks_exact(8).map(|d| f64::from_ne_bytes(d.try_into().unwrap())).collect())
    };
    for (b, bucket) in buckets.iter().enumerate() {
        let records = read_bucket(bucket)?;
        ticker.tick(records.len());
        let mut positions: Vec<Vec3> = records.iter().map(|r| Vec3::from(r.position)).collect();
        let zone = halo_zone(buckets, b, &positions, k)?;
        for_each_in_zone(buckets, b, &zone, |_, r| positions.push(Vec3::from(r.position)))?;
        let mean = outliers::mean_distances(&pointray::knn::k_nearest(&positions, k), records.len());
        std::fs::write(distances(bucket), bytemuck::cast_slice(&mean))
            .map_err(|e| IoError::io(&distances(bucket), e))?;
    }
    let limit = outliers::limit(
        |visit| {
            for b in buckets {
                read_distances(b)?.into_iter().for_each(&mut *visit);
            }
            Ok(())
        },
        std_ratio,
    )?;
    let mut dropped = 0;
    for b in buckets {
        let (records, mean) = (read_bucket(b)?, read_distances(b)?);
        let kept: Vec<Record> = records.iter().zip(&mean).filter(|(_, d)| **d <= limit).map(|(r, _)| *r).collect();
        dropped += records.len() - kept.len();
        write_bucket(b, &kept)?;
        std::fs::remove_file(distances(b)).map_err(|e| IoError::io(&distances(b), e))?;
    }
    Ok(dropped)
}

/// Whether the normals of the points `counted` picks in `set` (buckets in the sorted order) point
/// inward, by `orient::turn_given_outward`'s test in its blocks: their centre, then their normals
/// along their offsets from it.
fn pointing_in(set: &[&Bucket], counted: impl Fn(&Record) -> bool, ticker: &mut Ticker) -> Result<bool, IoError> {
    let mut sums = BlockSums::default();
    for b in set {
        for_each_record(b, |r| {
            let d = Vec3::from(r.position).as_dvec3();
            sums.add(counted(r).then_some([d.x, d.y, d.z, 1.0]));
        })?;
    }
    let [x, y, z, count] = sums.total();
    let center = DVec3::new(x, y, z) / count;
    let mut sums = BlockSums::default();
    for b in set {
        for_each_record(b, |r| {
            ticker.tick(1);
            let d = Vec3::from(r.position).as_dvec3() - center;
            let normal = Vec3::from(r.normal).as_dvec3().normalize_or_zero();
            sums.add(counted(r).then(|| [normal.dot(d), d.length(), 0.0, 0.0]));
        })?;
    }
    let [along, away, ..] = sums.total();
    Ok(along < pointray::preprocess::orient::INWARD * away)
}

/// Turns the normals `turned` picks in `set`, rewriting the buckets.
fn turn(set: &[&Bucket], turned: impl Fn(&Record) -> bool, ticker: &mut Ticker) -> Result<(), IoError> {
    for b in set {
        let mut records = read_bucket(b)?;
        ticker.tick(records.len());
        for r in records.iter_mut().filter(|r| turned(r)) {
            r.normal = r.normal.map(|v| -v);
        }
        write_bucket(b, &records)?;
    }
    Ok(())
}

/// Computes the missing normals and radii a bucket at a time, with the halo of points round it
/// that its points' neighbourhoods reach ([`halo_zone`]): the normals of the buckets done before
/// it, final, are fixed and orient its own across the border, as given normals orient computed
/// ones in memory (`preprocess::fill_chunk`). The buckets are taken breadth first from bucket to
/// overlapping bucket, so that only the first of each connected set decides its orientation
/// alone, on a part of the surface; a set whose normals then point in is turned whole.
/// Rewrites each bucket, its strays dropped (or clamped, as `config.strays` says); returns how
/// many were dropped.
fn fill(
    buckets: &[Bucket],
    config: &PreprocessConfig,
    sensors: &[Vec3],
    ticker: &mut Ticker,
) -> Result<usize, IoError> {
    let n = buckets.len();
    // Queued: met by the walk; filled: done, its normals final (fixed in later halos).
    let (mut queued, mut filled, mut dropped) = (vec![false; n], vec![false; n], 0);
    // Each connected set of buckets, and whether the file gave some of its normals.
    let mut sets: Vec<(Vec<usize>, bool)> = Vec::new();
    for seed in 0..n {
        if queued[seed] {
            continue;
        }
        let (mut queue, mut set, mut given) = (std::collections::VecDeque::from([seed]), Vec::new(), false);
        queued[seed] = true;
        while let Some(b) = queue.pop_front() {
            let done = fill_bucket(buckets, b, &filled, config, sensors, ticker)?;
            filled[b] = true;
            (dropped, given) = (dropped + done.dropped, given || done.given);
            set.push(b);
            for (o, other) in buckets.iter().enumerate() {
                if !queued[o] && overlap(&other.bounds, &done.zone) {
                    queued[o] = true;
                    queue.push_back(o);
                }
            }
        }
        sets.push((set, given));
    }
    // A closed surface whose first bucket, a part of it, was oriented inward is turned whole;
    // an open one (terrain, a wall) tests near 0 and stays. (Facing a sensor needs no turn;
    // given normals orient their sets; a set of one bucket was oriented as the cloud in memory
    // is, by the same code, and is left as it is.)
    for (set, _) in sets.iter().filter(|(set, given)| sensors.is_empty() && !given && set.len() > 1) {
        let set: Vec<&Bucket> = set.iter().map(|&b| &buckets[b]).collect();
        if pointing_in(&set, |_| true, ticker)? {
            tracing::info!("turned the normals of {} cells outward", set.len());
            turn(&set, |_| true, ticker)?;
        }
    }
    Ok(dropped)
}

/// What [`fill_bucket`] found.
struct Filled {
    dropped: usize,
    /// The box its halo came from.
    zone: Aabb,
    /// Whether the file gave some of its normals.
    given: bool,
}

/// [`fill`]'s work on bucket `b`: its halo from the others (fixed where `filled`), its normals
/// and radii computed, the bucket rewritten.
fn fill_bucket(
    buckets: &[Bucket],
    b: usize,
    filled: &[bool],
    config: &PreprocessConfig,
    sensors: &[Vec3],
    ticker: &mut Ticker,
) -> Result<Filled, IoError> {
    let bucket = &buckets[b];
    let mut records = read_bucket(bucket)?;
    ticker.tick(records.len());
    let given = records.iter().any(|r| r.flags & GIVEN_NORMAL != 0);
    if records.iter().all(Record::given) {
        return Ok(Filled { dropped: 0, zone: bucket.bounds, given });
    }
    let positions: Vec<Vec3> = records.iter().map(|r| Vec3::from(r.position)).collect();
    let zone = halo_zone(buckets, b, &positions, config.k_normals.max(config.k_radius))?;
    let mut halo = Vec::new();
    // Those done before this one: final, and fixed.
    for_each_in_zone(buckets, b, &zone, |o, r| {
        halo.push(if filled[o] { Record { flags: r.flags | GIVEN, ..*r } } else { *r })
    })?;
    let all = || records.iter().chain(&halo);
    let mut cloud = pointray::PointCloud {
        positions: all().map(|r| Vec3::from(r.position)).collect(),
        normals: Some(all().map(|r| Vec3::from(r.normal)).collect()),
        radii: Some(all().map(|r| r.radius).collect()),
        viewpoints: sensors.to_vec(),
        viewpoint_of: (sensors.len() > 1).then(|| all().map(Record::viewpoint).collect()),
        ..Default::default()
    };
    let missing = |flag: u32| all().map(|r| r.flags & flag == 0).collect::<Vec<bool>>();
    let strays = pointray::preprocess::fill_chunk(&mut cloud, [&missing(GIVEN_NORMAL), &missing(GIVEN_RADIUS)], config)
        .map_err(|e| IoError::invalid(&bucket.path, format!("preprocessing: {e}")))?;
    let (normals, radii) = (cloud.normals.unwrap_or_default(), cloud.radii.unwrap_or_default());
    for (i, r) in records.iter_mut().enumerate() {
        (r.normal, r.radius, r.flags) = (normals[i].to_array(), radii[i], r.flags | GIVEN);
    }
    let mut dropped = 0;
    if config.strays == pointray::preprocess::Strays::Drop {
        let own: Vec<usize> = strays.iter().map(|&i| i as usize).filter(|&i| i < records.len()).collect();
        dropped = own.len();
        let mut keep = vec![true; records.len()];
        own.iter().for_each(|&i| keep[i] = false);
        records = records.into_iter().zip(keep).filter(|(_, k)| *k).map(|(r, _)| r).collect();
    }
    write_bucket(bucket, &records)?;
    Ok(Filled { dropped, zone, given })
}

/// Calls `visit` with every record of the buckets but `b` that lies in `zone`, and its bucket.
fn for_each_in_zone(
    buckets: &[Bucket],
    b: usize,
    zone: &Aabb,
    mut visit: impl FnMut(usize, &Record),
) -> Result<(), IoError> {
    for (o, other) in buckets.iter().enumerate().filter(|&(o, other)| o != b && overlap(&other.bounds, zone)) {
        for_each_record(other, |r| {
            let p = Vec3::from(r.position);
            if zone.contains_box(&Aabb::new(p, p)) {
                visit(o, r);
            }
        })?;
    }
    Ok(())
}

/// The box round bucket `b` that holds its `positions`' `k` nearest neighbours, its halo's zone.
/// With more than `k` points: reaching the farthest k-th neighbour among its own points, which
/// no point outside can make farther (within the bucket's diagonal). With `k` or fewer (a cell
/// at the cloud's fringe): a box round it, doubled from its size until it holds `k` other
/// points, then widened by its own diagonal, within which each point has them.
fn halo_zone(buckets: &[Bucket], b: usize, positions: &[Vec3], k: usize) -> Result<Aabb, IoError> {
    let bounds = buckets[b].bounds;
    let around = |reach: f32| {
        let reach = reach * (1.0 + 1e-5) + f32::MIN_POSITIVE;
        Aabb::new(bounds.min - reach, bounds.max + reach)
    };
    if positions.len() > k {
        let nbrs = pointray::knn::k_nearest(positions, k);
        let last = |i| nbrs.sq_dists_of(i).last().copied().unwrap_or(f32::INFINITY);
        let farthest = (0..positions.len()).map(last).fold(0.0, f32::max);
        return Ok(around(farthest.sqrt().min(bounds.diagonal())));
    }
    let whole = buckets.iter().fold(Aabb::EMPTY, |w, b| w.union(b.bounds));
    let mut reach = bounds.diagonal().max(whole.diagonal() * 1e-4);
    loop {
        let (zone, mut count) = (around(reach), positions.len());
        for_each_in_zone(buckets, b, &zone, |_, _| count += 1)?;
        if count > k || zone.contains_box(&whole) {
            return Ok(around(zone.diagonal()));
        }
        reach *= 2.0;
    }
}

fn overlap(a: &Aabb, b: &Aabb) -> bool {
    a.min.cmple(b.max).all() && b.min.cmple(a.max).all()
}

/// What the build of the scene's BVH, or of its parts, takes: the chunks of the whole cloud
/// and the cells' points.
struct Build<'a> {
    plan: ChunkPlan,
    params: BvhParams,
    buckets: &'a [Bucket],
    origin: DVec3,
    style: &'a Style,
    /// Whether the kept points are named (else counted on).
    named: bool,
    dir: &'a Path,
}

/// The cloud's scalars, summed over the parts' points as they are built.
#[derive(Default)]
struct Sums {
    points: usize,
    bounds: Aabb,
    radii: f64,
}

/// Where a part lies: its first chunk among the whole cloud's, and its frame (none for a lone
/// part: the scene's frame, its positions as the cloud holds them, as a lone BVH in memory).
struct PartAt {
    first_chunk: usize,
    offset: Option<Vec3>,
}

/// Every chunk of `build` (the part `at` of `whole`'s) built in turn from its buckets' points
/// (taken from `left`), as splats in the part's frame.
fn build_chunks<'b>(
    mut build: StreamedBvh,
    whole: &Build<'b>,
    at: &PartAt,
    left: &mut std::iter::Peekable<impl Iterator<Item = &'b Bucket>>,
    sums: &mut Sums,
    spill: &mut Files,
    ticker: &mut Ticker,
) -> Result<StreamedBvh, IoError> {
    for c in 0..build.plan().chunks().len() {
        let (mut splats, mut names) = (Vec::new(), Vec::new());
        while let Some(bucket) = left.next_if(|b| whole.plan.chunk_of(b.first_code) == at.first_chunk + c) {
            for_each_record(bucket, |r| {
                let center = Vec3::from(r.position);
                sums.bounds = sums.bounds.union(Aabb::new(center, center));
                sums.radii += f64::from(r.radius);
                let (normal, color) = (Vec3::from(r.normal), whole.style.color(r));
                let center = at.offset.map_or(center, |o| moved_precisely(center, Vec3::from(r.residual), o));
                splats.push(Splat { center, radius: r.radius, normal, color });
                names.push(r.index);
            })?;
        }
        sums.points += splats.len();
        ticker.tick(splats.len());
        let names = whole.named.then_some(&names[..]);
        build.add_chunk(splats, names, spill).map_err(|e| IoError::invalid(&spill.dir, e.to_string()))?;
    }
    Ok(build)
}

/// Builds each part of `build` (one, or a two-level scene's) in turn into `file`, the
/// part's arrays after the parts' before; their places, what the metadata says of them and
/// the cloud's scalars.
fn build_parts(
    file: &File,
    build: &Build<'_>,
    ticker: &mut Ticker,
) -> Result<(Vec<PartRanges>, Vec<PartMeta>, StreamedCloud), IoError> {
    let parts = build.plan.parts(build.params.part_splats);
    // Cells every point was dropped from may lie outside every chunk: passed over.
    let mut kept = Vec::with_capacity(build.buckets.len());
    for b in build.buckets {
        if std::fs::metadata(&b.path).map_err(|e| IoError::io(&b.path, e))?.len() > 0 {
            kept.push(b);
        }
    }
    let mut left = kept.iter().copied().peekable();
    let (mut ranges, mut metas, mut sums) = (Vec::new(), Vec::new(), Sums::default());
    let (lone, mut first_chunk, mut first_id) = (parts.len() == 1, 0, 0);
    for (cell, chunks) in parts {
        let count = chunks.chunks().len();
        let chunks_of_part = first_chunk..first_chunk + count;
        let offset = match lone {
            true => None,
            false => Some(part_offset(part_bounds(build, &kept, chunks_of_part)?)),
        };
        let mut spill = Files::new(build.dir)?;
        let part = StreamedBvh::new(chunks, &build.params).starting_at(first_id);
        let at = PartAt { first_chunk, offset };
        let part = build_chunks(part, build, &at, &mut left, &mut sums, &mut spill, ticker)?;
        let placed = crate::prs::layout(part.lengths(), crate::prs::arrays_end(&ranges));
        let finished = part.finish(&mut spill, &mut FileSink { file, ranges: &placed }).map_err(|e| match e {
            pointray::accel::bvh::StreamedError::Io(e) => IoError::io(&spill.dir, e),
            e => IoError::invalid(&spill.dir, e.to_string()),
        })?;
        let mut bvh = finished.meta;
        let density = coverage_density(file, &placed, &bvh, &finished.coverage_samples);
        bvh.coverage_density = density.map_err(|e| IoError::io(&spill.dir, e))?;
        metas.push(PartMeta { offset: offset.unwrap_or(Vec3::ZERO).to_array(), bvh, ids_crc: finished.ids_crc });
        ranges.push(placed);
        (first_chunk, first_id) = (first_chunk + count, first_id + cell.count);
    }
    let Sums { points, bounds, radii } = sums;
    let cloud = StreamedCloud { points, origin: build.origin, bounds, mean_radius: radii / points as f64 };
    Ok((ranges, metas, cloud))
}

/// The bounds of the points of `chunks` (those of their buckets in `kept`, the buckets some point
/// is left in), found in a pass over them: a part's frame is centred on them, as in memory
/// (`TwoLevel`). (The buckets' own bounds may hold points since dropped.)
fn part_bounds(build: &Build<'_>, kept: &[&Bucket], chunks: std::ops::Range<usize>) -> Result<Aabb, IoError> {
    let mut bounds = Aabb::EMPTY;
    for b in kept.iter().filter(|b| chunks.contains(&build.plan.chunk_of(b.first_code))) {
        for_each_record(b, |r| bounds = bounds.union(Aabb::new(r.position.into(), r.position.into())))?;
    }
    Ok(bounds)
}

/// [`Bvh::measure_coverage_density`] of the tree written to `file` (its `samples` read while it
/// was written), mapped afresh for every batch of samples: a sample's neighbours lie in a few
/// treelets, each read whole for its check, and mapped once for all, the pages read stay
/// resident.
fn coverage_density(file: &File, ranges: &PartRanges, meta: &BvhMeta, samples: &[Splat]) -> std::io::Result<f32> {
    let tree = || -> std::io::Result<Bvh> {
        let bytes: Arc<dyn StableBytes> = Arc::new(crate::file::map_for_reading(file)?);
        let [nodes, lod, blocks, reps, aggregates, treelets, _] = ranges.clone();
        let meta = BvhMeta { coverage_density: 1.0, ..meta.clone() };
        Bvh::from_stored(meta, bytes, [nodes, lod, blocks, reps, aggregates, treelets])
            .map_err(|e| std::io::Error::other(format!("the tree written does not read back: {e}")))
    };
    let (mut covering, mut count) = (0, 0);
    for batch in samples.chunks(256) {
        let (c, n) = coverage_counts(&tree()?, batch.iter().copied());
        (covering, count) = (covering + c, count + n);
    }
    Ok(density_of((covering, count)))
}

/// The spilled arrays, a file each.
struct Files {
    dir: PathBuf,
    files: Vec<File>,
}

impl Files {
    fn new(dir: &Path) -> Result<Self, IoError> {
        let files = (0..7)
            .map(|i| {
                let path = dir.join(format!("spill{i}"));
                File::options()
                    .read(true)
                    .write(true)
                    .create(true)
                    .truncate(true)
                    .open(&path)
                    .map_err(|e| IoError::io(&path, e))
            })
            .collect::<Result<_, _>>()?;
        Ok(Self { dir: dir.to_path_buf(), files })
    }
}

impl Spill for Files {
    fn append(&mut self, array: Spilled, bytes: &[u8]) -> std::io::Result<()> {
        let f = &mut self.files[array as usize];
        f.seek(SeekFrom::End(0))?;
        f.write_all(bytes)
    }

    fn read_at(&mut self, array: Spilled, offset: usize, buf: &mut [u8]) -> std::io::Result<()> {
        std::os::unix::fs::FileExt::read_exact_at(&self.files[array as usize], buf, offset as u64)
    }
}

/// The scene file being written, its arrays where `ranges` put them.
struct FileSink<'a> {
    file: &'a File,
    ranges: &'a PartRanges,
}

impl Sink for FileSink<'_> {
    fn write_at(&mut self, array: usize, offset: usize, bytes: &[u8]) -> std::io::Result<()> {
        debug_assert!(self.ranges[array].start + offset + bytes.len() <= self.ranges[array].end);
        std::os::unix::fs::FileExt::write_all_at(self.file, bytes, (self.ranges[array].start + offset) as u64)
    }
}

/// Writes the scene file: each part's arrays, then (with each part's coverage density found
/// from them, mapped) the index, metadata and header; the cloud's scalars and the parts.
fn write(
    output: &Path,
    build: &Build<'_>,
    settings: &Settings,
    scene: impl Fn(&StreamedCloud) -> SceneParts,
    ticker: &mut Ticker,
) -> Result<(StreamedCloud, usize), IoError> {
    let (mut failed, mut done) = (None, None);
    crate::atomic_file(output, |file| {
        let mut fail = |e: IoError| {
            let message = e.to_string();
            failed = Some(e);
            std::io::Error::other(message)
        };
        let (ranges, parts, cloud) = build_parts(file, build, ticker).map_err(&mut fail)?;
        file.set_len(crate::prs::arrays_end(&ranges) as u64)?;
        let count = parts.len();
        let meta = SceneMeta::streamed(settings, &scene(&cloud), &cloud, parts);
        let (header, tail) = crate::prs::tail(output, &ranges, &meta).map_err(&mut fail)?;
        std::os::unix::fs::FileExt::write_all_at(file, &tail, crate::prs::arrays_end(&ranges) as u64)?;
        std::os::unix::fs::FileExt::write_all_at(file, &header, 0)?;
        done = Some((cloud, count));
        Ok(())
    })
    .map_err(|e| failed.take().unwrap_or(e))?;
    Ok(done.expect("written"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pointray::PointCloud;

    /// A thin wall: two sheets 0.03 apart, of `n` × `n / 6` points each, a little jittered.
    fn wall(n: usize) -> PointCloud {
        let mut positions = Vec::new();
        let jitter = |i: usize| ((i * 7_919) % 101) as f32 * 1e-5;
        for z in [0.0, 0.03] {
            for i in 0..n {
                for j in 0..n / 6 {
                    positions.push(Vec3::new(i as f32 * 0.01 + jitter(i + j), j as f32 * 0.01 + jitter(j * 3 + i), z));
                }
            }
        }
        PointCloud { positions, ..PointCloud::default() }
    }

    /// The points' normals, read back from the buckets, by their positions' bits.
    fn normals_in(buckets: &[Bucket]) -> std::collections::HashMap<[u32; 3], Vec3> {
        let mut normals = std::collections::HashMap::new();
        for b in buckets {
            for_each_record(b, |r| {
                assert!(r.given());
                normals.insert(r.position.map(f32::to_bits), Vec3::from(r.normal));
            })
            .unwrap();
        }
        normals
    }

    /// `cloud` written and prepared out of core in cells of at most `cell` points up to its
    /// normals: the normals read back by position, and the cloud preprocessed in memory.
    fn out_of_core_normals(cloud: &PointCloud, cell: usize) -> (std::collections::HashMap<[u32; 3], Vec3>, PointCloud) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cloud.ply");
        crate::write_ply(&path, cloud).unwrap();
        let config = PreprocessConfig::standard();
        let mut whole = crate::read_cloud(&path).unwrap().cloud;
        pointray::preprocess::preprocess(&mut whole, &config).unwrap();
        let ticker = &mut Ticker::new(&|_| {}, "test", 0);
        let mut stream = Input::open(std::slice::from_ref(&path)).unwrap();
        let origin = world_bounds_of(&mut stream, ticker).unwrap().origin();
        assert_eq!(origin, whole.origin);
        let (bounds, kept) = local_bounds(&mut stream, origin, ticker).unwrap();
        let plan = plan(&mut stream, origin, bounds, kept, cell, ticker).unwrap();
        let routing = Routing { origin, residuals: false, recompute: false, intensity: false };
        let mut buckets = route(&mut stream, &routing, &plan, dir.path(), ticker).unwrap();
        assert!(buckets.len() >= 8, "{} cells", buckets.len());
        let cleaned = clean(&mut buckets, ticker).unwrap();
        assert_eq!((cleaned.duplicates, cleaned.missing), (0, kept));
        assert_eq!(fill(&buckets, &config, &[], ticker).unwrap(), whole.len().abs_diff(kept));
        (normals_in(&buckets), whole)
    }

    #[test]
    fn normals_computed_a_cell_at_a_time_agree_across_the_cells_borders() {
        let (normals, whole) = out_of_core_normals(&wall(240), 1_500);
        let given = whole.normals.as_ref().unwrap();
        let agree =
            whole.positions.iter().zip(given).filter(|(p, n)| normals[&p.to_array().map(f32::to_bits)].dot(**n) > 0.9);
        // Every sheet's side, in every cell, as the whole cloud orients it.
        assert_eq!(agree.count(), whole.len());
        // And the two sheets (at z = ±0.015 about the origin) face away from each other, as a
        // wall's sides do.
        let outward = normals.iter().filter(|(p, n)| (n.z > 0.0) == (f32::from_bits(p[2]) > 0.0)).count();
        assert!(outward as f64 >= 0.97 * whole.len() as f64, "{outward} of {} face out", whole.len());
    }

    /// The statistical outlier filter, a cell at a time with halos, drops exactly the points the
    /// filter over the whole cloud drops: a sphere with its normals and radii (nothing else
    /// dropped) and 40 points strewn round it, in cells of at most 800.
    #[test]
    fn outliers_dropped_a_cell_at_a_time_are_those_dropped_in_memory() {
        let n = 12_000;
        let mut positions: Vec<Vec3> = (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let (r, phi) = ((1.0 - z * z).sqrt(), i as f32 * 2.399_963);
                Vec3::new(r * phi.cos(), r * phi.sin(), z) * 3.0
            })
            .collect();
        positions.extend((0..40).map(|i| {
            let a = i as f32 * 0.7;
            Vec3::new(a.cos(), a.sin(), (a * 0.3).cos()) * (3.2 + 0.05 * i as f32)
        }));
        let normals = Some(positions.iter().map(|p| p.normalize()).collect());
        let radii = Some(vec![0.05; positions.len()]);
        let cloud = PointCloud { positions, normals, radii, ..PointCloud::default() };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cloud.ply");
        crate::write_ply(&path, &cloud).unwrap();
        let config = PreprocessConfig { outlier_std: Some(1.0), ..PreprocessConfig::standard() };
        let mut whole = crate::read_cloud(&path).unwrap().cloud;
        let stats = pointray::preprocess::preprocess(&mut whole, &config).unwrap();
        assert!(stats.dropped_outliers >= 40, "{}", stats.dropped_outliers);
        let ticker = &mut Ticker::new(&|_| {}, "test", 0);
        let mut stream = Input::open(&[path]).unwrap();
        let origin = world_bounds_of(&mut stream, ticker).unwrap().origin();
        let (bounds, kept) = local_bounds(&mut stream, origin, ticker).unwrap();
        let plan = plan(&mut stream, origin, bounds, kept, 800, ticker).unwrap();
        let routing = Routing { origin, residuals: false, recompute: false, intensity: false };
        let mut buckets = route(&mut stream, &routing, &plan, dir.path(), ticker).unwrap();
        assert!(buckets.len() >= 16, "{} cells", buckets.len());
        clean(&mut buckets, ticker).unwrap();
        let dropped = drop_outliers(&buckets, config.k_normals, 1.0, ticker).unwrap();
        assert_eq!(dropped, stats.dropped_outliers);
        let mut left = Vec::new();
        for b in &buckets {
            for_each_record(b, |r| left.push(r.position)).unwrap();
        }
        let whole: Vec<[f32; 3]> = whole.positions.iter().map(|p| p.to_array()).collect();
        assert_eq!(left, whole, "the same points, in the same order");
        // The points left are planned over their own bounds, as a build in memory plans them.
        let final_plan = final_plan(&mut buckets, bounds, kept - dropped, 800, dir.path()).unwrap();
        let left_bounds = Aabb::from_points(whole.iter().map(|&p| Vec3::from(p)));
        for (c, b) in buckets.iter().enumerate() {
            for_each_record(b, |r| {
                assert_eq!(r.code, morton::encode(Vec3::from(r.position), &left_bounds));
                assert_eq!(final_plan.chunk_of(r.code), c);
            })
            .unwrap();
        }
    }

    #[test]
    fn a_closed_surface_in_many_cells_faces_out() {
        // A sphere of 20,000 points in cells of at most 800: the first cell of the walk, a cap,
        // decides its side alone; the sphere as a whole is turned out if it chose in.
        let n = 20_000;
        let positions = (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let (r, phi) = ((1.0 - z * z).sqrt(), i as f32 * 2.399_963);
                Vec3::new(r * phi.cos(), r * phi.sin(), z) * 3.0
            })
            .collect();
        let (normals, whole) = out_of_core_normals(&PointCloud { positions, ..PointCloud::default() }, 800);
        let outward = normals.iter().filter(|(p, n)| n.dot(Vec3::from(p.map(f32::from_bits))) > 0.0).count();
        assert_eq!(outward, whole.len(), "{outward} of {} face out", whole.len());
    }
}
