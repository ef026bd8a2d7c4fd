//! `pointray view`: the interactive viewer. A local web server (axum) serves one page and a
//! WebSocket; a render thread runs the library's progressive loop (`pointray::progressive`) on
//! the scene and pushes each frame, as a PNG with a line of JSON before it, to every open page;
//! what a page sends (a camera, options: `Settings` fields as JSON) becomes the next view, and
//! an option the scene was built with (what the colours show, classes, clips) builds it anew
//! from the parts kept for that. Every page shows and steers the one view. Ctrl-C stops the
//! server (`failure`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, RwLock};
use std::time::Duration;

use anyhow::Context;
use axum::extract::State;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::response::{Html, Response};
use axum::routing::get;
use pointray::progressive::{Progressive, ProgressiveFrame, ProgressiveOptions, Step, ViewControl};
use pointray::settings::Settings;
use pointray::{Scene, SceneParts};
use tokio::sync::{broadcast, watch};

use crate::args::ViewArgs;
use crate::failure;

/// The page: a canvas, the mouse's orbit, pan and zoom, a few options, the statistics.
const PAGE: &str = include_str!("view.html");

/// What the server's tasks and the render thread share.
struct Shared {
    /// The scene rendered, swapped when it is built anew.
    scene: RwLock<Arc<Scene>>,
    /// What it is built from, kept to build it again (the cloud's memory twice).
    parts: SceneParts,
    /// A page asked for a scene built otherwise: the render thread builds it.
    rebuild: AtomicBool,
    /// The view last asked for: a page's change is merged into it.
    settings: Mutex<Settings>,
    control: Arc<ViewControl>,
    /// The latest frame, for every page: one that comes before a page sent the last may
    /// replace it unsent.
    frames: watch::Sender<Option<Arc<Encoded>>>,
    /// What the render thread says (building, errors), every word to every page, each before
    /// the frames that follow it: on the frames' channel, a frame could replace an error unread
    /// (the viewer's test waited 60 s for a refused build's error in one full test run).
    notices: broadcast::Sender<Arc<Encoded>>,
    /// Show the nodes each pixel visited (a heat map) rather than the image.
    heat_map: AtomicBool,
    /// The first message to a page: the view's camera and size, the input's name.
    hello: String,
    stop: AtomicBool,
}

impl Shared {
    /// The view last asked for. A lock that a panicking thread left poisoned is taken as it is:
    /// every writer replaces the settings whole, so they are never half written.
    fn settings(&self) -> MutexGuard<'_, Settings> {
        self.settings.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The scene rendered now (poisoning as for [`Self::settings`]).
    fn scene(&self) -> Arc<Scene> {
        self.scene.read().unwrap_or_else(PoisonError::into_inner).clone()
    }

    /// The scene built anew, for the frames that follow.
    fn set_scene(&self, scene: Scene) {
        *self.scene.write().unwrap_or_else(PoisonError::into_inner) = Arc::new(scene);
    }
}

/// A frame as the pages get it: its JSON line, then its PNG (none for an error).
struct Encoded {
    meta: String,
    png: Option<Vec<u8>>,
}

pub fn run(a: &ViewArgs, quiet: bool) -> anyhow::Result<()> {
    let (parts, settings, name) = load(a, quiet)?;
    let scene = Arc::new(Scene::build(parts.clone(), &settings).with_context(|| name.clone())?);
    // A view the viewer cannot show is refused before a page is opened for it.
    Progressive::check(&scene, &settings).map_err(|e| failure::usage(e.into()))?;
    let listener = std::net::TcpListener::bind((a.bind.as_str(), a.port))
        .map_err(|e| failure::usage(anyhow::anyhow!("--bind {} --port {}: {e}", a.bind, a.port)))?;
    listener.set_nonblocking(true)?;
    let url = format!("http://{}/", listener.local_addr()?);
    println!("pointray view: {url}");
    if !a.no_open {
        open_in_browser(&url);
    }
    let shared = Arc::new(Shared {
        hello: hello(&scene, &settings, &name)?,
        scene: RwLock::new(scene),
        parts,
        rebuild: AtomicBool::new(false),
        settings: Mutex::new(settings),
        control: Arc::new(ViewControl::default()),
        frames: watch::channel(None).0,
        notices: broadcast::channel(NOTICES).0,
        stop: AtomicBool::new(false),
        heat_map: AtomicBool::new(false),
    });
    std::thread::scope(|s| {
        s.spawn(|| render_loop(&shared));
        let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
        let served = runtime.block_on(serve(listener, shared.clone()));
        shared.stop.store(true, Ordering::SeqCst);
        served
    })
}

