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
        // The linear bases' ridge weight, chosen among candidates that include none.
        if basis == "rbf" {
            assert!(r["ridge"].is_null());
        } else {
            let ridge = &r["ridge"];
            assert!(ridge["lambda"].as_f64().unwrap() >= 0.0, "{basis}");
            assert_eq!(ridge["candidates"][0]["lambda"].as_f64(), Some(0.0));
            // HSH also tries the grid's λ > 0 toward PTM's fit; PTM has only toward zero.
            let toward_ptm = ridge["candidates_toward_ptm"].as_array().unwrap();
            let hsh = basis.starts_with("hsh");
            assert_eq!(toward_ptm.len(), if hsh { 17 } else { 0 }, "{basis}");
            let toward = ridge["toward"].as_str().unwrap();
            assert!(
                toward == "zero" || (hsh && toward == "ptm"),
                "{basis}: {toward}"
            );
            assert_eq!(ridge["ptm_lambda"].is_null(), toward == "zero");
        }
        loo.push(m);
    }
    // --ridge 0: the unregularised fit.
    let o = photostereo(
        &[
            "rti", "cap", "--basis", "hsh3", "--ridge", "0", "-o", "plain", "--quiet",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let ridge = &report(&dir.join("plain/report.json"))["ridge"];
    assert_eq!(ridge["lambda"].as_f64(), Some(0.0));
    assert_eq!(ridge["candidates"].as_array().map(Vec::len), Some(0));
    // Nine terms per channel follow a glossy sphere better than four.
    assert!(loo[3] < loo[2], "hsh3 {} vs hsh2 {}", loo[3], loo[2]);
    // The viewer needs a run's normals: an rti folder is refused with the way to get them,
    // and nothing is written into it.
    let before = std::fs::read_dir(dir.join("out-hsh3")).unwrap().count();
    let o = photostereo(&["view", "out-hsh3"], dir);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("out-hsh3") && e.contains("photostereo rti") && e.contains("--rti"),
        "{e}"
    );
    assert_eq!(
        std::fs::read_dir(dir.join("out-hsh3")).unwrap().count(),
        before
    );
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
    // The options are refused before any image is read: a damaged image is not what is named.
    std::fs::create_dir(dir.join("damaged")).unwrap();
    for entry in std::fs::read_dir(dir.join("four")).unwrap() {
        let p = entry.unwrap().path();
        if p.is_file() {
            std::fs::copy(&p, dir.join("damaged").join(p.file_name().unwrap())).unwrap();
        }
    }
    std::fs::write(dir.join("damaged/001.png"), b"not a png").unwrap();
    let args = [
        "rti",
        "damaged",
        "--basis",
        "rbf",
        "--exclude-unreliable",
        "-o",
        "w",
    ];
    let o = photostereo(&args, dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("--exclude-unreliable") && !stderr(&o).contains("001.png"),
        "{}",
        stderr(&o)
    );
    assert!(!dir.join("w").exists());
    // RBF has no ridge weight, and a weight is a number ≥ 0.
    for (basis, weight) in [("rbf", "0.1"), ("hsh3", "-1"), ("hsh3", "some")] {
        let o = photostereo(
            &[
                "rti", "four", "--basis", basis, "--ridge", weight, "-o", "r",
            ],
            dir,
        );
        assert_eq!(o.status.code(), Some(2), "{basis} {weight}");
        assert!(stderr(&o).contains("--ridge"), "{}", stderr(&o));
        assert!(!dir.join("r").exists());
    }
    // A budget too small for the coefficients names --memory-limit.
    synth(dir, "dome-30", "cap");
    let o = photostereo(&["rti", "cap", "--memory-limit", "20K", "-o", "w"], dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--memory-limit"), "{}", stderr(&o));
    assert!(!dir.join("w").exists());
    // The smallest budget it names works, and the process's peak stays within it, for the
    // least-squares reference and for the recursive one.
    for extra in [None, Some("--exclude-unreliable")] {
        let mut args = vec!["rti", "cap", "--memory-limit", "20K", "-o", "w"];
        args.extend(extra);
        let e = stderr(&photostereo(&args, dir));
        let minimum = e
            .rsplit("smallest budget that works is ")
            .next()
            .unwrap()
            .trim();
        args[3] = minimum;
        args.push("--quiet");
        let o = photostereo(&args, dir);
        assert!(o.status.success(), "{extra:?} at {minimum}: {}", stderr(&o));
        let m = &report(&dir.join("w/report.json"))["memory"];
        let (peak, budget) = (
            m["peak_rss"].as_u64().unwrap(),
            m["budget"].as_u64().unwrap(),
        );
        assert!(
            peak > 0 && peak <= budget,
            "{extra:?}: peak {peak} of {budget}"
        );
        std::fs::remove_dir_all(dir.join("w")).unwrap();
    }
}

/// The width and height of a baseline or progressive JPEG, from its start-of-frame segment
/// (ITU-T T.81, B.2.2: after the marker, length (2), precision (1), lines (2), samples per line
/// (2)).
fn jpeg_size(path: &Path) -> (usize, usize) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&b[..2], &[0xFF, 0xD8], "{}: not a JPEG", path.display());
    let mut i = 2;
    while i + 9 < b.len() {
        assert_eq!(b[i], 0xFF, "{}: marker expected at {i}", path.display());
        let m = b[i + 1];
        let len = usize::from(b[i + 2]) << 8 | usize::from(b[i + 3]);
        if (0xC0..=0xC2).contains(&m) {
            let h = usize::from(b[i + 5]) << 8 | usize::from(b[i + 6]);
            let w = usize::from(b[i + 7]) << 8 | usize::from(b[i + 8]);
            return (w, h);
        }
        i += 2 + len;
    }
    panic!("{}: no start-of-frame segment", path.display());
}

