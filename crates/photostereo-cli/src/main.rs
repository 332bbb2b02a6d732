//! `photostereo`: the command-line front end of the photostereo library. Each subcommand parses
//! its arguments, calls the library, and prints a summary (or JSON with `--json`).
//!
//! Exit codes: 0 success, 2 any error (bad input, unreadable file, refused overwrite).

mod calibrate;
mod common;
mod demo;
mod eval;
mod integrate;
mod run;
mod synth;
mod view;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Photometric stereo: normals, albedo and error figures from images under known distant lights.
#[derive(Parser, Debug)]
#[command(name = "photostereo", version, about, long_about = None, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Reconstruct normals and albedo from a capture and write an output folder.
    Run(run::RunArgs),
    /// Compare a normal map with ground truth: mean, median and shares under 5°/10°/20°.
    Eval(eval::EvalArgs),
    /// Calibrate light directions from a mirror sphere (intensities from a matte one).
    Calibrate(calibrate::CalibrateArgs),
    /// Integrate a normal map into depth (depth.npy/.exr/.png), meshes (mesh.ply/.obj) and curl.npy.
    Integrate(integrate::IntegrateArgs),
    /// Render built-in scenes, reconstruct them, print the errors, write ./photostereo-demo/.
    Demo(demo::DemoArgs),
    /// Render a built-in scene under a light rig, with ground truth (DiLiGenT layout + gt/).
    Synth(synth::SynthArgs),
    /// Write FOLDER/index.html, a browser viewer of an output folder: relighting, layers, 3D, probe.
    View(view::ViewArgs),
    /// Write what OpenLIME's BRDF layer reads (kd, normals, layer configuration, a page).
    ExportOpenlime(view::ExportOpenLimeArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run(a) => run::main(a),
        Command::Eval(a) => eval::main(a),
        Command::Demo(a) => demo::main(a),
        Command::Calibrate(a) => calibrate::main(a),
        Command::Integrate(a) => integrate::main(a),
        Command::Synth(a) => synth::main(a),
        Command::View(a) => view::main(a),
        Command::ExportOpenlime(a) => view::export_main(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
