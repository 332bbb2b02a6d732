//! `photostereo integrate` and the depth stage of `photostereo run`, end to end.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_photostereo"));
    c.arg("integrate");
    c
}

fn run_cmd() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_photostereo"));
    c.arg("run");
    c
}

const W: usize = 40;
const H: usize = 30;

/// A sphere of radius 12 at (19.5, 14.5), normals zero outside; returns the normals and depth.
fn sphere() -> (Vec<f32>, Vec<f64>) {
    let mut n = vec![0f32; W * H * 3];
    let mut z = vec![f64::NAN; W * H];
    for r in 0..H {
        for c in 0..W {
            let (x, y) = (c as f64 - 19.5, r as f64 - 14.5);
            let d2 = 144.0 - x * x - y * y;
            if d2 > 16.0 {
                let h = d2.sqrt();
                // f = h: ∂f/∂col = −x/h, ∂f/∂row = −y/h → n ∝ (x/h, −y/h, 1).
                let (px, py) = (x / h, -y / h);
                let norm = (px * px + py * py + 1.0).sqrt();
                let i = r * W + c;
                n[3 * i] = (px / norm) as f32;
                n[3 * i + 1] = (py / norm) as f32;
                n[3 * i + 2] = (1.0 / norm) as f32;
                z[i] = h;
            }
        }
    }
    (n, z)
}

fn write_normals(dir: &Path) -> PathBuf {
    let (n, _) = sphere();
    let path = dir.join("normals.npy");
    let arr = ndarray::Array3::from_shape_vec((H, W, 3), n).unwrap();
    ndarray_npy::write_npy(&path, &arr).unwrap();
    path
}

fn read_depth(dir: &Path) -> Vec<f32> {
    let a: ndarray::Array2<f32> = ndarray_npy::read_npy(dir.join("depth.npy")).unwrap();
    assert_eq!(a.dim(), (H, W));
    a.iter().copied().collect()
}

#[test]
fn integrate_writes_depth_meshes_and_curl_for_every_method() {
    let tmp = tempfile::tempdir().unwrap();
    let normals = write_normals(tmp.path());
    let (_, truth) = sphere();
    for method in ["bilateral", "poisson", "dct", "fft", "paths"] {
        let out = tmp.path().join(format!("out-{method}"));
        let st = bin()
            .args([
                normals.to_str().unwrap(),
                "--method",
                method,
                "-o",
                out.to_str().unwrap(),
                "--quiet",
            ])
            .status()
            .unwrap();
        assert!(st.success(), "{method}");
        for f in [
            "depth.npy",
            "depth.exr",
            "depth.png",
            "mesh.ply",
            "mesh.obj",
            "curl.npy",
            "report.json",
        ] {
            assert!(out.join(f).is_file(), "{method}: {f} missing");
        }
        let d = read_depth(&out);
        let inside: Vec<usize> = (0..W * H).filter(|&i| truth[i].is_finite()).collect();
        assert!(
            (0..W * H).all(|i| d[i].is_finite() == truth[i].is_finite()),
            "{method}: NaN pattern"
        );
        assert_eq!(
            out.join("discontinuities.npy").is_file(),
            method == "bilateral",
            "{method}: discontinuities.npy"
        );
        if method == "poisson" || method == "paths" || method == "bilateral" {
            let off: f64 =
                inside.iter().map(|&i| d[i] as f64 - truth[i]).sum::<f64>() / inside.len() as f64;
            let max = inside
                .iter()
                .map(|&i| (d[i] as f64 - truth[i] - off).abs())
                .fold(0f64, f64::max);
            assert!(max < 0.2, "{method}: max depth error {max}");
        }
    }
}

