//! `photostereo`: the command-line front end of the photostereo library. Each subcommand parses
//! its arguments, calls the library, and prints a summary (or JSON with `--json`).
//!
//! Exit codes: 0 success, 2 any error (bad input, unreadable file, refused overwrite). On
//! SIGINT, SIGTERM or SIGHUP the output in progress (a `.NAME.tmp-PID` staging folder) is removed
//! and the process ends by that signal.

mod calibrate;
mod common;
mod compare;
mod demo;
mod eval;
mod integrate;
mod params;
mod photometry;
mod rti;
mod run;
mod serve;
mod synth;
mod view;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
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
    /// Run every method on one capture: the paper's Table 1 row (with --gt) and Table 2 row
    /// (mean highlight intensity), compare.json and a side-by-side figure (compare.png).
    Compare(compare::CompareArgs),
    /// Calibrate light directions from a mirror sphere (intensities from a matte one).
    Calibrate(calibrate::CalibrateArgs),
    /// Integrate a normal map into depth (depth.npy/.exr/.png), meshes (mesh.ply/.obj), curl.npy
    /// and, from the default bilateral integrator, the discontinuity map (discontinuities.npy/.png).
    Integrate(integrate::IntegrateArgs),
    /// Render built-in scenes, reconstruct them, print the errors, write ./photostereo-demo/.
    Demo(demo::DemoArgs),
    /// Render a built-in scene under a light rig, with ground truth (DiLiGenT layout + gt/).
    Synth(synth::SynthArgs),
    /// Write FOLDER/index.html, a browser viewer of an output folder: relighting, layers, 3D, probe.
    View(view::ViewArgs),
    /// Write what OpenLIME's BRDF layer reads (kd, normals, layer configuration, a page).
    ExportOpenlime(view::ExportOpenLimeArgs),
    /// Fit a relightable image (PTM or hemispherical harmonics) per pixel and write image.ptm
    /// or image.rti for RTIViewer, with the fit's leave-one-out error in report.json. Distant
    /// lights only: a near-light capture is refused.
    Rti(rti::RtiArgs),
}

/// Removes the output in progress when the process is interrupted, then ends it by the same
/// signal (so a shell sees "interrupted", exit status 128 + signal).
#[cfg(unix)]
fn remove_output_on_signals() {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) else {
        return;
    };
    std::thread::spawn(move || {
        if let Some(sig) = signals.forever().next() {
            photostereo::io::export::abandon_pending();
            let _ = signal_hook::low_level::emulate_default_handler(sig);
            std::process::exit(128 + sig);
        }
    });
}

#[cfg(not(unix))]
fn remove_output_on_signals() {}

/// The error and its causes, each cause once: a cause already part of the message before it
/// (the library's I/O errors print their OS error themselves) is not repeated. The library's
/// errors name parameters as this program's flags ([`params::spell`]).
fn message(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = match cause.downcast_ref::<photostereo::Error>() {
            Some(e) => e.spelled(&params::spell),
            None => cause.to_string(),
        };
        if out.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

/// `command` with every option that takes a value accepting a negative number as that value
/// (`--distance -5` reaches the option's own check instead of being read as a flag), in every
/// subcommand.
fn negative_values_allowed(command: clap::Command) -> clap::Command {
    command
        .mut_args(|a| {
            if a.get_action().takes_values() && !a.is_positional() {
                a.allow_negative_numbers(true)
            } else {
                a
            }
        })
        .mut_subcommands(negative_values_allowed)
}

fn main() -> ExitCode {
    // Before any thread: the allocator's retained memory must not grow with the thread count.
    photostereo::base::machine::cap_allocator_arenas();
    let matches = negative_values_allowed(Cli::command()).get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    remove_output_on_signals();
    let result = photostereo::base::machine::check_memory_limit_var()
        .map_err(anyhow::Error::from)
        .and_then(|()| run_command(cli.command));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", message(&e));
            ExitCode::from(2)
        }
    }
}

/// Runs one subcommand.
fn run_command(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Run(a) => run::main(a),
        Command::Eval(a) => eval::main(a),
        Command::Compare(a) => compare::main(a),
        Command::Demo(a) => demo::main(a),
        Command::Calibrate(a) => calibrate::main(a),
        Command::Integrate(a) => integrate::main(a),
        Command::Synth(a) => synth::main(a),
        Command::View(a) => view::main(a),
        Command::ExportOpenlime(a) => view::export_main(a),
        Command::Rti(a) => rti::main(a),
    }
}
