//! # crsh
//!
//! The `crsh` command line: `crsh render` renders a scene with a CPU pipeline (shadow,
//! reflection and refraction rays, seed 000 chapter 3), writes an 8-bit PNG and optionally a
//! stats JSON file, and prints a summary; `crsh scenes`, `crsh pipelines` and `crsh adapters`
//! list what can be rendered, with what, and on which GPUs; `crsh tables` prints seed 000's
//! evaluation tables for any scenes and hierarchy configurations; `crsh ablate` runs a matrix
//! of pipelines and parameters and writes data, charts and a report; `crsh stress` runs the
//! stability suite (procedural cases with known answers) against every pipeline.
//!
//! Errors print one line (`error: ...`) on stderr; the exit code is 2 when the command line
//! cannot be honoured and 1 when the work fails.

#![warn(missing_docs)]

mod ablate;
mod args;
mod error;
mod listing;
mod output;
mod render;
mod report;
mod stress;
mod tables;

use clap::Parser;

use crate::args::{Cli, Command};
use crate::error::CliResult;

fn run(cli: Cli) -> CliResult<()> {
    match cli.command {
        Command::Render(a) => render::run(&a),
        Command::Scenes(a) => listing::scenes(&a),
        Command::Pipelines(a) => listing::pipelines(&a),
        Command::Adapters(a) => listing::adapters(&a),
        Command::Tables(a) => tables::run(&a),
        Command::Ablate(a) => ablate::run(&a),
        Command::Stress(a) => stress::run(&a),
    }
}

fn main() {
    // clap prints its own usage errors (`error: ...`) and exits with code 2.
    let cli = Cli::parse();
    if let Err(e) = run(cli) {
        use std::io::Write;
        let _ = writeln!(std::io::stderr(), "error: {e}");
        std::process::exit(e.exit_code());
    }
}
