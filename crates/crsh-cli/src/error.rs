//! The CLI's error type: one line for the user, and an exit code that tells a script whether
//! the command line was wrong (2) or the work failed (1).

use std::fmt;

/// Exit code for a command line that cannot be honoured (clap uses the same).
pub const EXIT_USAGE: i32 = 2;
/// Exit code for a failure while doing the work (loading, rendering, writing files).
pub const EXIT_RUNTIME: i32 = 1;

/// A failure of a `crsh` command.
#[derive(Debug)]
pub enum CliError {
    /// The arguments are invalid (bad `--set`, unknown pipeline or variant, unsupported
    /// backend, bad output name): exit code 2.
    Usage(String),
    /// The work failed (scene file missing or malformed, render error, I/O): exit code 1.
    Runtime(String),
}

impl CliError {
    /// A usage error.
    pub fn usage(msg: impl Into<String>) -> CliError {
        CliError::Usage(msg.into())
    }

    /// A runtime error.
    pub fn runtime(msg: impl Into<String>) -> CliError {
        CliError::Runtime(msg.into())
    }

    /// The process exit code for this error.
    pub fn exit_code(&self) -> i32 {
        match self {
            CliError::Usage(_) => EXIT_USAGE,
            CliError::Runtime(_) => EXIT_RUNTIME,
        }
    }
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let msg = match self {
            CliError::Usage(m) | CliError::Runtime(m) => m,
        };
        // One line: nested error messages may carry newlines (e.g. TOML parse errors).
        let mut first = true;
        for line in msg.lines().map(str::trim).filter(|l| !l.is_empty()) {
            if !first {
                f.write_str(" ")?;
            }
            f.write_str(line)?;
            first = false;
        }
        Ok(())
    }
}

impl std::error::Error for CliError {}

/// Result with [`CliError`].
pub type CliResult<T> = Result<T, CliError>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_and_single_line() {
        let e = CliError::usage("bad\n  thing\n\n");
        assert_eq!(e.exit_code(), 2);
        assert_eq!(e.to_string(), "bad thing");
        assert_eq!(CliError::runtime("x").exit_code(), 1);
    }
}
