//! How a run ends: the exit statuses, the errors that choose them, warnings on stderr, and
//! Ctrl-C.
//!
//! | status | meaning |
//! |---|---|
//! | 0 | success |
//! | 1 | an input is missing, unreadable or invalid, or has no usable points (the message names the file and, where it can, the element and line or byte) |
//! | 2 | the command line is invalid (unknown flag, value out of range) |
//! | 3 | an output cannot be written (missing directory, no permission, full disk) |
//! | 130 | interrupted by Ctrl-C (or SIGTERM, SIGHUP) |
//!
//! No output file is ever left half-written: each is complete or absent. (A failure after
//! one output was written, say the statistics after the image, leaves that one.)

use std::fmt;

pub const EXIT_INPUT: u8 = 1;
pub const EXIT_USAGE: u8 = 2;
pub const EXIT_OUTPUT: u8 = 3;
/// 128 + SIGINT, what shells report for a program that Ctrl-C stopped.
pub const EXIT_INTERRUPTED: u8 = 130;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Usage,
    Output,
}

/// An error marked with the exit status it calls for; it prints as the error it wraps.
#[derive(Debug)]
struct Marked {
    kind: Kind,
    error: anyhow::Error,
}

impl fmt::Display for Marked {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:#}", self.error)
    }
}

impl std::error::Error for Marked {}

/// Marks `error` as a mistake on the command line (exit status 2).
pub fn usage(error: anyhow::Error) -> anyhow::Error {
    anyhow::Error::new(Marked { kind: Kind::Usage, error })
}

/// Marks `error` as a failure to write an output (exit status 3).
pub fn output(error: impl Into<anyhow::Error>) -> anyhow::Error {
    anyhow::Error::new(Marked { kind: Kind::Output, error: error.into() })
}

/// The exit status for `error`: the first mark in its chain, else [`EXIT_INPUT`].
pub fn exit_status(error: &anyhow::Error) -> u8 {
    let mark = error.chain().find_map(|e| e.downcast_ref::<Marked>()).map(|m| m.kind);
    match mark {
        Some(Kind::Usage) => EXIT_USAGE,
        Some(Kind::Output) => EXIT_OUTPUT,
        None => EXIT_INPUT,
    }
}

/// On Ctrl-C (or SIGTERM, SIGHUP): remove the temporary files of writes in progress
/// (finished outputs are never touched), say so, and exit with [`EXIT_INTERRUPTED`], before
/// any write can finish or report its failure.
pub fn exit_cleanly_on_interrupt() {
    let handler = || {
        pointray_io::discard_unfinished_writes_then(|| {
            eprintln!("pointray: interrupted");
            std::process::exit(i32::from(EXIT_INTERRUPTED))
        })
    };
    if let Err(e) = ctrlc::set_handler(handler) {
        tracing::debug!("no Ctrl-C handler: {e}");
    }
}

/// Whether a closed pipe on stdout or stderr ended the run, anywhere in the chain (which
/// [`Marked`] errors hide from `chain()`).
pub fn is_broken_pipe(error: &anyhow::Error) -> bool {
    error.chain().any(|e| match e.downcast_ref::<Marked>() {
        Some(marked) => is_broken_pipe(&marked.error),
        None => e.downcast_ref::<std::io::Error>().is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe),
    })
}

/// Writes log events as `pointray: warning: MESSAGE`, like the final `pointray: error:` line.
pub struct PlainFormat;

impl<S, N> tracing_subscriber::fmt::FormatEvent<S, N> for PlainFormat
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
    N: for<'a> tracing_subscriber::fmt::FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &tracing_subscriber::fmt::FmtContext<'_, S, N>,
        mut writer: tracing_subscriber::fmt::format::Writer<'_>,
        event: &tracing::Event<'_>,
    ) -> fmt::Result {
        let level = match *event.metadata().level() {
            tracing::Level::ERROR => "error",
            tracing::Level::WARN => "warning",
            tracing::Level::INFO => "info",
            tracing::Level::DEBUG => "debug",
            tracing::Level::TRACE => "trace",
        };
        write!(writer, "pointray: {level}: ")?;
        ctx.field_format().format_fields(writer.by_ref(), event)?;
        writeln!(writer)
    }
}