#[test]
fn the_ply_mesh_has_one_vertex_per_pixel_and_counter_clockwise_triangles() {
    let tmp = tempfile::tempdir().unwrap();
    let normals = write_normals(tmp.path());
    let out = tmp.path().join("out");
    assert!(bin()
        .args([
            normals.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--quiet"
        ])
        .status()
        .unwrap()
        .success());
    let d = read_depth(&out);
    let valid = |r: usize, c: usize| d[r * W + c].is_finite();
    let vertices = (0..W * H).filter(|&i| d[i].is_finite()).count();
    let mut faces = 0;
    for r in 0..H - 1 {
        for c in 0..W - 1 {
            let k = [
                valid(r, c),
                valid(r, c + 1),
                valid(r + 1, c),
                valid(r + 1, c + 1),
            ]
            .iter()
            .filter(|&&v| v)
            .count();
            faces += match k {
                4 => 2,
                3 => 1,
                _ => 0,
            };
        }
    }
    let bytes = std::fs::read(out.join("mesh.ply")).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.contains("format binary_little_endian 1.0"));
    assert!(
        header.contains(&format!("element vertex {vertices}\n")),
        "{header}"
    );
    assert!(
        header.contains(&format!("element face {faces}\n")),
        "{header}"
    );
    assert!(header.contains("property float nx"));
    assert_eq!(bytes.len(), end + vertices * 24 + faces * 13);
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    // Vertices in scan order: x = col, y = −row, z = depth.
    let first = (0..W * H).find(|&i| d[i].is_finite()).unwrap();
    assert_eq!(f32_at(end), (first % W) as f32);
    assert_eq!(f32_at(end + 4), -((first / W) as f32));
    assert_eq!(f32_at(end + 8), d[first]);
    // Every triangle faces the camera: (b − a) × (c − a) has z > 0 in (x, y) = (col, −row).
    let verts: Vec<[f32; 3]> = (0..vertices)
        .map(|k| [f32_at(end + 24 * k), f32_at(end + 24 * k + 4), 0.0])
        .collect();
    let fo = end + vertices * 24;
    for t in 0..faces {
        let o = fo + 13 * t;
        assert_eq!(bytes[o], 3);
        let idx: Vec<usize> = (0..3)
            .map(|k| {
                i32::from_le_bytes(bytes[o + 1 + 4 * k..o + 5 + 4 * k].try_into().unwrap()) as usize
            })
            .collect();
        let (a, b, c) = (verts[idx[0]], verts[idx[1]], verts[idx[2]]);
        let z = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        assert!(z > 0.0, "triangle {t} is clockwise");
    }
    let obj = std::fs::read_to_string(out.join("mesh.obj")).unwrap();
    assert_eq!(
        obj.lines().filter(|l| l.starts_with("v ")).count(),
        vertices
    );
    assert_eq!(
        obj.lines().filter(|l| l.starts_with("vn ")).count(),
        vertices
    );
    assert_eq!(obj.lines().filter(|l| l.starts_with("f ")).count(), faces);
    // depth.png spans 0..65535 over the object.
    let png = photostereo::io::imageio::read_image(&out.join("depth.png")).unwrap();
    assert_eq!((png.bit_depth, png.channels), (16, 1));
    let max = png.data.iter().fold(0f32, |m, &v| m.max(v));
    assert_eq!(max, 1.0);
}

