//! The Python package's native module, `pointray._pointray`: a thin layer over the library.
//! Clouds and images are numpy arrays; options are the command line's render options by the
//! same names (`pointray::Settings`' fields), checked there; errors are `OSError` (the system
//! refused a file) or `ValueError` (bad input or options), with the command line's messages.
//! Long work runs with the GIL released; a render stops at Ctrl-C.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::RecvTimeoutError;
use std::time::Duration;

use glam::{DVec3, Vec3};
use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{AllowTypeChange, IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayLike1, PyArrayLike2, PyArrayLike3};
use pointray::PointCloud;
use pointray::camera_path::Animation;
use pointray::film::ToneMap;
use pointray::frame::Aov;
use pointray::preprocess::PreprocessConfig;
use pointray::scene::SceneParts;
use pointray::settings::Settings;
use pointray_io::IoError;
use pointray_io::fetched::RangeReader;
use pointray_io::video::Mp4Writer;
use pyo3::exceptions::{PyFileNotFoundError, PyKeyboardInterrupt, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

/// A point cloud: positions (N×3, float64, in the file's coordinates), and where known the
/// normals (N×3), colours (N×3, sRGB-encoded as files store them, 0 to 1) and splat radii (N), float32; and the scan
/// attributes: intensity (float32), classification and return number (uint8), GPS time
/// (float64), N each.
#[pyclass(module = "pointray", name = "Cloud", frozen)]
struct Cloud {
    inner: PointCloud,
}

#[pymethods]
impl Cloud {
    #[new]
    #[pyo3(signature = (positions, normals=None, colors=None, radii=None, *, intensity=None,
        classification=None, return_number=None, gps_time=None))]
    #[allow(clippy::too_many_arguments)] // Python's keywords, one a column
    fn new(
        positions: PyArrayLike2<'_, f64, AllowTypeChange>,
        normals: Option<PyArrayLike2<'_, f32, AllowTypeChange>>,
        colors: Option<PyArrayLike2<'_, f32, AllowTypeChange>>,
        radii: Option<PyArrayLike1<'_, f32, AllowTypeChange>>,
        intensity: Option<PyArrayLike1<'_, f32, AllowTypeChange>>,
        classification: Option<PyArrayLike1<'_, u8, AllowTypeChange>>,
        return_number: Option<PyArrayLike1<'_, u8, AllowTypeChange>>,
        gps_time: Option<PyArrayLike1<'_, f64, AllowTypeChange>>,
    ) -> PyResult<Self> {
        let world: Vec<DVec3> = rows::<f64>("positions", &positions, None)?.into_iter().map(DVec3::from).collect();
        let n = world.len();
        let mut inner = PointCloud::from_world_positions(&world);
        inner.normals =
            normals.map(|a| rows("normals", &a, Some(n))).transpose()?.map(|v| v.into_iter().map(Vec3::from).collect());
        inner.colors = colors.map(|a| rows("colors", &a, Some(n))).transpose()?;
        inner.radii = radii.map(|a| column("radii", &a, n)).transpose()?;
        inner.scan.intensity = intensity.map(|a| column("intensity", &a, n)).transpose()?;
        inner.scan.classification = classification.map(|a| column("classification", &a, n)).transpose()?;
        inner.scan.return_number = return_number.map(|a| column("return_number", &a, n)).transpose()?;
        inner.scan.gps_time = gps_time.map(|a| column("gps_time", &a, n)).transpose()?;
        if inner.colors.as_ref().is_some_and(|c| c.iter().flatten().any(|v| !(0.0..=1.0).contains(v))) {
            return Err(PyValueError::new_err("colors: every channel must be between 0 and 1"));
        }
        Ok(Self { inner })
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        let has = |yes: bool, what: &str| if yes { format!(", {what}") } else { String::new() };
        format!(
            "Cloud({} points{}{}{})",
            c.len(),
            has(c.normals.is_some(), "normals"),
            has(c.colors.is_some(), "colors"),
            has(c.radii.is_some(), "radii")
        )
    }

    #[getter]
    fn positions<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let c = &self.inner;
        table((0..c.len()).map(|i| c.world_position(i).to_array())).into_pyarray(py)
    }

    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f32>>> {
        self.inner.normals.as_ref().map(|n| table(n.iter().map(|v| v.to_array())).into_pyarray(py))
    }

    #[getter]
    fn colors<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f32>>> {
        self.inner.colors.as_ref().map(|c| table(c.iter().copied()).into_pyarray(py))
    }

    #[getter]
    fn radii<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f32>>> {
        self.inner.radii.as_ref().map(|r| Array1::from(r.clone()).into_pyarray(py))
    }

    #[getter]
    fn intensity<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f32>>> {
        self.inner.scan.intensity.as_ref().map(|v| Array1::from(v.clone()).into_pyarray(py))
    }

    #[getter]
    fn classification<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<u8>>> {
        self.inner.scan.classification.as_ref().map(|v| Array1::from(v.clone()).into_pyarray(py))
    }

    #[getter]
    fn return_number<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<u8>>> {
        self.inner.scan.return_number.as_ref().map(|v| Array1::from(v.clone()).into_pyarray(py))
    }

    #[getter]
    fn gps_time<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.inner.scan.gps_time.as_ref().map(|v| Array1::from(v.clone()).into_pyarray(py))
    }
}

