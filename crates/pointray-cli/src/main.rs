//! `pointray`: the command line. Argument parsing, logging and progress live here; the work is
//! in the `pointray` and `pointray-io` libraries.

mod args;
#[cfg(feature = "bench")]
mod bench;
mod commands;
mod failure;
mod perceptual;
mod progress;
mod scene;

use std::io::{self, Write};
use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches};

use args::{Cli, Command};

fn main() -> ExitCode {
    let matches = Cli::command().get_matches();
    let mut cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    if let (Command::Render(a), Some(("render", m))) = (&mut cli.command, matches.subcommand()) {
        a.given = m
            .ids()
            .filter(|id| m.value_source(id.as_str()) == Some(clap::parser::ValueSource::CommandLine))
            .map(|id| id.to_string())
            .collect();
    }
    init_logging(&cli);
    failure::exit_cleanly_on_interrupt();
    let result = match &cli.command {
        Command::Render(a) => commands::render::run(a, cli.quiet),
        Command::Prepare(a) => commands::prepare::run(a, cli.quiet),
        Command::Sample(a) => commands::sample::run(a, cli.quiet),
        Command::Info(a) => commands::info::run(a, cli.quiet),
        Command::View(a) => commands::view::run(a, cli.quiet),
        Command::Compare(a) => commands::compare::run(a),
        #[cfg(feature = "bench")]
        Command::Bench(a) => bench::run(a, cli.quiet),
        #[cfg(feature = "bench")]
        Command::Report(a) => bench::run_report(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // Piped into `head`: the reader left, which is not an error (ripgrep does the same).
        Err(e) if failure::is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            let _ = writeln!(io::stderr(), "pointray: error: {e:#}");
            ExitCode::from(failure::exit_status(&e))
        }
    }
}

fn init_logging(cli: &Cli) {
    let level = match (cli.quiet, cli.verbose) {
        (true, _) => tracing::Level::ERROR,
        (false, 0) => tracing::Level::WARN,
        (false, 1) => tracing::Level::INFO,
        (false, 2) => tracing::Level::DEBUG,
        _ => tracing::Level::TRACE,
    };
    tracing_subscriber::fmt().with_max_level(level).with_writer(io::stderr).event_format(failure::PlainFormat).init();
}