#[test]
fn integrate_flags_and_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let normals = write_normals(tmp.path());
    let n = normals.to_str().unwrap();
    // --no-mesh, --max-slope, --tolerance, --json.
    let out = tmp.path().join("a");
    let o = bin()
        .args([
            n,
            "--no-mesh",
            "--max-slope",
            "1.5",
            "--tolerance",
            "1e-9",
            "--json",
            "-o",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!out.join("mesh.ply").exists() && !out.join("mesh.obj").exists());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["parameters"]["max_slope"], 1.5);
    assert!(v["integration"]["capped_pixels"].as_u64().unwrap() > 0);
    assert!(v["integration"]["relative_residual"].as_f64().unwrap() <= 1e-9);
    // An existing output is refused without --force.
    let o = bin()
        .args([n, "-o", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    // A mask of the wrong size.
    let mask = tmp.path().join("mask.png");
    photostereo::io::imageio::write_png8(&mask, 10, 10, 1, &[255u8; 100]).unwrap();
    let o = bin()
        .args([
            n,
            "--mask",
            mask.to_str().unwrap(),
            "-o",
            tmp.path().join("b").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("mask is 10×10"));
    // An unknown method.
    let o = bin()
        .args([
            n,
            "--method",
            "magic",
            "-o",
            tmp.path().join("c").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("poisson"));
    // A mask restricting the region: only its pixels get depth.
    let mut m = vec![0u8; W * H];
    for r in 5..25 {
        for c in 10..30 {
            m[r * W + c] = 255;
        }
    }
    photostereo::io::imageio::write_png8(&mask, W, H, 1, &m).unwrap();
    let out = tmp.path().join("d");
    assert!(bin()
        .args([
            n,
            "--mask",
            mask.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "-q"
        ])
        .status()
        .unwrap()
        .success());
    let d = read_depth(&out);
    let (_, truth) = sphere();
    for i in 0..W * H {
        assert_eq!(
            d[i].is_finite(),
            m[i] > 0 && truth[i].is_finite(),
            "pixel {i}"
        );
    }
}

#[test]
fn run_integrates_by_default_and_no_depth_skips_it() {
    let ball = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/diligent/ballPNG"
    );
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ball");
    let o = run_cmd()
        .args([ball, "-o", out.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in [
        "depth.npy",
        "depth.exr",
        "depth.png",
        "mesh.ply",
        "mesh.obj",
        "curl.npy",
        "discontinuities.npy",
        "discontinuities.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["timings_s"]["integrate"].as_f64().is_some());
    assert_eq!(v["integration"]["method"], "bilateral");
    assert_eq!(v["parameters"]["integration"]["method"], "bilateral");
    // Parameters as given, not as their f32 storage prints in f64.
    assert_eq!(v["parameters"]["integration"]["unreliable_weight"], 0.1);
    let out2 = tmp.path().join("ball2");
    let o = run_cmd()
        .args([ball, "-o", out2.to_str().unwrap(), "--no-depth", "--quiet"])
        .output()
        .unwrap();
    assert!(o.status.success());
    assert!(
        out2.join("normals.npy").is_file()
            && !out2.join("depth.npy").exists()
            && !out2.join("mesh.ply").exists()
    );
    let out3 = tmp.path().join("ball3");
    let o = run_cmd()
        .args([
            ball,
            "-o",
            out3.to_str().unwrap(),
            "--integrator",
            "paths",
            "--json",
        ])
        .output()
        .unwrap();
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["integration"]["method"], "paths");
}

#[test]
fn a_white_background_without_mask_is_left_out_with_a_note() {
    // A flat rectangle of unit normals on a white background decoded as (1, 1, 1) (most of the
    // map), given without a mask.
    let tmp = tempfile::tempdir().unwrap();
    let mut n = vec![1f32; W * H * 3];
    let inside = |r: usize, c: usize| (5..25).contains(&r) && (5..35).contains(&c);
    for r in 0..H {
        for c in 0..W {
            if inside(r, c) {
                let i = r * W + c;
                n[3 * i..3 * i + 3].copy_from_slice(&[0.0, 0.0, 1.0]);
            }
        }
    }
    let path = tmp.path().join("white.npy");
    let arr = ndarray::Array3::from_shape_vec((H, W, 3), n).unwrap();
    ndarray_npy::write_npy(&path, &arr).unwrap();
    let out = tmp.path().join("out");
    let o = bin()
        .args([path.to_str().unwrap(), "-o", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    let background = W * H - 20 * 30;
    assert!(
        err.contains(&format!(
            "{background} pixel(s) whose vector is not of unit length"
        )),
        "{err}"
    );
    let d = read_depth(&out);
    for r in 0..H {
        for c in 0..W {
            assert_eq!(d[r * W + c].is_finite(), inside(r, c), "({r}, {c})");
        }
    }
    let jumps: ndarray::Array2<f32> =
        ndarray_npy::read_npy(out.join("discontinuities.npy")).unwrap();
    assert!(jumps.iter().all(|v| v.is_nan() || (0.0..=1.0).contains(v)));
    assert!(out.join("discontinuities.png").is_file());
}
