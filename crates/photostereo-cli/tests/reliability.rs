//! Issue 15, the reliability pass: `--force` never destroys inputs or foreign folders; forged
//! or huge headers are refused before allocating; interrupted runs leave no temporary folder;
//! physically impossible captures are refused and doubtful ones noted; messages name the
//! right file, flag and numbers. Every failing case checks exit code 2, the message's key words,
//! that nothing was written, that no temporary folder is left, and that the inputs are intact.

mod common;

use common::{sphere_image, BIN, DIRS, SIZE};
use photostereo::io::imageio::write_png16;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A temporary folder `root` holding a valid capture in `root/cap`
/// ([`common::write_sphere_capture`]).
struct Fixture {
    dir: tempfile::TempDir,
}

impl Fixture {
    fn new() -> Self {
        let f = Fixture {
            dir: tempfile::tempdir().unwrap(),
        };
        std::fs::create_dir(f.cap()).unwrap();
        common::write_sphere_capture(&f.cap());
        f
    }
    fn root(&self) -> &Path {
        self.dir.path()
    }
    fn cap(&self) -> PathBuf {
        self.path("cap")
    }
    fn path(&self, name: &str) -> PathBuf {
        self.root().join(name)
    }
    fn write(&self, name: &str, text: &str) {
        std::fs::write(self.path(name), text).unwrap();
    }
    fn write_bytes(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let p = self.path(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }
    /// Writes image `k` (0-based) of the capture.
    fn image(&self, k: usize, data: &[u16]) {
        common::write_image(&self.cap(), k, data);
    }
    /// Every file under the root with its content: compared before and after a command.
    fn snapshot(&self) -> BTreeMap<PathBuf, Vec<u8>> {
        let mut out = BTreeMap::new();
        let mut stack = vec![self.root().to_path_buf()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    out.insert(p.clone(), Vec::new());
                    stack.push(p);
                } else {
                    out.insert(p.clone(), std::fs::read(&p).unwrap());
                }
            }
        }
        out
    }
    /// Runs `photostereo ARGS` (paths relative to the root), expects exit 2 with every needle
    /// in the message, and checks that nothing changed under the root.
    fn refuses(&self, args: &[&str], needles: &[&str]) -> String {
        self.refuses_with(args, needles, &[])
    }
    fn refuses_with(&self, args: &[&str], needles: &[&str], env: &[(&str, &str)]) -> String {
        let before = self.snapshot();
        let out = self.cmd(args, env);
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "panic: {err}");
        for n in needles {
            assert!(err.contains(n), "{args:?}: expected '{n}' in: {err}");
        }
        assert_eq!(
            self.snapshot().keys().collect::<Vec<_>>(),
            before.keys().collect::<Vec<_>>(),
            "{args:?} changed the files: {err}"
        );
        assert!(
            self.snapshot() == before,
            "{args:?} changed a file's content"
        );
        assert_no_temporaries(self.root());
        err
    }
    fn cmd(&self, args: &[&str], env: &[(&str, &str)]) -> Output {
        let mut c = Command::new(BIN);
        c.current_dir(self.root()).args(args);
        for (k, v) in env {
            c.env(k, v);
        }
        c.output().unwrap()
    }
    /// Runs a command that must succeed; returns stderr.
    fn succeeds(&self, args: &[&str]) -> String {
        let out = self.cmd(args, &[]);
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{args:?}: {err}");
        assert_no_temporaries(self.root());
        err
    }
    fn notes(&self, report: &str) -> Vec<String> {
        common::report_notes(&self.path(report))
    }
}

