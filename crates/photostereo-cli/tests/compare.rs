//! The paper's real-data evaluation end to end: the highlight / shadow indicator of
//! `report.json` recomputed independently from `light_status.npy` and the image files, and
//! `photostereo compare` against four separate `run`s.

use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_photostereo");

fn photostereo(args: &[&str]) -> serde_json::Value {
    let out = Command::new(BIN).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "{:?}: {}",
        args,
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Decodes a PNG into (width, height, channels, values / full scale).
fn read_png(path: &Path) -> (usize, usize, usize, Vec<f64>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let channels = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::Rgb => 3,
        other => panic!("{other:?}"),
    };
    let (w, h) = (info.width as usize, info.height as usize);
    let values = match info.bit_depth {
        png::BitDepth::Eight => buf[..w * h * channels]
            .iter()
            .map(|&v| v as f64 / 255.0)
            .collect(),
        png::BitDepth::Sixteen => buf[..w * h * channels * 2]
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]) as f64 / 65535.0)
            .collect(),
        other => panic!("{other:?}"),
    };
    (w, h, channels, values)
}

/// The mean raw image value per channel over the pairs with status `which`, from the files.
fn recompute(images: &[PathBuf], status: &ndarray::Array3<u8>, which: u8) -> (u64, Vec<f64>) {
    let (n, h, w) = status.dim();
    assert_eq!(images.len(), n);
    let mut sums = vec![0f64; 3];
    let mut pairs = 0u64;
    let mut channels = 0;
    for (k, path) in images.iter().enumerate() {
        let (iw, ih, c, v) = read_png(path);
        assert_eq!((iw, ih), (w, h));
        channels = c;
        for r in 0..h {
            for col in 0..w {
                if status[[k, r, col]] == which {
                    pairs += 1;
                    for ch in 0..c {
                        sums[ch] += v[(r * w + col) * c + ch];
                    }
                }
            }
        }
    }
    sums.truncate(channels);
    (
        pairs,
        sums.iter().map(|v| v / pairs.max(1) as f64).collect(),
    )
}

