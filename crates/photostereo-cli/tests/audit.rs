//! The second reliability audit's command-line cases: each input that used to be accepted
//! without a word, or refused with a misleading message, is now refused with a message naming
//! the flag or file at fault (exit 2, nothing written), or run with a note on stderr and in
//! `report.json`.

mod common;

use common::{photostereo, report_notes as notes, write_sphere_capture};
use std::path::Path;
use std::process::Output;

fn text(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

/// Expects exit 2, every needle in the message, no panic, and no output folder `out`.
fn refused(o: Output, cwd: &Path, needles: &[&str]) {
    let e = text(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(!e.contains("panicked"), "{e}");
    for n in needles {
        assert!(e.contains(n), "expected '{n}' in: {e}");
    }
    assert!(!cwd.join("out").exists(), "an output was written: {e}");
}

fn capture() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir(d.path().join("cap")).unwrap();
    write_sphere_capture(&d.path().join("cap"));
    d
}

#[test]
fn a_missing_intensity_file_is_said() {
    let d = capture();
    let o = photostereo(&["run", "cap", "-o", "out", "--no-depth"], d.path());
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        text(&o).contains("no light_intensities.txt"),
        "{}",
        text(&o)
    );
    assert!(notes(&d.path().join("out/report.json"))
        .iter()
        .any(|n| n.contains("no light_intensities.txt")));
    // With the file, no such note.
    std::fs::write(d.path().join("cap/light_intensities.txt"), "1\n1\n1\n1\n").unwrap();
    let o = photostereo(&["run", "cap", "-o", "out2", "--no-depth"], d.path());
    assert!(o.status.success() && !text(&o).contains("light_intensities"));
}

#[test]
fn light_refinement_that_cannot_apply_is_said() {
    let d = capture();
    let o = photostereo(
        &["run", "cap", "-o", "out", "--no-depth", "--refine-lights"],
        d.path(),
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(notes(&d.path().join("out/report.json"))
        .iter()
        .any(|n| n.contains("not refined") && n.contains("4 lights are too few")));
}

#[test]
fn flags_accepted_without_a_word_are_refused() {
    let d = capture();
    let p = d.path();
    refused(
        photostereo(&["run", "cap", "-o", "out", "--light-subset", "1,1,2,3"], p),
        p,
        &["--light-subset", "light 1 is named twice"],
    );
    refused(
        photostereo(
            &[
                "run",
                "cap",
                "-o",
                "out",
                "--memory-limit",
                "99999999999999999999T",
            ],
            p,
        ),
        p,
        &["--memory-limit", "99999999999999999999T"],
    );
    let o = std::process::Command::new(common::BIN)
        .args(["run", "cap", "-o", "out"])
        .current_dir(p)
        .env("PHOTOSTEREO_MAX_MEMORY", "lots")
        .output()
        .unwrap();
    refused(o, p, &["PHOTOSTEREO_MAX_MEMORY=lots", "expected a size"]);
    refused(
        photostereo(&["compare", "cap", "-o", "out", "--panel-size", "0"], p),
        p,
        &["--panel-size 0", "32 to 2048"],
    );
    assert!(photostereo(&["run", "cap", "-o", "run", "--no-depth"], p)
        .status
        .success());
    let o = photostereo(&["view", "run", "--error-max", "0"], p);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("--error-max 0"), "{}", text(&o));
    assert!(!p.join("run/index.html").exists());
    // An .lp file carries its own directions: --lights beside it is refused.
    std::fs::write(
        p.join("cap.lp"),
        "4\ncap/001.png 0.3 0.3 0.9\ncap/002.png -0.3 0.3 0.9\n\
         cap/003.png -0.3 -0.3 0.9\ncap/004.png 0.3 -0.3 0.9\n",
    )
    .unwrap();
    refused(
        photostereo(
            &[
                "run",
                "cap.lp",
                "--lights",
                "cap/light_directions.txt",
                "-o",
                "out",
            ],
            p,
        ),
        p,
        &["cap.lp carries its own light directions", "--lights"],
    );
    assert!(photostereo(&["run", "cap.lp", "-o", "lp", "--no-depth"], p)
        .status
        .success());
}

#[test]
fn negative_values_reach_the_flags_own_check() {
    let d = capture();
    let p = d.path();
    let o = photostereo(&["eval", "a.npy", "b.npy", "--error-map-max", "-5"], p);
    assert_eq!(o.status.code(), Some(2));
    let e = text(&o);
    assert!(
        e.contains("--error-map-max -5") && !e.contains("unexpected argument"),
        "{e}"
    );
    let o = photostereo(&["run", "cap", "-o", "out", "--distance", "-5"], p);
    let e = text(&o);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        e.contains("--distance") && !e.contains("unexpected argument"),
        "{e}"
    );
}

#[test]
fn a_small_memory_limit_is_echoed_as_given() {
    let d = capture();
    let o = photostereo(
        &["run", "cap", "-o", "out", "--memory-limit", "1000"],
        d.path(),
    );
    refused(o, d.path(), &["--memory-limit 1000:"]);
}

/// A near-light capture rendered by `synth`, in `root/near`.
fn near_capture(root: &Path) {
    let o = photostereo(
        &[
            "synth",
            "sphere",
            "--rig",
            "near-square",
            "--size",
            "48",
            "-o",
            "near",
            "-q",
        ],
        root,
    );
    assert!(o.status.success(), "{}", text(&o));
}

#[test]
fn near_light_inputs_that_cannot_be_right_are_refused_by_name() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    near_capture(p);
    assert!(photostereo(&["run", "near", "-o", "ok", "--no-depth"], p)
        .status
        .success());
    // K of another image size: the principal point outside the 48 × 48 images.
    let k = std::fs::read_to_string(p.join("near/K.txt")).unwrap();
    let rows: Vec<Vec<f64>> = k
        .lines()
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect();
    std::fs::write(
        p.join("near/K.txt"),
        format!(
            "{} 0 {}\n0 {} {}\n0 0 1\n",
            rows[0][0],
            rows[0][2] + 500.0,
            rows[1][1],
            rows[1][2]
        ),
    )
    .unwrap();
    refused(
        photostereo(&["run", "near", "-o", "out"], p),
        p,
        &["K.txt", "principal point", "outside the 48×48 images"],
    );
    std::fs::write(p.join("near/K.txt"), &k).unwrap();
    // A distance at which the LEDs merge into one direction.
    refused(
        photostereo(&["run", "near", "-o", "out", "--distance", "1e30"], p),
        p,
        &["--distance", "1e30", "one another"],
    );
    // One light position too few: the positions file is named, not the axes file.
    let positions = std::fs::read_to_string(p.join("near/light_positions.txt")).unwrap();
    let fewer: String = positions
        .lines()
        .skip(1)
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(p.join("near/light_positions.txt"), fewer).unwrap();
    refused(
        photostereo(&["run", "near", "-o", "out"], p),
        p,
        &["light_positions.txt", "3 light position(s) for 4 image(s)"],
    );
}