/// What the scene to view is built from and its first settings: a cloud or scene file as
/// `render` reads it, or the demo.
fn load(a: &ViewArgs, quiet: bool) -> anyhow::Result<(SceneParts, Settings, String)> {
    let config = a.preprocess.config();
    config.check().map_err(|e| failure::usage(super::render::flag_error(e)))?;
    let stage = |_: &str| {};
    let (parts, scene_settings, name) = match &a.input {
        Some(path) => {
            let source = crate::progress::spinning("read", quiet, || {
                pointray_io::source::load(path, &config, &a.read.options(), &stage)
            })?;
            (source.parts, source.settings, path.display().to_string())
        }
        None => {
            let demo = pointray_io::source::demo(pointray::demo::DEMO_POINTS, 0, &config, &stage);
            (demo.map_err(anyhow::Error::msg)?.parts, None, "demo".to_string())
        }
    };
    let base = scene_settings.unwrap_or_default();
    // The whole frame, its work counted: the page shows the nodes a ray visits, and their heat map.
    let (width, height, spp, color_by) = (a.width, a.height, a.spp, a.color_by.unwrap_or(base.color_by));
    let whole = Settings { region: None, crop_to_model: false, count_work: true, ..base };
    let settings = Settings { width, height, spp, color_by, ..whole };
    settings.check().map_err(|e| failure::usage(super::render::flag_error(e)))?;
    Ok((parts, settings, name))
}

/// The camera a page starts from, in the file's coordinates, with the frame's size.
fn hello(scene: &Scene, settings: &Settings, name: &str) -> anyhow::Result<String> {
    let job = scene.job(settings)?;
    let bounds = scene.bounds();
    let eye = scene.origin() + job.camera.eye.as_dvec3();
    let look_at = settings.look_at.unwrap_or(scene.origin() + bounds.center().as_dvec3());
    Ok(serde_json::json!({
        "kind": "hello",
        "input": name,
        "width": settings.width,
        "height": settings.height,
        "eye": eye.to_array(),
        "look_at": look_at.to_array(),
        "up": scene.up(settings).normalize().to_array(),
        "fov": settings.fov,
        "diagonal": bounds.diagonal(),
        "settings": settings,
    })
    .to_string())
}

/// Renders the latest view of the latest scene, frame after frame, until the server stops;
/// builds the scene anew when the settings ask for another build.
fn render_loop(shared: &Shared) {
    // The settings last rendered on the scene there is: where a failed build goes back to.
    let mut shown = shared.settings().clone();
    while !shared.stop.load(Ordering::SeqCst) {
        let scene = shared.scene();
        let settings = shared.settings().clone();
        // Settings of another build are a rebuild, whether or not the page's task has said so yet.
        if !scene.built_for(&settings) {
            shared.rebuild.store(true, Ordering::SeqCst);
        } else {
            let options = ProgressiveOptions::default();
            match Progressive::with_control(&scene, settings, options, shared.control.clone()) {
                Ok(mut view) => shown = render_scene(&mut view, shared),
                Err(e) => {
                    notify(shared, message("error", &e.to_string()));
                    wait_for_change(shared);
                }
            }
        }
        if shared.rebuild.swap(false, Ordering::SeqCst) {
            rebuild(shared, &shown);
        }
    }
}

