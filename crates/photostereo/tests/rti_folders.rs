//! Capture folders as RTI tools write them: RTIBuilder's (`assembly-files/*.lp` naming images
//! of another machine, JPEGs in `jpeg-exports/`) and relight's (the images beside an `.lp` or
//! a `.dome` file), found by `CaptureFiles::from_inputs` on the folder alone and reconstructed
//! as well as the rendered capture they came from. The `.dome` keys and frame follow relight's
//! documentation of its dome configuration file.

use photostereo::base::progress::Silent;
use photostereo::io::camera::{reencode_capture, CameraFormat, CameraSpec};
use photostereo::io::layouts::CaptureFiles;
use photostereo::io::photometry::Response;
use photostereo::method::engine::{reconstruct, Method, Params};
use photostereo::scene::{Brdf, Rig, SceneKind, SynthSpec};
use std::path::{Path, PathBuf};

/// A rendered Lambertian sphere under 12 lights: its files and true normals.
fn rendered(dir: &Path) -> (CaptureFiles, Vec<[f32; 3]>) {
    let mut spec = SynthSpec::new(SceneKind::Sphere, Rig::Dome(12));
    spec.size = 64;
    spec.render.brdf = Brdf::Lambert;
    spec.render.noise_sigma = 0.002;
    let (r, target) = photostereo::io::synth::synth_to_folder(&spec, dir, false).unwrap();
    (CaptureFiles::diligent(&target).unwrap(), r.truth.normals)
}

fn l2_error(files: &CaptureFiles, truth: &[[f32; 3]]) -> f64 {
    let capture = files.load(&Silent).unwrap();
    let params = Params {
        method: Method::L2,
        integrate: false,
        ..Params::default()
    };
    let mut rec = reconstruct(&capture, &params, &Silent).unwrap();
    rec.evaluate(truth).unwrap().mean_deg
}

/// The rendered images as sRGB JPEGs named `img_0001.jpg`, … (light order) in `dir`.
fn jpegs(src: &CaptureFiles, dir: &Path) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let spec = CameraSpec {
        response: Response::Srgb,
        ambient: 0.0,
        exposure_jitter: 1.0,
        format: CameraFormat::Jpeg(95),
        seed: 1,
    };
    let (written, _) = reencode_capture(src, dir, &spec).unwrap();
    std::fs::remove_file(dir.join("filenames.txt")).unwrap();
    written
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let to = dir.join(format!("img_{:04}.jpg", k + 1));
            std::fs::rename(p, &to).unwrap();
            to
        })
        .collect()
}

fn lp_text(names: &[String], dirs: &[[f64; 3]]) -> String {
    let mut s = format!("{}\n", names.len());
    for (n, d) in names.iter().zip(dirs) {
        s += &format!("{n} {:.6} {:.6} {:.6}\n", d[0], d[1], d[2]);
    }
    s
}

