//! Captures in tiles (ALGORITHMS.md §10): a capture loaded in tiles at the input's precision,
//! in memory or in a spill file, gives the same samples (bit for bit) and the same results as
//! the capture held whole, for every method, on DiLiGenT cat and bear and on a synthetic
//! capture; the spill file never outlives the load (success, error, cancellation); a budget
//! too small is refused with the smallest that works.

use photostereo::base::progress::{Progress, Silent};
use photostereo::io::layouts::{CaptureFiles, LoadOptions};
use photostereo::io::synth::synth_to_folder;
use photostereo::method::engine::{
    reconstruct, reconstruct_to_write, Method, Params, Reconstruction,
};
use photostereo::model::capture::Capture;
use photostereo::model::memory::{Force, Layout};
use photostereo::scene::{Rig, SceneKind, SynthSpec};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

fn diligent(object: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/diligent")
        .join(format!("{object}PNG"));
    p.is_dir().then_some(p)
}

fn tiled(layout: Layout, tile_pixels: usize, dir: &Path) -> LoadOptions {
    LoadOptions {
        budget: Some(64 << 30),
        spill_dir: Some(dir.to_path_buf()),
        force: Force {
            layout: Some(layout),
            tile_pixels: Some(tile_pixels),
            // A spilled capture also parks its per-pixel arrays during the full-frame stages:
            // the results stay those of the capture held whole.
            park: Some(layout == Layout::Spill),
        },
        ..Default::default()
    }
}

/// Open spill files of this process: links in /proc/self/fd to a deleted file in `dir`.
fn open_spill_files(dir: &Path) -> usize {
    std::fs::read_dir("/proc/self/fd")
        .map(|d| {
            d.filter_map(|e| std::fs::read_link(e.ok()?.path()).ok())
                .filter(|t| t.starts_with(dir) && t.to_string_lossy().contains(".spill"))
                .count()
        })
        .unwrap_or(0)
}

fn assert_same_samples(whole: &Capture, tiled: &Capture) {
    assert!(!whole.is_tiled() && tiled.is_tiled());
    assert_eq!(whole.pixels, tiled.pixels);
    let stride = whole.n_lights() * whole.channels;
    let mut tiles = 0;
    tiled
        .for_each_tile(|off, tile| {
            let n = tile.n_pixels();
            // Bit-identical: u16 scaled on use reproduces the decoder's f32 exactly.
            assert!(
                tile.samples == whole.samples[off * stride..(off + n) * stride],
                "tile at pixel {off} differs"
            );
            tiles += 1;
            Ok(())
        })
        .unwrap();
    assert!(tiles > 3, "only {tiles} tiles");
    // A scattered subset of the pixels, read a tile at a time, answers as the whole capture.
    let ids: Vec<usize> = (0..whole.n_pixels())
        .filter(|p| p % 7 == 3 || p % 11 == 0)
        .collect();
    let (mut seen, mut calls) = (Vec::new(), 0);
    tiled
        .for_ids_by_tile(&ids, |sub, view| {
            for &p in sub {
                assert!(view.pixel_samples(p) == whole.pixel_samples(p), "pixel {p}");
            }
            seen.extend_from_slice(sub);
            calls += 1;
            Ok(())
        })
        .unwrap();
    assert_eq!(seen, ids);
    assert!(
        calls > 3 && calls <= tiles,
        "{calls} calls for {tiles} tiles"
    );
}

fn max_normal_difference(a: &Reconstruction, b: &Reconstruction) -> f32 {
    a.normals
        .iter()
        .zip(&b.normals)
        .flat_map(|(x, y)| (0..3).map(move |i| (x[i] - y[i]).abs()))
        .fold(0.0, f32::max)
}

