//! Bad input: every case gives a clear message naming the file, line or parameter, exit code 2,
//! and writes nothing.

mod common;

use common::BIN;
use photostereo::io::imageio::{write_png16, write_png8};
use std::path::{Path, PathBuf};
use std::process::Command;

/// A valid small capture ([`common::write_sphere_capture`]) at the root of a temporary folder.
struct Fixture {
    dir: tempfile::TempDir,
}

impl Fixture {
    fn new() -> Self {
        let f = Fixture {
            dir: tempfile::tempdir().unwrap(),
        };
        common::write_sphere_capture(f.dir.path());
        f
    }
    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }
    fn write(&self, name: &str, text: &str) {
        std::fs::write(self.path(name), text).unwrap();
    }
    fn out(&self) -> PathBuf {
        self.dir.path().join("out")
    }
    /// Runs `photostereo run <capture> -o out [extra]`, expects exit 2 and a message with all
    /// `needles`, and checks that nothing was written.
    fn fails(&self, extra: &[&str], needles: &[&str]) {
        let before = listing(self.dir.path());
        let mut cmd = Command::new(BIN);
        cmd.arg("run")
            .arg(self.dir.path())
            .arg("-o")
            .arg(self.out())
            .args(extra);
        expect_failure(cmd, needles);
        assert_eq!(
            listing(self.dir.path()),
            before,
            "the failed run changed the folder"
        );
    }
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    v.sort();
    v
}

fn expect_failure(mut cmd: Command, needles: &[&str]) {
    let out = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles {
        assert!(err.contains(n), "expected '{n}' in: {err}");
    }
}

#[test]
fn valid_fixture_runs() {
    let f = Fixture::new();
    let (report, _) = run_json(&f, &["--quiet"]);
    assert_eq!(report["input"]["lights"], 4);
    assert!(f.out().join("normals.npy").exists());
}

#[test]
fn missing_light_file() {
    let f = Fixture::new();
    std::fs::remove_file(f.path("light_directions.txt")).unwrap();
    f.fails(&[], &["light_directions.txt"]);
    let mut cmd = Command::new(BIN);
    cmd.arg("run")
        .arg(f.path("001.png"))
        .arg(f.path("002.png"))
        .arg(f.path("003.png"));
    cmd.arg("--lights")
        .arg(f.path("nope.txt"))
        .arg("-o")
        .arg(f.out());
    expect_failure(cmd, &["nope.txt"]);
}

#[test]
fn malformed_light_rows() {
    let f = Fixture::new();
    f.write(
        "light_directions.txt",
        "0.3 0.3 0.9\n-0.3 0.3\n-0.3 -0.3 0.9\n0.3 -0.3 0.9\n",
    );
    f.fails(&[], &["light_directions.txt", "line 2", "exactly 3"]);
    f.write(
        "light_directions.txt",
        "0.3 0.3 0.9\n-0.3 0.3 0.9\n-0.3 -0.3 inf\n0.3 -0.3 0.9\n",
    );
    f.fails(&[], &["line 3", "finite"]);
    f.write(
        "light_directions.txt",
        "0.3 0.3 0.9\n0 0 0\n-0.3 -0.3 0.9\n0.3 -0.3 0.9\n",
    );
    f.fails(&[], &["line 2", "zero light direction"]);
}

#[test]
fn light_and_image_counts() {
    let f = Fixture::new();
    f.write(
        "light_directions.txt",
        "0.3 0.3 0.9\n-0.3 0.3 0.9\n-0.3 -0.3 0.9\n",
    );
    f.fails(
        &[],
        &[
            "light_directions.txt",
            "3 light direction(s) for 4 image(s)",
        ],
    );
    let f = Fixture::new();
    f.write("light_directions.txt", "0.3 0.3 0.9\n-0.3 0.3 0.9\n");
    f.write("filenames.txt", "001.png\n002.png\n");
    f.fails(&[], &["at least three"]);
}

#[test]
fn coplanar_lights() {
    let f = Fixture::new();
    f.write(
        "light_directions.txt",
        "0.3 0 0.9\n-0.3 0 0.9\n0.1 0 0.9\n0.2 0 0.5\n",
    );
    f.fails(&[], &["rank < 3", "condition number"]);
}

