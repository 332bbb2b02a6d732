//! Fuzzing every reader on the stable toolchain, inside the normal test run: valid seed files
//! of each format are mutated deterministically (PCG32 from `photostereo::base::rng`) and fed to the
//! reader. Every outcome must be `Ok` or an `Error`: a panic fails the test (caught with
//! `catch_unwind`, the input saved under the system's temporary folder), and so does any single
//! allocation above [`MAX_ALLOCATION`] (a counting global allocator watches them).
//!
//! `FUZZ_ITERATIONS` (default 10,000 per reader) sets the count; `FUZZ_SECONDS` runs each reader
//! for that long instead; `FUZZ_SEED` changes the sequence; `FUZZ_TRACE=1` prints each case's
//! number and writes its input to `photostereo-fuzz-NAME-current.bin` in the system's temporary
//! folder before reading it (to catch an input that ends the process: a memory cap, a stack
//! overflow). `cargo fuzz` targets for longer,
//! coverage-guided runs live in `fuzz/` (not a workspace member; needs a nightly toolchain).

use photostereo::base::rng::Pcg32;

#[path = "dng/mod.rs"]
mod dng;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io::Cursor;
use std::path::Path;
use std::time::{Duration, Instant};

/// No reader may ask for more than this at once while reading inputs of a few kilobytes.
const MAX_ALLOCATION: usize = 256 << 20;

struct Counting;

thread_local! {
    /// The largest single allocation of this thread since the last reset.
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note_size(size: usize) {
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_size(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note_size(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note_size(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn env_u64(name: &str) -> Option<u64> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

/// Silences the default panic message (the panics are reported by the harness instead).
fn quiet_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if std::thread::current()
                .name()
                .is_some_and(|n| n.starts_with("fuzz_"))
            {
                return;
            }
            default(info)
        }));
    });
}

// ---------------------------------------------------------------------------------------------
// Mutations.

struct Mutator {
    rng: Pcg32,
}

const INTERESTING_U8: [u8; 8] = [0, 1, 0x7f, 0x80, 0xff, 0x10, 0x40, 0xfe];
const INTERESTING_U32: [u32; 10] = [
    0,
    1,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    0xffff,
    0x1_0000,
    100_000,
    1 << 20,
    0x4000_0000,
];