/// A reconstruction made to be written ([`reconstruct_to_write`]) of a capture that parks (`tiled`) keeps
/// its surface's maps in the parking file (empty in memory) and reads them back bit for bit:
/// they equal those of `reference` (the capture held whole).
fn assert_surface_waits_and_returns(reference: &Reconstruction, tiled: &Capture, params: &Params) {
    let name = params.method.name();
    let mut rec = reconstruct_to_write(tiled, params, None, &Silent).unwrap();
    let held = |r: &Reconstruction| r.surface.as_ref().map(|s| !s.depth.values.is_empty());
    assert_eq!(held(&rec), Some(false), "{name}: the surface waits parked");
    rec.unpark_surface().unwrap();
    let maps = |r: &Reconstruction| {
        r.surface.as_ref().map(|s| {
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let jumps = s.depth.discontinuities.as_deref().map(bits);
            (bits(&s.depth.values), bits(&s.curl), jumps)
        })
    };
    assert!(
        maps(&rec) == maps(reference),
        "{name}: surface after unparking"
    );
    assert!(
        !maps(reference).is_some_and(|(d, _, _)| d.is_empty()),
        "{name}: no depth"
    );
}

fn assert_same_results(whole: &Capture, tiled: &Capture, methods: &[Method]) {
    for &method in methods {
        let params = Params {
            method,
            ..Params::default()
        };
        let a = reconstruct(whole, &params, &Silent).unwrap();
        let b = reconstruct(tiled, &params, &Silent).unwrap();
        let d = max_normal_difference(&a, &b);
        assert!(d <= 1e-6, "{}: normals differ by {d}", method.name());
        assert_eq!(a.albedo, b.albedo, "{}: albedo", method.name());
        assert_eq!(
            a.light_status,
            b.light_status,
            "{}: statuses",
            method.name()
        );
        assert_eq!(a.residual, b.residual, "{}: residual", method.name());
        let bits = |r: &Reconstruction| {
            r.depth()
                .map(|d| d.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
        };
        assert!(bits(&a) == bits(&b), "{}: depth", method.name());
        if tiled.memory.as_ref().is_some_and(|m| m.park) {
            assert_surface_waits_and_returns(&a, tiled, &params);
        }
        for key in [
            "detection",
            "highlights",
            "shadows",
            "all_pairs",
            "recursive",
        ] {
            let strip = |r: &Reconstruction| {
                let mut v = r.report.extra.get(key).cloned();
                // Timings differ from run to run.
                if let Some(its) = v.as_mut().and_then(|v| v.get_mut("iterations")) {
                    for it in its.as_array_mut().into_iter().flatten() {
                        if let Some(o) = it.as_object_mut() {
                            o.remove("seconds");
                        }
                    }
                }
                v
            };
            assert!(strip(&a) == strip(&b), "{}: report {key}", method.name());
        }
    }
}

/// A DiLiGenT object held whole and in a spill file of 5000-pixel tiles (the spill file's
/// folder kept with them), or `None` (and a note) when ../shared/data does not have it.
fn whole_and_spilled(object: &str) -> Option<(Capture, Capture, tempfile::TempDir)> {
    let Some(dir) = diligent(object) else {
        eprintln!("SKIPPED: no DiLiGenT {object} in ../shared/data");
        return None;
    };
    let files = CaptureFiles::diligent(&dir).unwrap();
    let whole = files.load(&Silent).unwrap();
    let spill = tempfile::tempdir().unwrap();
    let tiled = files
        .load_with(&Silent, &tiled(Layout::Spill, 5000, spill.path()))
        .unwrap();
    Some((whole, tiled, spill))
}

#[test]
fn cat_in_a_spill_file_gives_the_results_of_cat_in_memory() {
    let Some((whole, tiled, spill)) = whole_and_spilled("cat") else {
        return;
    };
    let plan = tiled.memory.clone().unwrap();
    assert_eq!(
        (plan.layout, plan.sample_type),
        ("tiles in a spill file", "u16")
    );
    assert_eq!(plan.spill_bytes, 45200 * 96 * 3 * 2);
    // The spill file is open (unlinked: no name in the folder) while the capture lives.
    assert_eq!(open_spill_files(spill.path()), 1);
    assert_eq!(std::fs::read_dir(spill.path()).unwrap().count(), 0);
    assert_same_samples(&whole, &tiled);
    assert_same_results(&whole, &tiled, Method::ALL);
    drop(tiled);
    assert_eq!(open_spill_files(spill.path()), 0);
}

#[test]
fn bear_in_a_spill_file_gives_the_results_of_bear_in_memory() {
    let Some((whole, tiled, _spill)) = whole_and_spilled("bear") else {
        return;
    };
    assert!(tiled.memory.as_ref().is_some_and(|m| m.park && m.tiles > 3));
    assert_same_results(&whole, &tiled, Method::ALL);
}

#[test]
fn a_synthetic_capture_in_tiles_gives_the_results_held_whole() {
    let out = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Blocks, Rig::parse("ring8").unwrap());
    spec.size = 64;
    let (_, folder) = synth_to_folder(&spec, &out.path().join("blocks"), false).unwrap();
    let files = CaptureFiles::diligent(&folder).unwrap();
    let whole = files.load(&Silent).unwrap();
    for layout in [Layout::Tiles, Layout::Spill] {
        let tiled = files
            .load_with(&Silent, &tiled(layout, 300, out.path()))
            .unwrap();
        assert_eq!(tiled.memory.as_ref().unwrap().layout, layout.name());
        assert_same_samples(&whole, &tiled);
        assert_same_results(&whole, &tiled, Method::ALL);
    }
    assert_eq!(open_spill_files(out.path()), 0);
}

