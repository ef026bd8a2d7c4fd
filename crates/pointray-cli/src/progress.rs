//! Progress bars on stderr (indicatif draws nothing when stderr is not a terminal).

use indicatif::{ProgressBar, ProgressStyle};

pub fn bar(len: u64, message: &'static str, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len).with_message(message);
    pb.set_style(
        ProgressStyle::with_template("{msg:>10} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb
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