impl Mutator {
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            ((self.rng.next_u32() as u64 * n as u64) >> 32) as usize
        }
    }

    /// One to four byte-level mutations of `seed`, sometimes spliced with `other`.
    fn bytes(&mut self, seed: &[u8], other: &[u8]) -> Vec<u8> {
        let mut v = seed.to_vec();
        for _ in 0..1 + self.below(4) {
            let len = v.len();
            match self.below(9) {
                0 if len > 0 => {
                    let i = self.below(len);
                    v[i] ^= 1 << self.below(8);
                }
                1 if len > 0 => {
                    let i = self.below(len);
                    v[i] = INTERESTING_U8[self.below(INTERESTING_U8.len())];
                }
                2 if len >= 4 => {
                    let i = self.below(len - 3);
                    let x = if self.below(3) == 0 {
                        self.rng.next_u32()
                    } else {
                        INTERESTING_U32[self.below(INTERESTING_U32.len())]
                    };
                    let b = if self.below(2) == 0 {
                        x.to_le_bytes()
                    } else {
                        x.to_be_bytes()
                    };
                    v[i..i + 4].copy_from_slice(&b);
                }
                3 if len > 1 => {
                    let a = self.below(len);
                    let n = 1 + self.below((len - a).min(64));
                    v.drain(a..a + n);
                }
                4 => {
                    let a = self.below(len + 1);
                    let n = 1 + self.below(16);
                    let ins: Vec<u8> = (0..n).map(|_| self.rng.next_u32() as u8).collect();
                    v.splice(a..a, ins);
                }
                5 if len > 1 => {
                    let a = self.below(len);
                    let n = 1 + self.below((len - a).min(256));
                    let chunk = v[a..a + n].to_vec();
                    let at = self.below(len + 1);
                    v.splice(at..at, chunk);
                }
                6 if len > 0 => v.truncate(self.below(len)),
                7 if !other.is_empty() => {
                    let cut = self.below(v.len() + 1);
                    let from = self.below(other.len());
                    v.truncate(cut);
                    v.extend_from_slice(&other[from..]);
                }
                _ if len > 0 => {
                    let i = self.below(len);
                    v[i] = self.rng.next_u32() as u8;
                }
                _ => v.push(self.rng.next_u32() as u8),
            }
        }
        v
    }

    /// Text-level mutations: odd numbers, odd lines, byte-order marks, CRLF, non-UTF-8.
    fn text(&mut self, seed: &str) -> Vec<u8> {
        const TOKENS: [&str; 21] = [
            "nan",
            "inf",
            "-inf",
            "1e309",
            "18446744073709551615",
            "-0",
            "0",
            "-1",
            "4294967296",
            "18446744073709551616",
            "1e-320",
            "0x10",
            "",
            " ",
            "\t",
            "#",
            ",",
            "3",
            "99999999999",
            "\u{feff}",
            "é",
        ];
        let mut lines: Vec<String> = seed.lines().map(str::to_string).collect();
        for _ in 0..1 + self.below(3) {
            let n = lines.len();
            match self.below(8) {
                0 if n > 0 => {
                    let i = self.below(n);
                    let mut toks: Vec<String> =
                        lines[i].split_whitespace().map(str::to_string).collect();
                    let t = TOKENS[self.below(TOKENS.len())].to_string();
                    if toks.is_empty() {
                        toks.push(t);
                    } else {
                        let j = self.below(toks.len());
                        toks[j] = t;
                    }
                    lines[i] = toks.join(" ");
                }
                1 if n > 0 => {
                    lines.remove(self.below(n));
                }
                2 if n > 0 => {
                    let l = lines[self.below(n)].clone();
                    let at = self.below(n + 1);
                    lines.insert(at, l);
                }
                3 => {
                    let at = self.below(n + 1);
                    lines.insert(at, TOKENS[self.below(TOKENS.len())].to_string());
                }
                4 if n > 0 => lines[0] = format!("\u{feff}{}", lines[0]),
                5 if n > 0 => {
                    let i = self.below(n);
                    lines[i] = format!("{} {}", lines[i], lines[i]);
                }
                6 => {
                    let count = self.below(40);
                    lines.insert(0, count.to_string());
                }
                _ => {}
            }
        }
        let sep = if self.below(4) == 0 { "\r\n" } else { "\n" };
        let text = lines.join(sep);
        if self.below(6) == 0 {
            self.bytes(text.as_bytes(), &[])
        } else {
            text.into_bytes()
        }
    }
}

