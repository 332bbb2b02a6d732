//! `photostereo calibrate` end to end on the public psmImages data.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn psm(name: &str) -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/psmImages"
    ))
    .join(name)
}

fn photostereo(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_photostereo"))
        .args(args)
        .output()
        .unwrap()
}

macro_rules! run {
    ($($a:expr),* $(,)?) => { photostereo(&[$(std::ffi::OsStr::new(&$a)),*]) };
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).to_string()
}

fn read_rows(p: &Path) -> Vec<Vec<f64>> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .map(|l| l.split_whitespace().map(|t| t.parse().unwrap()).collect())
        .collect()
}

#[test]
fn calibrate_then_run_on_gray() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cal");
    let o = run!("calibrate", psm("chrome.txt"), "-o", out);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let stdout = text(&o.stdout);
    assert!(
        stdout.contains("radius 120.11 px") && stdout.contains("wrote"),
        "{stdout}"
    );
    for f in [
        "light_directions.txt",
        "calibration.json",
        "calibration.png",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    assert!(!out.join("light_intensities.txt").exists());
    let rows = read_rows(&out.join("light_directions.txt"));
    assert_eq!(rows.len(), 12);
    let reference = read_rows(&psm("lights.reference.txt"))[1..].to_vec();
    for (r, q) in rows.iter().zip(&reference) {
        let n = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
        assert!((n - 1.0).abs() < 1e-5);
        // Within 9° of the reference (see docs/calibration.md for the difference).
        let d = (r[0] * q[0] + r[1] * q[1] + r[2] * q[2]) / n;
        assert!(d.acos().to_degrees() < 9.0);
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("calibration.json")).unwrap())
            .unwrap();
    let lights = json["lights"].as_array().unwrap();
    assert_eq!(lights.len(), 12);
    for l in lights {
        let c = l["confidence"].as_f64().unwrap();
        assert!(c > 0.0 && c <= 1.0, "{c}");
    }
    assert_eq!(json["sphere_source"], "mask");
    // The figure is a PNG.
    let png = std::fs::read(out.join("calibration.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG"));
    // The calibrated lights drive a reconstruction.
    let rec = tmp.path().join("gray");
    let o = run!(
        "run",
        psm("gray.txt"),
        "--lights",
        out.join("light_directions.txt"),
        "-o",
        rec
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(rec.join("normals.npy").is_file());
}

#[test]
fn output_flags_and_folder_input() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cal");
    let o = run!("calibrate", psm("chrome.txt"), "-o", out, "--quiet");
    assert!(o.status.success());
    assert!(o.stdout.is_empty() && o.stderr.is_empty());
    // An existing folder is refused without --force (exit 2), replaced with it.
    let o = run!("calibrate", psm("chrome.txt"), "-o", out);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("already exists"),
        "{}",
        text(&o.stderr)
    );
    // The folder layout (natural order, *mask* file as mask) gives the same lights; --json.
    let o = run!("calibrate", psm("chrome"), "-o", out, "--force", "--json");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["output"], out.display().to_string());
    assert_eq!(v["lights"].as_array().unwrap().len(), 12);
    assert_eq!(v["sphere_source"], "mask");
    let from_folder = std::fs::read_to_string(out.join("light_directions.txt")).unwrap();
    let out2 = tmp.path().join("cal2");
    assert!(run!("calibrate", psm("chrome.txt"), "-o", out2, "-q")
        .status
        .success());
    assert_eq!(
        from_folder,
        std::fs::read_to_string(out2.join("light_directions.txt")).unwrap()
    );
}

#[test]
fn matte_sphere_gives_intensities() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cal");
    let o = run!(
        "calibrate",
        psm("chrome.txt"),
        "--matte",
        psm("gray.txt"),
        "-o",
        out
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    let rows = read_rows(&out.join("light_intensities.txt"));
    assert_eq!(rows.len(), 12);
    for ch in 0..3 {
        let mean: f64 = rows.iter().map(|r| r[ch]).sum::<f64>() / 12.0;
        assert!((mean - 1.0).abs() < 1e-4, "{mean}");
    }
    // The gray sphere's lights are of nearly equal strength: all within 10% of the mean.
    assert!(rows.iter().all(|r| (r[0] - 1.0).abs() < 0.1), "{rows:?}");
    // Lights and intensities together drive a run.
    let rec = tmp.path().join("gray");
    let o = run!(
        "run",
        psm("gray.txt"),
        "--lights",
        out.join("light_directions.txt"),
        "--intensities",
        out.join("light_intensities.txt"),
        "-o",
        rec
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
}

/// A folder with the chrome images linked in, image 3 replaced by a black image.
fn chrome_without_highlight(dir: &Path) {
    for k in 0..12 {
        let dst = dir.join(format!("chrome.{k}.png"));
        if k == 2 {
            photostereo::io::imageio::write_png8(&dst, 512, 340, 3, &vec![3u8; 512 * 340 * 3])
                .unwrap();
        } else {
            std::os::unix::fs::symlink(psm(&format!("chrome/chrome.{k}.png")), dst).unwrap();
        }
    }
    std::os::unix::fs::symlink(psm("chrome/chrome.mask.png"), dir.join("mask.png")).unwrap();
}

#[test]
fn missing_highlight_is_warned_and_fails() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = tmp.path().join("cap");
    std::fs::create_dir(&cap).unwrap();
    chrome_without_highlight(&cap);
    let out = tmp.path().join("cal");
    let o = run!("calibrate", cap, "-o", out);
    assert_eq!(o.status.code(), Some(2));
    let err = text(&o.stderr);
    assert!(
        err.contains("warning: image 3") && err.contains("no highlight"),
        "{err}"
    );
    assert!(
        err.contains("error:") && err.contains("image(s) 3"),
        "{err}"
    );
    assert!(!out.exists());
    // No staging folder is left behind.
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 1);
}

