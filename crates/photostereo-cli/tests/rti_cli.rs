//! `photostereo rti` end to end: the files and report on a synthetic dome capture, the light
//! mask of `--exclude-unreliable`, `--force` by the project's rule, and refusals (near lights,
//! too few lights for the basis, an unknown basis, RBF with a light mask) that name the cause and leave no output.

mod common;

use common::photostereo;
use std::path::Path;

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn synth(dir: &Path, rig: &str, name: &str) {
    let o = photostereo(
        &[
            "synth", "sphere", "--rig", rig, "--size", "40", "-o", name, "--quiet",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
}

fn report(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn fits_every_basis_and_writes_its_file_and_report() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    synth(dir, "dome-30", "cap");
    let mut loo = Vec::new();
    for (basis, file) in [
        ("ptm", "image.ptm"),
        ("ptm-rgb", "image.ptm"),
        ("hsh2", "image.rti"),
        ("hsh3", "image.rti"),
        ("rbf", "basis.npy"),
    ] {
        let out = format!("out-{basis}");
        let o = photostereo(
            &["rti", "cap", "--basis", basis, "-o", &out, "--quiet"],
            dir,
        );
        assert!(o.status.success(), "{basis}: {}", stderr(&o));
        assert!(dir.join(&out).join(file).is_file(), "{basis}");
        assert!(dir.join(&out).join("coefficients.npy").is_file());
        // relight's web folder: info.json and ceil(nplanes / 3) plane images.
        let info = report(&dir.join(&out).join("relight/info.json"));
        let planes = info["nplanes"].as_u64().unwrap() as usize;
        for g in 0..planes.div_ceil(3) {
            assert!(dir
                .join(&out)
                .join(format!("relight/plane_{g}.png"))
                .is_file());
        }
        assert!(!dir
            .join(&out)
            .join(format!("relight/plane_{}.png", planes.div_ceil(3)))
            .exists());
        let r = report(&dir.join(&out).join("report.json"));
        assert_eq!(r["basis"], basis);
        assert_eq!(
            r["leave_one_out"]["rmse_8bit"].as_array().unwrap().len(),
            30
        );
        let m = r["leave_one_out"]["mean_rmse_8bit"].as_f64().unwrap();
        assert!(m.is_finite() && m > 0.0, "{basis}: {m}");
        let lam = r["lambertian_reference"]["errors"]["mean_rmse_8bit"]
            .as_f64()
            .unwrap();
        assert!(lam.is_finite() && lam > 0.0);
        loo.push(m);
    }
    // Nine terms per channel follow a glossy sphere better than four.
    assert!(loo[3] < loo[2], "hsh3 {} vs hsh2 {}", loo[3], loo[2]);
    // --force replaces an rti folder, and never a run folder.
    let o = photostereo(&["rti", "cap", "-o", "out-hsh3", "--quiet"], dir);
    assert!(!o.status.success() && stderr(&o).contains("out-hsh3"));
    let o = photostereo(&["rti", "cap", "-o", "out-hsh3", "--force", "--quiet"], dir);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = photostereo(
        &["run", "cap", "--no-depth", "-o", "run-out", "--quiet"],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let o = photostereo(&["rti", "cap", "-o", "run-out", "--force", "--quiet"], dir);
    assert!(
        !o.status.success() && stderr(&o).contains("run folder"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn exclude_unreliable_leaves_out_the_recursive_methods_rejected_readings() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    synth(dir, "dome-30", "cap");
    let o = photostereo(
        &["rti", "cap", "--exclude-unreliable", "-o", "ex", "--quiet"],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&dir.join("ex/report.json"));
    assert_eq!(r["exclude_unreliable"], true);
    assert!(r["excluded_readings"].as_u64().unwrap() > 0);
    assert_eq!(r["lambertian_reference"]["method"], "recursive");
}

#[test]
fn refusals_name_their_cause_and_leave_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    // Four lights cannot determine nine coefficients.
    synth(dir, "square4", "four");
    let o = photostereo(&["rti", "four", "--basis", "hsh3", "-o", "x"], dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("do not determine"), "{}", stderr(&o));
    assert!(!dir.join("x").exists());
    // Near lights.
    let o = photostereo(
        &[
            "synth",
            "sphere",
            "--rig",
            "near-dome",
            "--size",
            "40",
            "-o",
            "near",
            "--quiet",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let o = photostereo(&["rti", "near", "-o", "y"], dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("near lights"), "{}", stderr(&o));
    assert!(!dir.join("y").exists());
    // An unknown basis names the flag.
    let o = photostereo(&["rti", "four", "--basis", "rbf3", "-o", "z"], dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--basis"), "{}", stderr(&o));
    // RBF has no per-pixel light mask.
    let o = photostereo(
        &[
            "rti",
            "four",
            "--basis",
            "rbf",
            "--exclude-unreliable",
            "-o",
            "v",
        ],
        dir,
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("--exclude-unreliable"),
        "{}",
        stderr(&o)
    );
    assert!(!dir.join("v").exists());
    // A budget too small for the coefficients names --memory-limit.
    synth(dir, "dome-30", "cap");
    let o = photostereo(&["rti", "cap", "--memory-limit", "20K", "-o", "w"], dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--memory-limit"), "{}", stderr(&o));
    assert!(!dir.join("w").exists());
}
