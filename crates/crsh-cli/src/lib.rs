//! # crsh-cli
//!
//! The `crsh` command line as a library. `crsh render` renders a scene with a pipeline
//! (shadow, reflection and refraction rays, seed 000 chapter 3), writes an 8-bit PNG and
//! optionally a stats JSON file, and prints a summary; `crsh scenes`, `crsh pipelines` and
//! `crsh adapters` list what can be rendered, with what, and on which GPUs; `crsh tables`
//! prints seed 000's evaluation tables for any scenes and hierarchy configurations; `crsh
//! ablate` runs a matrix of pipelines and parameters (sharded over processes if need be) and
//! writes data, charts and a report; `crsh stress` runs the stability suite (procedural cases
//! with known answers) against every pipeline; `crsh grid-build` times the uniform grid's
//! rebuild on seed 002's random soups next to its table 1.
//!
//! Every command resolves pipeline, variant and parameter names through the
//! [`crsh::Registries`] it is given, so a program that registers its own stage variants and
//! calls [`main_with`] gets `--set STAGE.kind=NAME`, `crsh pipelines`, `crsh tables`, `crsh
//! stress` and ablation plans for them with no other change:
//!
//! ```
//! let registries = crsh::Registries::builtin();
//! // registries.cpu.add_hasher(info, |ctx, spec| ...) would add a variant here.
//! crsh_cli::run(&registries, ["crsh", "pipelines", "--json"]).unwrap();
//! let err = crsh_cli::run(&registries, ["crsh", "render", "--set", "hash.kind=nosuch"]);
//! assert_eq!(err.unwrap_err().exit_code(), crsh_cli::EXIT_USAGE);
//! ```
//!
//! Errors print one line (`error: ...`) on stderr; the exit code is 2 when the command line
//! cannot be honoured and 1 when the work fails.

#![warn(missing_docs)]

mod ablate;
pub mod allocator;
mod args;
mod error;
mod grid_build;
mod listing;
mod output;
mod render;
mod stress;
mod tables;

use std::ffi::OsString;

use clap::Parser;
use crsh::Registries;

use crate::args::{Cli, Command};
pub use crate::error::{CliError, CliResult, EXIT_RUNTIME, EXIT_USAGE};

fn dispatch(registries: &Registries, cli: Cli) -> CliResult<()> {
    match cli.command {
        Command::Render(a) => render::run(&a, registries),
        Command::Scenes(a) => listing::scenes(&a),
        Command::Pipelines(a) => listing::pipelines(&a, registries),
        Command::Adapters(a) => listing::adapters(&a),
        Command::Tables(a) => tables::run(&a, registries),
        Command::Ablate(a) => ablate::run(&a, registries),
        Command::Stress(a) => stress::run(&a, registries),
        Command::GridBuild(a) => grid_build::run(&a),
    }
}

/// Runs the command line `args` (the first item is the program name) with `registries`.
/// `--help` and `--version` print and return `Ok`; malformed arguments are
/// [`CliError::Usage`] with clap's message.
///
/// `--threads` sets the size of rayon's global pool, which can be set once per process.
pub fn run<I, T>(registries: &Registries, args: I) -> CliResult<()>
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    match Cli::try_parse_from(args) {
        Ok(cli) => dispatch(registries, cli),
        Err(e) if !e.use_stderr() => {
            output::print_stdout(&e.render().to_string())?;
            Ok(())
        }
        Err(e) => Err(CliError::usage(e.render().to_string())),
    }
}

/// Keeps Mesa's Vulkan device-selection layer (`VK_LAYER_MESA_device_select`, an implicit
/// layer loaded into every Vulkan instance) from printing `error: XDG_RUNTIME_DIR is invalid
/// or not set in the environment.` on stderr — twice, from libwayland straight to file
/// descriptor 2 — on a successful `--backend wgpu` run without a Wayland session: it asks
/// the compositor which GPU drives the display. Without `XDG_RUNTIME_DIR` there is no such
/// compositor to ask, so the layer is switched off (`NODEVICE_SELECT=1`, its own switch)
/// unless the user steers it (`NODEVICE_SELECT`, `MESA_VK_DEVICE_SELECT`, `DRI_PRIME`) or a
/// Wayland socket is named by an absolute path. crsh picks its adapter itself
/// (`WGPU_ADAPTER_NAME`, `WGPU_POWER_PREF`), so nothing else changes.
///
/// Called first thing in [`main_with_args`], while the process has one thread (setting the
/// environment is not safe once other threads may read it).
fn quiet_vulkan_device_select() {
    let set = |k: &str| std::env::var_os(k).is_some_and(|v| !v.is_empty());
    let runtime_dir = std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| {
        std::path::Path::new(&d).is_absolute() && std::path::Path::new(&d).is_dir()
    });
    let wayland_socket =
        std::env::var_os("WAYLAND_DISPLAY").is_some_and(|d| std::path::Path::new(&d).is_absolute());
    let steered = ["NODEVICE_SELECT", "MESA_VK_DEVICE_SELECT", "DRI_PRIME"]
        .iter()
        .any(|k| set(k));
    if !runtime_dir && !wayland_socket && !steered {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
}

/// The `crsh` program with `registries`: parses the process's arguments, runs the command,
/// prints an error as one line on stderr and exits with its code (2 for usage errors, as
/// clap's own, 1 for failures of the work, 0 on success). First it tells glibc's `malloc` to
/// keep freed memory ([`allocator::keep_freed_memory`]), unless the environment tunes it.
pub fn main_with(registries: Registries) -> ! {
    main_with_args(registries, std::env::args_os())
}

/// [`main_with`] on the given arguments (the first item is the program name), e.g. an
/// example's default command line.
pub fn main_with_args<I, T>(registries: Registries, args: I) -> !
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    allocator::keep_freed_memory();
    quiet_vulkan_device_select();
    // clap prints its own usage errors (`error: ...`) and exits with code 2.
    let cli = Cli::parse_from(args);
    let code = match dispatch(&registries, cli) {
        Ok(()) => 0,
        Err(e) => {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "error: {e}");
            e.exit_code()
        }
    };
    std::process::exit(code)
}