/// No `.NAME.tmp-PID` or `.NAME.old-PID` anywhere below `dir`.
fn assert_no_temporaries(dir: &Path) {
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let e = e.unwrap();
            let name = e.file_name().to_string_lossy().to_string();
            assert!(
                !(name.starts_with('.') && (name.contains(".tmp-") || name.contains(".old-"))),
                "temporary left behind: {}",
                e.path().display()
            );
            if e.path().is_dir() {
                stack.push(e.path());
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 1. --force

#[test]
fn force_never_replaces_an_input_or_a_folder_holding_one() {
    let f = Fixture::new();
    // The capture itself, and its parent folder (which holds an unrelated file too).
    f.write("unrelated.txt", "keep me");
    let e = f.refuses(
        &["run", "cap", "-o", "cap", "--force"],
        &["--force refused"],
    );
    assert!(e.contains("input"), "{e}");
    f.refuses(
        &["run", "cap", "-o", ".", "--force"],
        &["--force refused", "holds an input"],
    );
    let parent = f.root().file_name().unwrap().to_string_lossy().to_string();
    f.refuses(
        &["run", "cap", "-o", &format!("../{parent}"), "--force"],
        &["--force refused", "holds an input"],
    );
    // Explicit images, lights from elsewhere, a mask and ground truth: each one protected.
    let args = |out: &str| {
        vec![
            "run".to_string(),
            "cap/001.png".into(),
            "cap/002.png".into(),
            "cap/003.png".into(),
            "cap/004.png".into(),
            "--lights".into(),
            "cap/light_directions.txt".into(),
            "-o".into(),
            out.to_string(),
            "--force".into(),
        ]
    };
    for out in ["cap", "cap/001.png", "cap/light_directions.txt"] {
        let a = args(out);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        f.refuses(&a, &["--force refused"]);
    }
}

#[test]
fn force_replaces_only_folders_photostereo_wrote_or_empty_ones() {
    let f = Fixture::new();
    std::fs::create_dir(f.path("mine")).unwrap();
    f.write("mine/thesis.tex", "years of work");
    f.refuses(
        &["run", "cap", "-o", "mine", "--force"],
        &[
            "mine",
            "--force refused",
            "not written by photostereo",
            ".photostereo",
        ],
    );
    f.write("afile", "x");
    f.refuses(
        &["run", "cap", "-o", "afile", "--force"],
        &["--force refused", "is a file"],
    );
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(f.path("mine"), f.path("link")).unwrap();
        f.refuses(
            &["run", "cap", "-o", "link", "--force"],
            &["--force refused", "symbolic link"],
        );
    }
    // Empty: replaced. Ours (with the marker): replaced, extra content gone.
    std::fs::create_dir(f.path("empty")).unwrap();
    f.succeeds(&["run", "cap", "-o", "empty", "--force", "--quiet"]);
    assert!(f.path("empty/normals.npy").exists() && f.path("empty/.photostereo").exists());
    f.write("empty/stale.txt", "old");
    f.succeeds(&["run", "cap", "-o", "empty", "--force", "--quiet"]);
    assert!(!f.path("empty/stale.txt").exists());
    // integrate's input inside a folder photostereo wrote: that folder is protected.
    f.refuses(
        &["integrate", "empty/normals.npy", "-o", "empty", "--force"],
        &["--force refused", "holds an input"],
    );
    f.refuses(
        &["calibrate", "cap", "-o", "cap", "--force"],
        &["--force refused", "input"],
    );
}

#[test]
fn eval_force_replaces_only_its_own_error_maps_never_an_input() {
    let f = Fixture::new();
    f.succeeds(&["run", "cap", "-o", "out", "--quiet", "--no-depth"]);
    f.refuses(
        &[
            "eval",
            "out/normals.npy",
            "out/normals.png",
            "--error-map",
            "out/normals.png",
            "--force",
        ],
        &["--force refused", "input"],
    );
    f.write_bytes("photo.png", b"\x89PNG\r\n\x1a\nnot ours");
    f.refuses(
        &[
            "eval",
            "out/normals.npy",
            "out/normals.png",
            "--error-map",
            "photo.png",
            "--force",
        ],
        &["photo.png", "--force refused", "did not write"],
    );
    let eval = |force: bool| {
        let mut a = vec![
            "eval",
            "out/normals.npy",
            "out/normals.png",
            "--error-map",
            "err.png",
        ];
        if force {
            a.push("--force");
        }
        f.succeeds(&a);
    };
    eval(false);
    f.refuses(
        &[
            "eval",
            "out/normals.npy",
            "out/normals.png",
            "--error-map",
            "err.png",
        ],
        &["err.png", "already exists"],
    );
    eval(true);
    assert!(f.path("err.png").exists());
}

/// `--force` replaces only what the same command wrote in that place: every subcommand that
/// takes it refuses another command's output (and a folder photostereo never wrote) and
/// replaces its own.
#[test]
fn force_replaces_only_what_the_same_command_wrote() {
    let f = Fixture::new();
    let chrome = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/psmImages/chrome.txt"
    ));
    let chrome = chrome.to_str().unwrap();
    f.succeeds(&["run", "cap", "-o", "run", "--quiet", "--no-depth"]);
    f.succeeds(&[
        "synth", "sphere", "--rig", "ring8", "--size", "32", "-o", "syn", "-q",
    ]);

    // eval --error-map over a photograph photostereo rendered, and over a run's picture.
    for target in ["syn/001.png", "run/normals.png"] {
        f.refuses(
            &[
                "eval",
                "syn/gt/normal.npy",
                "syn/gt/normal.npy",
                "--error-map",
                target,
                "--force",
            ],
            &[target, "--force refused", "error-map"],
        );
    }
    // export-openlime over its own run folder, over a run, and over a folder of the user's.
    f.refuses(
        &["export-openlime", "run", "-o", "run", "--force"],
        &["--force refused", "input"],
    );
    std::fs::create_dir(f.path("site")).unwrap();
    f.write("site/index.html", "<p>mine</p>");
    f.refuses(
        &["export-openlime", "run", "-o", "site", "--force"],
        &["--force refused", "not written by photostereo"],
    );
    f.refuses(
        &["export-openlime", "run", "-o", "syn", "--force"],
        &["--force refused", "synth folder", "openlime folder"],
    );

    // Every folder-writing command over a folder another command wrote.
    let over_run: [&[&str]; 6] = [
        &[
            "synth", "sphere", "--rig", "ring8", "--size", "32", "-o", "run", "--force",
        ],
        &["compare", "cap", "-o", "run", "--force"],
        &["integrate", "syn/gt/normal.npy", "-o", "run", "--force"],
        &["calibrate", chrome, "-o", "run", "--force"],
        &[
            "demo", "--size", "16", "--rig", "square4", "-o", "run", "--force",
        ],
        &["export-openlime", "run2", "-o", "run", "--force"],
    ];
    f.succeeds(&["run", "cap", "-o", "run2", "--quiet", "--no-depth"]);
    for args in over_run {
        f.refuses(args, &["--force refused", "run folder"]);
    }
    f.refuses(
        &["run", "cap", "-o", "syn", "--force"],
        &["--force refused", "synth folder", "run folder"],
    );

    // Each replaces its own.
    let own: [&[&str]; 8] = [
        &["run", "cap", "-o", "run", "--quiet", "--no-depth"],
        &[
            "synth", "sphere", "--rig", "ring8", "--size", "32", "-o", "syn", "-q",
        ],
        &["compare", "cap", "-o", "cmp", "--quiet"],
        &["integrate", "syn/gt/normal.npy", "-o", "depth", "--quiet"],
        &["calibrate", chrome, "-o", "cal", "--quiet"],
        &[
            "demo", "--size", "16", "--rig", "square4", "-o", "dem", "--quiet",
        ],
        &["export-openlime", "run", "-o", "lime", "--quiet"],
        &[
            "eval",
            "syn/gt/normal.npy",
            "syn/gt/normal.npy",
            "--error-map",
            "err.png",
        ],
    ];
    for args in own {
        let out = args[args
            .iter()
            .position(|a| *a == "-o" || *a == "--error-map")
            .unwrap()
            + 1];
        if !f.path(out).exists() {
            f.succeeds(args);
        }
        let mut again = args.to_vec();
        again.push("--force");
        f.succeeds(&again);
    }
}

