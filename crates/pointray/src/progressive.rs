//! Progressive rendering, the loop of an interactive viewer (`pointray view`), on the library's
//! scene: right after the view changes, a preview at a resolution chosen to hold a frame time;
//! then, while the view rests, passes of more samples at full resolution, averaged, until the
//! view's `spp` samples a pixel are spent. A view set from another thread ([`ViewControl`]) cancels
//! the pass in flight, and the next frame starts over from a preview of the new view.
//!
//! The refinement passes trace disjoint ranges of the same samples (`RenderConfig::sample_range`),
//! so the converged image is the render of all of them at once, whatever the passes were.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant;

use crate::frame::Frame;
use crate::scene::RenderError;
use crate::scene::Scene;
use crate::settings::{Settings, SettingsError};

/// How a [`Progressive`] spends its time.
#[derive(Clone, Debug, PartialEq)]
pub struct ProgressiveOptions {
    /// What a preview frame should take, in seconds (30 frames a second).
    pub frame_seconds: f64,
    /// The coarsest preview: one pixel for this many across (and down).
    pub max_preview_scale: u32,
}

impl Default for ProgressiveOptions {
    fn default() -> Self {
        Self { frame_seconds: 1.0 / 30.0, max_preview_scale: 8 }
    }
}

/// The side of a [`Progressive`] that other threads hold: where a new view goes.
#[derive(Debug, Default)]
pub struct ViewControl {
    pending: Mutex<Option<Settings>>,
    generation: AtomicU64,
    cancel: AtomicBool,
}

impl ViewControl {
    /// Renders `settings` next (the camera moved, an option changed): the pass in flight stops
    /// within a band's time, and the view's generation counts up.
    pub fn set_view(&self, settings: Settings) {
        *self.pending.lock().unwrap_or_else(PoisonError::into_inner) = Some(settings);
        self.restart();
    }

    /// Stops the pass in flight and counts a new view without giving one: the caller starts
    /// another [`Progressive`] on this control (a scene built anew).
    pub fn restart(&self) {
        self.generation.fetch_add(1, Ordering::SeqCst);
        self.cancel.store(true, Ordering::SeqCst);
    }

    /// How many views have been set.
    pub fn generation(&self) -> u64 {
        self.generation.load(Ordering::SeqCst)
    }
}

/// A frame to show: a preview (`scale` > 1: each pixel stands for scale × scale of the view) or
/// the mean of the `samples` a pixel so far, of the view of `generation`.
pub struct ProgressiveFrame {
    pub frame: Frame,
    pub generation: u64,
    pub samples: u32,
    pub scale: u32,
    /// The pass's own seconds.
    pub seconds: f64,
    /// The level-of-detail threshold it took.
    pub lod_threshold: f32,
}

/// What [`Progressive::step`] did.
pub enum Step {
    /// Boxed: a frame's film beside two empty variants.
    Frame(Box<ProgressiveFrame>),
    /// A new view came while rendering: nothing to show, step again.
    Cancelled,
    /// The view has all its samples: nothing to do until it changes.
    Idle,
}

enum State {
    Preview,
    /// Samples `0..done` a pixel summed, full resolution.
    Refining {
        done: u32,
        sum: Vec<[f32; 3]>,
    },
    Converged,
}

/// A view rendered progressively (see the module's documentation).
pub struct Progressive<'s> {
    scene: &'s Scene,
    control: Arc<ViewControl>,
    options: ProgressiveOptions,
    settings: Settings,
    generation: u64,
    state: State,
    /// Seconds a preview pixel took last (none before the first preview).
    seconds_per_pixel: Option<f64>,
}

impl<'s> Progressive<'s> {
    /// Starts at a preview of `settings`, which must be a whole frame (no region, no crop).
    pub fn new(scene: &'s Scene, settings: Settings, options: ProgressiveOptions) -> Result<Self, SettingsError> {
        Self::with_control(scene, settings, options, Arc::new(ViewControl::default()))
    }

    /// [`Self::new`], steered by `control` (which a scene built anew keeps), at its generation.
    pub fn with_control(
        scene: &'s Scene,
        settings: Settings,
        options: ProgressiveOptions,
        control: Arc<ViewControl>,
    ) -> Result<Self, SettingsError> {
        Self::check(scene, &settings)?;
        let generation = control.generation();
        Ok(Self { scene, control, options, settings, generation, state: State::Preview, seconds_per_pixel: None })
    }

    /// Whether `scene` can show `settings` progressively (the whole frame, a job it accepts); the
    /// error names the option it refuses.
    pub fn check(scene: &Scene, settings: &Settings) -> Result<(), SettingsError> {
        whole_frame(settings)?;
        scene.job(settings).map(|_| ())
    }

    pub fn control(&self) -> Arc<ViewControl> {
        self.control.clone()
    }

