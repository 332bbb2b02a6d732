//! The library's error type. Every variant names what the user supplied (a file, a line, a
//! parameter) and what was expected, so that a front end can print it as it is.
//!
//! Messages name parameters in the library's spelling (`relative_noise`, `force`, `lights`)
//! through *references* ([`param`], [`param_set`]): marked spans that [`Error::spelled`] hands
//! to a front end's speller, so that the command line says `--relative-noise` and Python says
//! `relative_noise=` without rewriting words in the text. [`Display`](std::fmt::Display)
//! spells them as the library does.

use std::path::{Path, PathBuf};

/// Opens a parameter reference in a message (see [`param`]).
const OPEN: char = '⟦';
/// Closes a parameter reference.
const CLOSE: char = '⟧';

/// A reference to the parameter `name` in a message: the front ends spell it as their flag or
/// keyword (`--distance`, `distance`).
pub fn param(name: &str) -> String {
    format!("{OPEN}{name}{CLOSE}")
}

/// A reference asking for the parameter `name` to be given `value` (`force`, `"true"`); with
/// an empty value, asking for the parameter to be given at all (`lights`, `""`: "pass
/// `--lights FILE`" / "pass `lights=`"). The front ends spell it (`--force`, `force=True`).
pub fn param_set(name: &str, value: &str) -> String {
    format!("{OPEN}{name}={value}{CLOSE}")
}

/// A parameter reference as a speller receives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParamRef<'a> {
    /// The library's name of the parameter.
    pub name: &'a str,
    /// `None`: the parameter itself is named; `Some("")`: a value for it is asked for;
    /// `Some(v)`: the value `v` is asked for (`"true"` for a switch).
    pub value: Option<&'a str>,
}

impl ParamRef<'_> {
    /// The library's own spelling: `name`, `name=` or `name=value`.
    pub fn library(&self) -> String {
        match self.value {
            None => self.name.to_string(),
            Some(v) => format!("{}={v}", self.name),
        }
    }
}

/// `text` with every parameter reference replaced by `spell(reference)`.
pub fn spell_text(text: &str, spell: &dyn Fn(ParamRef<'_>) -> String) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(start) = rest.find(OPEN) {
        let after = &rest[start + OPEN.len_utf8()..];
        let Some(end) = after.find(CLOSE) else {
            break;
        };
        out.push_str(&rest[..start]);
        let inner = &after[..end];
        let r = match inner.split_once('=') {
            Some((name, value)) => ParamRef {
                name,
                value: Some(value),
            },
            None => ParamRef {
                name: inner,
                value: None,
            },
        };
        out.push_str(&spell(r));
        rest = &after[end + CLOSE.len_utf8()..];
    }
    out.push_str(rest);
    out
}

/// Errors raised by the library. None of them is a panic: every user-supplied input that is
/// wrong ends up here.
#[derive(Debug)]
pub enum Error {
    /// A file could not be opened, read or written.
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A text file has a malformed line (1-based line number).
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    /// A file was read but its content is not what was expected (corrupt image, wrong size…).
    File { path: PathBuf, message: String },
    /// A parameter or an in-memory input is out of its domain.
    Invalid(String),
    /// A parameter is out of its domain. `name` is the library's name of the parameter
    /// (`relative_noise`); front ends spell it their own way (`--relative-noise`) through
    /// [`Error::spelled`].
    Parameter { name: &'static str, message: String },
    /// The caller asked to stop ([`crate::base::progress::Progress::cancelled`]).
    Cancelled,
    /// The output folder exists and overwriting it was not asked for.
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

    /// The message with its parameter references still marked (see [`param`]); the
    /// [`Error::Parameter`] variant's name is a reference too.
    fn marked(&self) -> String {
        match self {
            Error::Io { path, source } => format!("{}: {source}", path.display()),
            Error::Parse {
                path,
                line,
                message,
            } => format!("{}, line {line}: {message}", path.display()),
            Error::File { path, message } => format!("{}: {message}", path.display()),
            Error::Invalid(m) => m.clone(),
            Error::Parameter { name, message } => format!("{} {message}", param(name)),
            Error::Cancelled => "cancelled".into(),
            Error::OutputExists { path } => format!(
                "{}: already exists (pass {} to replace it)",
                path.display(),
                param_set("force", "true")
            ),
        }
    }

    /// The message with every parameter it names spelt by `spell` — a front end's flag or
    /// keyword for the library's name (the command line's `--relative-noise`, Python's
    /// `relative_noise`); what is not a parameter is left as it is.
    pub fn spelled(&self, spell: &dyn Fn(ParamRef<'_>) -> String) -> String {
        spell_text(&self.marked(), spell)
    }
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.spelled(&|r| r.library()))
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Error::Io { source, .. } => Some(source),
            _ => None,
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn references_are_spelt_by_the_front_end_and_shown_as_the_library_names_them() {
        let e = Error::file(
            "cap/mean_distance.txt",
            format!("missing (this file or {})", param_set("distance", "")),
        );
        assert_eq!(
            e.to_string(),
            "cap/mean_distance.txt: missing (this file or distance=)"
        );
        let flag = |r: ParamRef<'_>| format!("--{}", r.name.replace('_', "-"));
        assert_eq!(
            e.spelled(&flag),
            "cap/mean_distance.txt: missing (this file or --distance)"
        );
        let e = Error::parameter("relative_noise", "-1: expected a number ≥ 0");
        assert_eq!(e.to_string(), "relative_noise -1: expected a number ≥ 0");
        assert_eq!(
            e.spelled(&flag),
            "--relative-noise -1: expected a number ≥ 0"
        );
        let e = Error::OutputExists { path: "out".into() };
        assert_eq!(
            e.to_string(),
            "out: already exists (pass force=true to replace it)"
        );
        // Text without references, or with a stray bracket, is left as it is.
        assert_eq!(spell_text("a ⟦b", &flag), "a ⟦b");
        assert_eq!(spell_text("plain", &flag), "plain");
    }
}