// ---------------------------------------------------------------------------------------------
// 2. Forged and huge headers

fn png_chunk(kind: &[u8], data: &[u8]) -> Vec<u8> {
    let mut v = (data.len() as u32).to_be_bytes().to_vec();
    v.extend_from_slice(kind);
    v.extend_from_slice(data);
    let crc = crc32(&[kind, data].concat());
    v.extend_from_slice(&crc.to_be_bytes());
    v
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// A PNG whose header declares `w`×`h` 16-bit RGB but holds almost no data.
fn forged_png(w: u32, h: u32) -> Vec<u8> {
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[16, 2, 0, 0, 0]);
    let mut v = b"\x89PNG\r\n\x1a\n".to_vec();
    v.extend(png_chunk(b"IHDR", &ihdr));
    // A valid zlib stream of a few zero bytes.
    v.extend(png_chunk(
        b"IDAT",
        &[0x78, 0x01, 0x63, 0x60, 0x00, 0x00, 0x00, 0x02, 0x00, 0x01],
    ));
    v.extend(png_chunk(b"IEND", &[]));
    v
}

/// A little-endian TIFF declaring `w`×`h` 16-bit grey, one tiny strip.
fn forged_tiff(w: u32, h: u32) -> Vec<u8> {
    let entries: [(u16, u16, u32, u32); 8] = [
        (256, 4, 1, w),  // ImageWidth
        (257, 4, 1, h),  // ImageLength
        (258, 3, 1, 16), // BitsPerSample
        (259, 3, 1, 1),  // Compression: none
        (262, 3, 1, 1),  // Photometric: black is zero
        (273, 4, 1, 8),  // StripOffsets
        (278, 4, 1, h),  // RowsPerStrip
        (279, 4, 1, 4),  // StripByteCounts
    ];
    let mut v = b"II*\0".to_vec();
    v.extend_from_slice(&12u32.to_le_bytes());
    v.extend_from_slice(&[0, 0, 0, 0]);
    v.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for (tag, ty, count, value) in entries {
        v.extend_from_slice(&tag.to_le_bytes());
        v.extend_from_slice(&ty.to_le_bytes());
        v.extend_from_slice(&count.to_le_bytes());
        if ty == 3 {
            v.extend_from_slice(&(value as u16).to_le_bytes());
            v.extend_from_slice(&[0, 0]);
        } else {
            v.extend_from_slice(&value.to_le_bytes());
        }
    }
    v.extend_from_slice(&0u32.to_le_bytes());
    v
}