/// Recomputes the CRC of every PNG chunk, so that mutations reach past the checksum test.
fn fix_png_crcs(v: &mut [u8]) {
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
    let mut pos = 8;
    while pos + 12 <= v.len() {
        let len = u32::from_be_bytes([v[pos], v[pos + 1], v[pos + 2], v[pos + 3]]) as usize;
        let Some(end) = (pos + 8).checked_add(len).filter(|&e| e + 4 <= v.len()) else {
            return;
        };
        let crc = crc32(&v[pos + 4..end]);
        v[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        pos = end + 4;
    }
}

// ---------------------------------------------------------------------------------------------
// The harness.

/// Runs `read` on mutations of `seeds` (each input made by `mutate` from a seed and another
/// seed to splice with); panics and oversized allocations fail the test, naming the saved
/// input. `read` returns whether the input was accepted.
fn fuzz<M, R>(name: &'static str, seeds: Vec<Vec<u8>>, mutate: M, read: R)
where
    M: Fn(&mut Mutator, &[u8], &[u8]) -> Vec<u8> + Send + 'static,
    R: Fn(&[u8]) -> bool + std::panic::RefUnwindSafe + Send + 'static,
{
    quiet_panics();
    // A named thread, so that the panic hook stays quiet for the panics caught here.
    let h = std::thread::Builder::new()
        .name(format!("fuzz_{name}"))
        .stack_size(32 << 20)
        .spawn(move || run(name, &seeds, mutate, read))
        .unwrap();
    if let Err(e) = h.join() {
        std::panic::resume_unwind(e);
    }
}

fn run<M, R>(name: &str, seeds: &[Vec<u8>], mutate: M, read: R)
where
    M: Fn(&mut Mutator, &[u8], &[u8]) -> Vec<u8>,
    R: Fn(&[u8]) -> bool + std::panic::RefUnwindSafe,
{
    for (i, s) in seeds.iter().enumerate() {
        assert!(read(s), "{name}: seed {i} is not accepted");
    }
    let iterations = env_u64("FUZZ_ITERATIONS").unwrap_or(10_000);
    let seconds = env_u64("FUZZ_SECONDS");
    let stream = name
        .bytes()
        .fold(0u64, |h, b| h.wrapping_mul(31).wrapping_add(b as u64));
    let mut m = Mutator {
        rng: Pcg32::new(env_u64("FUZZ_SEED").unwrap_or(15), stream),
    };
    let start = Instant::now();
    let (mut done, mut accepted, mut slowest) = (0u64, 0u64, Duration::ZERO);
    let mut failures: Vec<String> = Vec::new();
    let trace = std::env::var_os("FUZZ_TRACE").is_some();
    let current = std::env::temp_dir().join(format!("photostereo-fuzz-{name}-current.bin"));
    loop {
        match seconds {
            Some(s) if start.elapsed().as_secs() >= s => break,
            None if done >= iterations => break,
            _ => {}
        }
        let seed = &seeds[m.below(seeds.len())];
        let other = &seeds[m.below(seeds.len())];
        let input = mutate(&mut m, seed, other);
        if trace {
            let _ = std::fs::write(&current, &input);
            eprintln!("fuzz {name}: case {done}");
        }
        LARGEST.with(|l| l.set(0));
        let t = Instant::now();
        let outcome = std::panic::catch_unwind(|| read(&input));
        slowest = slowest.max(t.elapsed());
        let largest = LARGEST.with(Cell::get);
        let problem = match outcome {
            Err(e) => Some(format!(
                "panic: {}",
                e.downcast_ref::<String>()
                    .cloned()
                    .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default()
            )),
            Ok(_) if largest > MAX_ALLOCATION => Some(format!("allocated {largest} bytes at once")),
            Ok(ok) => {
                accepted += u64::from(ok);
                None
            }
        };
        if let Some(p) = problem {
            let path = std::env::temp_dir().join(format!("photostereo-fuzz-{name}-{done}.bin"));
            let _ = std::fs::write(&path, &input);
            failures.push(format!("{p} (input saved as {})", path.display()));
        }
        done += 1;
    }
    eprintln!(
        "fuzz {name}: {done} inputs in {:.2} s, {accepted} accepted, slowest {:.1} ms, {} failure(s)",
        start.elapsed().as_secs_f64(),
        slowest.as_secs_f64() * 1e3,
        failures.len()
    );
    if !failures.is_empty() {
        // Printed here: the panic hook keeps this thread's panics quiet.
        eprintln!(
            "fuzz {name} failures:\n{}",
            failures[..failures.len().min(20)].join("\n")
        );
    }
    assert!(
        failures.is_empty(),
        "fuzz {name}: {} failure(s)",
        failures.len()
    );
}

fn byte_mutations(m: &mut Mutator, seed: &[u8], other: &[u8]) -> Vec<u8> {
    m.bytes(seed, other)
}

fn text_mutations(m: &mut Mutator, seed: &[u8], _other: &[u8]) -> Vec<u8> {
    m.text(std::str::from_utf8(seed).unwrap_or(""))
}

// ---------------------------------------------------------------------------------------------
// Seeds.

fn png_seed(w: u32, h: u32, color: png::ColorType, depth: png::BitDepth) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(color);
        enc.set_depth(depth);
        if color == png::ColorType::Indexed {
            enc.set_palette(vec![0u8, 0, 0, 255, 0, 0, 0, 255, 0, 0, 0, 255]);
        }
        let mut writer = enc.write_header().unwrap();
        let samples = match color {
            png::ColorType::Grayscale | png::ColorType::Indexed => 1,
            png::ColorType::GrayscaleAlpha => 2,
            png::ColorType::Rgb => 3,
            png::ColorType::Rgba => 4,
        };
        let bits = samples * depth as usize;
        let row = (w as usize * bits).div_ceil(8);
        let data: Vec<u8> = (0..row * h as usize)
            .map(|i| {
                if color == png::ColorType::Indexed {
                    (i % 3) as u8
                } else {
                    (i * 37 % 251) as u8
                }
            })
            .collect();
        writer.write_image_data(&data).unwrap();
    }
    out
}