#[test]
fn an_rtibuilder_folder_is_found_and_paired_by_name_or_order() {
    let root = tempfile::tempdir().unwrap();
    let (src, truth) = rendered(&root.path().join("render"));
    let base = l2_error(&src, &truth);
    let dirs = src.lights.directions.clone();
    let n = dirs.len();
    let project = root.path().join("project");
    jpegs(&src, &project.join("jpeg-exports"));
    std::fs::create_dir_all(project.join("assembly-files")).unwrap();
    let lp = project.join("assembly-files").join("capture.lp");
    // Names of the machine that built it: found by file name, whatever the case.
    let names: Vec<String> = (1..=n)
        .map(|k| format!("C:\\rti\\project\\jpeg-exports\\IMG_{k:04}.JPG"))
        .collect();
    std::fs::write(&lp, lp_text(&names, &dirs)).unwrap();
    let files =
        CaptureFiles::from_inputs(std::slice::from_ref(&project), None, None, None).unwrap();
    assert_eq!(files.images.len(), n);
    assert!(files.images[3].ends_with("jpeg-exports/img_0004.jpg"));
    assert!(!files.notes.iter().any(|m| m.contains("sorted order")));
    let e = l2_error(&files, &truth);
    assert!(e < base + 0.8, "{e:.2}° vs {base:.2}°");
    // Names that are not there: paired by sorted order, and said.
    let names: Vec<String> = (1..=n).map(|k| format!("shot-{k}.tif")).collect();
    std::fs::write(&lp, lp_text(&names, &dirs)).unwrap();
    let files =
        CaptureFiles::from_inputs(std::slice::from_ref(&project), None, None, None).unwrap();
    assert!(
        files
            .notes
            .iter()
            .any(|m| m.contains("sorted order") && m.contains("shot-1.tif")),
        "{:?}",
        files.notes
    );
    let e = l2_error(&files, &truth);
    assert!(e < base + 0.8, "{e:.2}° vs {base:.2}°");
    // Paired in the wrong order, the same lines give a far worse result: the order matters.
    let mut shuffled = dirs.clone();
    shuffled.reverse();
    std::fs::write(&lp, lp_text(&names, &shuffled)).unwrap();
    let files =
        CaptureFiles::from_inputs(std::slice::from_ref(&project), None, None, None).unwrap();
    assert!(l2_error(&files, &truth) > base + 5.0);
    // Fewer lines than images: refused, naming the file and the counts.
    std::fs::write(&lp, lp_text(&names[..n - 1], &dirs[..n - 1])).unwrap();
    let e = CaptureFiles::from_inputs(std::slice::from_ref(&project), None, None, None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("capture.lp")
            && e.contains(&format!("{} light line", n - 1))
            && e.contains(&format!("{n} in")),
        "{e}"
    );
    // Two light files: refused, naming both.
    std::fs::write(&lp, lp_text(&names, &dirs)).unwrap();
    std::fs::write(project.join("assembly-files").join("other.lp"), "0\n").unwrap();
    let e = CaptureFiles::from_inputs(&[project], None, None, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("capture.lp") && e.contains("other.lp"), "{e}");
}

fn xyz(v: &[[f64; 3]]) -> String {
    let items: Vec<String> = v
        .iter()
        .map(|d| format!("{{\"x\": {}, \"y\": {}, \"z\": {}}}", d[0], d[1], d[2]))
        .collect();
    format!("[{}]", items.join(", "))
}