/// A `.npy` declaring `shape` of float32 with no data.
fn forged_npy(shape: &str) -> Vec<u8> {
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut v = b"\x93NUMPY\x01\x00".to_vec();
    v.extend_from_slice(&(header.len() as u16).to_le_bytes());
    v.extend_from_slice(header.as_bytes());
    v.extend_from_slice(&[0; 16]);
    v
}

/// A MAT-file whose `Normal_gt` declares `dims` but holds no values.
fn forged_mat(dims: [i32; 3]) -> Vec<u8> {
    fn el(ty: u32, payload: &[u8]) -> Vec<u8> {
        let mut v = ty.to_le_bytes().to_vec();
        v.extend_from_slice(&(payload.len() as u32).to_le_bytes());
        v.extend_from_slice(payload);
        while v.len() % 8 != 0 {
            v.push(0);
        }
        v
    }
    let mut body = el(6, &[6, 0, 0, 0, 0, 0, 0, 0]);
    body.extend(el(
        5,
        &dims
            .iter()
            .flat_map(|d| d.to_le_bytes())
            .collect::<Vec<_>>(),
    ));
    body.extend(el(1, b"Normal_gt"));
    body.extend(el(9, &[]));
    let mut out = vec![b' '; 128];
    out[..10].copy_from_slice(b"MATLAB 5.0");
    out[124..128].copy_from_slice(&[0, 1, b'I', b'M']);
    out.extend(el(14, &body));
    out
}