fn png_seeds() -> Vec<Vec<u8>> {
    use png::{BitDepth::*, ColorType::*};
    vec![
        png_seed(9, 7, Grayscale, Eight),
        png_seed(6, 5, Rgb, Sixteen),
        png_seed(8, 8, Rgba, Eight),
        png_seed(5, 4, GrayscaleAlpha, Sixteen),
        png_seed(7, 3, Indexed, Two),
        png_seed(16, 2, Grayscale, One),
    ]
}

fn tiff_seeds() -> Vec<Vec<u8>> {
    use tiff::encoder::{colortype, compression::DeflateLevel, Compression, TiffEncoder};
    let mut seeds = Vec::new();
    for compression in [
        Compression::Uncompressed,
        Compression::Lzw,
        Compression::Deflate(DeflateLevel::Fast),
        Compression::Packbits,
    ] {
        let mut buf = Cursor::new(Vec::new());
        {
            let mut enc = TiffEncoder::new(&mut buf)
                .unwrap()
                .with_compression(compression);
            let g8: Vec<u8> = (0..6 * 5).map(|i| (i * 7) as u8).collect();
            enc.write_image::<colortype::Gray8>(6, 5, &g8).unwrap();
        }
        seeds.push(buf.into_inner());
    }
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let v: Vec<u16> = (0..4 * 3 * 3).map(|i| (i * 1000) as u16).collect();
        enc.write_image::<colortype::RGB16>(4, 3, &v).unwrap();
    }
    seeds.push(buf.into_inner());
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let v: Vec<f32> = (0..5 * 4).map(|i| i as f32 * 0.1).collect();
        enc.write_image::<colortype::Gray32Float>(5, 4, &v).unwrap();
    }
    seeds.push(buf.into_inner());
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let v: Vec<u8> = (0..3 * 3 * 4).map(|i| i as u8).collect();
        enc.write_image::<colortype::RGBA8>(3, 3, &v).unwrap();
    }
    seeds.push(buf.into_inner());
    seeds
}

fn exr_seeds() -> Vec<Vec<u8>> {
    use exr::prelude::*;
    let mut seeds = Vec::new();
    for (k, compression) in [
        Compression::Uncompressed,
        Compression::RLE,
        Compression::ZIP1,
        Compression::ZIP16,
        Compression::PIZ,
        Compression::PXR24,
        Compression::B44,
    ]
    .into_iter()
    .enumerate()
    {
        let (w, h) = (6 + k, 5);
        let plane =
            |c: usize| -> Vec<f32> { (0..w * h).map(|i| (i * (c + 1)) as f32 * 0.01).collect() };
        let channels = if k % 2 == 0 {
            SmallVec::from_vec(vec![
                AnyChannel::new("B", FlatSamples::F32(plane(2))),
                AnyChannel::new("G", FlatSamples::F32(plane(1))),
                AnyChannel::new("R", FlatSamples::F32(plane(0))),
            ])
        } else {
            SmallVec::from_vec(vec![
                AnyChannel::new(
                    "A",
                    FlatSamples::F16(plane(3).into_iter().map(f16::from_f32).collect()),
                ),
                AnyChannel::new(
                    "B",
                    FlatSamples::F16(plane(2).into_iter().map(f16::from_f32).collect()),
                ),
                AnyChannel::new(
                    "G",
                    FlatSamples::F16(plane(1).into_iter().map(f16::from_f32).collect()),
                ),
                AnyChannel::new(
                    "R",
                    FlatSamples::F16(plane(0).into_iter().map(f16::from_f32).collect()),
                ),
            ])
        };
        let layer = Layer::new(
            (w, h),
            LayerAttributes::named("main"),
            Encoding {
                compression,
                ..Encoding::default()
            },
            AnyChannels::sort(channels),
        );
        let mut buf = Cursor::new(Vec::new());
        Image::from_layer(layer)
            .write()
            .to_buffered(&mut buf)
            .unwrap();
        seeds.push(buf.into_inner());
    }
    seeds
}