/// A column of `n` values, checked for the length.
fn column<T: numpy::Element + Copy>(
    name: &str,
    a: &PyArrayLike1<'_, T, AllowTypeChange>,
    n: usize,
) -> PyResult<Vec<T>> {
    let a = a.as_array();
    if a.len() != n {
        return Err(PyValueError::new_err(format!("{name}: {} values for {n} points", a.len())));
    }
    Ok(a.iter().copied().collect())
}

/// An N×3 array's rows, checked for the shape (and `expect`ed count).
fn rows<T: numpy::Element + Copy>(
    name: &str,
    a: &PyArrayLike2<'_, T, AllowTypeChange>,
    expect: Option<usize>,
) -> PyResult<Vec<[T; 3]>> {
    let a = a.as_array();
    let (n, k) = a.dim();
    if k != 3 || expect.is_some_and(|e| e != n) {
        let want = expect.map_or("N".to_string(), |e| e.to_string());
        return Err(PyValueError::new_err(format!("{name}: expected a {want}x3 array, got {n}x{k}")));
    }
    Ok(a.outer_iter().map(|r| [r[0], r[1], r[2]]).collect())
}

/// Rows of three as an N×3 array.
fn table<T: Copy>(rows: impl Iterator<Item = [T; 3]>) -> Array2<T> {
    let flat: Vec<T> = rows.flatten().collect();
    let n = flat.len() / 3;
    Array2::from_shape_vec((n, 3), flat).expect("rows of three")
}

/// `Scene.intersect`'s distances, splat ids and normals.
type Hits<'py> = (Bound<'py, PyArray1<f32>>, Bound<'py, PyArray1<i64>>, Bound<'py, PyArray2<f32>>);

/// `Scene.camera_rays`' origins and directions.
type Rays<'py> = (Bound<'py, PyArray3<f64>>, Bound<'py, PyArray3<f32>>);

/// A prepared scene: splats in a multiresolution accelerator, built once, rendered and
/// queried as often as wanted. `pointray.prepare` makes one.
#[pyclass(module = "pointray", name = "Scene", frozen)]
struct Scene {
    inner: pointray::Scene,
    /// The settings it was built with (and a scene file's own): the base of every render.
    settings: Settings,
    /// A scene file's `[animation]`.
    animation: Option<Animation>,
}

#[pymethods]
impl Scene {
    fn __len__(&self) -> usize {
        self.inner.points()
    }

    fn __repr__(&self) -> String {
        format!("Scene({} splats, {})", self.inner.points(), self.inner.accel_name())
    }

