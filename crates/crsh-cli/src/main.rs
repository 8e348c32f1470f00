//! The `crsh` binary: the command line of [`crsh_cli`] with the built-in stage variants.

fn main() {
    crsh_cli::main_with(crsh::Registries::builtin())
}
