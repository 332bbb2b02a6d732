//! `run` and `eval` on the shared real captures (../shared/data), checked against public ground
//! truth and the published least-squares figures.

use std::path::PathBuf;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_photostereo");

fn data(rel: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data")).join(rel)
}

fn run_json(args: &[&std::ffi::OsStr]) -> serde_json::Value {
    let out = Command::new(BIN).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn diligent_least_squares_matches_reference_figures() {
    let tmp = tempfile::tempdir().unwrap();
    // Least squares on the channel mean of the intensity-normalised images over the full mask.
    for (object, expected) in [("ball", 4.29), ("cat", 8.45), ("bear", 8.94)] {
        let dir = data(&format!("diligent/{object}PNG"));
        let out = tmp.path().join(object);
        let v = run_json(&[
            "run".as_ref(),
            dir.as_os_str(),
            "--method".as_ref(),
            "l2".as_ref(),
            // The benchmark's plain least squares: every mask pixel from its own readings.
            "--no-occluding-contour".as_ref(),
            "--gt".as_ref(),
            dir.join("Normal_gt.mat").as_os_str(),
            "--error-map".as_ref(),
            "-o".as_ref(),
            out.as_os_str(),
            "--json".as_ref(),
        ]);
        let mean = v["error"]["mean_deg"].as_f64().unwrap();
        assert!(
            (mean - expected).abs() < 0.1,
            "{object}: {mean} vs {expected}"
        );
        // Output contract.
        let normals: ndarray::Array3<f32> = ndarray_npy::read_npy(out.join("normals.npy")).unwrap();
        assert_eq!(normals.dim(), (512, 612, 3));
        let png = std::fs::read(out.join("normals.png")).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(png))
            .read_info()
            .unwrap();
        assert_eq!(dec.info().bit_depth, png::BitDepth::Sixteen);
        assert_eq!(dec.info().color_type, png::ColorType::Rgb);
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        assert_eq!(report["input"]["lights"], 96);
        assert!(report["timings_s"]["load"].as_f64().unwrap() > 0.0);
        assert!(
            out.join("error_map.png").exists()
                && out.join("albedo.npy").exists()
                && out.join("normals.exr").exists()
        );
        // eval on the written normals reproduces the figure.
        let e = run_json(&[
            "eval".as_ref(),
            out.join("normals.npy").as_os_str(),
            dir.join("Normal_gt.mat").as_os_str(),
            "--mask".as_ref(),
            dir.join("mask.png").as_os_str(),
            "--json".as_ref(),
        ]);
        assert!((e["mean_deg"].as_f64().unwrap() - mean).abs() < 1e-3);
        // The 16-bit PNG normal map is a faithful ground-truth format too.
        let e2 = run_json(&[
            "eval".as_ref(),
            out.join("normals.png").as_os_str(),
            dir.join("Normal_gt.mat").as_os_str(),
            "--json".as_ref(),
        ]);
        assert!((e2["mean_deg"].as_f64().unwrap() - mean).abs() < 0.01);
    }
}