    /// The first surface point along each ray, at full detail: `origins` (N×3, in the file's
    /// coordinates) and `directions` (N×3, any length). Returns `(t, splat_id, normal)`: the
    /// distance along the normalised direction (inf for a miss), the nearest splat's index in
    /// the prepared cloud (-1 for a miss) and the shading normal facing the ray (NaN for a miss).
    #[pyo3(signature = (origins, directions, **options))]
    fn intersect<'py>(
        &self,
        py: Python<'py>,
        origins: PyArrayLike2<'py, f64, AllowTypeChange>,
        directions: PyArrayLike2<'py, f32, AllowTypeChange>,
        options: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<Hits<'py>> {
        let (pool, options) = RunOptions::pool_only(options, "intersect")?;
        let settings = with_options(&self.settings, options.as_ref())?;
        let origins = rows::<f64>("origins", &origins, None)?;
        let directions = rows::<f32>("directions", &directions, Some(origins.len()))?;
        let rays: Vec<(DVec3, Vec3)> =
            origins.into_iter().zip(directions).map(|(o, d)| (DVec3::from(o), Vec3::from(d))).collect();
        let hits = py.detach(|| pool.install(|| self.inner.intersect(&rays, &settings))).map_err(value_error)?;
        let t = hits.iter().map(|h| h.map_or(f32::INFINITY, |h| h.t)).collect::<Vec<_>>();
        let ids = hits.iter().map(|h| h.map_or(-1, |h| i64::from(h.splat))).collect::<Vec<_>>();
        let normals = table(hits.iter().map(|h| h.map_or([f32::NAN; 3], |h| h.normal.to_array())));
        Ok((Array1::from(t).into_pyarray(py), Array1::from(ids).into_pyarray(py), normals.into_pyarray(py)))
    }

    /// Writes the scene as a scene file (`.prs`, written whole or not at all), which
    /// `pointray.prepare` and `pointray render` open without a build, reading only what a view
    /// needs. Only a BVH scene made from a lone cloud can be stored.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| pointray_io::prs::write_prs(&path, &self.inner)).map_err(io_error)
    }

    /// A turntable's views, as `pointray render --turntable` turns them: for each of `frames`
    /// frames, the camera options (`eye`, `look_at`, `fov`, `view_dir`, `view`) of the view
    /// `options` give turned about the up axis by 360°·k/frames (frame 0 is that view), to
    /// render with them.
    #[pyo3(signature = (frames, **options))]
    fn turntable<'py>(
        &self,
        py: Python<'py>,
        frames: u32,
        options: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let settings = with_options(&self.settings, options)?;
        self.inner.turntable(&settings, frames).iter().map(|view| camera_options(py, view)).collect()
    }

    /// The frames of the scene file's `[animation]` (0 without one).
    #[getter]
    fn frames(&self) -> u32 {
        self.animation.as_ref().map_or(0, Animation::frames)
    }

    /// Frame `k` of the scene file's `[animation]` (a camera path through keyframes, or an
    /// orbit): its camera options (`eye`, `look_at`, `fov`, `view_dir`, `view`) over those
    /// `options` give, to render with them.
    #[pyo3(signature = (k, **options))]
    fn animation_frame<'py>(
        &self,
        py: Python<'py>,
        k: u32,
        options: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let Some(animation) = &self.animation else {
            return Err(PyValueError::new_err("the scene has no [animation]"));
        };
        if k >= animation.frames() {
            return Err(PyValueError::new_err(format!("frame {k}: the animation has {}", animation.frames())));
        }
        let settings = with_options(&self.settings, options)?;
        camera_options(py, &animation.frame(&self.inner, &settings, k))
    }

    /// The camera's rays through every pixel's centre, for `intersect`: origins (H×W×3,
    /// float64) and directions (H×W×3, float32, not normalised). Options as for `render`.
    #[pyo3(signature = (**options))]
    fn camera_rays<'py>(&self, py: Python<'py>, options: Option<&Bound<'py, PyDict>>) -> PyResult<Rays<'py>> {
        let settings = with_options(&self.settings, options)?;
        // Without the GIL: the job's probes may fetch parts of a scene file at a URL, through
        // Python on another thread.
        let job = py.detach(|| self.inner.job(&settings)).map_err(value_error)?;
        let (w, h) = (settings.width as usize, settings.height as usize);
        let (mut origins, mut directions) = (Vec::with_capacity(w * h * 3), Vec::with_capacity(w * h * 3));
        for y in 0..settings.height {
            for x in 0..settings.width {
                let (o, d) = job.camera_ray(x, y);
                origins.extend(o.to_array());
                directions.extend(d.to_array());
            }
        }
        let shape = (h, w, 3);
        let origins = Array3::from_shape_vec(shape, origins).expect("a ray a pixel");
        let directions = Array3::from_shape_vec(shape, directions).expect("a ray a pixel");
        Ok((origins.into_pyarray(py), directions.into_pyarray(py)))
    }
}

/// The camera options of `view`, by `Settings`' names: what a frame of an animation changes.
fn camera_options<'py>(py: Python<'py>, view: &Settings) -> PyResult<Bound<'py, PyDict>> {
    let all = serde_json::to_value(view).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    let camera = PyDict::new(py);
    for key in ["eye", "look_at", "fov", "view_dir", "view"] {
        let value = pythonize::pythonize(py, &all[key]).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
        camera.set_item(key, value)?;
    }
    Ok(camera)
}

/// A rendered frame: the image, the AOVs asked for (`aovs=["depth", ...]`) and the statistics.
#[pyclass(module = "pointray", name = "Frame", frozen)]
struct Frame {
    frame: pointray::Frame,
    aovs: Vec<Aov>,
    stats: serde_json::Value,
}

#[pymethods]
impl Frame {
    /// The whole frame's linear RGB (H×W×3, float32), the background outside the region.
    #[getter]
    fn image<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f32>> {
        image_array(&self.frame).into_pyarray(py)
    }

