//! The figures of the real captures in `../shared/data`: per capture and method the
//! mean error against ground truth (DiLiGenT), the roughness (psmImages) and the `gray`
//! sphere's error against the sphere fitted to its outline, the noise model, the unreliable
//! share, what the shadow labels mean, and the recursion's convergence.
//!
//! `cargo run --release -p photostereo --example real_figures [-- OBJECT... [--method M]...]`
//! with objects among ball bear cat buddha cat-psm gray horse owl rock (default: all) and
//! methods among l2 coleman-jain barsky-petrou recursive (default: all).

use photostereo::base::progress::Silent;
use photostereo::io::groundtruth::{read_normal_map, NormalMap};
use photostereo::io::layouts::CaptureFiles;
use photostereo::method::engine::{reconstruct, Method, Params, Reconstruction};
use photostereo::model::capture::Capture;
use photostereo::solve::lambert::{shadow_labels, Estimate};
use photostereo::solve::metrics::{
    circle_from_mask, evaluate, quantile, roughness_deg, sphere_errors,
};
use std::path::PathBuf;
use std::time::Instant;

fn data() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data"))
}

/// The objects and methods named on the command line (default: all).
fn arguments() -> (Vec<String>, Vec<Method>) {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut objects = Vec::new();
    let mut methods = Vec::new();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        if a == "--method" {
            methods.push(it.next().unwrap().parse::<Method>().unwrap());
        } else {
            objects.push(a.clone());
        }
    }
    if objects.is_empty() {
        objects = [
            "ball", "bear", "cat", "buddha", "cat-psm", "gray", "horse", "owl", "rock",
        ]
        .map(String::from)
        .to_vec();
    }
    if methods.is_empty() {
        methods = Method::ALL.to_vec();
    }
    (objects, methods)
}

/// The object's capture (lights refined first when `PS_REFINE=1`) and, for DiLiGenT, its
/// ground-truth normals.
fn load(object: &str) -> (Capture, Option<NormalMap>) {
    let (files, truth) = if ["ball", "bear", "cat"].contains(&object) {
        let dir = data().join(format!("diligent/{object}PNG"));
        (
            CaptureFiles::diligent(&dir).unwrap(),
            Some(read_normal_map(&dir.join("Normal_gt.mat")).unwrap()),
        )
    } else {
        let name = object.trim_end_matches("-psm");
        (
            CaptureFiles::list_file(
                &data().join(format!("psmImages/{name}.txt")),
                &data().join("psmImages/lights.reference.txt"),
            )
            .unwrap(),
            None,
        )
    };
    let mut capture = files.load(&Silent).unwrap();
    if std::env::var("PS_REFINE").is_ok_and(|v| v == "1") {
        photostereo::solve::refine::refine_capture_lights(
            &mut capture,
            &photostereo::solve::refine::RefineParams::default(),
        )
        .unwrap();
        if let Some(note) = capture.notes.last() {
            eprintln!("{object}: {note}");
        }
    }
    (capture, truth)
}

/// The method's parameters with the environment's overrides: `PS_ITERS` (iteration limit),
/// `PS_RADIUS` (consensus radius, pixels), `PS_KAPPA` (a fixed κ, or `measured`), `PS_PRIOR`
/// (the surface prior, degrees; 0 turns it off), `PS_LIGHT_NOISE=0` (no per-light factors).
fn params(method: Method) -> Params {
    let mut params = Params {
        method,
        integrate: false,
        ..Params::default()
    };
    let var = |name: &str| std::env::var(name).ok();
    if let Some(i) = var("PS_ITERS") {
        params.recursive.max_iterations = i.parse().unwrap();
    }
    if let Some(r) = var("PS_RADIUS") {
        params.recursive.consensus_radius = r.parse().unwrap();
    }
    if let Some(k) = var("PS_KAPPA") {
        params.detection.relative_noise = (k != "measured").then(|| k.parse().unwrap());
    }
    if let Some(v) = var("PS_PRIOR") {
        params.recursive.surface_prior_deg = v.parse().unwrap();
    }
    if let Some(v) = var("PS_LIGHT_NOISE") {
        params.detection.light_noise = v != "0";
    }
    params
}