/// Steps `view` until the server stops or a page asks for another build; the settings it
/// rendered last.
fn render_scene(view: &mut Progressive, shared: &Shared) -> Settings {
    while !shared.stop.load(Ordering::SeqCst) && !shared.rebuild.load(Ordering::SeqCst) {
        let encoded = match view.step() {
            Ok(Step::Frame(f)) => encode(&f, view.settings(), shared),
            Ok(Step::Cancelled) => {
                tracing::debug!("pass cancelled");
                continue;
            }
            Ok(Step::Idle) => {
                wait_for_change(shared);
                continue;
            }
            Err(e) => {
                notify(shared, message("error", &e.to_string()));
                continue;
            }
        };
        shared.frames.send_replace(Some(Arc::new(encoded)));
    }
    view.settings().clone()
}

/// Builds the scene for the settings a page last asked for; if it cannot be, says why and
/// goes back to `before`, the settings of the scene there is.
fn rebuild(shared: &Shared, before: &Settings) {
    let settings = shared.settings().clone();
    notify(shared, message("status", "building the scene"));
    match Scene::build(shared.parts.clone(), &settings) {
        Ok(scene) => shared.set_scene(scene),
        Err(e) => {
            *shared.settings() = before.clone();
            shared.control.set_view(before.clone());
            notify(shared, message("error", &e.to_string()));
        }
    }
}

/// Tells every page (none listening is no error).
fn notify(shared: &Shared, notice: Encoded) {
    let _ = shared.notices.send(Arc::new(notice));
}

/// Notices a page may fall behind by before it misses some (it then goes on from the oldest
/// kept).
const NOTICES: usize = 64;

