//! The library's error type. Every variant names what the user supplied (a file, a line, a
//! parameter) and what was expected, so that a front end can print it as it is.

use std::path::{Path, PathBuf};

/// Errors raised by the library. None of them is a panic: every user-supplied input that is
/// wrong ends up here.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be opened, read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A text file has a malformed line (1-based line number).
    #[error("{}, line {line}: {message}", path.display())]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    /// A file was read but its content is not what was expected (corrupt image, wrong size…).
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
    /// A parameter or an in-memory input is out of its domain.
    #[error("{0}")]
    Invalid(String),
    /// A parameter is out of its domain. `name` is the library's name of the parameter
    /// (`relative_noise`); front ends map it to their own spelling (`--relative-noise`).
    #[error("{name} {message}")]
    Parameter { name: &'static str, message: String },
    /// The caller asked to stop ([`crate::base::progress::Progress::cancelled`]).
    #[error("cancelled")]
    Cancelled,
    /// The output folder exists and overwriting it was not asked for.
    #[error("{}: already exists (pass --force to replace it)", path.display())]
    OutputExists { path: PathBuf },
}

/// Result alias of the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }
    /// A malformed line `line` (1-based) of the text file `path`.
    pub fn parse(path: impl AsRef<Path>, line: usize, message: impl Into<String>) -> Self {
        Error::Parse {
            path: path.as_ref().to_path_buf(),
            line,
            message: message.into(),
        }
    }
    /// Unexpected content in `path`.
    pub fn file(path: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Error::File {
            path: path.as_ref().to_path_buf(),
            message: message.into(),
        }
    }
    /// The parameter `name` (the library's spelling) is out of its domain; `message` says the
    /// value and what was expected ("-0.5: expected a value ≥ 0").
    pub fn parameter(name: &'static str, message: impl Into<String>) -> Self {
        Error::Parameter {
            name,
            message: message.into(),
        }
    }
    /// An invalid parameter or in-memory input.
    pub fn invalid(message: impl Into<String>) -> Self {
        Error::Invalid(message.into())
    }
}

/// Finds the item of `all` whose `name` is `s`, or an error listing the accepted names
/// ("unknown {what} 's': expected one of …"). Shared by the `FromStr` impls of named enums.
pub fn parse_name<T: Copy>(
    s: &str,
    all: &[T],
    name: impl Fn(T) -> &'static str,
    what: &str,
) -> Result<T> {
    all.iter().copied().find(|&t| name(t) == s).ok_or_else(|| {
        let names: Vec<&str> = all.iter().map(|&t| name(t)).collect();
        Error::invalid(format!(
            "unknown {what} '{s}': expected one of {}",
            names.join(", ")
        ))
    })
}