    /// An AOV as a whole-frame array: "depth" (H×W, inf where nothing was hit), "nodes"
    /// (H×W), "normal" or "albedo" (H×W×3).
    fn aov<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
        let aov: Aov = serde_json::from_value(serde_json::Value::String(name.to_string()))
            .map_err(|_| PyValueError::new_err(format!("{name:?}: not an AOV (depth, normal, albedo, nodes)")))?;
        if !self.aovs.contains(&aov) {
            return Err(PyValueError::new_err(format!("{name:?} was not recorded: render with aovs=[{name:?}]")));
        }
        let channels = self.frame.float_channels(&[aov]);
        let (h, w) = (self.frame.height as usize, self.frame.width as usize);
        let planes: Vec<&Vec<f32>> = channels.iter().skip(3).map(|(_, v)| v).collect();
        Ok(if planes.len() == 1 {
            Array2::from_shape_vec((h, w), planes[0].clone()).expect("a value a pixel").into_pyarray(py).into_any()
        } else {
            let interleaved: Vec<f32> = (0..w * h).flat_map(|i| planes.iter().map(move |p| p[i])).collect();
            Array3::from_shape_vec((h, w, planes.len()), interleaved)
                .expect("values a pixel")
                .into_pyarray(py)
                .into_any()
        })
    }

    /// What was rendered and how, as `pointray render --stats` reports it (a dict).
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        pythonize::pythonize(py, &self.stats).map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }
}

fn image_array(frame: &pointray::Frame) -> Array3<f32> {
    let flat: Vec<f32> = frame.linear_rgb().into_iter().flatten().collect();
    Array3::from_shape_vec((frame.height as usize, frame.width as usize, 3), flat).expect("a pixel each")
}

/// Reads a point-cloud file (PLY, LAS/LAZ, E57, PCD, XYZ/PTS, an OFF or OBJ mesh's vertices, a scan set), recognised by
/// its content; `columns` ("x,y,z,r,g,b,i") names a text file's columns, as `--columns` does.
#[pyfunction]
#[pyo3(signature = (path, *, columns=None))]
fn read_cloud(py: Python<'_>, path: PathBuf, columns: Option<String>) -> PyResult<Cloud> {
    let read = read_options(columns)?;
    let loaded = py.detach(|| pointray_io::read_cloud_with(&path, &read)).map_err(io_error)?;
    Ok(Cloud { inner: loaded.cloud })
}

/// The read options of a `columns` keyword.
fn read_options(columns: Option<String>) -> PyResult<pointray_io::ReadOptions> {
    let columns = columns.map(|c| c.parse().map_err(|e: String| PyValueError::new_err(format!("columns: {e}"))));
    Ok(pointray_io::ReadOptions { columns: columns.transpose()? })
}

/// Prepares a scene from a cloud file, a scene file (.toml) or a `Cloud`: what it lacks
/// computed (normals, orientation, radii; `k_normals`, `k_radius`, `radius_scale`,
/// `recompute`, `strays`, `outlier_std`; a text file's `columns`), points filtered by class
/// (`classes`, `exclude_classes`) and coloured (`color_by`), and the accelerator built
/// (`accel`, `sphere_from_level`, and the disks `surface` tests). The other options become
/// the scene's defaults for `render`; `threads` (default all cores) for the work.
#[pyfunction]
#[pyo3(signature = (source, **options))]
fn prepare(py: Python<'_>, source: &Bound<'_, PyAny>, options: Option<&Bound<'_, PyDict>>) -> PyResult<Scene> {
    let (pool, options) = RunOptions::pool_only(options, "prepare")?;
    let (preprocess, read, options) = split_preprocess(options.as_ref())?;
    let (parts, base, animation) = if let Ok(cloud) = source.cast::<Cloud>() {
        let mut cloud = cloud.get().inner.clone();
        py.detach(|| pool.install(|| pointray_io::source::prepare(&mut cloud, &preprocess, "cloud", &|_| {})))
            .map_err(|e| PyValueError::new_err(format!("cloud: {e}")))?;
        (SceneParts::from(cloud), Settings::default(), None)
    } else if let Some(AtUrl { url, len, reader }) = at_url(source)? {
        let loaded = py.detach(|| pointray_io::source::open_fetched(&url, len, reader, &|_| {})).map_err(io_error)?;
        (loaded.parts, Settings::default(), None)
    } else {
        let paths = source_paths(source)?;
        let loaded = py
            .detach(|| pool.install(|| pointray_io::source::load_tiles(&paths, &preprocess, &read, &|_| {})))
            .map_err(io_error)?;
        (loaded.parts, loaded.settings.unwrap_or_default(), loaded.animation)
    };
    let settings = with_options(&base, options.as_ref())?;
    let env_map = pointray_io::source::environment_map(&settings).map_err(io_error)?;
    let mut inner = py.detach(|| pool.install(|| pointray::Scene::build(parts, &settings))).map_err(value_error)?;
    inner.set_environment_map(env_map);
    Ok(Scene { inner, settings, animation })
}

