//! `photostereo view`: write the browser viewer of an output folder (and optionally serve it),
//! and `photostereo export-openlime`: write what OpenLIME's BRDF layer reads.

use crate::common::print_json;
use crate::serve::Server;
use anyhow::{bail, Context, Result};
use clap::Args;
use photostereo::io::viewer::{
    openlime::export_openlime, write_view, RunFolder, ViewOptions, ViewSummary,
};
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// An output folder of `photostereo run`.
    pub folder: PathBuf,
    /// Ground-truth normals for the error layer (default: the file named in report.json).
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Light directions of the capture (N rows `x y z`), shown in the probe and as presets.
    #[arg(long)]
    pub lights: Option<PathBuf>,
    /// Upper end of the error layer's colour bar, degrees.
    #[arg(long, default_value_t = 45.0)]
    pub error_max: f32,
    /// Also write the OpenLIME export into FOLDER/openlime (see `export-openlime`).
    #[arg(long)]
    pub openlime: bool,
    /// Serve the folder on 127.0.0.1 (a free port unless --port) and print the address.
    #[arg(long)]
    pub serve: bool,
    /// Port for --serve (0 = any free port).
    #[arg(long, default_value_t = 0, requires = "serve")]
    pub port: u16,
    /// With --serve: serve the folder as it is, without writing the page.
    #[arg(long, requires = "serve")]
    pub no_write: bool,
    /// Print nothing but errors (and the address with --serve).
    #[arg(short, long)]
    pub quiet: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Args, Debug)]
pub struct ExportOpenLimeArgs {
    /// An output folder of `photostereo run`.
    pub folder: PathBuf,
    /// Where to write (default: FOLDER/openlime).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Replace the output folder's files if it exists.
    #[arg(long)]
    pub force: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
    /// Print nothing but errors.
    #[arg(short, long)]
    pub quiet: bool,
}

/// Writes the view of `folder` (used by `view` and `run --view`).
pub fn write(folder: &Path, options: &ViewOptions) -> Result<ViewSummary> {
    write_view(folder, options)
        .with_context(|| format!("writing the viewer of {}", folder.display()))
}

/// One line for people.
pub fn describe(s: &ViewSummary) -> String {
    format!(
        "wrote {} ({}×{}, {} pyramid levels, {} files, {:.1} MB; layers: {}) in {:.2} s",
        s.index.display(),
        s.width,
        s.height,
        s.levels,
        s.files,
        s.bytes as f64 / 1e6,
        s.layers.join(", "),
        s.seconds
    )
}

pub fn main(a: ViewArgs) -> Result<()> {
    if !(a.error_max > 0.0 && a.error_max <= 180.0) {
        bail!(
            "--error-max {}: expected an angle in (0, 180] degrees",
            a.error_max
        );
    }
    if !a.folder.is_dir() {
        bail!("{}: no such folder", a.folder.display());
    }
    if !a.no_write {
        let lights = match &a.lights {
            Some(p) => Some(photostereo::io::light_files::read_directions(p)?.directions),
            None => None,
        };
        let options = ViewOptions {
            ground_truth: a.gt.clone(),
            lights,
            error_max_deg: a.error_max,
            title: None,
        };
        let s = write(&a.folder, &options)?;
        if a.json {
            print_json(&serde_json::to_value(&s)?);
        } else if !a.quiet {
            for n in &s.notes {
                eprintln!("note: {n}");
            }
            println!("{}", describe(&s));
        }
        if a.openlime {
            let f = RunFolder::read(&a.folder, None)?;
            let o = export_openlime(&f, &a.folder.join("openlime"), true)?;
            if !a.quiet && !a.json {
                println!("wrote {} (OpenLIME BRDF layer)", o.dir.display());
            }
        }
    }
    if a.serve {
        let server = Server::bind(&a.folder, a.port)?;
        // The address goes to stdout even with --quiet: it is what the user asked for.
        println!("serving {} at {}", a.folder.display(), server.url());
        use std::io::Write;
        let _ = std::io::stdout().flush();
        server.run()?;
    }
    Ok(())
}

pub fn export_main(a: ExportOpenLimeArgs) -> Result<()> {
    let f = RunFolder::read(&a.folder, None)?;
    let out = a
        .output
        .clone()
        .unwrap_or_else(|| a.folder.join("openlime"));
    let s = export_openlime(&f, &out, a.force)?;
    if a.json {
        print_json(&serde_json::to_value(&s)?);
    } else if !a.quiet {
        println!(
            "wrote {} ({}×{}: {})",
            s.dir.display(),
            s.width,
            s.height,
            s.files.join(", ")
        );
    }
    Ok(())
}

/// `run --view`: the viewer of a run just written, with the capture's light directions (those
/// the run kept when it used a subset).
pub fn after_run(
    output: &Path,
    files: &photostereo::CaptureFiles,
    gt: Option<&Path>,
    report: &photostereo::method::report::Report,
    print: bool,
) -> Result<()> {
    let all = &files.lights.directions;
    let lights = match report
        .parameters
        .get("light_subset")
        .and_then(|v| v.as_array())
    {
        Some(keep) => keep
            .iter()
            .map(|k| {
                k.as_u64()
                    .and_then(|k| all.get((k as usize).wrapping_sub(1)).copied())
            })
            .collect::<Option<Vec<_>>>(),
        None => Some(all.clone()),
    };
    let options = ViewOptions {
        ground_truth: gt.map(Path::to_path_buf),
        lights,
        ..Default::default()
    };
    let s = write(output, &options)?;
    if print {
        println!("{}", describe(&s));
    }
    Ok(())
}