    /// The settings of the view being rendered.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Renders the next frame of the latest view: its preview first, then the next pass.
    /// Settings that the scene refuses are an error, and the view before them stays.
    pub fn step(&mut self) -> Result<Step, RenderError> {
        // Cleared before the pending view is taken: a view set after this cancels what follows.
        self.control.cancel.store(false, Ordering::SeqCst);
        let pending = self.control.pending.lock().unwrap_or_else(PoisonError::into_inner).take();
        if let Some(settings) = pending {
            Self::check(self.scene, &settings)?;
            (self.settings, self.state) = (settings, State::Preview);
            self.generation = self.control.generation();
        }
        match std::mem::replace(&mut self.state, State::Converged) {
            State::Preview => self.preview(),
            State::Refining { done, sum } => self.refine(done, sum),
            State::Converged => Ok(Step::Idle),
        }
    }

    /// A frame of one sample a pixel at the scale the last preview's time allows (the coarsest
    /// at first), level of detail at least at a pixel, and at two where even the coarsest
    /// scale is predicted to take longer than the frame time.
    fn preview(&mut self) -> Result<Step, RenderError> {
        let (scale, too_slow) = self.preview_scale();
        let s = &self.settings;
        let lod_threshold = s.lod_threshold.max(1.0) * if too_slow { 2.0 } else { 1.0 };
        let (width, height) = (s.width.div_ceil(scale), s.height.div_ceil(scale));
        let preview = Settings { width, height, spp: 1, lod_threshold, ..s.clone() };
        let start = Instant::now();
        let Some(frame) = self.scene.job(&preview)?.render_until(&|_| {}, &self.control.cancel)? else {
            self.state = State::Preview;
            return Ok(Step::Cancelled);
        };
        let seconds = start.elapsed().as_secs_f64();
        self.seconds_per_pixel = Some(seconds / f64::from(preview.width * preview.height));
        let pixels = (self.settings.width * self.settings.height) as usize;
        self.state = State::Refining { done: 0, sum: vec![[0.0; 3]; pixels] };
        let generation = self.generation;
        Ok(Step::Frame(Box::new(ProgressiveFrame { frame, generation, samples: 1, scale, seconds, lod_threshold })))
    }

    /// The least scale (a power of two) whose preview the measured time a pixel says fits the
    /// frame time, and whether even the coarsest does not.
    fn preview_scale(&self) -> (u32, bool) {
        let most = self.options.max_preview_scale.max(1);
        let Some(per_pixel) = self.seconds_per_pixel else { return (most, false) };
        let pixels = f64::from(self.settings.width) * f64::from(self.settings.height);
        let seconds = |scale: u32| per_pixel * pixels / f64::from(scale * scale);
        let mut scale = 1;
        while scale < most && seconds(scale) > self.options.frame_seconds {
            scale *= 2;
        }
        (scale.min(most), seconds(most) > self.options.frame_seconds)
    }

    /// The next pass at full resolution: as many samples as are done already (at least one), up
    /// to the view's `spp`, so that the image sharpens at once and the passes stay few.
    fn refine(&mut self, done: u32, mut sum: Vec<[f32; 3]>) -> Result<Step, RenderError> {
        // At least 1: the settings passed `Self::check`.
        let budget = self.settings.spp;
        if done >= budget {
            return Ok(Step::Idle);
        }
        let range = done..(2 * done).clamp(done + 1, budget);
        let mut job = self.scene.job(&self.settings)?;
        job.config.sample_range = Some(range.clone());
        let start = Instant::now();
        let Some(mut frame) = job.render_until(&|_| {}, &self.control.cancel)? else {
            self.state = State::Refining { done, sum };
            return Ok(Step::Cancelled);
        };
        let seconds = start.elapsed().as_secs_f64();
        let lod_threshold = job.config.lod_threshold;
        let weight = range.len() as f32;
        let done = range.end;
        for (s, p) in sum.iter_mut().zip(frame.film.rgb.iter_mut()) {
            for k in 0..3 {
                s[k] += p[k] * weight;
                p[k] = s[k] / done as f32;
            }
        }
        self.state = if done >= budget { State::Converged } else { State::Refining { done, sum } };
        let generation = self.generation;
        Ok(Step::Frame(Box::new(ProgressiveFrame {
            frame,
            generation,
            samples: done,
            scale: 1,
            seconds,
            lod_threshold,
        })))
    }
}