#[test]
fn a_relight_dome_folder_reads_directions_or_positions() {
    let root = tempfile::tempdir().unwrap();
    let (src, truth) = rendered(&root.path().join("render"));
    let base = l2_error(&src, &truth);
    let dirs = src.lights.directions.clone();
    let folder = root.path().join("relight");
    jpegs(&src, &folder);
    let dome = folder.join("rig.dome");
    std::fs::write(
        &dome,
        format!(
            "{{\"label\": \"test\", \"imageWidth\": 0, \"domeDiameter\": 0, \"verticalOffset\": 0, \
             \"lightConfiguration\": \"directional\", \"directions\": {}, \"positionsSphere\": [], \
             \"positions3d\": [], \"ledAdjust\": []}}",
            xyz(&dirs)
        ),
    )
    .unwrap();
    let files = CaptureFiles::from_inputs(std::slice::from_ref(&folder), None, None, None).unwrap();
    assert_eq!(files.lights.directions.len(), dirs.len());
    let e = l2_error(&files, &truth);
    assert!(e < base + 0.8, "{e:.2}° vs {base:.2}°");
    // The LEDs on a 2 m dome, the imaged area 2 cm wide: distant lights toward the centre, off
    // by at most atan(1 / 100) at the edge; LED factors that halve light 1's pixel values make
    // it twice as bright.
    let positions: Vec<[f64; 3]> = dirs.iter().map(|d| d.map(|v| v * 100.0)).collect();
    let mut adjust = vec!["{\"r\": 1, \"g\": 1, \"b\": 1}".to_string(); dirs.len()];
    adjust[0] = "{\"r\": 0.5, \"g\": 0.5, \"b\": 0.5}".into();
    std::fs::write(
        &dome,
        format!(
            "{{\"imageWidth\": 2, \"domeDiameter\": 200, \"verticalOffset\": 0, \
             \"lightConfiguration\": \"lights3d\", \"directions\": [], \"positions3d\": {}, \
             \"ledAdjust\": [{}]}}",
            xyz(&positions),
            adjust.join(", ")
        ),
    )
    .unwrap();
    let files = CaptureFiles::from_inputs(std::slice::from_ref(&dome), None, None, None).unwrap();
    for (a, b) in files.lights.directions.iter().zip(&dirs) {
        assert!((0..3).all(|i| (a[i] - b[i]).abs() < 1e-9));
    }
    assert_eq!(files.lights.intensities[0], [2.0; 3]);
    assert!(
        files
            .notes
            .iter()
            .any(|m| m.contains("distant") && m.contains("0.6°")),
        "{:?}",
        files.notes
    );
    // Spherical, saved with directions only: placed on the sphere, then read as distant.
    std::fs::write(
        &dome,
        format!(
            "{{\"imageWidth\": 2, \"domeDiameter\": 200, \"verticalOffset\": 0, \
             \"lightConfiguration\": \"spherical\", \"directions\": {}}}",
            xyz(&dirs)
        ),
    )
    .unwrap();
    let files = CaptureFiles::from_inputs(std::slice::from_ref(&folder), None, None, None).unwrap();
    assert!((files.lights.directions[2][2] - dirs[2][2]).abs() < 1e-9);
    // Bad files name the file and what is wrong.
    for (text, expect) in [
        ("{\"lightConfiguration\": \"ring\"}", "ring"),
        ("{\"directions\": [{\"x\": 0, \"y\": 0}]}", "\"z\""),
        ("{\"directions\": 3}", "array"),
        ("{\"lightConfiguration\": \"lights3d\"}", "positions3d"),
        ("not json", "JSON"),
        (
            "{\"directions\": [{\"x\": 0, \"y\": 0, \"z\": -1}]}",
            "below",
        ),
    ] {
        std::fs::write(&dome, text).unwrap();
        let e = CaptureFiles::from_inputs(std::slice::from_ref(&folder), None, None, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("rig.dome") && e.contains(expect), "{text}: {e}");
    }
    // One LED more than there are images.
    let mut more = dirs.clone();
    more.push([0.0, 0.0, 1.0]);
    std::fs::write(&dome, format!("{{\"directions\": {}}}", xyz(&more))).unwrap();
    let e = CaptureFiles::from_inputs(&[folder], None, None, None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&format!("{} LEDs but {} images", more.len(), dirs.len())),
        "{e}"
    );
}

/// L2's mean angular error on a near-light rendering, with the solver's defaults.
fn near_error(files: &CaptureFiles, truth: &[[f32; 3]]) -> f64 {
    let capture = files.load(&Silent).unwrap();
    let params = Params {
        method: Method::L2,
        ..Params::default()
    };
    let mut rec =
        photostereo::method::engine::reconstruct_with_truth(&capture, &params, None, &Silent)
            .unwrap();
    rec.evaluate(truth).unwrap().mean_deg
}

