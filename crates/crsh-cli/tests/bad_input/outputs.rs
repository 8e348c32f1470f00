//! Output paths, write failures, `ablate --compare` inputs, sizes and `--set` values.
