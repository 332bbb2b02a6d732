//! `photostereo synth` and `photostereo demo` end to end: the binary, its files and its output.

use std::process::Output;

mod common;
use common::photostereo;

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).to_string()
}

#[test]
fn list_names_scenes_rigs_and_models_under_headings() {
    let dir = tempfile::tempdir().unwrap();
    let o = photostereo(&["synth", "--list"], dir.path());
    assert!(o.status.success());
    let text = stdout(&o);
    let lines: Vec<&str> = text.lines().collect();
    let after = |heading: &str| -> Vec<&str> {
        let i = lines.iter().position(|l| *l == heading).expect(heading);
        lines[i + 1..]
            .iter()
            .take_while(|l| !l.ends_with(':'))
            .copied()
            .collect()
    };
    assert_eq!(
        after("scenes:"),
        ["sphere", "cavities", "blocks", "terrain", "bumps", "face"]
    );
    assert_eq!(
        after("rigs:"),
        [
            "square4",
            "ring8",
            "ring-N",
            "dome-N",
            "near-ring",
            "near-square",
            "near-dome"
        ]
    );
    assert_eq!(
        after("reflectance models:"),
        ["lambert", "blinn-phong", "torrance-sparrow"]
    );
    // Without --list a scene is required.
    let o = photostereo(&["synth"], dir.path());
    assert!(!o.status.success());
}

#[test]
fn synth_writes_the_diligent_layout_and_ground_truth() {
    let dir = tempfile::tempdir().unwrap();
    let o = photostereo(
        &[
            "synth",
            "blocks",
            "--rig",
            "ring8",
            "--size",
            "48",
            "--brdf",
            "torrance-sparrow",
            "--noise",
            "0.01",
            "--seed",
            "3",
            "--mask",
            "circle",
            "--intensities",
            "coloured",
            "-o",
            "out",
            "--json",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["lights"], 8);
    assert_eq!(v["mask"], "circle");
    assert_eq!(v["brdf"], "torrance-sparrow");
    let shadow = v["stats"]["shadow_fraction"].as_f64().unwrap();
    assert!(shadow > 0.01 && shadow < 0.9, "{shadow}");
    let out = dir.path().join("out");
    let names = std::fs::read_to_string(out.join("filenames.txt")).unwrap();
    let names: Vec<&str> = names.lines().collect();
    assert_eq!(
        names,
        ["001.png", "002.png", "003.png", "004.png", "005.png", "006.png", "007.png", "008.png"]
    );
    for n in &names {
        let bytes = std::fs::read(out.join(n)).unwrap();
        // PNG signature, then IHDR: bit depth 16, colour type 2 (RGB).
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        assert_eq!((bytes[24], bytes[25]), (16, 2), "{n} is 16-bit RGB");
    }
    let dirs = std::fs::read_to_string(out.join("light_directions.txt")).unwrap();
    assert_eq!(dirs.lines().count(), 8);
    let intens = std::fs::read_to_string(out.join("light_intensities.txt")).unwrap();
    let first: Vec<f64> = intens
        .lines()
        .next()
        .unwrap()
        .split_whitespace()
        .map(|t| t.parse().unwrap())
        .collect();
    assert!(
        first[0] != first[1] || first[1] != first[2],
        "coloured lights"
    );
    let normal: ndarray::Array3<f32> = ndarray_npy::read_npy(out.join("gt/normal.npy")).unwrap();
    let depth: ndarray::Array2<f32> = ndarray_npy::read_npy(out.join("gt/depth.npy")).unwrap();
    let albedo: ndarray::Array3<f32> = ndarray_npy::read_npy(out.join("gt/albedo.npy")).unwrap();
    let shadow: ndarray::Array3<bool> = ndarray_npy::read_npy(out.join("gt/shadow.npy")).unwrap();
    let hl: ndarray::Array3<bool> = ndarray_npy::read_npy(out.join("gt/highlight.npy")).unwrap();
    assert_eq!(normal.dim(), (48, 48, 3));
    assert_eq!(depth.dim(), (48, 48));
    assert_eq!(albedo.dim(), (48, 48, 3));
    assert_eq!(shadow.dim(), (8, 48, 48));
    assert_eq!(hl.dim(), (8, 48, 48));
    // Corner: outside the circle mask. Centre: inside.
    assert!(depth[[0, 0]].is_nan() && normal[[0, 0, 2]] == 0.0);
    assert!(depth[[24, 24]].is_finite() && normal[[24, 24, 2]] > 0.0);
    assert!(!(0..8).any(|k| shadow[[k, 24, 24]] && hl[[k, 24, 24]]));
}

#[test]
fn synth_refuses_existing_output_without_force_and_repeats_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let args = ["synth", "face", "--size", "32", "-o", "f", "--quiet"];
    let o = photostereo(&args, dir.path());
    assert!(o.status.success());
    assert!(stdout(&o).is_empty(), "--quiet prints nothing");
    let before = std::fs::read(dir.path().join("f/001.png")).unwrap();
    let o = photostereo(&args, dir.path());
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--force"));
    let mut forced = args.to_vec();
    forced.push("--force");
    let o = photostereo(&forced, dir.path());
    assert!(o.status.success());
    assert_eq!(before, std::fs::read(dir.path().join("f/001.png")).unwrap());
    // Text output reports the shadowed and highlighted shares.
    forced.retain(|a| *a != "--quiet");
    let o = photostereo(&forced, dir.path());
    let text = stdout(&o);
    assert!(
        text.contains("shadowed") && text.contains("highlighted"),
        "{text}"
    );
}