#[test]
fn bad_masks_are_errors() {
    let tmp = tempfile::tempdir().unwrap();
    // Writes a mask, runs `calibrate` with it and expects a refusal naming the file and `what`.
    let refused = |name: &str, w: usize, h: usize, pixels: &[u8], what: &str| {
        let m = tmp.path().join(name);
        photostereo::io::imageio::write_png8(&m, w, h, 1, pixels).unwrap();
        let o = run!(
            "calibrate",
            psm("chrome.txt"),
            "--mask",
            m,
            "-o",
            tmp.path().join(format!("out-{name}"))
        );
        assert_eq!(o.status.code(), Some(2));
        let err = text(&o.stderr);
        assert!(err.contains(name) && err.contains(what), "{err}");
    };
    let (w, h) = (512usize, 340usize);
    let disc = |inside: &dyn Fn(f64, f64) -> bool| -> Vec<u8> {
        (0..w * h)
            .map(|i| {
                let (r, c) = ((i / w) as f64, (i % w) as f64);
                if inside(r, c) {
                    255
                } else {
                    0
                }
            })
            .collect()
    };
    // An ellipse.
    let ellipse = disc(&|r, c| ((c - 253.0) / 120.0).powi(2) + ((r - 148.0) / 90.0).powi(2) <= 1.0);
    refused("ellipse.png", w, h, &ellipse, "not circular");
    // A disc mostly outside the frame.
    let cut = disc(&|r, c| (c - 560.0).powi(2) + (r - 170.0).powi(2) <= 100.0 * 100.0);
    refused("cut.png", w, h, &cut, "touches the frame");
    // A mask of the wrong size.
    refused("small.png", 10, 10, &[255u8; 100], "small.png");
    // Without a mask the dark chrome sphere cannot be detected: a clear error.
    let imgs: Vec<PathBuf> = (0..12)
        .map(|k| psm(&format!("chrome/chrome.{k}.png")))
        .collect();
    let mut args: Vec<&std::ffi::OsStr> = vec![std::ffi::OsStr::new("calibrate")];
    args.extend(imgs.iter().map(|p| p.as_os_str()));
    let d = tmp.path().join("d");
    args.extend([std::ffi::OsStr::new("-o"), d.as_os_str()]);
    let o = photostereo(&args);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("pass --mask"),
        "{}",
        text(&o.stderr)
    );
    // Bad option values.
    let o = run!(
        "calibrate",
        psm("chrome.txt"),
        "--min-contrast",
        "1.5",
        "-o",
        tmp.path().join("e")
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("--min-contrast"));
}

#[test]
fn tuning_options_take_effect() {
    let tmp = tempfile::tempdir().unwrap();
    // Image 3 dimmed to 8% of its brightness: its highlight (peak ≈ 0.08) is below the default
    // contrast floor of 0.1, found with --min-contrast 0.05.
    let cap = tmp.path().join("cap");
    std::fs::create_dir(&cap).unwrap();
    chrome_without_highlight(&cap);
    let img = photostereo::io::imageio::read_image(&psm("chrome/chrome.2.png")).unwrap();
    let dim: Vec<u8> = img
        .data
        .iter()
        .map(|v| (v * 0.08 * 255.0).round() as u8)
        .collect();
    let p = cap.join("chrome.2.png");
    std::fs::remove_file(&p).unwrap();
    photostereo::io::imageio::write_png8(&p, img.width, img.height, 3, &dim).unwrap();
    let o = run!("calibrate", cap, "-o", tmp.path().join("a"));
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("image(s) 3"),
        "{}",
        text(&o.stderr)
    );
    let out = tmp.path().join("b");
    let o = run!("calibrate", cap, "--min-contrast", "0.05", "-o", out);
    assert!(o.status.success(), "{}", text(&o.stderr));
    // The dimmed highlight gives nearly the undimmed direction.
    let full = tmp.path().join("c");
    assert!(run!("calibrate", psm("chrome.txt"), "-o", full, "-q")
        .status
        .success());
    let (a, b) = (
        read_rows(&out.join("light_directions.txt"))[2].clone(),
        read_rows(&full.join("light_directions.txt"))[2].clone(),
    );
    let d = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
        .min(1.0)
        .acos()
        .to_degrees();
    assert!(d < 0.5, "{d}");
    // Blobs must be larger than any highlight: all are treated as dust.
    let o = run!(
        "calibrate",
        psm("chrome.txt"),
        "--min-blob-pixels",
        "100000",
        "-o",
        tmp.path().join("d")
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("dust"), "{}", text(&o.stderr));
}

