//! Near point lights end to end: `synth --rig near-*` writes the near-light layout,
//! `run` reads it (with `--distance` or `mean_distance.txt`), and `integrate --camera
//! --distance` integrates any normal map through a camera.

use std::path::Path;
use std::process::Output;

mod common;
use common::photostereo;

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

fn report(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn synth_run_and_integrate_a_near_light_capture() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = photostereo(
        &[
            "synth",
            "sphere",
            "--rig",
            "near-dome",
            "--size",
            "48",
            "-o",
            "cap",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    for f in [
        "K.txt",
        "light_positions.txt",
        "light_axes.txt",
        "light_anisotropy.txt",
        "light_intensities.txt",
        "mean_distance.txt",
        "gt/depth.npy",
    ] {
        assert!(d.join("cap").join(f).is_file(), "{f}");
    }
    let distance: f64 = std::fs::read_to_string(d.join("cap/mean_distance.txt"))
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    assert!((250.0..300.0).contains(&distance), "{distance}");
    // run with the folder's distance, then with --distance.
    let o = photostereo(&["run", "cap", "--gt", "cap/gt/normal.npy", "-o", "out"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&d.join("out/report.json"));
    let err = r["error"]["mean_deg"].as_f64().unwrap();
    assert!(err < 3.0, "near recursive {err}°");
    let rounds = r["near"]["rounds"].as_array().unwrap();
    assert!(!rounds.is_empty());
    assert_eq!(r["near"]["mean_distance_mm"].as_f64().unwrap(), distance);
    let ply = std::fs::read(d.join("out/mesh.ply")).unwrap();
    let header = String::from_utf8_lossy(&ply[..200]).to_string();
    assert!(header.contains("mm, camera frame"), "{header}");
    let given = format!("{}", distance + 20.0);
    let o = photostereo(
        &[
            "run",
            "cap",
            "--method",
            "l2",
            "--distance",
            &given,
            "-o",
            "out2",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&d.join("out2/report.json"));
    assert_eq!(
        r["near"]["mean_distance_mm"].as_f64().unwrap(),
        distance + 20.0
    );
    // --intensities cannot replace a near capture's LED radiance: refused, not ignored.
    std::fs::write(d.join("other.txt"), "1\n".repeat(24)).unwrap();
    let o = photostereo(
        &["run", "cap", "--intensities", "other.txt", "-o", "out3"],
        d,
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("near-light capture") && stderr(&o).contains("--intensities"),
        "{}",
        stderr(&o)
    );
    assert!(!d.join("out3").exists());
    // Bad distances and a distance for a distant capture are refused (exit 2, named).
    let o = photostereo(&["run", "cap", "--distance=-5", "-o", "out3"], d);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("distance"), "{}", stderr(&o));
    // Without the LED positions the folder is distant lights (the directions at the centre)
    // seen through K.txt: the depth is still Z in mm, the meshes in mm.
    std::fs::remove_file(d.join("cap/light_positions.txt")).unwrap();
    let o = photostereo(
        &[
            "run",
            "cap",
            "--method",
            "l2",
            "--distance",
            "300",
            "-o",
            "out4",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&d.join("out4/report.json"));
    assert!(r.get("near").is_none());
    let ply = std::fs::read(d.join("out4/mesh.ply")).unwrap();
    assert!(String::from_utf8_lossy(&ply[..200]).contains("mm, camera frame"));
    // Without K.txt a distance has nothing to apply to.
    std::fs::remove_file(d.join("cap/K.txt")).unwrap();
    let o = photostereo(&["run", "cap", "--distance", "300", "-o", "out5"], d);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("K.txt"), "{}", stderr(&o));
    std::fs::write(d.join("cap/K.txt"), "768 0 23.5\n0 768 23.5\n0 0 1\n").unwrap();
    // integrate through the camera: the mean depth is the distance, in mm.
    let o = photostereo(
        &[
            "integrate",
            "cap/gt/normal.npy",
            "--mask",
            "cap/mask.png",
            "--camera",
            "cap/K.txt",
            "--distance",
            "300",
            "-o",
            "depth",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&d.join("depth/report.json"));
    assert_eq!(r["parameters"]["distance_mm"].as_f64(), Some(300.0), "{r}");
    let o = photostereo(
        &[
            "integrate",
            "cap/gt/normal.npy",
            "--camera",
            "cap/K.txt",
            "-o",
            "d2",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}