/// `rti --iiif BASE`: every plane image of relight's web folder as IIIF Image API 3.0 level-0
/// static tiles. `info.json` must hold the fields the specification requires of a level-0
/// service (`@context`, `id`, `type` ImageService3, `protocol`, `profile` level0, `width`,
/// `height`) with the tiles and sizes it lists, and each tile must be where a client asks for
/// it (`{region}/{size}/0/default.jpg`, §4) at the size the specification gives: at scale
/// factor s, the region of tile (col, row) is x = col·512·s, w = min(512·s, W − x) (y and h
/// alike), delivered at ⌈w / s⌉ × ⌈h / s⌉ (§5.6: a tile's size is the region's divided by s,
/// rounded up).
#[test]
fn iiif_level0_tiles_follow_the_image_api() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let o = photostereo(
        &[
            "synth", "sphere", "--rig", "dome-12", "--size", "700x560", "-o", "cap", "--quiet",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let o = photostereo(
        &[
            "rti",
            "cap",
            "--basis",
            "hsh2",
            "--iiif",
            "https://example.org/iiif/sphere/",
            "-o",
            "out",
            "--quiet",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let web = dir.join("out/relight");
    let nplanes = report(&web.join("info.json"))["nplanes"].as_u64().unwrap() as usize;
    assert_eq!(nplanes, 12);
    for g in 0..nplanes.div_ceil(3) {
        let root = web.join(format!("plane_{g}"));
        let info = report(&root.join("info.json"));
        assert_eq!(info["@context"], "http://iiif.io/api/image/3/context.json");
        assert_eq!(
            info["id"],
            format!("https://example.org/iiif/sphere/relight/plane_{g}")
        );
        assert_eq!(info["type"], "ImageService3");
        assert_eq!(info["protocol"], "http://iiif.io/api/image");
        assert_eq!(info["profile"], "level0");
        let (w, h) = (700usize, 560usize);
        assert_eq!(info["width"], w);
        assert_eq!(info["height"], h);
        let tiles = info["tiles"].as_array().unwrap();
        assert_eq!(tiles.len(), 1);
        let t = tiles[0]["width"].as_u64().unwrap() as usize;
        assert_eq!(tiles[0]["height"].as_u64(), Some(t as u64));
        let scales: Vec<usize> = tiles[0]["scaleFactors"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as usize)
            .collect();
        // 700 × 560 in tiles of 512: scale 1 (2 × 2 tiles) and 2 (one tile, 350 × 280).
        assert_eq!((t, scales.as_slice()), (512, &[1usize, 2][..]));
        let mut n = 0;
        for &s in &scales {
            let span = t * s;
            for y in (0..h).step_by(span) {
                for x in (0..w).step_by(span) {
                    let (rw, rh) = (span.min(w - x), span.min(h - y));
                    let (tw, th) = (rw.div_ceil(s), rh.div_ceil(s));
                    let p = root.join(format!("{x},{y},{rw},{rh}/{tw},{th}/0/default.jpg"));
                    assert_eq!(jpeg_size(&p), (tw, th), "{}", p.display());
                    n += 1;
                }
            }
        }
        assert_eq!(n, 4 + 1);
        // `sizes`: each level's whole image, listed smallest first, at full/W,H/.
        let sizes: Vec<(u64, u64)> = info["sizes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| (v["width"].as_u64().unwrap(), v["height"].as_u64().unwrap()))
            .collect();
        assert_eq!(sizes, vec![(350, 280), (700, 560)]);
        for (sw, sh) in sizes {
            let p = root.join(format!("full/{sw},{sh}/0/default.jpg"));
            assert_eq!(jpeg_size(&p), (sw as usize, sh as usize));
        }
    }
    // A base that is not a URI is refused, naming the flag, and leaves nothing.
    let o = photostereo(
        &[
            "rti", "cap", "--basis", "hsh2", "--iiif", "tiles", "-o", "bad", "--quiet",
        ],
        dir,
    );
    assert!(!o.status.success());
    assert!(stderr(&o).contains("iiif"), "{}", stderr(&o));
    assert!(!dir.join("bad").exists());
}

/// `run --rti BASIS`: the RTI files beside the normals and the fit's leave-one-out figure in
/// report.json's `rti`, the same figure `rti` gives for the same capture and basis.
#[test]
fn run_rti_writes_the_fit_beside_the_normals() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    synth(dir, "dome-30", "cap");
    let o = photostereo(
        &["run", "cap", "--rti", "hsh3", "-o", "run", "--quiet"],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    for f in [
        "normals.npy",
        "image.rti",
        "coefficients.npy",
        "rti.json",
        "relight/info.json",
    ] {
        assert!(dir.join("run").join(f).is_file(), "{f}");
    }
    let r = report(&dir.join("run/report.json"));
    let loo = r["rti"]["leave_one_out"]["mean_rmse_8bit"]
        .as_f64()
        .unwrap();
    let o = photostereo(
        &["rti", "cap", "--basis", "hsh3", "-o", "alone", "--quiet"],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let alone = report(&dir.join("alone/report.json"))["leave_one_out"]["mean_rmse_8bit"]
        .as_f64()
        .unwrap();
    assert!(
        loo > 0.0 && (loo - alone).abs() <= 1e-9 * alone,
        "{loo} vs {alone}"
    );
    assert_eq!(r["rti"]["basis"], "hsh3");
    assert!(r["rti"]["lambertian_reference"]["errors"]["mean_rmse_8bit"]
        .as_f64()
        .is_some());
}