/// A scene file at a URL (`pointray._remote.is_url`): its length and its reader by ranges
/// (fsspec's, made by `pointray._remote.reader`).
struct AtUrl {
    url: String,
    len: u64,
    reader: Box<dyn RangeReader>,
}

/// The scene file a source names, where it is a URL.
fn at_url(source: &Bound<'_, PyAny>) -> PyResult<Option<AtUrl>> {
    let remote = source.py().import("pointray._remote")?;
    if !remote.call_method1("is_url", (source,))?.is_truthy()? {
        return Ok(None);
    }
    let (len, read): (u64, Py<PyAny>) = remote.call_method1("reader", (source,))?.extract()?;
    Ok(Some(AtUrl { url: source.extract()?, len, reader: Box::new(Ranges { read }) }))
}

/// Ranges of a file read through a Python callable given [(start, end), ...] and returning
/// the bytes of each (`pointray._remote.reader`), from whichever thread needs them.
struct Ranges {
    read: Py<PyAny>,
}

impl RangeReader for Ranges {
    fn read(&self, ranges: &[std::ops::Range<u64>]) -> Result<Vec<Vec<u8>>, String> {
        let pairs: Vec<(u64, u64)> = ranges.iter().map(|r| (r.start, r.end)).collect();
        Python::attach(|py| {
            let read: Vec<Bound<'_, PyBytes>> = self.read.call1(py, (pairs,))?.extract(py)?;
            Ok(read.iter().map(|b| b.as_bytes().to_vec()).collect())
        })
        .map_err(|e: PyErr| e.to_string())
    }
}

/// The files a source names: a path, or a list of them (a survey's tiles, read as one cloud).
fn source_paths(source: &Bound<'_, PyAny>) -> PyResult<Vec<PathBuf>> {
    let wrong =
        || pyo3::exceptions::PyTypeError::new_err("source: expected a path, a list of paths, a Cloud or a Scene");
    match source.extract::<PathBuf>() {
        Ok(path) => Ok(vec![path]),
        Err(_) if source.is_instance_of::<pyo3::types::PyString>() => Err(wrong()),
        Err(_) => source.extract::<Vec<PathBuf>>().ok().filter(|p| !p.is_empty()).ok_or_else(wrong),
    }
}

/// Prepares the cloud at `source` (a path, or a survey's tiles) into the scene file `output`
/// (`.prs`, written whole or not at all), as `pointray prepare SOURCE -o OUTPUT` does: in memory,
/// or out of core where that would take more than `memory_budget` bytes (default: half this
/// machine's memory). Options: the preprocessing's and the build's, as for `prepare`. Returns
/// what it did: `points`, `chunks` (out of core; else None), `parts` (a scene in parts: more
/// than one) and `bytes`.
#[pyfunction]
#[pyo3(signature = (source, output, *, memory_budget=None, **options))]
fn prepare_file<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    output: PathBuf,
    memory_budget: Option<u64>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    let (pool, options) = RunOptions::pool_only(options, "prepare_file")?;
    let (preprocess, read, options) = split_preprocess(options.as_ref())?;
    let settings = with_options(&Settings::default(), options.as_ref())?;
    let paths = source_paths(source)?;
    let file_options = pointray_io::prepare::SceneFileOptions { preprocess, read, settings, memory_budget };
    let prepared = py
        .detach(|| pool.install(|| pointray_io::prepare::prepare_scene_file(&paths, &output, &file_options, &|_| {})));
    let done = prepared.map_err(|e| match e {
        pointray_io::prepare::SceneFileError::Settings(e) | pointray_io::prepare::SceneFileError::Unmet(e) => {
            value_error(format!("{}: {}", e.option, e.problem))
        }
        pointray_io::prepare::SceneFileError::Input(e) | pointray_io::prepare::SceneFileError::Output(e) => io_error(e),
    })?;
    let summary = PyDict::new(py);
    summary.set_item("points", done.points)?;
    summary.set_item("chunks", done.chunks)?;
    summary.set_item("parts", done.parts)?;
    summary.set_item("bytes", done.bytes)?;
    Ok(summary)
}

/// Renders `source` (a path, a `Cloud` or a `Scene`) with the command line's render options
/// by the same names: the linear RGB image, H×W×3 float32 (`to_srgb8` gives the PNG's bytes).
#[pyfunction]
#[pyo3(signature = (source, **options))]
fn render<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let frame = render_frame(py, source, options)?;
    Ok(image_array(&frame.frame).into_pyarray(py))
}