#[test]
fn bad_arguments_exit_2_and_say_what_was_expected() {
    let dir = tempfile::tempdir().unwrap();
    for (args, needle) in [
        (vec!["synth", "teapot"], "sphere"),
        (vec!["synth", "face", "--rig", "hexagon"], "dome-N"),
        (vec!["synth", "face", "--brdf", "phong"], "blinn-phong"),
        (vec!["synth", "face", "--mask", "square"], "irregular"),
        (vec!["synth", "face", "--noise=-1"], "noise"),
        (vec!["synth", "face", "--albedo", "wood"], "texture"),
    ] {
        let o = photostereo(&args, dir.path());
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(needle), "{args:?}: {err}");
    }
    assert!(
        !dir.path().join("synth-face").exists(),
        "nothing written on error"
    );
}

#[test]
fn synth_accepts_a_light_file_as_rig() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("lights.txt"),
        "3\n0.3 0.3 0.9\n-0.3 0.3 0.9\n0 -0.4 0.9\n",
    )
    .unwrap();
    let o = photostereo(
        &[
            "synth",
            "sphere",
            "--rig",
            "lights.txt",
            "--size",
            "24",
            "-o",
            "s",
            "--json",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["lights"], 3);
}

#[test]
fn demo_scores_every_method_on_six_scenes_and_replaces_its_own_folder() {
    let dir = tempfile::tempdir().unwrap();
    let o = photostereo(&["demo", "--size", "48", "--json"], dir.path());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let results = v["results"].as_array().unwrap();
    // Three rigs × six scenes × every method.
    let methods = photostereo::method::engine::Method::ALL.len();
    assert_eq!(results.len(), 3 * 6 * methods);
    for r in results {
        let e = r["error"]["mean_deg"].as_f64().unwrap();
        assert!(e.is_finite() && e > 0.0 && e < 90.0, "{r}");
        if r["method"] == "recursive" {
            // The recursive method stays accurate on every scene and rig.
            assert!(e < 10.0, "{r}");
        }
    }
    let out = dir.path().join("photostereo-demo");
    for rig in ["square4", "ring8", "dome-20"] {
        assert!(results.iter().filter(|r| r["rig"] == rig).count() == 6 * methods);
        for scene in ["sphere", "cavities", "blocks", "terrain", "bumps", "face"] {
            assert!(out.join(format!("{rig}-{scene}.png")).is_file());
            assert!(out
                .join(rig)
                .join(scene)
                .join("capture/gt/normal.npy")
                .is_file());
            assert!(out.join(rig).join(scene).join("l2/normals.npy").is_file());
            assert!(out
                .join(rig)
                .join(scene)
                .join("recursive/light_status.npy")
                .is_file());
        }
    }
    // Re-running replaces its own folder without --force; text output holds the table.
    let o = photostereo(&["demo", "--size", "48", "--rig", "square4"], dir.path());
    assert!(o.status.success());
    let text = stdout(&o);
    assert!(text.lines().any(|l| l.starts_with("l2 ")), "{text}");
    assert!(text.contains("mean"));
    // A folder that is not the demo's is refused.
    std::fs::create_dir(dir.path().join("mine")).unwrap();
    let o = photostereo(&["demo", "-o", "mine"], dir.path());
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn any_width_and_height_rendered_one_light_at_a_time() {
    let dir = tempfile::tempdir().unwrap();
    let o = photostereo(
        &[
            "synth", "sphere", "--rig", "ring8", "--size", "40x24", "-o", "wh", "--json",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(
        (summary["width"].as_u64(), summary["height"].as_u64()),
        (Some(40), Some(24))
    );
    assert_eq!(summary["streamed"], true);
    let img = photostereo::io::imageio::read_image(&dir.path().join("wh/001.png")).unwrap();
    assert_eq!((img.width, img.height, img.bit_depth), (40, 24, 16));
    // The capture runs, and its normals match the ground truth of the W×H scene.
    let o = photostereo(
        &[
            "run",
            "wh",
            "--gt",
            "wh/gt/normal.npy",
            "--method",
            "l2",
            "-o",
            "r",
            "--json",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("r/report.json")).unwrap())
            .unwrap();
    let mean = report["error"]["mean_deg"].as_f64().unwrap();
    assert!(mean < 10.0, "mean error {mean}°");
    let o = photostereo(
        &["synth", "sphere", "--size", "40x4", "-o", "bad"],
        dir.path(),
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("at least 8 pixels"));
}