#[test]
fn forged_image_headers_are_refused_before_allocating() {
    let f = Fixture::new();
    let huge = forged_png(100_000, 150_000);
    // An image of the capture, in run and calibrate.
    std::fs::write(f.path("cap/003.png"), &huge).unwrap();
    f.refuses(
        &["run", "cap", "-o", "out"],
        &["003.png", "declares 100000×150000 pixels", "limit"],
    );
    f.refuses(
        &["calibrate", "cap", "-o", "out"],
        &["003.png", "declares 100000×150000"],
    );
    // Below the pixel limit but more than the file can hold.
    std::fs::write(f.path("cap/003.png"), forged_png(30_000, 30_000)).unwrap();
    f.refuses(
        &["run", "cap", "-o", "out"],
        &["003.png", "declares 30000×30000", "forged"],
    );
    std::fs::write(f.path("cap/003.png"), forged_tiff(60_000, 60_000)).unwrap();
    f.refuses(
        &["run", "cap", "-o", "out"],
        &["003.png", "declares 60000×60000"],
    );
    // A mask, in run, integrate and eval.
    let f = Fixture::new();
    f.write_bytes("mask.png", &huge);
    f.refuses(
        &["run", "cap", "--mask", "mask.png", "-o", "out"],
        &["mask.png", "declares 100000×150000"],
    );
    f.succeeds(&["run", "cap", "-o", "good", "--quiet", "--no-depth"]);
    f.refuses(
        &[
            "integrate",
            "good/normals.npy",
            "--mask",
            "mask.png",
            "-o",
            "out",
        ],
        &["mask.png", "declares 100000×150000"],
    );
    f.refuses(
        &[
            "eval",
            "good/normals.npy",
            "good/normals.npy",
            "--mask",
            "mask.png",
        ],
        &["mask.png", "declares 100000×150000"],
    );
    // Normal maps: PNG, .npy and .mat, in integrate, eval and run --gt.
    f.write_bytes("n.png", &huge);
    f.write_bytes("n.npy", &forged_npy("(200000, 300000, 3)"));
    f.write_bytes("n.mat", &forged_mat([200_000, 300_000, 3]));
    for (file, needle) in [
        ("n.png", "declares 100000×150000"),
        ("n.npy", "(200000, 300000, 3)"),
        ("n.mat", "Normal_gt"),
    ] {
        f.refuses(&["integrate", file, "-o", "out"], &[file, needle]);
        f.refuses(&["eval", "good/normals.npy", file], &[file, needle]);
        f.refuses(&["run", "cap", "--gt", file, "-o", "out"], &[file, needle]);
    }
}

#[test]
fn images_beyond_the_memory_budget_are_refused_naming_the_size() {
    let f = Fixture::new();
    f.refuses_with(
        &["run", "cap", "-o", "out"],
        &[
            "001.png",
            "declares 24×24",
            "memory",
            "PHOTOSTEREO_MAX_MEMORY",
        ],
        &[("PHOTOSTEREO_MAX_MEMORY", "1K")],
    );
}

// ---------------------------------------------------------------------------------------------
// 3. Interrupted runs