#[test]
fn mismatched_images() {
    let f = Fixture::new();
    write_png16(&f.path("003.png"), 20, 24, 1, &vec![0u16; 480]).unwrap();
    f.fails(&[], &["003.png", "share size"]);
    let f = Fixture::new();
    write_png16(&f.path("002.png"), 24, 24, 3, &vec![0u16; 24 * 24 * 3]).unwrap();
    f.fails(&[], &["002.png", "channel"]);
}

#[test]
fn corrupt_and_unsupported_images() {
    let f = Fixture::new();
    let bytes = std::fs::read(f.path("004.png")).unwrap();
    std::fs::write(f.path("004.png"), &bytes[..bytes.len() / 2]).unwrap();
    f.fails(&[], &["004.png", "PNG"]);
    let f = Fixture::new();
    std::fs::write(f.path("002.png"), b"GIF89a not an image we read").unwrap();
    f.fails(&[], &["002.png", "unsupported image format"]);
}

#[test]
fn bad_masks() {
    let f = Fixture::new();
    write_png8(&f.path("mask.png"), 10, 10, 1, &[255u8; 100]).unwrap();
    f.fails(&[], &["mask.png", "mask is 10×10"]);
    write_png8(&f.path("mask.png"), 24, 24, 1, &[0u8; 576]).unwrap();
    f.fails(&[], &["mask.png", "empty"]);
}

#[test]
fn bad_intensities() {
    for (text, needle) in [
        ("1\n1\n0\n1\n", "line 3"),
        ("1\n-2\n1\n1\n", "line 2"),
        ("1\n1\n1\nnan\n", "line 4"),
        (
            "1 1 1\n1 1 1\n",
            "2 intensity row(s) for 4 light direction(s)",
        ),
    ] {
        let f = Fixture::new();
        f.write("light_intensities.txt", text);
        f.fails(&[], &["light_intensities.txt", needle]);
    }
}

#[test]
fn ground_truth_of_another_shape() {
    let f = Fixture::new();
    let gt = ndarray::Array3::<f32>::zeros((5, 5, 3));
    ndarray_npy::write_npy(f.path("gt.npy"), &gt).unwrap();
    let gt_path = f.path("gt.npy");
    f.fails(
        &["--gt", gt_path.to_str().unwrap()],
        &["gt.npy", "5×5", "24×24"],
    );
}

#[test]
fn existing_output_needs_force() {
    let f = Fixture::new();
    let run = |force: bool| {
        let mut cmd = Command::new(BIN);
        cmd.arg("run")
            .arg(f.dir.path())
            .arg("-o")
            .arg(f.out())
            .arg("--quiet");
        if force {
            cmd.arg("--force");
        }
        cmd
    };
    // A folder photostereo did not write is never replaced, even with --force.
    std::fs::create_dir(f.out()).unwrap();
    std::fs::write(f.out().join("keep.txt"), "mine").unwrap();
    expect_failure(run(false), &["already exists", "--force"]);
    expect_failure(
        run(true),
        &["--force refused", "not written by photostereo"],
    );
    assert!(f.out().join("keep.txt").exists());
    // An empty folder, and then a folder photostereo wrote, are replaced with --force.
    std::fs::remove_file(f.out().join("keep.txt")).unwrap();
    assert!(run(true).output().unwrap().status.success());
    assert!(f.out().join("normals.npy").exists() && f.out().join(".photostereo").exists());
    expect_failure(run(false), &["already exists", "--force"]);
    std::fs::write(f.out().join("extra.txt"), "old").unwrap();
    assert!(run(true).output().unwrap().status.success());
    assert!(!f.out().join("extra.txt").exists() && f.out().join("normals.npy").exists());
}

#[test]
fn out_of_range_parameters_are_refused() {
    let f = Fixture::new();
    f.fails(&["--max-iterations", "0"], &["--max-iterations 0"]);
    f.fails(&["--unreliable-weight", "2"], &["--unreliable-weight 2"]);
    f.fails(&["--change-tolerance=-0.5"], &["--change-tolerance -0.5"]);
    f.fails(
        &["--surface-prior", "-1"],
        &["--surface-prior -1", "[0, 90]"],
    );
    f.fails(&["--surface-prior", "nan"], &["--surface-prior NaN"]);
    f.fails(&["--max-slope", "0"], &["--max-slope 0"]);
    f.fails(&["--sigma=-1"], &["--sigma -1"]);
    f.fails(&["--relative-noise=-0.5"], &["--relative-noise -0.5"]);
    f.fails(&["--confidence", "1.5"], &["--confidence 1.5"]);
    f.fails(&["--light-subset", "1,2,99"], &["light index 99"]);
}