fn npy_seeds() -> Vec<Vec<u8>> {
    use ndarray_npy::WriteNpyExt;
    let mut seeds = Vec::new();
    let a = ndarray::Array3::<f32>::from_shape_fn((3, 4, 3), |(r, c, k)| (r + c + k) as f32 * 0.1);
    let mut v = Vec::new();
    a.write_npy(&mut v).unwrap();
    seeds.push(v);
    let b = ndarray::Array3::<f64>::from_shape_fn((2, 5, 3), |(r, c, k)| (r * c + k) as f64 - 1.0);
    let mut v = Vec::new();
    b.write_npy(&mut v).unwrap();
    seeds.push(v);
    let mut v = Vec::new();
    a.t().write_npy(&mut v).unwrap(); // Fortran order
    seeds.push(v);
    seeds
}

fn mat_seed(name: &str, dims: &[i32], data: &[f64], compress: bool) -> Vec<u8> {
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
    body.extend(el(1, name.as_bytes()));
    body.extend(el(
        9,
        &data
            .iter()
            .flat_map(|d| d.to_le_bytes())
            .collect::<Vec<_>>(),
    ));
    let matrix = el(14, &body);
    let mut out = vec![b' '; 128];
    out[..10].copy_from_slice(b"MATLAB 5.0");
    out[124..128].copy_from_slice(&[0, 1, b'I', b'M']);
    if compress {
        use std::io::Write;
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(&matrix).unwrap();
        let c = z.finish().unwrap();
        out.extend_from_slice(&15u32.to_le_bytes());
        out.extend_from_slice(&(c.len() as u32).to_le_bytes());
        out.extend(c);
    } else {
        out.extend(matrix);
    }
    out
}

fn mat_seeds() -> Vec<Vec<u8>> {
    let data: Vec<f64> = (0..2 * 3 * 3).map(|i| i as f64 * 0.1).collect();
    vec![
        mat_seed("Normal_gt", &[2, 3, 3], &data, false),
        mat_seed("Normal_gt", &[2, 3, 3], &data, true),
        mat_seed("x", &[3, 6], &data, true),
    ]
}

/// A folder with three small images and a mask, for the list-file seeds to name.
fn list_folder() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("obj");
    std::fs::create_dir(&sub).unwrap();
    for name in ["a.png", "b.png", "c.png", "mask.png"] {
        photostereo::io::imageio::write_png8(&sub.join(name), 2, 2, 1, &[1, 2, 3, 4]).unwrap();
    }
    dir
}

/// Text as the text readers see it: the bytes' byte-order mark removed, UTF-8 checked.
fn text(bytes: &[u8]) -> Option<String> {
    photostereo::io::limits::text_from_bytes(bytes).ok()
}

// ---------------------------------------------------------------------------------------------
// One test per reader.

/// Inputs the long runs found (saved under tests/fuzz_regressions): each must give an error,
/// without a panic and without a large allocation.
#[test]
fn fuzz_regressions() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_regressions");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert!(!files.is_empty());
    for f in files {
        let bytes = std::fs::read(&f).unwrap();
        LARGEST.with(|l| l.set(0));
        let r = std::panic::catch_unwind(|| photostereo::io::imageio::decode_image(&bytes).is_ok());
        assert!(matches!(r, Ok(false)), "{}: {r:?}", f.display());
        let largest = LARGEST.with(Cell::get);
        assert!(
            largest < 16 << 20,
            "{}: allocated {largest} bytes",
            f.display()
        );
    }
}

