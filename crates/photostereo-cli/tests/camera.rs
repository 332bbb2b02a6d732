//! Captures as cameras write them, end to end: `synth --response/--ambient/--exposure-jitter/
//! --format jpeg`, then `run` with no flag (report.json's per-image photometry), with
//! `--response`, `--ambient` and `--ignore-exposure`, and the flags' refusals.

use std::path::Path;

mod common;
use common::photostereo;

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

fn report(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap()
}

fn mean_error(dir: &Path) -> f64 {
    report(dir)["error"]["mean_deg"].as_f64().unwrap()
}

/// `synth` of a 64 × 64 sphere (unless `extra` gives `--size`) under dome-24 into `dir/name`.
fn synth(dir: &Path, name: &str, extra: &[&str]) {
    let mut args = vec![
        "synth", "sphere", "--rig", "dome-24", "--brdf", "lambert", "-q", "-o", name,
    ];
    if !extra.contains(&"--size") {
        args.extend_from_slice(&["--size", "64"]);
    }
    args.extend_from_slice(extra);
    let o = photostereo(&args, dir);
    assert!(o.status.success(), "{}", stderr(&o));
}

fn run(dir: &Path, capture: &str, out: &str, extra: &[&str]) -> std::process::Output {
    let gt = format!("{capture}/gt/normal.npy");
    let mut args = vec![
        "run",
        capture,
        "--gt",
        &gt,
        "--method",
        "l2",
        "--no-depth",
        "-o",
        out,
    ];
    args.extend_from_slice(extra);
    photostereo(&args, dir)
}

/// Runs `linear` and `capture` (into `r-linear`, `r-CAPTURE`); returns the capture's run and
/// the two mean errors (linear, capture).
fn against_linear(dir: &Path, capture: &str) -> (std::process::Output, f64, f64) {
    assert!(run(dir, "linear", "r-linear", &[]).status.success());
    let out = format!("r-{capture}");
    let o = run(dir, capture, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (base, own) = (
        mean_error(&dir.join("r-linear")),
        mean_error(&dir.join(&out)),
    );
    (o, base, own)
}

#[test]
fn a_cameras_jpegs_reconstruct_like_the_linear_capture() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    synth(dir, "linear", &[]);
    synth(
        dir,
        "camera",
        &[
            "--response",
            "srgb",
            "--format",
            "jpeg",
            "--exposure-jitter",
            "2",
            "--ambient",
            "0.05",
        ],
    );
    assert!(dir.join("camera/ambient.jpg").is_file());
    assert!(dir.join("camera/001.jpg").is_file() && !dir.join("camera/001.png").exists());
    let (o, base, cam) = against_linear(dir, "camera");
    assert!(stderr(&o).contains("exposures differ"), "{}", stderr(&o));
    assert!(cam < base + 0.8, "camera {cam:.2}° vs linear {base:.2}°");
    let r = report(&dir.join("r-camera"));
    let images = r["photometry"]["images"].as_array().unwrap();
    assert_eq!(images.len(), 24);
    for i in images {
        assert!(i["decoder"].as_str().unwrap().starts_with("jpeg baseline"));
        assert_eq!(i["response"], "srgb");
        assert_eq!(i["ambient_removed"], true);
        assert!(i["exposure"]["time_s"].as_f64().unwrap() > 0.0);
        let f = i["exposure_factor"].as_f64().unwrap();
        assert!((0.2..=5.0).contains(&f), "{f}");
    }
    assert!(r["photometry"]["ambient_file"]
        .as_str()
        .unwrap()
        .ends_with("ambient.jpg"));
    // Each step left out costs accuracy: the exposures, the response.
    let o = run(dir, "camera", "r-raw", &["--ignore-exposure"]);
    assert!(o.status.success());
    assert!(mean_error(&dir.join("r-raw")) > cam + 2.0);
    let o = run(dir, "camera", "r-lin", &["--response", "linear"]);
    assert!(o.status.success());
    assert!(mean_error(&dir.join("r-lin")) > cam + 2.0);
    let r = report(&dir.join("r-lin"));
    assert_eq!(
        r["photometry"]["images"][0]["response_source"],
        "--response"
    );
}