fn check_indicator(report: &serde_json::Value, out: &Path, images: &[PathBuf], what: &str) {
    let status: ndarray::Array3<u8> = ndarray_npy::read_npy(out.join("light_status.npy")).unwrap();
    for (key, which) in [("highlights", 2u8), ("shadows", 1)] {
        let (pairs, means) = recompute(images, &status, which);
        let r = &report[key];
        assert_eq!(r["pairs"].as_u64().unwrap(), pairs, "{what} {key}");
        if pairs == 0 {
            assert!(r["mean_intensity"].is_null(), "{what} {key}");
            continue;
        }
        let got: Vec<f64> = r["mean_intensity"]["channels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(got.len(), means.len());
        for (g, m) in got.iter().zip(&means) {
            assert!((g - m).abs() < 1e-6, "{what} {key}: {g} vs {m}");
        }
        let grey = means.iter().sum::<f64>() / means.len() as f64;
        let g = r["mean_intensity"]["grey"].as_f64().unwrap();
        assert!((g - grey).abs() < 1e-6, "{what} {key} grey: {g} vs {grey}");
        let g255 = r["mean_intensity_255"]["grey"].as_f64().unwrap();
        assert!((g255 - 255.0 * grey).abs() < 255e-6, "{what} {key} 255");
    }
}

/// A small synthetic capture with coloured, unequal light intensities (so raw and
/// intensity-normalised values differ) and ground truth.
fn synth(dir: &Path) -> PathBuf {
    let cap = dir.join("capture");
    photostereo(&[
        "synth",
        "blocks",
        "--rig",
        "ring8",
        "--size",
        "48",
        "--intensities",
        "coloured",
        "-o",
        s(&cap),
        "--json",
    ]);
    cap
}

fn listed_images(cap: &Path) -> Vec<PathBuf> {
    std::fs::read_to_string(cap.join("filenames.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| cap.join(l.trim()))
        .collect()
}

#[test]
fn highlight_and_shadow_intensities_match_a_recomputation_from_the_files() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = synth(tmp.path());
    let images = listed_images(&cap);
    let intens = std::fs::read_to_string(cap.join("light_intensities.txt")).unwrap();
    assert!(
        intens.lines().any(|l| !l.trim().starts_with("1 1 1")),
        "the test needs unequal intensities: {intens}"
    );
    let mut classified = 0;
    for method in ["l2", "coleman-jain", "barsky-petrou", "recursive"] {
        let out = tmp.path().join(method);
        let v = photostereo(&["run", s(&cap), "--method", method, "-o", s(&out), "--json"]);
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        assert_eq!(report["highlights"], v["highlights"]);
        check_indicator(&report, &out, &images, method);
        classified += report["highlights"]["pairs"].as_u64().unwrap();
        if method == "l2" {
            assert_eq!(report["highlights"]["pairs"], 0);
            assert!(report["highlights"]["mean_intensity"].is_null());
        }
    }
    assert!(classified > 0, "some method must classify highlights");
}

#[test]
fn indicator_on_an_8_bit_list_capture_matches_the_files() {
    let data = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data"));
    let list = data.join("psmImages/gray.txt");
    if !list.exists() {
        eprintln!("skipped: {} not found", list.display());
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("gray");
    photostereo(&[
        "run",
        s(&list),
        "--lights",
        s(&data.join("psmImages/lights.reference.txt")),
        "--no-depth",
        "--method",
        "barsky-petrou",
        "-o",
        s(&out),
        "--json",
    ]);
    let text = std::fs::read_to_string(&list).unwrap();
    let lines: Vec<&str> = text.lines().map(str::trim).collect();
    let n: usize = lines[0].parse().unwrap();
    let images: Vec<PathBuf> = lines[1..=n].iter().map(|l| data.join(l)).collect();
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert!(report["highlights"]["pairs"].as_u64().unwrap() > 0);
    check_indicator(&report, &out, &images, "psm gray");
}

#[test]
fn compare_rows_equal_four_separate_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = synth(tmp.path());
    let gt = cap.join("gt/normal.npy");
    let out = tmp.path().join("cmp");
    let v = photostereo(&["compare", s(&cap), "--gt", s(&gt), "-o", s(&out), "--json"]);
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("compare.json")).unwrap()).unwrap();
    assert!(out.join("compare.png").exists());
    let methods = ["l2", "coleman-jain", "barsky-petrou", "recursive"];
    let rows = file["methods"].as_array().unwrap();
    assert_eq!(rows.len(), 4);
    for (i, method) in methods.iter().enumerate() {
        let run_out = tmp.path().join(format!("run-{method}"));
        let r = photostereo(&[
            "run",
            s(&cap),
            "--method",
            method,
            "--gt",
            s(&gt),
            "-o",
            s(&run_out),
            "--json",
        ]);
        assert_eq!(rows[i]["method"], *method);
        // Table 1: the mean angular error, and every other error figure, equal the run's.
        assert_eq!(rows[i]["error"], r["error"], "{method}");
        assert_eq!(
            file["table1_mean_angular_error_deg"][method], r["error"]["mean_deg"],
            "{method}"
        );
        // Table 2: the highlight indicator equals the run's report.
        assert_eq!(rows[i]["highlights"]["pairs"], r["highlights"]["pairs"]);
        assert_eq!(
            file["table2_mean_highlight_intensity_255"][method],
            r["highlights"]["mean_intensity_255"]["grey"],
            "{method}"
        );
    }
    assert_eq!(
        v["table1_mean_angular_error_deg"],
        file["table1_mean_angular_error_deg"]
    );
    // Written atomically: a second compare into the same folder is refused without --force.
    let again = Command::new(BIN)
        .args(["compare", s(&cap), "-o", s(&out)])
        .output()
        .unwrap();
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("already exists"));
}

#[test]
fn compare_accepts_explicit_images_and_saves_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = synth(tmp.path());
    let images = listed_images(&cap);
    let out = tmp.path().join("cmp");
    let mut args: Vec<String> = vec!["compare".into()];
    args.extend(images.iter().map(|p| s(p).to_string()));
    for a in [
        "--lights",
        s(&cap.join("light_directions.txt")),
        "--intensities",
        s(&cap.join("light_intensities.txt")),
        "--mask",
        s(&cap.join("mask.png")),
        "--methods",
        "l2,recursive",
        "--light",
        "3",
        "--save-runs",
        "-o",
        s(&out),
        "--json",
    ] {
        args.push(a.to_string());
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let v = photostereo(&args);
    assert_eq!(v["methods"].as_array().unwrap().len(), 2);
    assert_eq!(v["figure_light"]["index"], 3);
    assert!(v["table1_mean_angular_error_deg"]["l2"].is_null());
    for m in ["l2", "recursive"] {
        assert!(out.join(m).join("report.json").exists(), "{m}");
        assert!(out.join(m).join("normals.npy").exists(), "{m}");
    }
    let bad = Command::new(BIN)
        .args(["compare", s(&cap), "--light", "9", "-o"])
        .arg(tmp.path().join("bad"))
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--light 9"));
}