#[test]
fn a_tiled_detection_leaves_the_kappa_of_its_report_with_the_capture() {
    use photostereo::solve::detect::{estimate_kappa_weighted, remembered_kappa, DetectionParams};
    use photostereo::solve::tiled::{detect_tiles, measured_kappa, statistics_view};
    let out = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Blocks, Rig::parse("ring8").unwrap());
    spec.size = 64;
    let (_, folder) = synth_to_folder(&spec, &out.path().join("blocks"), false).unwrap();
    let files = CaptureFiles::diligent(&folder).unwrap();
    let tiled = files
        .load_with(&Silent, &tiled(Layout::Tiles, 300, out.path()))
        .unwrap();
    let params = DetectionParams::default();
    let d = detect_tiles(&tiled, &params, &Silent).unwrap();
    let n = &d.noise;
    // Measured afresh on a new statistics view: the value the capture remembered.
    let view = statistics_view(&tiled).unwrap();
    let fresh = estimate_kappa_weighted(&view, n.sigma0, n.floor, &params, &n.light_factor);
    assert!(fresh.is_some(), "eight lights measure κ");
    let kept = remembered_kappa(&tiled, n.sigma0, n.floor, &params, &n.light_factor);
    assert_eq!(kept, Some(fresh));
    assert_eq!(measured_kappa(&tiled, n, &params).unwrap(), fresh);
}

/// Cancels once `after` units of progress were reported.
struct CancelAfter {
    after: u64,
    done: AtomicU64,
}

impl Progress for CancelAfter {
    fn advance(&self, units: u64) {
        self.done.fetch_add(units, Ordering::Relaxed);
    }
    fn cancelled(&self) -> bool {
        self.done.load(Ordering::Relaxed) >= self.after
    }
}

#[test]
fn the_spill_file_goes_on_error_and_on_cancellation() {
    let out = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Sphere, Rig::parse("ring8").unwrap());
    spec.size = 48;
    let (_, folder) = synth_to_folder(&spec, &out.path().join("sphere"), false).unwrap();
    let spill = out.path().join("spill");
    std::fs::create_dir(&spill).unwrap();
    let files = CaptureFiles::diligent(&folder).unwrap();
    // Cancelled while loading.
    let cancel = CancelAfter {
        after: 1,
        done: AtomicU64::new(0),
    };
    let e = files
        .load_with(&cancel, &tiled(Layout::Spill, 100, &spill))
        .unwrap_err();
    assert!(matches!(e, photostereo::Error::Cancelled), "{e}");
    assert_eq!(open_spill_files(&spill), 0);
    assert_eq!(std::fs::read_dir(&spill).unwrap().count(), 0);
    // A truncated image met half-way through the rows.
    let bytes = std::fs::read(folder.join("005.png")).unwrap();
    std::fs::write(folder.join("005.png"), &bytes[..bytes.len() / 2]).unwrap();
    let e = files
        .load_with(&Silent, &tiled(Layout::Spill, 100, &spill))
        .unwrap_err();
    assert!(e.to_string().contains("005.png"), "{e}");
    assert_eq!(open_spill_files(&spill), 0);
    assert_eq!(std::fs::read_dir(&spill).unwrap().count(), 0);
}

