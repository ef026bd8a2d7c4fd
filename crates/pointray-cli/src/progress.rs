//! Progress bars on stderr (indicatif draws nothing when stderr is not a terminal).

use indicatif::{ProgressBar, ProgressStyle};

pub fn bar(len: u64, message: &'static str, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len).with_message(message);
    pb.set_style(bar_style());
    pb
}

fn bar_style() -> ProgressStyle {
    ProgressStyle::with_template("{msg:>10} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}")
        .expect("valid template")
        .progress_chars("=> ")
}

/// Runs `work` under a spinner labelled `message`, cleared when it ends.
pub fn spinning<T>(message: &'static str, quiet: bool, work: impl FnOnce() -> T) -> T {
    let spinner = spinner(message, quiet);
    let result = work();
    spinner.finish_and_clear();
    result
}

pub fn spinner(message: &'static str, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new_spinner().with_message(message);
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    pb
}

/// A display of named stages: a spinner while a stage's work is not counted, a bar with its
/// ETA once it is (`total` above 0).
pub struct Stages {
    bar: ProgressBar,
    counted: std::cell::Cell<bool>,
}

pub fn stages(quiet: bool) -> Stages {
    let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new_spinner() };
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    Stages { bar, counted: std::cell::Cell::new(false) }
}

impl Stages {
    pub fn show(&self, stage: &str, done: usize, total: usize) {
        if self.bar.message() != stage {
            self.bar.reset();
            self.bar.set_message(stage.to_string());
        }
        if self.counted.replace(total > 0) != (total > 0) {
            self.bar.set_style(if total > 0 { bar_style() } else { ProgressStyle::default_spinner() });
        }
        self.bar.set_length(total as u64);
        self.bar.set_position(done as u64);
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}