fn decode(bytes: &[u8]) -> bool {
    photostereo::io::imageio::decode_image(bytes).is_ok()
}

#[test]
fn fuzz_png() {
    fuzz(
        "png",
        png_seeds(),
        |m, seed, other| {
            let mut v = m.bytes(seed, other);
            if m.below(2) == 0 {
                fix_png_crcs(&mut v);
            }
            v
        },
        decode,
    );
}

#[test]
fn fuzz_tiff() {
    fuzz("tiff", tiff_seeds(), byte_mutations, decode);
}

/// The libjpeg-turbo fixtures of `tests/data/jpeg` (baseline, progressive, grey), one with an
/// EXIF block (orientation 6 and exposure) written by the crate's own encoder.
fn jpeg_seeds() -> Vec<Vec<u8>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/jpeg");
    let mut seeds: Vec<Vec<u8>> = ["baseline.jpg", "progressive.jpg", "grey.jpg"]
        .iter()
        .map(|n| std::fs::read(dir.join(n)).unwrap())
        .collect();
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("exif.jpg");
    let exif = photostereo::io::camera::exif_block_oriented(
        &photostereo::io::photometry::Exposure {
            time_s: Some(0.01),
            iso: Some(200.0),
            f_number: Some(4.0),
        },
        6,
    );
    let px: Vec<u8> = (0..12 * 8 * 3).map(|i| (i * 7 % 256) as u8).collect();
    photostereo::io::camera::write_jpeg(&p, 12, 8, 3, &px, 80, exif).unwrap();
    seeds.push(std::fs::read(&p).unwrap());
    seeds
}

#[test]
fn fuzz_jpeg() {
    fuzz("jpeg", jpeg_seeds(), byte_mutations, |b| {
        let meta = photostereo::io::photometry::meta::read_meta(b).is_ok();
        decode(b) || meta
    });
}

/// DNG mosaics written from the specification (tests/dng): three Bayer phases, per-site black
/// levels.
fn raw_seeds() -> Vec<Vec<u8>> {
    let rgb: Vec<f32> = (0..5 * 4 * 3).map(|i| (i % 7) as f32 / 7.0).collect();
    [[0, 1, 1, 2], [1, 0, 2, 1], [2, 1, 1, 0]]
        .iter()
        .enumerate()
        .map(|(k, cfa)| {
            let black = [64 * k as u16, 64, 70, 80];
            dng::mosaic(5, 4, &rgb, *cfa, black, 4095).bytes()
        })
        .collect()
}

#[test]
fn fuzz_raw() {
    fuzz("raw", raw_seeds(), byte_mutations, |b| {
        let meta = photostereo::io::photometry::meta::read_meta(b).is_ok();
        decode(b) || meta
    });
}

#[test]
fn fuzz_exr() {
    fuzz("exr", exr_seeds(), byte_mutations, decode);
}

#[test]
fn fuzz_npy() {
    fuzz("npy", npy_seeds(), byte_mutations, |b| {
        photostereo::io::groundtruth::decode_npy(b).is_ok()
    });
}

#[test]
fn fuzz_mat() {
    fuzz("mat", mat_seeds(), byte_mutations, |b| {
        photostereo::io::matfile::parse_mat(b, None).is_ok()
    });
}

#[test]
fn fuzz_list_file() {
    let dir = list_folder();
    let root = dir.keep();
    let seeds = vec![
        b"3
obj/a.png
obj/b.png
obj/c.png
obj/mask.png
"
        .to_vec(),
        b"# images
3
a.png
b.png
c.png
"
        .to_vec(),
    ];
    let list = root.join("obj").join("list.txt");
    fuzz("list_file", seeds, text_mutations, move |b| {
        text(b).is_some_and(|t| photostereo::io::layouts::parse_list_file(&t, &list).is_ok())
    });
    let _ = std::fs::remove_dir_all(root);
}