#[test]
fn unknown_method_is_a_usage_error() {
    let f = Fixture::new();
    f.fails(&["--method", "magic"], &["unknown method 'magic'"]);
}

/// Runs `cmd`, expects success and returns its stderr.
fn succeeds(mut cmd: Command) -> String {
    let out = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{err}");
    err
}

/// The `report.json` a command wrote into the fixture's output folder.
fn report_of(f: &Fixture) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(f.out().join("report.json")).unwrap()).unwrap()
}

/// Runs `photostereo run <capture> -o out [extra]`, expects success and returns
/// (report.json, stderr).
fn run_json(f: &Fixture, extra: &[&str]) -> (serde_json::Value, String) {
    let mut cmd = Command::new(BIN);
    cmd.arg("run")
        .arg(f.dir.path())
        .arg("-o")
        .arg(f.out())
        .args(extra);
    let err = succeeds(cmd);
    (report_of(f), err)
}

/// Issue 17.4: a capture without `mask.png` is run on the whole frame, and says so on stderr
/// (also with --json), in the report's notes and in `input.whole_frame_mask`.
#[test]
fn missing_mask_is_said() {
    let f = Fixture::new();
    let (with_mask, err) = run_json(&f, &["--quiet"]);
    assert!(!err.contains("no mask"), "{err}");
    assert_eq!(
        with_mask["input"]["whole_frame_mask"],
        serde_json::Value::Null
    );
    assert!(with_mask["input"]["mask_file"]
        .as_str()
        .unwrap()
        .ends_with("mask.png"));
    let masked_pixels = with_mask["input"]["mask_pixels"].as_u64().unwrap();
    assert!(masked_pixels < 24 * 24);

    std::fs::remove_file(f.path("mask.png")).unwrap();
    for mode in ["--json", "--verbose"] {
        let extra: &[&str] = if mode == "--json" {
            &["--json", "--force"]
        } else {
            &["--force"]
        };
        let (report, err) = run_json(&f, extra);
        assert!(
            err.contains("note: no mask: the whole 24×24 frame is used as the object"),
            "{mode}: {err}"
        );
        assert_eq!(report["input"]["whole_frame_mask"], true);
        assert_eq!(report["input"]["mask_pixels"], 24 * 24);
        assert_eq!(report["input"]["mask_file"], serde_json::Value::Null);
        assert!(report["notes"]
            .as_array()
            .unwrap()
            .iter()
            .any(|n| n.as_str().unwrap().starts_with("no mask:")));
    }
}