/// Whether `settings` are for a viewer: the whole frame, or an error naming the option that
/// crops it.
fn whole_frame(settings: &Settings) -> Result<(), SettingsError> {
    let option = if settings.region.is_some() {
        "region"
    } else if settings.crop_to_model {
        "crop_to_model"
    } else {
        return Ok(());
    };
    Err(SettingsError::new(option, "a progressive view renders the whole frame"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn demo(settings: &Settings) -> Scene {
        let mut cloud = crate::demo::demo_cloud(4000, 3);
        crate::preprocess::preprocess(&mut cloud, &crate::preprocess::PreprocessConfig::standard()).unwrap();
        Scene::build(crate::demo::demo_scene_parts(cloud), settings).unwrap()
    }

    fn frame(step: Step) -> ProgressiveFrame {
        match step {
            Step::Frame(f) => *f,
            Step::Cancelled => panic!("cancelled"),
            Step::Idle => panic!("idle"),
        }
    }

    #[test]
    fn a_view_at_rest_converges_to_the_render_of_all_its_samples() {
        let integrator = crate::render::Integrator::Path;
        let settings = Settings { width: 40, height: 30, spp: 8, integrator, ..Settings::default() };
        let scene = demo(&settings);
        let mut view = Progressive::new(&scene, settings.clone(), ProgressiveOptions::default()).unwrap();
        let preview = frame(view.step().unwrap());
        assert_eq!((preview.samples, preview.scale, preview.frame.width), (1, 8, 5));
        let passes: Vec<ProgressiveFrame> = std::iter::from_fn(|| match view.step().unwrap() {
            Step::Frame(f) => Some(*f),
            _ => None,
        })
        .collect();
        assert_eq!(passes.iter().map(|f| f.samples).collect::<Vec<_>>(), [1, 2, 4, 8]);
        assert!(matches!(view.step().unwrap(), Step::Idle));
        let whole = crate::scene::render(&scene, &settings).unwrap();
        let last = &passes[3].frame.film.rgb;
        for (i, (a, b)) in last.iter().zip(&whole.film.rgb).enumerate() {
            assert!((0..3).all(|k| (a[k] - b[k]).abs() <= 1e-5 * b[k].max(1.0)), "pixel {i}: {a:?} against {b:?}");
        }
    }

    #[test]
    fn a_new_view_starts_over_from_a_preview_and_a_refused_one_keeps_the_last() {
        let settings = Settings { width: 32, height: 24, ..Settings::default() };
        let scene = demo(&settings);
        let mut view = Progressive::new(&scene, settings.clone(), ProgressiveOptions::default()).unwrap();
        frame(view.step().unwrap());
        frame(view.step().unwrap());
        let control = view.control();
        control.set_view(Settings { fov: 40.0, ..settings.clone() });
        let preview = frame(view.step().unwrap());
        assert_eq!((preview.generation, preview.samples, view.settings().fov), (1, 1, 40.0));
        // Timed: the first preview measured the time a pixel takes; a slow frame time allows
        // the full resolution at a pixel's level of detail, one too short for any scale takes
        // the coarsest and twice the level of detail.
        view.options.frame_seconds = 1e-12;
        control.set_view(Settings { fov: 45.0, ..settings.clone() });
        let hurried = frame(view.step().unwrap());
        assert_eq!((hurried.scale, hurried.lod_threshold), (8, 2.0));
        view.options.frame_seconds = 1e9;
        control.set_view(Settings { fov: 50.0, ..settings.clone() });
        let leisurely = frame(view.step().unwrap());
        assert_eq!((leisurely.scale, leisurely.lod_threshold), (1, 1.0));
        control.set_view(Settings { spp: 0, ..settings });
        assert!(matches!(view.step(), Err(RenderError::Settings(e)) if e.option == "spp"));
        assert_eq!(view.settings().fov, 50.0);
        // The kept view's first pass, not a new view's preview.
        let kept = frame(view.step().unwrap());
        assert_eq!((kept.generation, kept.samples, kept.scale), (leisurely.generation, 1, 1));
    }

    #[test]
    fn a_view_set_while_a_pass_renders_cancels_it() {
        // A pass long enough (the path tracer, 512², 64 samples: seconds) that the view set
        // 50 ms into it lands inside it: the pass stops at the next band.
        let integrator = crate::render::Integrator::Path;
        let settings = Settings { width: 512, height: 512, spp: 4096, integrator, ..Settings::default() };
        let scene = demo(&settings);
        let mut view = Progressive::new(&scene, settings.clone(), ProgressiveOptions::default()).unwrap();
        frame(view.step().unwrap());
        view.state = State::Refining { done: 64, sum: vec![[0.0; 3]; 512 * 512] };
        let control = view.control();
        let started = Instant::now();
        let setter = std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(50));
            control.set_view(settings);
        });
        let step = view.step().unwrap();
        setter.join().unwrap();
        assert!(matches!(step, Step::Cancelled), "after {:?}", started.elapsed());
        assert!(matches!(view.step().unwrap(), Step::Frame(f) if f.generation == 1 && f.samples == 1));
    }

    #[test]
    fn a_cropped_view_is_refused() {
        let settings = Settings { width: 16, height: 16, ..Settings::default() };
        let scene = demo(&settings);
        let crop = Settings { crop_to_model: true, ..settings };
        assert_eq!(
            Progressive::new(&scene, crop, ProgressiveOptions::default()).err().unwrap().option,
            "crop_to_model"
        );
    }
}