/// `--format jpeg` alone writes what a camera writes, sRGB declared in EXIF, which `run` reads
/// back to the linear readings; a response a JPEG cannot declare is refused, naming the flags.
#[test]
fn a_plain_jpeg_capture_is_srgb_and_says_so() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    synth(dir, "linear", &[]);
    synth(dir, "jpeg", &["--format", "jpeg"]);
    let (_, base, jpeg) = against_linear(dir, "jpeg");
    assert!(jpeg < base + 0.8, "jpeg {jpeg:.2}° vs linear {base:.2}°");
    let r = report(&dir.join("r-jpeg"));
    for i in r["photometry"]["images"].as_array().unwrap() {
        assert_eq!(i["response"], "srgb");
        assert_eq!(i["response_source"], "EXIF colour space sRGB");
    }
    for response in ["linear", "gamma:2.2"] {
        let args = [
            "synth",
            "sphere",
            "--format",
            "jpeg",
            "--response",
            response,
            "-o",
            "bad",
        ];
        let o = photostereo(&args, dir);
        assert!(!o.status.success());
        assert!(
            stderr(&o).contains("JPEG") && stderr(&o).contains(response),
            "{}",
            stderr(&o)
        );
        assert!(!dir.join("bad").exists());
    }
}

/// A non-square camera capture (rendered one light at a time) is written and read like a
/// square one: its JPEGs reconstruct within the same margin of the linear render.
#[test]
fn a_non_square_cameras_jpegs_reconstruct_like_the_linear_capture() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let size = ["--size", "72x56"];
    synth(dir, "linear", &size);
    let camera = [
        "--response",
        "srgb",
        "--format",
        "jpeg",
        "--ambient",
        "0.05",
    ];
    synth(dir, "camera", &[&size[..], &camera[..]].concat());
    assert!(dir.join("camera/ambient.jpg").is_file() && !dir.join("camera/001.png").exists());
    let (_, base, cam) = against_linear(dir, "camera");
    assert!(cam < base + 0.8, "camera {cam:.2}° vs linear {base:.2}°");
    let r = report(&dir.join("r-camera"));
    assert_eq!(r["input"]["width"], 72, "{}", r["input"]);
    assert_eq!(r["photometry"]["images"][0]["response"], "srgb");
    assert_eq!(r["photometry"]["images"][0]["ambient_removed"], true);
    // Read as linear, the sRGB encoding costs accuracy: the images were encoded.
    let o = run(dir, "camera", "r-lin", &["--response", "linear"]);
    assert!(o.status.success());
    assert!(mean_error(&dir.join("r-lin")) > cam + 1.0);
}