#[test]
fn a_budget_below_the_full_frame_stages_is_refused_with_the_minimum() {
    let out = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Sphere, Rig::parse("square4").unwrap());
    spec.size = 64;
    let (_, folder) = synth_to_folder(&spec, &out.path().join("s"), false).unwrap();
    let files = CaptureFiles::diligent(&folder).unwrap();
    let options = |budget| LoadOptions {
        budget: Some(budget),
        ..Default::default()
    };
    let e = files.load_with(&Silent, &options(1 << 20)).unwrap_err();
    let m = e.to_string();
    assert!(m.starts_with("memory_limit 1M: too small"), "{m}");
    let minimum: u64 = m
        .rsplit("smallest budget that works is ")
        .next()
        .and_then(|s| s.strip_suffix('M'))
        .and_then(|s| s.parse().ok())
        .expect("the minimum in MiB");
    // The minimum it names works, and is the plan's own figure.
    let c = files.load_with(&Silent, &options(minimum << 20)).unwrap();
    let plan = c.memory.unwrap();
    assert_eq!(plan.minimum_budget.div_ceil(1 << 20), minimum);
    assert!(files
        .load_with(&Silent, &options((minimum - 1) << 20))
        .is_err());
}

#[test]
fn synth_one_light_at_a_time_writes_a_cameras_files_as_synth_whole() {
    use photostereo::io::camera::{CameraFormat, CameraSpec};
    use photostereo::io::photometry::Response;
    let out = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Cavities, Rig::parse("ring8").unwrap());
    spec.size = 40;
    let camera = CameraSpec {
        response: Response::Srgb,
        ambient: 0.05,
        exposure_jitter: 2.0,
        format: CameraFormat::Jpeg(90),
        seed: 3,
    };
    let (_, whole) = photostereo::io::synth::synth_camera_to_folder(
        &spec,
        &camera,
        &out.path().join("whole"),
        false,
    )
    .unwrap();
    let (_, _, streamed) = photostereo::io::synth::synth_streamed(
        &spec,
        Some(&camera),
        &out.path().join("s"),
        false,
        &Silent,
    )
    .unwrap();
    for name in ["001.jpg", "008.jpg", "ambient.jpg", "filenames.txt"] {
        assert!(
            std::fs::read(whole.join(name)).unwrap() == std::fs::read(streamed.join(name)).unwrap(),
            "{name} differs"
        );
    }
    assert!(!streamed.join("001.png").exists());
}

#[test]
fn synth_one_light_at_a_time_writes_the_images_of_synth_whole() {
    let out = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Cavities, Rig::parse("ring8").unwrap());
    spec.size = 40;
    let (_, whole) = synth_to_folder(&spec, &out.path().join("whole"), false).unwrap();
    let (_, _, streamed) =
        photostereo::io::synth::synth_streamed(&spec, None, &out.path().join("s"), false, &Silent)
            .unwrap();
    for name in [
        "001.png",
        "005.png",
        "008.png",
        "mask.png",
        "light_directions.txt",
    ] {
        assert!(
            std::fs::read(whole.join(name)).unwrap() == std::fs::read(streamed.join(name)).unwrap(),
            "{name} differs"
        );
    }
    // The streamed boolean stacks hold the same bytes after their headers.
    for name in ["gt/shadow.npy", "gt/highlight.npy"] {
        let (a, b) = (
            std::fs::read(whole.join(name)).unwrap(),
            std::fs::read(streamed.join(name)).unwrap(),
        );
        let n = 8 * 40 * 40;
        assert_eq!(a[a.len() - n..], b[b.len() - n..], "{name}");
        assert_eq!(
            b.len() % 64,
            n % 64,
            "{name}: header not padded to 64 bytes"
        );
    }
}