#[test]
fn a_relight_dome_seen_through_a_camera_places_its_leds_as_near_lights() {
    use photostereo::scene::near::{synthesize_near, NearRig, NearSpec};
    // 24 LEDs on a hemisphere of radius D = 300 mm about the object's centre, rendered with
    // the near image model; the same capture as a near-light folder and as a relight folder.
    let spec = NearSpec {
        size: 48,
        ..NearSpec::new(SceneKind::Sphere, NearRig::Dome)
    };
    let r = synthesize_near(&spec).unwrap();
    let truth = &r.rendered.truth.normals;
    let root = tempfile::tempdir().unwrap();
    let near = root.path().join("near");
    std::fs::create_dir(&near).unwrap();
    photostereo::io::synth::write_near_capture(&near, &r).unwrap();
    let near_files =
        CaptureFiles::from_inputs(std::slice::from_ref(&near), None, None, None).unwrap();
    let e_near = near_error(&near_files, truth);
    let folder = root.path().join("relight");
    std::fs::create_dir(&folder).unwrap();
    for (k, p) in near_files.images.iter().enumerate() {
        std::fs::copy(p, folder.join(format!("img_{:04}.png", k + 1))).unwrap();
    }
    let mask = near.join("mask.png");
    // The dome's frame: cm, origin at the centre of the imaged area (D below the camera).
    let d = spec.distance;
    let cm: Vec<[f64; 3]> = r
        .positions
        .iter()
        .map(|p| [p[0] / 10.0, p[1] / 10.0, (p[2] + d) / 10.0])
        .collect();
    let adjust: Vec<[f64; 3]> = r.radiance.iter().map(|e| e.map(|v| 1.0 / v)).collect();
    let adjust: Vec<String> = adjust
        .iter()
        .map(|a| format!("{{\"r\": {}, \"g\": {}, \"b\": {}}}", a[0], a[1], a[2]))
        .collect();
    let dome = folder.join("rig.dome");
    std::fs::write(
        &dome,
        format!(
            "{{\"imageWidth\": {}, \"domeDiameter\": {}, \"lightConfiguration\": \"lights3d\", \
             \"positions3d\": {}, \"ledAdjust\": [{}]}}",
            d / 30.0,
            d / 5.0,
            xyz(&cm),
            adjust.join(", ")
        ),
    )
    .unwrap();
    let camera = photostereo::io::layouts::near::read_camera(&near.join("K.txt")).unwrap();
    let input = std::slice::from_ref(&folder);
    let seen =
        CaptureFiles::from_inputs_with(input, None, None, Some(&mask), Some(d), Some(camera))
            .unwrap();
    assert!(seen.lights.near.is_some(), "{:?}", seen.notes);
    assert!(seen.notes.iter().any(|n| n.contains("near lights")));
    let e_dome = near_error(&seen, truth);
    let distant = CaptureFiles::from_inputs(input, None, None, Some(&mask)).unwrap();
    assert!(distant.lights.near.is_none());
    assert!(distant.notes.iter().any(|n| n.contains("distant")));
    let e_distant = near_error(&distant, truth);
    eprintln!(
        "l2: dome as near lights {e_dome:.2}°, near layout {e_near:.2}°, dome as distant \
         {e_distant:.2}°"
    );
    assert!(
        (e_dome - e_near).abs() < 0.1 && e_dome < 0.5 * e_distant,
        "dome as near lights {e_dome:.2}°, near layout {e_near:.2}°, dome as distant \
         {e_distant:.2}°"
    );
    // The camera's files in the folder do the same.
    std::fs::copy(near.join("K.txt"), folder.join("K.txt")).unwrap();
    std::fs::write(folder.join("mean_distance.txt"), format!("{d}\n")).unwrap();
    let in_folder = CaptureFiles::from_inputs(input, None, None, Some(&mask)).unwrap();
    assert!(in_folder.lights.near.is_some());
    // A camera without the distance is refused, the file named.
    std::fs::remove_file(folder.join("mean_distance.txt")).unwrap();
    let e = CaptureFiles::from_inputs(input, None, None, None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("mean_distance.txt") && e.contains("distance"),
        "{e}"
    );
    // A dome of directions only stays distant, and says so.
    let dirs: Vec<[f64; 3]> = near_files.lights.directions.clone();
    std::fs::write(&dome, format!("{{\"directions\": {}}}", xyz(&dirs))).unwrap();
    let f = CaptureFiles::from_inputs_with(input, None, None, None, Some(d), Some(camera)).unwrap();
    assert!(f.lights.near.is_none() && f.lights.camera.is_some());
    assert!(
        f.notes.iter().any(|n| n.contains("directions only")),
        "{:?}",
        f.notes
    );
}