#[test]
fn an_untagged_gamma_capture_is_flagged_and_auto_recovers_it() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    synth(dir, "gamma", &["--response", "gamma:2.2"]);
    let o = run(dir, "gamma", "r-plain", &[]);
    assert!(o.status.success());
    assert!(
        stderr(&o).contains("--response gamma:2.2") || stderr(&o).contains("--response gamma:2.1"),
        "{}",
        stderr(&o)
    );
    let o = run(dir, "gamma", "r-auto", &["--response", "auto"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = &report(&dir.join("r-auto"))["photometry"]["response_estimate"];
    let g = e["gamma"].as_f64().unwrap();
    assert!((g - 2.2).abs() <= 0.1, "{e}");
    assert!(mean_error(&dir.join("r-auto")) < mean_error(&dir.join("r-plain")));
}

#[test]
fn photometry_flags_are_refused_clearly() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    synth(dir, "linear", &[]);
    let o = run(dir, "linear", "r1", &["--response", "gamma:9"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--response") && stderr(&o).contains("gamma:G"));
    let o = run(dir, "linear", "r2", &["--ambient", "nowhere.png"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--ambient nowhere.png"),
        "{}",
        stderr(&o)
    );
    assert!(!dir.join("r2").exists());
    // An ambient frame of another size names the file.
    let o = photostereo(
        &["synth", "sphere", "--size", "32", "-q", "-o", "small"],
        dir,
    );
    assert!(o.status.success());
    let o = run(dir, "linear", "r3", &["--ambient", "small/001.png"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("small/001.png"), "{}", stderr(&o));
    assert!(!dir.join("r3").exists());
    // Exposures need EXIF: PNG cannot carry them here.
    let o = photostereo(
        &["synth", "sphere", "--exposure-jitter", "2", "-o", "x"],
        dir,
    );
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--format jpeg"), "{}", stderr(&o));
}

/// An RTIBuilder project folder (JPEGs in `jpeg-exports/`, an `.lp` in `assembly-files/` naming
/// files of another machine): `run FOLDER` finds the light file, pairs its lines with the
/// images in sorted order, says so, and reconstructs like the folder it came from.
#[test]
fn run_finds_an_rtibuilder_projects_light_file() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    synth(dir, "camera", &["--response", "srgb", "--format", "jpeg"]);
    let o = run(dir, "camera", "r-folder", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let project = dir.join("project");
    std::fs::create_dir_all(project.join("jpeg-exports")).unwrap();
    std::fs::create_dir_all(project.join("assembly-files")).unwrap();
    let dirs = std::fs::read_to_string(dir.join("camera/light_directions.txt")).unwrap();
    let dirs: Vec<&str> = dirs.lines().filter(|l| !l.trim().is_empty()).collect();
    let mut images: Vec<_> = std::fs::read_dir(dir.join("camera"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "jpg") && !p.ends_with("ambient.jpg"))
        .collect();
    images.sort();
    assert_eq!(images.len(), dirs.len());
    let mut lp = format!("{}\n", dirs.len());
    for (k, (img, d)) in images.iter().zip(&dirs).enumerate() {
        std::fs::copy(
            img,
            project.join("jpeg-exports").join(img.file_name().unwrap()),
        )
        .unwrap();
        lp += &format!("D:\\capture\\IMG_{:04}.JPG {d}\n", k + 1);
    }
    std::fs::write(project.join("assembly-files").join("capture.lp"), lp).unwrap();
    let o = photostereo(
        &[
            "run",
            "project",
            "--gt",
            "camera/gt/normal.npy",
            "--mask",
            "camera/mask.png",
            "--method",
            "l2",
            "--no-depth",
            "-o",
            "r-project",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("sorted order"), "{}", stderr(&o));
    let (a, b) = (
        mean_error(&dir.join("r-folder")),
        mean_error(&dir.join("r-project")),
    );
    assert!((a - b).abs() < 0.05, "{a:.3}° vs {b:.3}°");
}

/// `rti` and `compare` take `run`'s photometry flags: on an untagged 2.2 power-law capture of a
/// Lambertian sphere, `--response gamma:2.2` makes the readings linear, so that `rti` fits the
/// coefficients it fits to the linear rendering of the same scene, and `compare`'s l2 error
/// falls to `run`'s with the same flag.
#[test]
fn rti_and_compare_take_the_photometry_flags() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    synth(dir, "linear", &[]);
    synth(dir, "gamma", &["--response", "gamma:2.2"]);
    // Each hemispherical-harmonics term's range over the pixels.
    let rti = |capture: &str, out: &str, extra: &[&str]| {
        let mut args = vec!["rti", capture, "--basis", "hsh2", "-q", "-o", out];
        args.extend_from_slice(extra);
        let o = photostereo(&args, dir);
        assert!(o.status.success(), "{}", stderr(&o));
        let r = report(&dir.join(out));
        let ranges: Vec<f64> = r["coefficient_ranges"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|t| t.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()))
            .collect();
        ranges
    };
    let truth = rti("linear", "rti-linear", &[]);
    let off = |v: Vec<f64>| {
        v.iter()
            .zip(&truth)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    };
    let plain = off(rti("gamma", "rti-plain", &[]));
    let given = off(rti("gamma", "rti-gamma", &["--response", "gamma:2.2"]));
    assert!(
        given < 0.05 && plain > 0.2,
        "coefficient ranges off the linear capture's by {given} with --response, {plain} without"
    );
    let compare = |out: &str, extra: &[&str]| {
        let mut args = vec![
            "compare",
            "gamma",
            "--gt",
            "gamma/gt/normal.npy",
            "--methods",
            "l2",
            "-q",
            "-o",
            out,
        ];
        args.extend_from_slice(extra);
        let o = photostereo(&args, dir);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join(out).join("compare.json")).unwrap(),
        )
        .unwrap();
        v["table1_mean_angular_error_deg"]["l2"].as_f64().unwrap()
    };
    let plain = compare("cmp-plain", &[]);
    let given = compare("cmp-gamma", &["--response", "gamma:2.2"]);
    let o = run(dir, "gamma", "r-gamma", &["--response", "gamma:2.2"]);
    assert!(o.status.success());
    let by_run = mean_error(&dir.join("r-gamma"));
    assert!(
        given < plain - 2.0 && (given - by_run).abs() < 1e-6,
        "compare l2 {given:.2}° with --response, {plain:.2}° without, run {by_run:.2}°"
    );
}