/// The recursive method (the default of `run`) on the three DiLiGenT objects: the issue's
/// bounds, below the robust-PCA figures of a popular Python package (3.11° / 7.75° / 7.65°),
/// and the output folder's recursive maps.
#[test]
fn diligent_recursive_beats_the_bounds() {
    let tmp = tempfile::tempdir().unwrap();
    for (object, bound) in [("ball", 2.5), ("cat", 7.0), ("bear", 6.5)] {
        let dir = data(&format!("diligent/{object}PNG"));
        let out = tmp.path().join(object);
        let v = run_json(&[
            "run".as_ref(),
            dir.as_os_str(),
            "--gt".as_ref(),
            dir.join("Normal_gt.mat").as_os_str(),
            "-o".as_ref(),
            out.as_os_str(),
            "--json".as_ref(),
        ]);
        assert_eq!(v["method"], "recursive");
        let mean = v["error"]["mean_deg"].as_f64().unwrap();
        assert!(mean <= bound, "{object}: {mean} > {bound}");
        // Shadow labels mean shadow: few of them read lit.
        let lit = v["detection"]["shadow_labels"]["lit"].as_f64().unwrap();
        assert!(lit < 0.2, "{object}: {lit} of the shadow pairs read lit");
        // Per-light model error: κ_k for every light, never below the capture's κ.
        // Bear's first 20 images are the ones the benchmark's users drop (they disagree with
        // the rest): the lights singled out there, and at most a few beyond them.
        let kappa = v["detection"]["noise"]["kappa"].as_f64().unwrap();
        let light_kappa: Vec<f64> = v["detection"]["light_kappa"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        assert_eq!(light_kappa.len(), 96, "{object}");
        assert!(light_kappa.iter().all(|&k| k >= kappa - 1e-12), "{object}");
        if object == "bear" {
            let raised = |r: std::ops::Range<usize>| {
                light_kappa[r].iter().filter(|&&k| k > 1.5 * kappa).count()
            };
            assert!(raised(0..20) >= 10, "bear: {light_kappa:?}");
            assert!(raised(20..96) <= 3, "bear: {light_kappa:?}");
        }
        // The recursion settles within its default limit and says so.
        assert_eq!(
            v["recursive"]["converged"], true,
            "{object}: {}",
            v["recursive"]["stop_reason"]
        );
        assert!(!v["recursive"]["stop_reason"].as_str().unwrap().is_empty());
        let iterations = v["recursive"]["iterations"].as_array().unwrap();
        assert!(!iterations.is_empty() && iterations[0]["mean_error_deg"].as_f64().is_some());
        let status: ndarray::Array3<u8> =
            ndarray_npy::read_npy(out.join("light_status.npy")).unwrap();
        assert_eq!(status.dim(), (96, 512, 612));
        // Some lights are dropped, outside pixels are 255.
        assert!(status.iter().any(|&s| s == 1) && status[[0, 0, 0]] == 255);
        let depth: ndarray::Array2<f32> = ndarray_npy::read_npy(out.join("depth.npy")).unwrap();
        assert_eq!(depth.dim(), (512, 612));
        for f in [
            "shadows.png",
            "highlight.png",
            "fewer_than_three.png",
            "residual.npy",
            "unreliable_mask.png",
            "mesh.ply",
        ] {
            assert!(out.join(f).exists(), "{object}: {f} missing");
        }
    }
}

#[test]
fn psm_list_layout_loads_and_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("buddha");
    let v = run_json(&[
        "run".as_ref(),
        data("psmImages/buddha.txt").as_os_str(),
        "--lights".as_ref(),
        data("psmImages/lights.reference.txt").as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
        "--json".as_ref(),
    ]);
    assert_eq!(v["input"]["lights"], 12);
    assert_eq!(v["input"]["width"], 512);
    assert_eq!(v["input"]["height"], 340);
    assert_eq!(v["input"]["bit_depth"], 8);
    assert!(v["notes"]
        .as_array()
        .unwrap()
        .iter()
        .any(|n| n.as_str().unwrap().contains("resolved relative")));
    // A matte object seen from the front: nearly every mask pixel faces the camera.
    let normals: ndarray::Array3<f32> = ndarray_npy::read_npy(out.join("normals.npy")).unwrap();
    let mut inside = 0;
    let mut facing = 0;
    for n in normals.outer_iter().flat_map(|row| {
        row.outer_iter()
            .map(|v| [v[0], v[1], v[2]])
            .collect::<Vec<_>>()
    }) {
        if n != [0.0; 3] {
            inside += 1;
            facing += usize::from(n[2] > 0.0);
        }
    }
    assert!(inside > 20_000, "{inside}");
    assert!(facing as f64 > 0.97 * inside as f64, "{facing}/{inside}");
}
