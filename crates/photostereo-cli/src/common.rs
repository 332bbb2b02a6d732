//! Options and helpers shared by the subcommands: the capture they read, `--quiet`, `--json`,
//! `--force`, and the terminal progress bar.

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use photostereo::base::progress::Progress;
use std::io::IsTerminal;
use std::sync::Mutex;

/// The capture a subcommand reads (`run`, `compare`, `rti`), given as `run` takes it.
#[derive(Args, Debug, Clone)]
pub struct CaptureInput {
    /// A DiLiGenT-layout folder, an RTI capture folder (with its .lp or .dome), a list file
    /// (with --lights), or image files (with --lights).
    #[arg(required = true)]
    pub input: Vec<std::path::PathBuf>,
    /// Light directions (N rows `x y z`, optionally preceded by a count line).
    #[arg(long)]
    pub lights: Option<std::path::PathBuf>,
    /// Per-light intensities (N rows `R G B` or one value each).
    #[arg(long)]
    pub intensities: Option<std::path::PathBuf>,
    /// Mask image (non-zero = object); overrides the layout's own mask.
    #[arg(long)]
    pub mask: Option<std::path::PathBuf>,
}

impl CaptureInput {
    /// Checks that the paths exist ([`check_input_paths`]) and reads the capture's layout.
    pub fn files(&self) -> anyhow::Result<photostereo::io::layouts::CaptureFiles> {
        self.check()?;
        Ok(photostereo::io::layouts::CaptureFiles::from_inputs(
            &self.input,
            self.lights.as_deref(),
            self.intensities.as_deref(),
            self.mask.as_deref(),
        )?)
    }

    /// Checks that the paths exist, naming the flag that gave each.
    pub fn check(&self) -> anyhow::Result<()> {
        check_input_paths(
            &self.input,
            self.lights.as_deref(),
            self.intensities.as_deref(),
            self.mask.as_deref(),
        )
    }

    /// The paths given on the command line besides the mask (`--force` never replaces them).
    pub fn given(&self) -> impl Iterator<Item = &std::path::Path> {
        self.input
            .iter()
            .map(std::path::PathBuf::as_path)
            .chain(self.lights.as_deref())
            .chain(self.intensities.as_deref())
    }
}

/// Options common to every subcommand that writes output.
#[derive(Args, Debug, Clone)]
pub struct OutputOpts {
    /// Print nothing but errors.
    #[arg(short, long)]
    pub quiet: bool,
    /// Print a JSON summary on stdout (for scripts) instead of text.
    #[arg(long)]
    pub json: bool,
    /// Replace the output if it exists.
    #[arg(long)]
    pub force: bool,
}

impl OutputOpts {
    /// Whether human-readable text should be printed.
    pub fn text(&self) -> bool {
        !self.quiet && !self.json
    }

    /// A progress bar on stderr when it is a terminal and output is not quiet.
    pub fn progress(&self) -> Bar {
        Bar {
            enabled: !self.quiet && std::io::stderr().is_terminal(),
            bar: Mutex::new(None),
        }
    }
}

/// A terminal progress bar implementing the library's [`Progress`].
pub struct Bar {
    enabled: bool,
    bar: Mutex<Option<ProgressBar>>,
}

impl Progress for Bar {
    fn begin(&self, stage: &str, total: u64) {
        if !self.enabled {
            return;
        }
        let bar = ProgressBar::new(total);
        if let Ok(style) =
            ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} {elapsed} (ETA {eta})")
        {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message(stage.to_string());
        if let Ok(mut b) = self.bar.lock() {
            *b = Some(bar);
        }
    }
    fn advance(&self, units: u64) {
        if let Ok(b) = self.bar.lock() {
            if let Some(bar) = b.as_ref() {
                bar.inc(units);
            }
        }
    }
    fn end(&self) {
        if let Ok(mut b) = self.bar.lock() {
            if let Some(bar) = b.take() {
                bar.finish_and_clear();
            }
        }
    }
}

/// Prints a JSON value on stdout.
pub fn print_json(value: &serde_json::Value) {
    println!(
        "{}",
        serde_json::to_string_pretty(value).unwrap_or_default()
    );
}

/// Checks that the capture arguments name existing files before anything is read, naming the
/// flag that gave each path.
pub fn check_input_paths(
    input: &[std::path::PathBuf],
    lights: Option<&std::path::Path>,
    intensities: Option<&std::path::Path>,
    mask: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    for p in input {
        if std::fs::metadata(p).is_err() {
            anyhow::bail!("{}: no such file or folder", p.display());
        }
    }
    for (flag, p) in [
        ("--lights", lights),
        ("--intensities", intensities),
        ("--mask", mask),
    ] {
        if let Some(p) = p {
            if !p.is_file() {
                let what = if p.exists() {
                    "not a file"
                } else {
                    "no such file"
                };
                anyhow::bail!("{}: {what} (given as {flag})", p.display());
            }
        }
    }
    Ok(())
}

/// `--memory-limit SIZE`: bytes, or with a `K`, `M`, `G` or `T` suffix (powers of 1024).
pub fn parse_memory_limit(s: &str) -> Result<u64, String> {
    match photostereo::base::machine::parse_bytes(s) {
        Some(b) if b > 0 => Ok(b),
        _ => Err(format!(
            "'{s}': expected a size in bytes such as 4G, 500M or 1.5G (powers of 1024)"
        )),
    }
}