/// Issue 17.5: the report names the input files (images, mask) in order.
#[test]
fn report_names_the_inputs() {
    let f = Fixture::new();
    let (report, _) = run_json(&f, &["--quiet"]);
    let files: Vec<String> = report["input"]["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .collect();
    let expected: Vec<String> = (1..=4)
        .map(|k| f.path(&format!("{k:03}.png")).display().to_string())
        .collect();
    assert_eq!(files, expected);
    assert_eq!(report["input"]["lights"], 4);
    assert_eq!(report["input"]["channels"], 1);
    assert_eq!(report["input"]["bit_depth"], 16);
}

/// Issue 17.5: `integrate`'s report omits what does not apply to a normal map (channels, bit
/// depth, lights, the light matrix's condition number) instead of writing zeros.
#[test]
fn integrate_report_omits_capture_fields() {
    let f = Fixture::new();
    let size = 16;
    let mut normals = ndarray::Array3::<f32>::zeros((size, size, 3));
    for r in 0..size {
        for c in 0..size {
            normals[[r, c, 0]] = 0.1;
            normals[[r, c, 2]] = 1.0;
        }
    }
    ndarray_npy::write_npy(f.path("n.npy"), &normals).unwrap();
    let mut cmd = Command::new(BIN);
    cmd.arg("integrate")
        .arg(f.path("n.npy"))
        .arg("-o")
        .arg(f.out())
        .arg("--quiet");
    succeeds(cmd);
    let report = report_of(&f);
    let input = report["input"].as_object().unwrap();
    for absent in [
        "channels",
        "bit_depth",
        "lights",
        "light_condition_number",
        "lights_renormalised",
    ] {
        assert!(!input.contains_key(absent), "{absent} in {input:?}");
    }
    assert_eq!(input["width"], size);
    assert_eq!(input["mask_pixels"], size * size);
    assert_eq!(
        input["files"][0].as_str().unwrap(),
        f.path("n.npy").display().to_string()
    );
}

/// Issue 17.6: `eval` names the file and what was expected for an integer array, a folder
/// given as a file, and an error map into a missing folder (not an internal temporary path).
#[test]
fn eval_messages_name_files_and_expectations() {
    let f = Fixture::new();
    let ones = ndarray::Array3::<f32>::from_elem((4, 4, 3), 0.5);
    ndarray_npy::write_npy(f.path("f32.npy"), &ones).unwrap();
    ndarray_npy::write_npy(f.path("i32.npy"), &ndarray::Array3::<i32>::zeros((4, 4, 3))).unwrap();
    let eval = |args: &[PathBuf]| {
        let mut cmd = Command::new(BIN);
        cmd.arg("eval").args(args);
        cmd
    };
    expect_failure(
        eval(&[f.path("i32.npy"), f.path("f32.npy")]),
        &["i32.npy", "int32", "expected", "float32 or float64"],
    );
    std::fs::create_dir(f.path("adir")).unwrap();
    expect_failure(
        eval(&[f.path("adir"), f.path("f32.npy")]),
        &["adir", "not a file"],
    );
    let mut cmd = eval(&[f.path("f32.npy"), f.path("f32.npy")]);
    cmd.arg("--error-map").arg(f.path("missing/map.png"));
    let out = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("missing") && err.contains("does not exist"),
        "{err}"
    );
    assert!(!err.contains("map.png.") && !err.contains("tmp-"), "{err}");
}

/// Issue 17.1: a list file whose count line counts the mask as a photograph (4 announced, 3
/// photographs and the mask follow) is refused, naming the file and both numbers; with the
/// right count the same list runs with the mask.
#[test]
fn list_count_that_swallows_the_mask_is_refused() {
    let f = Fixture::new();
    let lights = f.path("light_directions.txt");
    let run = |list: &str| {
        let mut cmd = Command::new(BIN);
        cmd.arg("run")
            .arg(f.path(list))
            .arg("--lights")
            .arg(&lights)
            .arg("-o")
            .arg(f.out())
            .arg("--quiet");
        cmd
    };
    f.write("bad.txt", "4\n001.png\n002.png\n003.png\nmask.png\n");
    expect_failure(
        run("bad.txt"),
        &[
            "bad.txt",
            "announces 4 images",
            "'mask.png' (line 5), names a mask",
            "3 photograph(s) and a mask",
        ],
    );
    assert!(!f.out().exists());
    f.write(
        "good.txt",
        "4\n001.png\n002.png\n003.png\n004.png\nmask.png\n",
    );
    let out = run("good.txt").output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn memory_limits() {
    let f = Fixture::new();
    // Below the full-frame stages: refused with the smallest budget that works, which works.
    let mut cmd = Command::new(BIN);
    cmd.arg("run")
        .arg(f.dir.path())
        .arg("-o")
        .arg(f.out())
        .args(["--memory-limit", "1M"]);
    let out = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("--memory-limit 1M: too small"), "{err}");
    assert!(!f.out().exists());
    let minimum = err
        .rsplit("smallest budget that works is ")
        .next()
        .unwrap()
        .trim();
    let (report, _) = run_json(&f, &["--quiet", "--memory-limit", minimum]);
    assert!(
        report["memory"]["minimum_budget"].as_u64().unwrap()
            <= report["memory"]["budget"].as_u64().unwrap()
    );
    // The run stays inside the budget it was given (the process's peak resident memory).
    let peak = report["memory"]["peak_rss"].as_u64().unwrap();
    assert!(peak > 0);
    assert!(
        peak <= report["memory"]["budget"].as_u64().unwrap(),
        "{peak}"
    );
    // No spill file is left in the output.
    assert!(!listing(&f.out()).iter().any(|n| n.contains("spill")));
    for bad in ["0", "lots", "3Q"] {
        f.fails(
            &["--memory-limit", bad],
            &["--memory-limit", "expected a size in bytes"],
        );
    }
}