#[test]
fn fuzz_light_file() {
    let seeds = vec![
        b"0.3 0.3 0.9
-0.3 0.3 0.9
-0.3 -0.3 0.9
0.3 -0.3 0.9
"
        .to_vec(),
        b"3
0 0 1
1, 0, 1
0 1 1
"
        .to_vec(),
        b"# x y z
0.1 0.2 0.97

-0.5 0.1 0.86
0.4 -0.4 0.8
"
        .to_vec(),
    ];
    fuzz("light_file", seeds, text_mutations, |b| {
        text(b).is_some_and(|t| {
            photostereo::io::light_files::parse_directions(&t, Path::new("lights.txt"))
                .and_then(|l| l.check_rank())
                .is_ok()
        })
    });
}

#[test]
fn fuzz_intensity_file() {
    let seeds = vec![
        b"1 1 1
0.9 1.1 1
1 1 0.8
1.2 1 1
"
        .to_vec(),
        b"4
1
2
0.5
1
"
        .to_vec(),
        b"1
1
1
1
"
        .to_vec(),
    ];
    let lights = photostereo::Lights::new(&[
        [0.3, 0.3, 0.9],
        [-0.3, 0.3, 0.9],
        [-0.3, -0.3, 0.9],
        [0.3, -0.3, 0.9],
    ])
    .unwrap();
    fuzz("intensity_file", seeds, text_mutations, move |b| {
        text(b).is_some_and(|t| {
            photostereo::io::light_files::parse_intensity_rows(
                &t,
                Path::new("intensities.txt"),
                Some(4),
            )
            .and_then(|rows| lights.clone().with_intensities(rows))
            .is_ok()
        })
    });
}

#[test]
fn fuzz_lp_file() {
    let seeds = vec![
        b"3
a.png 0 0 1
b.png 0.5 0 0.86
c.png 0 0.5 0.86
"
        .to_vec(),
        b"# RTI
4
img1.jpg -0.3 0.3 0.9
img2.jpg 0.3 0.3 0.9
img3.jpg 0.3 -0.3 0.9
img4.jpg -0.3 -0.3 0.9
"
        .to_vec(),
    ];
    fuzz("lp_file", seeds, text_mutations, |b| {
        text(b).is_some_and(|t| {
            photostereo::io::layouts::near::parse_lp(&t, Path::new("capture.lp"))
                .and_then(|(_, l)| l.check_rank())
                .is_ok()
        })
    });
}

#[test]
fn fuzz_near_layout() {
    // The positions file mutated; K and the distance fixed (each is fuzzed by its own seed
    // set below through the same parser).
    let k = "768 0 127.5\n0 768 127.5\n0 0 1\n";
    let names = [
        Path::new("K.txt"),
        Path::new("light_positions.txt"),
        Path::new("light_axes.txt"),
        Path::new("light_anisotropy.txt"),
        Path::new("light_intensities.txt"),
        Path::new("mean_distance.txt"),
    ];
    let seeds = vec![
        b"75 0 0
0 75 0
-75 0 0
0 -75 0
"
        .to_vec(),
        b"210 210 0
-210 210 0
-210 -210 0
210 -210 -10
"
        .to_vec(),
    ];
    fuzz("near_positions", seeds, text_mutations, move |b| {
        text(b).is_some_and(|t| {
            photostereo::io::layouts::near::parse_near_layout(
                Some(k),
                &t,
                None,
                None,
                None,
                Some("300\n"),
                None,
                names,
            )
            .and_then(|l| l.lights(names[1]))
            .is_ok()
        })
    });
    let seeds = vec![
        b"768 0 127.5\n0 768 127.5\n0 0 1\n".to_vec(),
        b"3772.08 0 305.875\n0 3759.01 255.125\n0 0 1\n".to_vec(),
    ];
    fuzz("camera_file", seeds, text_mutations, move |b| {
        text(b).is_some_and(|t| photostereo::io::layouts::near::parse_camera(&t, names[0]).is_ok())
    });
}