/// Renders the pixels `region` = (x0, y0, x1, y1) of the frame (x1, y1 exclusive): the tile's
/// linear RGB, (y1 − y0)×(x1 − x0)×3 float32, equal to that part of `render`'s image.
#[pyfunction]
#[pyo3(signature = (source, region, **options))]
fn render_region<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    region: (u32, u32, u32, u32),
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let options = match options {
        Some(o) => o.copy()?,
        None => PyDict::new(py),
    };
    options.set_item("region", region)?;
    let frame = render_frame(py, source, Some(&options))?;
    let film = &frame.frame.film;
    let (w, h) = (film.region.width() as usize, film.region.height() as usize);
    let flat: Vec<f32> = film.rgb.iter().flatten().copied().collect();
    Ok(Array3::from_shape_vec((h, w, 3), flat).expect("a pixel each").into_pyarray(py))
}

/// `render`, returning a `Frame`: the image, the AOVs of `aovs=[...]` and the statistics
/// (`count_work=True` counts the traversal's work too). Every render also takes `threads`
/// (default: all cores) and `progress`, a callable given (pixels done, pixels in all) as the
/// render goes, e.g. a tqdm bar's update.
#[pyfunction]
#[pyo3(signature = (source, **options))]
fn render_frame(py: Python<'_>, source: &Bound<'_, PyAny>, options: Option<&Bound<'_, PyDict>>) -> PyResult<Frame> {
    let (run, options) = RunOptions::take(options)?;
    let options = options.as_ref();
    let prepared;
    let (scene, settings) = match source.cast::<Scene>() {
        Ok(scene) => {
            let scene = scene.get();
            let settings = with_options(&scene.settings, options)?;
            if settings.env_map != scene.settings.env_map {
                return Err(PyValueError::new_err(
                    "env_map: a Scene renders with the map prepare() read; give it there",
                ));
            }
            (scene, settings)
        }
        Err(_) => {
            prepared = prepare(py, source, options)?;
            (&prepared, prepared.settings.clone())
        }
    };
    // Without the GIL, as `camera_rays`.
    let job = py.detach(|| scene.inner.job(&settings)).map_err(value_error)?;
    let pool = run.pool()?;
    let (done, total) = (AtomicU64::new(0), job.config.region.pixel_count());
    let count = |n: u64| {
        done.fetch_add(n, Ordering::Relaxed);
    };
    let report = || match &run.progress {
        Some(progress) => Python::attach(|py| progress.call1(py, (done.load(Ordering::Relaxed), total)).map(drop)),
        None => Ok(()),
    };
    let frame = cancellable(py, report, |cancel| pool.install(|| job.render_until(&count, cancel).transpose()))?
        .map_err(value_error)?;
    let stats = serde_json::to_value(job.report(&frame)).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok(Frame { frame, aovs: settings.aovs.clone(), stats })
}

/// Linear RGB (H×W×3) as the 8-bit sRGB a PNG of `pointray render` holds, through the tone
/// map (`tonemap` "clamp" or "filmic", `exposure` in stops).
#[pyfunction]
#[pyo3(signature = (image, *, tonemap="clamp", exposure=0.0))]
fn to_srgb8<'py>(
    py: Python<'py>,
    image: PyArrayLike3<'py, f32, AllowTypeChange>,
    tonemap: &str,
    exposure: f32,
) -> PyResult<Bound<'py, PyArray3<u8>>> {
    let encode = tone_map(tonemap, exposure)?.encoder();
    let image = image.as_array();
    if image.dim().2 != 3 {
        return Err(PyValueError::new_err("image: expected an HxWx3 array"));
    }
    Ok(image.mapv(encode).into_pyarray(py))
}

/// The tone map `tonemap` ("clamp" or "filmic") and `exposure` (stops) name.
fn tone_map(tonemap: &str, exposure: f32) -> PyResult<ToneMap> {
    let curve = serde_json::from_value(serde_json::Value::String(tonemap.to_string()))
        .map_err(|_| PyValueError::new_err(format!("tonemap {tonemap:?}: expected \"clamp\" or \"filmic\"")))?;
    let probe = Settings { exposure, ..Settings::default() };
    probe.check().map_err(value_error)?;
    Ok(ToneMap { exposure, curve })
}

/// An MP4 video (H.264) written a frame at a time through ffmpeg (Debian's package;
/// `POINTRAY_FFMPEG` names another): ``with pointray.VideoWriter("fly.mp4", fps=30) as video:
/// video.write(image)`` for each linear H×W×3 image, 8-bit sRGB through the tone map as
/// `to_srgb8`. The file appears, whole, when the writer closes after no error; else none.
#[pyclass(module = "pointray", name = "VideoWriter")]
struct VideoWriter {
    path: PathBuf,
    program: String,
    fps: f32,
    tone: ToneMap,
    /// Started by the first frame, which sets the size.
    writer: Option<Mp4Writer>,
    size: Option<(usize, usize)>,
    /// Closed (the video in place, or dropped after an error): no more frames.
    closed: bool,
}

