//! Bad input: every case gives a clear message naming the file, line or parameter, exit code 2,
//! and writes nothing.

use photostereo::imageio::{write_png16, write_png8};
use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_photostereo");

/// A valid small capture: 4 grey 16-bit images of a Lambertian sphere, lights and a mask.
struct Fixture {
    dir: tempfile::TempDir,
}

const DIRS: [[f64; 3]; 4] = [
    [0.3, 0.3, 0.9],
    [-0.3, 0.3, 0.9],
    [-0.3, -0.3, 0.9],
    [0.3, -0.3, 0.9],
];

impl Fixture {
    fn new() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let f = Fixture { dir };
        let size = 24;
        for (k, l) in DIRS.iter().enumerate() {
            let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
            let mut data = vec![0u16; size * size];
            for r in 0..size {
                for c in 0..size {
                    let x = (c as f64 - 11.5) / 10.0;
                    let y = (11.5 - r as f64) / 10.0;
                    let rr = x * x + y * y;
                    if rr < 1.0 {
                        let n = [x, y, (1.0 - rr).sqrt()];
                        let s = (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]) / norm;
                        data[r * size + c] = (s.max(0.0) * 50000.0) as u16;
                    }
                }
            }
            write_png16(&f.path(&format!("{:03}.png", k + 1)), size, size, 1, &data).unwrap();
        }
        f.write(
            "light_directions.txt",
            &DIRS
                .iter()
                .map(|d| format!("{} {} {}\n", d[0], d[1], d[2]))
                .collect::<String>(),
        );
        let mask: Vec<u8> = (0..size * size)
            .map(|i| {
                let (r, c) = (i / size, i % size);
                let (x, y) = (c as f64 - 11.5, r as f64 - 11.5);
                if x * x + y * y < 81.0 {
                    255
                } else {
                    0
                }
            })
            .collect();
        write_png8(&f.path("mask.png"), size, size, 1, &mask).unwrap();
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
    let out = Command::new(BIN)
        .arg("run")
        .arg(f.dir.path())
        .arg("-o")
        .arg(f.out())
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(f.out().join("normals.npy").exists() && f.out().join("report.json").exists());
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
    let out = Command::new(BIN)
        .arg("run")
        .arg(f.dir.path())
        .args(["-o"])
        .arg(f.out())
        .args(["--quiet", "--memory-limit", minimum])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(f.out().join("report.json")).unwrap())
            .unwrap();
    assert!(
        report["memory"]["minimum_budget"].as_u64().unwrap()
            <= report["memory"]["budget"].as_u64().unwrap()
    );
    assert!(report["memory"]["peak_rss"].as_u64().unwrap() > 0);
    // No spill file is left in the output.
    assert!(!listing(&f.out()).iter().any(|n| n.contains("spill")));
    for bad in ["0", "lots", "3Q"] {
        f.fails(
            &["--memory-limit", bad],
            &["--memory-limit", "expected a size in bytes"],
        );
    }
}