/// Runs `calibrate` on `capture` and expects a refusal (exit 2, no output folder) whose message
/// contains each of `words`; returns stderr.
fn refused_capture(capture: &Path, words: &[&str]) -> String {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cal");
    let o = run!("calibrate", capture, "-o", out);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    for w in words {
        assert!(err.contains(w), "{w:?} not in {err}");
    }
    assert!(!out.exists());
    err
}

#[test]
fn a_matte_sphere_is_refused() {
    let err = refused_capture(
        &psm("gray.txt"),
        &[
            "error: no confident highlight",
            "not the highlights of a mirror sphere",
            "in 12 of 12 images the brightest region covers",
            "(a matte sphere?)",
        ],
    );
    println!("{err}");
}

#[test]
fn pure_noise_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    // Uniform 8-bit noise, then Gaussian noise about mid-grey, with the chrome mask.
    for (kind, words) in [
        (0, vec!["no confident highlight"]),
        (1, vec!["no confident highlight", "(noise?)"]),
    ] {
        let cap = tmp.path().join(format!("noise{kind}"));
        std::fs::create_dir(&cap).unwrap();
        let mut state = 0x2545_F491_4F6C_DD1Du64 + kind;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for k in 0..12 {
            let px: Vec<u8> = (0..512 * 340 * 3)
                .map(|_| {
                    let v = if kind == 0 {
                        next()
                    } else {
                        // Sum of 12 uniforms: near-Gaussian, σ 1 → σ 0.1 about 0.5.
                        0.5 + 0.1 * ((0..12).map(|_| next()).sum::<f64>() - 6.0)
                    };
                    (v.clamp(0.0, 1.0) * 255.0).round() as u8
                })
                .collect();
            photostereo::io::imageio::write_png8(&cap.join(format!("n.{k}.png")), 512, 340, 3, &px)
                .unwrap();
        }
        std::os::unix::fs::symlink(psm("chrome/chrome.mask.png"), cap.join("mask.png")).unwrap();
        let err = refused_capture(&cap, &words);
        println!("noise {kind}: {err}");
    }
}

#[test]
fn a_weak_light_is_warned_of() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = tmp.path().join("cap");
    std::fs::create_dir(&cap).unwrap();
    chrome_without_highlight(&cap);
    // Image 3: the brighter of images 3 and 6 at each pixel, two highlights of equal strength.
    let a = photostereo::io::imageio::read_image(&psm("chrome/chrome.2.png")).unwrap();
    let b = photostereo::io::imageio::read_image(&psm("chrome/chrome.5.png")).unwrap();
    let px: Vec<u8> = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (x.max(*y) * 255.0).round() as u8)
        .collect();
    let p = cap.join("chrome.2.png");
    std::fs::remove_file(&p).unwrap();
    photostereo::io::imageio::write_png8(&p, a.width, a.height, 3, &px).unwrap();
    let out = tmp.path().join("cal");
    let o = run!("calibrate", cap, "-o", out);
    let err = text(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("warning: image 3") && err.contains("low confidence"),
        "{err}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("calibration.json")).unwrap())
            .unwrap();
    let low: Vec<&serde_json::Value> = json["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|w| w["kind"] == "low_confidence")
        .collect();
    assert_eq!(low.len(), 1, "{low:?}");
    assert_eq!(low[0]["image"], 2);
    assert!(json["lights"][2]["confidence"].as_f64().unwrap() < 0.25);
    assert_eq!(json["options"]["min_confidence"], 0.25);
    // A lower floor silences it; a floor outside [0, 1] is refused.
    let o = run!(
        "calibrate",
        cap,
        "--min-confidence",
        "0",
        "-o",
        tmp.path().join("b")
    );
    assert!(o.status.success());
    assert!(!text(&o.stderr).contains("low confidence"));
    let o = run!(
        "calibrate",
        cap,
        "--min-confidence",
        "2",
        "-o",
        tmp.path().join("c")
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("--min-confidence"));
}