/// The error against ground truth, or the roughness (and the `gray` sphere's error), and the
/// mask pixels left without a normal.
fn accuracy(object: &str, rec: &Reconstruction, truth: Option<&NormalMap>) -> String {
    let (w, h) = (rec.width, rec.height);
    let mut line = String::new();
    if let Some(t) = truth {
        let (_, s) = evaluate(&rec.normals, &t.normals, Some(&rec.mask)).unwrap();
        line += &format!(" mean {:6.3} median {:6.3}", s.mean_deg, s.median_deg);
    } else {
        line += &format!(
            " rough {:6.3}",
            roughness_deg(&rec.normals, &rec.mask, w, h)
        );
        if object == "gray" {
            let circle = circle_from_mask(&rec.mask, w, h).unwrap();
            let mut e = sphere_errors(&rec.normals, w, circle, 0.9);
            let mean = e.iter().sum::<f64>() / e.len() as f64;
            line += &format!(" sphere mean {mean:6.3} p90 {:6.3}", quantile(&mut e, 0.9));
        }
    }
    let missing = rec
        .normals
        .iter()
        .zip(&rec.mask)
        .filter(|(n, &m)| m && **n == [0.0; 3])
        .count();
    line + &format!(" missing {missing}")
}

/// The detection's unreliable share and noise model (`PS_FACTORS` lists the light factors).
fn noise_model(object: &str, rec: &Reconstruction) -> String {
    let Some(d) = rec.report.extra.get("detection") else {
        return String::new();
    };
    let mut line = format!(
        " unrel {:.3} kappa {:.4} s0 {:.5}",
        d["unreliable_share"].as_f64().unwrap_or(f64::NAN),
        d["noise"]["kappa"].as_f64().unwrap_or(f64::NAN),
        d["noise"]["sigma0"].as_f64().unwrap_or(f64::NAN),
    );
    if let Some(f) = d["noise"]["light_factor"].as_array() {
        let f: Vec<f64> = f.iter().filter_map(|x| x.as_f64()).collect();
        let above = f.iter().filter(|&&x| x > 1.0).count();
        let max = f.iter().cloned().fold(1.0, f64::max);
        line += &format!(" factors>1 {above}/{} max {max:.2}", f.len());
        if std::env::var("PS_FACTORS").is_ok() {
            let list: Vec<String> = f.iter().map(|x| format!("{x:.2}")).collect();
            eprintln!("{object} factors {}", list.join(" "));
        }
    }
    line
}

/// What the lights left out mean: shadows by the estimate's own shading, and the lights kept.
fn shadow_meaning(capture: &Capture, rec: &Reconstruction) -> String {
    let np = capture.n_pixels();
    let n = capture.n_lights();
    let c = capture.channels;
    let est = Estimate {
        normals: capture
            .pixels
            .iter()
            .map(|&i| rec.normals[i as usize])
            .collect(),
        albedo: capture
            .pixels
            .iter()
            .flat_map(|&i| rec.albedo[i as usize * c..(i as usize + 1) * c].to_vec())
            .collect(),
        light_status: None,
    };
    let mut st = vec![0u8; np * n];
    for (p, &i) in capture.pixels.iter().enumerate() {
        for k in 0..n {
            st[p * n + k] = rec.light_status.get(k, i as usize);
        }
    }
    let sl = shadow_labels(capture, &est, &st);
    let kept = st.iter().filter(|&&s| s == 0).count() as f64 / np as f64;
    format!(
        " shadow {:.3} lit {:.3} away {:.3} kept {:.1}/{n}",
        sl.share_of_all, sl.lit, sl.facing_away, kept
    )
}

/// The recursion's iterations, last change and whether it converged.
fn convergence(rec: &Reconstruction) -> String {
    let Some(r) = rec.report.extra.get("recursive") else {
        return String::new();
    };
    let its = r["iterations"].as_array().unwrap();
    let last = its.last().unwrap();
    format!(
        " iters {} change {:.4} conv {}",
        its.len(),
        last["changed_share"].as_f64().unwrap(),
        r.get("converged")
            .map(|v| v.to_string())
            .unwrap_or("-".into())
    )
}

fn main() {
    let (objects, methods) = arguments();
    for object in &objects {
        let (capture, truth) = load(object);
        for &method in &methods {
            let t = Instant::now();
            let rec = reconstruct(&capture, &params(method), &Silent).unwrap();
            let secs = t.elapsed().as_secs_f64();
            let mut line = format!("{object:8} {:14}", method.name());
            line += &accuracy(object, &rec, truth.as_ref());
            line += &noise_model(object, &rec);
            if rec.statuses_decided && method != Method::L2 {
                line += &shadow_meaning(&capture, &rec);
            }
            line += &convergence(&rec);
            println!("{line} {secs:.1}s");
        }
    }
}