#[pymethods]
impl VideoWriter {
    #[new]
    #[pyo3(signature = (path, *, fps=30.0, tonemap="clamp", exposure=0.0))]
    fn new(path: PathBuf, fps: f32, tonemap: &str, exposure: f32) -> PyResult<Self> {
        if !(fps.is_finite() && fps > 0.0) {
            return Err(PyValueError::new_err(format!("fps: expected a positive number, got {fps}")));
        }
        let tone = tone_map(tonemap, exposure)?;
        let program = pointray_io::video::ffmpeg()
            .ok_or_else(|| PyOSError::new_err(format!("{}: {}", path.display(), pointray_io::video::NO_FFMPEG)))?;
        Ok(Self { path, program, fps, tone, writer: None, size: None, closed: false })
    }

    /// Adds a frame: linear RGB, H×W×3, every frame the first's size.
    fn write(&mut self, py: Python<'_>, image: PyArrayLike3<'_, f32, AllowTypeChange>) -> PyResult<()> {
        if self.closed {
            return Err(PyValueError::new_err(format!("{}: the video is closed", self.path.display())));
        }
        let image = image.as_array();
        let (h, w, c) = image.dim();
        if c != 3 || self.size.is_some_and(|size| size != (w, h)) {
            let first = self.size.map_or(String::new(), |(w, h)| format!(" ({h}x{w}x3, as the first frame)"));
            return Err(PyValueError::new_err(format!("image: expected an HxWx3 array{first}, got {:?}", image.dim())));
        }
        let encode = self.tone.encoder();
        let srgb8: Vec<u8> = image.iter().map(|&v| encode(v)).collect();
        if self.writer.is_none() {
            let (path, program, fps) = (&self.path, &self.program, self.fps);
            let writer = py.detach(|| Mp4Writer::create(program, path, w as u32, h as u32, fps)).map_err(io_error)?;
            (self.writer, self.size) = (Some(writer), Some((w, h)));
        }
        let writer = self.writer.as_mut().expect("started above");
        py.detach(|| writer.push(&srgb8)).map_err(io_error)
    }

    /// Ends the video and puts it in place (no frames: no video, an error). Closing again
    /// does nothing.
    fn close(&mut self, py: Python<'_>) -> PyResult<()> {
        let writer = self.writer.take();
        if std::mem::replace(&mut self.closed, true) {
            return Ok(());
        }
        match writer {
            Some(writer) => py.detach(|| writer.finish()).map_err(io_error),
            None => Err(PyValueError::new_err(format!("{}: no frames written", self.path.display()))),
        }
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    /// Closes the video, or on an exception drops it (no file).
    fn __exit__(
        &mut self,
        py: Python<'_>,
        error: Option<Bound<'_, PyAny>>,
        _value: Option<Bound<'_, PyAny>>,
        _traceback: Option<Bound<'_, PyAny>>,
    ) -> PyResult<bool> {
        if error.is_some_and(|e| !e.is_none()) {
            (self.writer, self.closed) = (None, true);
            return Ok(false);
        }
        self.close(py).map(|()| false)
    }
}

/// Runs `work` on another thread with the GIL released, checking for Ctrl-C and calling
/// `report` (the progress) meanwhile: a signal, or an exception from `report`, sets `cancel`
/// (the render stops within a band) and is raised.
fn cancellable<T: Send>(
    py: Python<'_>,
    report: impl Fn() -> PyResult<()> + Send + Sync,
    work: impl FnOnce(&AtomicBool) -> Option<T> + Send,
) -> PyResult<T> {
    let cancel = AtomicBool::new(false);
    py.detach(|| {
        std::thread::scope(|s| {
            let (finished, done) = std::sync::mpsc::channel::<()>();
            let cancel = &cancel;
            let handle = s.spawn(move || {
                let result = work(cancel);
                let _ = finished.send(());
                result
            });
            // Woken by the work's end, not only every 20 ms: a tile of a frame split among
            // many renders (pointray.dask) waited 10 ms on average for the next poll.
            while let Err(RecvTimeoutError::Timeout) = done.recv_timeout(Duration::from_millis(20)) {
                if let Err(e) = Python::attach(|py| py.check_signals()).and_then(|()| report()) {
                    cancel.store(true, Ordering::Relaxed);
                    let _ = handle.join();
                    return Err(e);
                }
            }
            let done = handle.join().map_err(|_| PyRuntimeError::new_err("the render panicked"))?;
            report()?;
            done.ok_or_else(|| PyKeyboardInterrupt::new_err("render cancelled"))
        })
    })
}

/// A render's own options beside the settings: its threads and a progress callable.
struct RunOptions {
    threads: Option<usize>,
    progress: Option<Py<PyAny>>,
}

impl RunOptions {
    /// These options taken out of `options`, and the rest.
    fn take<'py>(options: Option<&Bound<'py, PyDict>>) -> PyResult<(Self, Option<Bound<'py, PyDict>>)> {
        let mut run = Self { threads: None, progress: None };
        let Some(options) = options else { return Ok((run, None)) };
        let rest = options.copy()?;
        if let Some(threads) = pop(&rest, "threads")? {
            run.threads = threads.extract()?;
        }
        if let Some(progress) = pop(&rest, "progress")?.filter(|p| !p.is_none()) {
            if !progress.is_callable() {
                return Err(PyValueError::new_err("progress: expected a callable (done, total)"));
            }
            run.progress = Some(progress.unbind());
        }
        Ok((run, Some(rest)))
    }