#[cfg(unix)]
fn interrupt(signal: &str, code: i32) {
    use std::os::unix::process::ExitStatusExt;
    let f = Fixture::new();
    let mut child = Command::new(BIN)
        .current_dir(f.root())
        .args(["demo", "--size", "512", "-o", "out", "--quiet"])
        .spawn()
        .unwrap();
    let staging = f.path(&format!(".out.tmp-{}", child.id()));
    let start = std::time::Instant::now();
    while !staging.exists() {
        assert!(start.elapsed().as_secs() < 30, "no staging folder appeared");
        assert!(child.try_wait().unwrap().is_none(), "demo ended early");
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    let killed = Command::new("kill")
        .args([&format!("-{signal}"), &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let status = child.wait().unwrap();
    assert!(
        status.signal() == Some(code) || status.code() == Some(128 + code),
        "{signal}: {status:?}"
    );
    assert!(!f.path("out").exists());
    assert_no_temporaries(f.root());
}

#[cfg(unix)]
#[test]
fn sigterm_removes_the_temporary_folder() {
    interrupt("TERM", 15);
}

#[cfg(unix)]
#[test]
fn sigint_removes_the_temporary_folder() {
    interrupt("INT", 2);
}

/// The id of a process that has ended.
fn dead_pid() -> u32 {
    let mut c = Command::new("true").spawn().unwrap();
    let pid = c.id();
    c.wait().unwrap();
    pid
}

#[test]
fn stale_temporaries_of_dead_processes_are_removed_foreign_ones_kept() {
    let f = Fixture::new();
    let pid = dead_pid();
    // A staging folder a killed run left (it has the marker), an empty one, a foreign folder
    // that only looks like one, and one of a process that still runs (this test).
    let stale = f.path(&format!(".old-run.tmp-{pid}"));
    std::fs::create_dir(&stale).unwrap();
    std::fs::write(stale.join(".photostereo"), "x").unwrap();
    std::fs::write(stale.join("normals.npy"), "half").unwrap();
    // An empty one just made: kept (its process may be on another machine, about to write).
    let empty = f.path(&format!(".other.tmp-{pid}"));
    std::fs::create_dir(&empty).unwrap();
    let foreign = f.path(&format!(".notes.tmp-{pid}"));
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("notes.txt"), "not ours").unwrap();
    let alive = f.path(&format!(".busy.tmp-{}", std::process::id()));
    std::fs::create_dir(&alive).unwrap();
    std::fs::write(alive.join(".photostereo"), "x").unwrap();
    // A replacement cut short between its two renames: the old output is put back.
    let old = f.path(&format!(".prev.old-{pid}"));
    std::fs::create_dir(&old).unwrap();
    std::fs::write(old.join(".photostereo"), "x").unwrap();
    let out = f.cmd(&["run", "cap", "-o", "out", "--quiet", "--no-depth"], &[]);
    assert!(out.status.success());
    assert!(!stale.exists() && empty.exists());
    assert!(foreign.join("notes.txt").exists() && alive.exists());
    assert!(!old.exists() && f.path("prev/.photostereo").exists());
    std::fs::remove_dir(&empty).unwrap();
}

// ---------------------------------------------------------------------------------------------
// 4. Physically impossible or doubtful captures

fn write_lights(f: &Fixture, name: &str, dirs: &[[f64; 3]]) {
    f.write(
        name,
        &dirs
            .iter()
            .map(|d| format!("{} {} {}\n", d[0], d[1], d[2]))
            .collect::<String>(),
    );
}

#[test]
fn impossible_captures_are_refused() {
    let f = Fixture::new();
    let below: Vec<[f64; 3]> = DIRS.iter().map(|d| [d[0], d[1], -d[2]]).collect();
    write_lights(&f, "below.txt", &below);
    for method in ["l2", "recursive"] {
        f.refuses(
            &[
                "run",
                "cap",
                "--lights",
                "below.txt",
                "--method",
                method,
                "-o",
                "out",
            ],
            &["all 4 lights", "below the horizon", "z ≤ 0"],
        );
    }
    f.write("cap/filenames.txt", "001.png\n002.png\n001.png\n004.png\n");
    f.refuses(
        &["run", "cap", "-o", "out"],
        &["001.png", "listed 2 times", "images 1, 3"],
    );
    f.refuses(
        &[
            "run",
            "cap/001.png",
            "cap/002.png",
            "./cap/001.png",
            "cap/004.png",
            "--lights",
            "cap/light_directions.txt",
            "-o",
            "out",
        ],
        &["listed 2 times"],
    );
    let f = Fixture::new();
    for k in 0..4 {
        f.image(k, &vec![0u16; SIZE * SIZE]);
    }
    f.refuses(
        &["run", "cap", "-o", "out"],
        &["every image is black inside the mask"],
    );
    for k in 0..4 {
        f.image(k, &vec![65535u16; SIZE * SIZE]);
    }
    f.refuses(
        &["run", "cap", "-o", "out"],
        &["every image is saturated inside the mask"],
    );
}

#[test]
fn doubtful_captures_are_noted_in_the_output_and_the_report() {
    let f = Fixture::new();
    // A fifth light duplicating the first, and a sixth below the horizon.
    let mut dirs = DIRS.to_vec();
    dirs.push(DIRS[0]);
    dirs.push([0.2, 0.1, -0.3]);
    write_lights(&f, "cap/light_directions.txt", &dirs);
    f.image(4, &sphere_image(DIRS[0], 1.0));
    f.image(5, &sphere_image([0.2, 0.1, 0.3], 0.8));
    // Image 2 overexposed: most of the mask saturated.
    f.image(1, &sphere_image(DIRS[1], 3.0));
    // A few mask pixels black in every image: no normal there.
    for k in 0..6 {
        let p = f.path(&format!("cap/{:03}.png", k + 1));
        let img = photostereo::io::imageio::read_image(&p).unwrap();
        let mut data: Vec<u16> = img
            .data
            .iter()
            .map(|v| (v * 65535.0).round() as u16)
            .collect();
        for i in [11 * SIZE + 11, 11 * SIZE + 12, 12 * SIZE + 11] {
            data[i] = 0;
        }
        write_png16(&p, SIZE, SIZE, 1, &data).unwrap();
    }
    let err = f.succeeds(&["run", "cap", "-o", "out", "--method", "l2"]);
    let notes = f.notes("out/report.json");
    for needle in [
        "lights 1 and 5",
        "light 6",
        "horizon",
        "saturated inside the mask: image 2",
        "left without a normal",
    ] {
        assert!(err.contains(needle), "'{needle}' not printed: {err}");
        assert!(
            notes.iter().any(|n| n.contains(needle)),
            "'{needle}' not in report.json notes: {notes:?}"
        );
    }
}

#[test]
fn integrate_without_a_valid_normal_is_refused() {
    let f = Fixture::new();
    let write = |name: &str, v: f32| {
        let a = ndarray::Array3::<f32>::from_elem((8, 8, 3), v);
        ndarray_npy::write_npy(f.path(name), &a).unwrap();
    };
    write("nan.npy", f32::NAN);
    write("zero.npy", 0.0);
    let a = ndarray::Array3::<f32>::from_shape_fn(
        (8, 8, 3),
        |(_, _, c)| {
            if c == 2 {
                -1.0
            } else {
                0.0
            }
        },
    );
    ndarray_npy::write_npy(f.path("away.npy"), &a).unwrap();
    f.refuses(
        &["integrate", "nan.npy", "-o", "out"],
        &["nan.npy", "no pixel with a valid normal", "64 invalid"],
    );
    f.refuses(
        &["integrate", "zero.npy", "-o", "out"],
        &["zero.npy", "no pixel with a valid normal"],
    );
    f.refuses(
        &["integrate", "away.npy", "-o", "out"],
        &["no pixel with a valid normal", "64 facing away"],
    );
}

// ---------------------------------------------------------------------------------------------
// 5. Messages

#[test]
fn messages_name_the_right_file_flag_and_numbers() {
    let f = Fixture::new();
    f.refuses(
        &["run", "nowhere", "-o", "out"],
        &["nowhere: no such file or folder"],
    );
    let e = f.refuses(&["run", "nowhere", "-o", "out"], &[]);
    assert!(!e.contains("--lights"), "{e}");
    // Light counts: the directions file is blamed, with both numbers, even when the
    // intensities agree with the images.
    f.write(
        "cap/light_directions.txt",
        "0.3 0.3 0.9\n-0.3 0.3 0.9\n-0.3 -0.3 0.9\n",
    );
    f.write("cap/light_intensities.txt", "1\n1\n1\n1\n");
    let e = f.refuses(
        &["run", "cap", "-o", "out"],
        &[
            "light_directions.txt",
            "3 light direction(s) for 4 image(s)",
        ],
    );
    assert!(!e.contains("light_intensities.txt:"), "{e}");
    // A count line that disagrees with its rows.
    f.write(
        "cap/light_directions.txt",
        "5\n0.3 0.3 0.9\n-0.3 0.3 0.9\n-0.3 -0.3 0.9\n0.3 -0.3 0.9\n",
    );
    let e = f.refuses(
        &["run", "cap", "-o", "out"],
        &["light_directions.txt", "announces 5 rows but 4 follow"],
    );
    assert!(!e.contains("line 1:"), "{e}");
    // A byte-order mark is not part of the first number.
    f.write_bytes(
        "cap/light_directions.txt",
        "\u{feff}0.3 0.3 0.9\n-0.3 0.3 0.9\n-0.3 -0.3 0.9\n0.3 -0.3 0.9\n".as_bytes(),
    );
    f.write_bytes(
        "cap/light_intensities.txt",
        "\u{feff}4\n1\n1\n1\n1\n".as_bytes(),
    );
    f.succeeds(&["run", "cap", "-o", "bom", "--quiet", "--no-depth"]);
    // OS errors once.
    f.write(
        "cap/filenames.txt",
        "001.png\n002.png\nmissing.png\n004.png\n",
    );
    let e = f.refuses(&["run", "cap", "-o", "out"], &["missing.png"]);
    assert_eq!(e.matches("os error").count(), 1, "{e}");
    // Flags, not internal names; out-of-range values refused.
    let f = Fixture::new();
    for (args, needle) in [
        (vec!["--unreliable-weight", "2"], "--unreliable-weight 2"),
        (vec!["--change-tolerance=-0.5"], "--change-tolerance -0.5"),
        (vec!["--error-map-max=-5"], "--error-map-max -5"),
        (vec!["--error-map-max", "NaN"], "--error-map-max NaN"),
    ] {
        let mut a = vec!["run", "cap", "-o", "out"];
        a.extend(args);
        let e = f.refuses(&a, &[needle]);
        assert!(!e.contains("unreliable_weight"), "{e}");
    }
    f.succeeds(&["run", "cap", "-o", "good", "--quiet", "--no-depth"]);
    let e = f.refuses(
        &[
            "integrate",
            "good/normals.npy",
            "--max-slope",
            "0",
            "-o",
            "out",
        ],
        &["--max-slope 0"],
    );
    assert!(!e.contains("max_slope"), "{e}");
    f.refuses(
        &[
            "eval",
            "good/normals.npy",
            "good/normals.npy",
            "--error-map-max=-5",
            "--error-map",
            "e.png",
        ],
        &["--error-map-max -5"],
    );
    // eval names the error map it was asked for, never an internal temporary.
    let e = f.refuses(
        &[
            "eval",
            "good/normals.npy",
            "good/normals.npy",
            "--error-map",
            "no/such/e.png",
        ],
        &["no/such"],
    );
    assert!(!e.contains(".tmp"), "{e}");
}

#[test]
fn nan_normals_are_counted_not_hidden() {
    let f = Fixture::new();
    let mut a = ndarray::Array3::<f32>::zeros((8, 8, 3));
    for r in 0..8 {
        for c in 0..8 {
            a[[r, c, 2]] = 1.0;
        }
    }
    a[[2, 2, 0]] = f32::NAN;
    a[[3, 3, 1]] = f32::INFINITY;
    ndarray_npy::write_npy(f.path("n.npy"), &a).unwrap();
    let out = f.cmd(&["integrate", "n.npy", "-o", "out"], &[]);
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("2 invalid"), "{text}");
    assert!(
        text.contains("2 normal(s) with NaN or infinite components"),
        "{text}"
    );
    let out = f.cmd(&["eval", "n.npy", "n.npy"], &[]);
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(
        text.contains("2 vector(s) with NaN or infinite components"),
        "{text}"
    );
}