fn wait_for_change(shared: &Shared) {
    let generation = shared.control.generation();
    while shared.control.generation() == generation && !shared.stop.load(Ordering::SeqCst) {
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A frame for the pages: the image (or the heat map of the nodes visited) and its statistics.
fn encode(f: &ProgressiveFrame, settings: &Settings, shared: &Shared) -> Encoded {
    let frame = &f.frame;
    let rgb8 = if shared.heat_map.load(Ordering::SeqCst) {
        frame.aov_rgb8(pointray::frame::Aov::Nodes)
    } else {
        frame.srgb8(settings.tone_map())
    };
    let stats = &frame.stats;
    let meta = serde_json::json!({
        "kind": "frame", "generation": f.generation, "samples": f.samples, "scale": f.scale,
        "width": frame.width, "height": frame.height, "seconds": f.seconds, "lod_threshold": f.lod_threshold,
        "prefilter": settings.prefilter,
        "mrays_per_second": stats.rays as f64 / f.seconds.max(1e-9) / 1e6,
        "nodes_per_ray": stats.traversal.nodes_visited as f64 / stats.rays.max(1) as f64,
    });
    Encoded { meta: meta.to_string(), png: Some(pointray_io::encode_png(frame.width, frame.height, &rgb8)) }
}

/// A message without an image: `kind` "error" or "status".
fn message(kind: &str, text: &str) -> Encoded {
    Encoded { meta: serde_json::json!({ "kind": kind, "message": text }).to_string(), png: None }
}

async fn serve(listener: std::net::TcpListener, shared: Arc<Shared>) -> anyhow::Result<()> {
    let listener = tokio::net::TcpListener::from_std(listener)?;
    let app =
        axum::Router::new().route("/", get(|| async { Html(PAGE) })).route("/ws", get(connect)).with_state(shared);
    axum::serve(listener, app).await?;
    Ok(())
}

async fn connect(upgrade: WebSocketUpgrade, State(shared): State<Arc<Shared>>) -> Response {
    upgrade.on_upgrade(move |socket| page(socket, shared))
}

/// One page: the hello, then every new frame; its messages become views.
async fn page(mut socket: WebSocket, shared: Arc<Shared>) {
    if socket.send(Message::Text(shared.hello.clone().into())).await.is_err() {
        return;
    }
    let mut frames = shared.frames.subscribe();
    frames.mark_changed();
    let mut notices = shared.notices.subscribe();
    loop {
        tokio::select! {
            // Notices first: a frame sent after a notice never reaches the page before it.
            biased;
            notice = notices.recv() => match notice {
                Ok(notice) => {
                    if socket.send(Message::Text(notice.meta.clone().into())).await.is_err() {
                        return;
                    }
                }
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => return,
            },
            changed = frames.changed() => {
                if changed.is_err() {
                    return;
                }
                let Some(frame) = frames.borrow_and_update().clone() else { continue };
                if socket.send(Message::Text(frame.meta.clone().into())).await.is_err() {
                    return;
                }
                if let Some(png) = &frame.png && socket.send(Message::Binary(png.clone().into())).await.is_err() {
                    return;
                }
            }
            message = socket.recv() => match message {
                Some(Ok(Message::Text(text))) => {
                    let reply = match answer(&shared, &text) {
                        Ok(reply) => reply,
                        Err(e) => Some(serde_json::json!({ "kind": "error", "message": format!("{e:#}") })),
                    };
                    if let Some(reply) = reply && socket.send(Message::Text(reply.to_string().into())).await.is_err() {
                        return;
                    }
                }
                Some(Ok(_)) => {}
                _ => return,
            },
        }
    }
}

/// What a page's message asks: `{"pick": [x, y]}` makes the surface under that pixel the point
/// the camera turns about (the reply names it), `{"heat_map": true}` shows the nodes visited
/// instead of the image; any other object is settings for the view.
fn answer(shared: &Shared, text: &str) -> anyhow::Result<Option<serde_json::Value>> {
    let given: serde_json::Value = serde_json::from_str(text).context("not JSON")?;
    let serde_json::Value::Object(mut given) = given else { anyhow::bail!("expected a JSON object of settings") };
    if let Some(on) = given.remove("heat_map") {
        shared.heat_map.store(on.as_bool().context("heat_map: expected true or false")?, Ordering::SeqCst);
    }
    let Some(pixel) = given.remove("pick") else {
        change_view(shared, given)?;
        return Ok(None);
    };
    let [x, y]: [u32; 2] = serde_json::from_value(pixel).context("pick: expected [x, y] in pixels")?;
    let settings = shared.settings().clone();
    let scene = shared.scene();
    let job = scene.job(&settings)?;
    anyhow::ensure!(x < settings.width && y < settings.height, "pick: ({x}, {y}) lies outside the view");
    let (origin, direction) = job.camera_ray(x, y);
    let Some(hit) = scene.intersect(&[(origin, direction)], &settings)?[0] else { return Ok(None) };
    let eye = scene.origin() + job.camera.eye.as_dvec3();
    let pivot = serde_json::json!({ "eye": eye.to_array(), "look_at": hit.position.to_array() });
    let serde_json::Value::Object(view) = pivot.clone() else { unreachable!("an object") };
    change_view(shared, view)?;
    Ok(Some(serde_json::json!({ "kind": "pivot", "eye": pivot["eye"], "look_at": pivot["look_at"] })))
}

/// Merges a page's settings into the view and renders it next; an unknown option or a value
/// out of range is an error, and the view stays.
fn change_view(shared: &Shared, given: serde_json::Map<String, serde_json::Value>) -> anyhow::Result<()> {
    let mut current = shared.settings();
    let mut merged = serde_json::to_value(&*current)?;
    if let Some(m) = merged.as_object_mut() {
        m.extend(given);
    }
    let settings: Settings = serde_json::from_value(merged)?;
    settings.check()?;
    let scene = shared.scene();
    if scene.built_for(&settings) {
        // Refused here, not by the render thread, so that the view kept stays the one merged
        // into (a crop, say, would otherwise be refused again with every later message).
        Progressive::check(&scene, &settings)?;
        *current = settings.clone();
        tracing::debug!("view {} set", shared.control.generation() + 1);
        shared.control.set_view(settings);
    } else {
        // Colours, classes or clips changed: the render thread builds the scene anew.
        *current = settings;
        shared.rebuild.store(true, Ordering::SeqCst);
        shared.control.restart();
    }
    Ok(())
}

/// Opens `url` in the desktop's browser, if it has one (a failure only says so).
fn open_in_browser(url: &str) {
    let opener = if cfg!(target_os = "macos") {
        "open"
    } else if cfg!(windows) {
        "explorer"
    } else {
        "xdg-open"
    };
    if let Err(e) = std::process::Command::new(opener).arg(url).spawn() {
        tracing::warn!("could not open a browser ({opener}: {e}); open {url}");
    }
}