    /// The pool of a call that takes `threads` but reports no progress (`what` names it), and
    /// the other options.
    fn pool_only<'py>(
        options: Option<&Bound<'py, PyDict>>,
        what: &str,
    ) -> PyResult<(rayon::ThreadPool, Option<Bound<'py, PyDict>>)> {
        let (run, rest) = Self::take(options)?;
        if run.progress.is_some() {
            return Err(PyValueError::new_err(format!("progress: {what} reports none (renders do)")));
        }
        Ok((run.pool()?, rest))
    }

    /// A pool of `threads` threads (all cores without).
    fn pool(&self) -> PyResult<rayon::ThreadPool> {
        if self.threads == Some(0) || self.threads.is_some_and(|t| t > 1024) {
            return Err(PyValueError::new_err("threads must be between 1 and 1024"));
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(self.threads.unwrap_or(0))
            .build()
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }
}

/// The preprocessing and reading options taken out of `options`, and the rest.
fn split_preprocess<'py>(
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<(PreprocessConfig, pointray_io::ReadOptions, Option<Bound<'py, PyDict>>)> {
    let mut config = PreprocessConfig::standard();
    let Some(options) = options else { return Ok((config, pointray_io::ReadOptions::default(), None)) };
    let rest = options.copy()?;
    macro_rules! take {
        ($($key:ident),*) => {
            $(if let Some(v) = pop(&rest, stringify!($key))? {
                config.$key = v.extract()?;
            })*
        };
    }
    take!(k_normals, k_radius, radius_scale, recompute, outlier_std);
    if let Some(v) = pop(&rest, "strays")? {
        config.strays = pythonize::depythonize(&v).map_err(value_error)?;
    }
    config.check().map_err(value_error)?;
    let columns = pop(&rest, "columns")?.map(|v| v.extract::<String>()).transpose()?;
    Ok((config, read_options(columns)?, Some(rest)))
}

/// The value of `key` in `dict`, taken out of it.
fn pop<'py>(dict: &Bound<'py, PyDict>, key: &str) -> PyResult<Option<Bound<'py, PyAny>>> {
    let value = dict.get_item(key)?;
    if value.is_some() {
        dict.del_item(key)?;
    }
    Ok(value)
}

/// `base` with `options` (keyword arguments by `Settings`' names) put in, checked.
fn with_options(base: &Settings, options: Option<&Bound<'_, PyDict>>) -> PyResult<Settings> {
    let Some(options) = options.filter(|o| !o.is_empty()) else { return Ok(base.clone()) };
    let given: serde_json::Value =
        pythonize::depythonize(options.as_any()).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let mut merged = serde_json::to_value(base).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    if let (Some(m), serde_json::Value::Object(g)) = (merged.as_object_mut(), given) {
        m.extend(g);
    }
    let settings: Settings = serde_json::from_value(merged).map_err(|e| PyValueError::new_err(e.to_string()))?;
    settings.check().map_err(value_error)?;
    Ok(settings)
}

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// The system's refusals as `OSError` (`FileNotFoundError` for a missing file), the rest as
/// `ValueError`; the message names the file as the command line's does.
fn io_error(e: IoError) -> PyErr {
    match &e {
        IoError::Io { io, .. } if io.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(e.to_string())
        }
        IoError::Io { .. } => PyOSError::new_err(e.to_string()),
        _ => PyValueError::new_err(e.to_string()),
    }
}

#[pymodule]
fn _pointray(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Cloud>()?;
    m.add_class::<Scene>()?;
    m.add_class::<Frame>()?;
    m.add_class::<VideoWriter>()?;
    m.add_function(wrap_pyfunction!(read_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(prepare, m)?)?;
    m.add_function(wrap_pyfunction!(prepare_file, m)?)?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(render_region, m)?)?;
    m.add_function(wrap_pyfunction!(render_frame, m)?)?;
    m.add_function(wrap_pyfunction!(to_srgb8, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
