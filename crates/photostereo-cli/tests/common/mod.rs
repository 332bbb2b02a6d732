//! The small capture the command-line tests share: four grey 16-bit 24×24 images of a
//! Lambertian sphere (radius 10 px) under four lights at 18° from the view axis,
//! `light_directions.txt` and a circular `mask.png` (radius 9 px).

#![allow(dead_code)]

use photostereo::io::imageio::{write_png16, write_png8};
use std::path::Path;

/// The binary under test.
pub const BIN: &str = env!("CARGO_BIN_EXE_photostereo");

/// Runs the binary under test with `args` in the folder `cwd`.
pub fn photostereo(args: &[&str], cwd: &Path) -> std::process::Output {
    std::process::Command::new(BIN)
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("the binary runs")
}
/// Width and height of the images, pixels.
pub const SIZE: usize = 24;
/// The light directions (not unit length; the reader normalises them).
pub const DIRS: [[f64; 3]; 4] = [
    [0.3, 0.3, 0.9],
    [-0.3, 0.3, 0.9],
    [-0.3, -0.3, 0.9],
    [0.3, -0.3, 0.9],
];

/// The sphere lit from `l`, 16-bit: `gain · 50000 · max(0, n·l̂)`, clipped at 65535.
pub fn sphere_image(l: [f64; 3], gain: f64) -> Vec<u16> {
    let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
    let mut data = vec![0u16; SIZE * SIZE];
    for r in 0..SIZE {
        for c in 0..SIZE {
            let x = (c as f64 - 11.5) / 10.0;
            let y = (11.5 - r as f64) / 10.0;
            let rr = x * x + y * y;
            if rr < 1.0 {
                let n = [x, y, (1.0 - rr).sqrt()];
                let s = (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]) / norm;
                data[r * SIZE + c] = (s.max(0.0) * gain * 50000.0).min(65535.0) as u16;
            }
        }
    }
    data
}

/// Writes image `k` (0-based) of the capture in `dir` as `NNN.png`.
pub fn write_image(dir: &Path, k: usize, data: &[u16]) {
    write_png16(&dir.join(format!("{:03}.png", k + 1)), SIZE, SIZE, 1, data).unwrap();
}

/// Writes the whole capture (images `001.png`…, `light_directions.txt`, `mask.png`) into `dir`.
pub fn write_sphere_capture(dir: &Path) {
    for (k, l) in DIRS.iter().enumerate() {
        write_image(dir, k, &sphere_image(*l, 1.0));
    }
    let lights: String = DIRS
        .iter()
        .map(|d| format!("{} {} {}\n", d[0], d[1], d[2]))
        .collect();
    std::fs::write(dir.join("light_directions.txt"), lights).unwrap();
    let mask: Vec<u8> = (0..SIZE * SIZE)
        .map(|i| {
            let (x, y) = ((i % SIZE) as f64 - 11.5, (i / SIZE) as f64 - 11.5);
            if x * x + y * y < 81.0 {
                255
            } else {
                0
            }
        })
        .collect();
    write_png8(&dir.join("mask.png"), SIZE, SIZE, 1, &mask).unwrap();
}

/// The notes of a run's `report.json`.
pub fn report_notes(report: &Path) -> Vec<String> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap();
    v["notes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_str().unwrap().to_string())
        .collect()
}
