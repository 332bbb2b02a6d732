//! Writing integrated surfaces (CONVENTIONS.md, "The output folder of a run"): `depth.npy`,
//! `depth.exr`, `depth.png`, `mesh.ply`, `mesh.obj`, the integrability map `curl.npy` and, from a
//! discontinuity-preserving integrator, the discontinuity map `discontinuities.npy`/`.png`.
//!
//! Mesh frame: one vertex per pixel with a finite depth, at x = col, y = −row, z = depth (pixel
//! units; x right, y up, z toward the camera), with the pixel's unit normal. Triangles join
//! 4-neighbouring pixels: two per 2×2 block of valid pixels, one when exactly three are valid,
//! wound counter-clockwise seen from the camera (+z).

use crate::base::error::{Error, Result};
use crate::geometry::integrate::Surface;
use crate::io::export::write_npy_f32;
use crate::io::imageio::{write_exr_grey, write_png16_rows, write_png8};
use crate::model::lightmodel::Camera;
use std::io::Write;
use std::path::Path;

/// Writes `depth.npy` (float32 (H, W), NaN outside), `depth.exr` and `depth.png` (16-bit grey,
/// the finite depths' min..max mapped to 0..65535, 0 elsewhere) into `dir`.
pub fn write_depth(dir: &Path, width: usize, height: usize, depth: &[f32]) -> Result<()> {
    if depth.len() != width * height {
        return Err(Error::invalid(format!(
            "depth map has {} values: expected {width}×{height}",
            depth.len()
        )));
    }
    // The three files are independent: written side by side.
    let (npy, (exr, png)) = rayon::join(
        || write_npy_f32(&dir.join("depth.npy"), &[height, width], depth),
        || {
            rayon::join(
                || write_exr_grey(&dir.join("depth.exr"), width, height, depth),
                || write_depth_png(&dir.join("depth.png"), width, height, depth),
            )
        },
    );
    npy.and(exr).and(png)
}

/// Writes the discontinuity map of a discontinuity-preserving integrator:
/// `discontinuities.npy` (float32 (H, W), 0 continuous … 1 a jump, NaN outside) and
/// `discontinuities.png` (8-bit grey, 0..1 → 0..255, 0 outside).
pub fn write_discontinuities(dir: &Path, width: usize, height: usize, jumps: &[f32]) -> Result<()> {
    use rayon::prelude::*;
    let grey: Vec<u8> = jumps
        .par_iter()
        .map(|&v| {
            if v.is_finite() {
                (v.clamp(0.0, 1.0) * 255.0).round() as u8
            } else {
                0
            }
        })
        .collect();
    let (npy, png) = rayon::join(
        || write_npy_f32(&dir.join("discontinuities.npy"), &[height, width], jumps),
        || write_png8(&dir.join("discontinuities.png"), width, height, 1, &grey),
    );
    npy.and(png)
}

/// `depth.png`: 16-bit grey, the finite depths' min..max mapped to 0..65535, 0 elsewhere.
fn write_depth_png(path: &Path, width: usize, height: usize, depth: &[f32]) -> Result<()> {
    use rayon::prelude::*;
    let (lo, hi) = depth
        .par_iter()
        .filter(|v| v.is_finite())
        .fold(
            || (f32::INFINITY, f32::NEG_INFINITY),
            |(a, b), &v| (a.min(v), b.max(v)),
        )
        .reduce(
            || (f32::INFINITY, f32::NEG_INFINITY),
            |x, y| (x.0.min(y.0), x.1.max(y.1)),
        );
    let span = if hi > lo { hi - lo } else { 1.0 };
    write_png16_rows(path, width, height, 1, |r, out| {
        for (o, &v) in out.iter_mut().zip(&depth[r * width..(r + 1) * width]) {
            *o = if v.is_finite() {
                (((v - lo) / span).clamp(0.0, 1.0) * 65535.0).round() as u16
            } else {
                0
            };
        }
    })
}

/// Vertex numbering and triangles of a depth map's mesh.
struct Mesh {
    /// Vertex index per pixel (`u32::MAX` for none).
    index: Vec<u32>,
    vertices: usize,
    faces: usize,
}

impl Mesh {
    fn new(width: usize, height: usize, depth: &[f32]) -> Result<Mesh> {
        let mut index = vec![u32::MAX; width * height];
        let mut vertices = 0usize;
        for (i, v) in depth.iter().enumerate() {
            if v.is_finite() {
                index[i] = u32::try_from(vertices)
                    .map_err(|_| Error::invalid("mesh: more than 2³² vertices"))?;
                vertices += 1;
            }
        }
        let mut mesh = Mesh {
            index,
            vertices,
            faces: 0,
        };
        let mut faces = 0;
        mesh.for_each_face(width, height, |_| faces += 1);
        mesh.faces = faces;
        Ok(mesh)
    }

    /// Calls `f` with each triangle's vertex indices (counter-clockwise from +z).
    fn for_each_face(&self, width: usize, height: usize, f: impl FnMut([u32; 3])) {
        self.for_each_face_in_rows(width, 0..height.saturating_sub(1), f);
    }

    /// [`Mesh::for_each_face`] for the 2×2 blocks whose top row is in `rows`.
    fn for_each_face_in_rows(
        &self,
        width: usize,
        rows: std::ops::Range<usize>,
        mut f: impl FnMut([u32; 3]),
    ) {
        for r in rows {
            self.for_each_face_in_row(width, r, |t| {
                f(t.map(|(c, below)| self.index[(r + usize::from(below)) * width + c]))
            });
        }
    }

    /// The triangles of the 2×2 blocks whose top row is `r` (counter-clockwise from +z), each
    /// corner as (column, whether it is in row `r + 1`).
    #[inline]
    fn for_each_face_in_row(&self, width: usize, r: usize, mut f: impl FnMut([(usize, bool); 3])) {
        let none = u32::MAX;
        for c in 0..width.saturating_sub(1) {
            let i = r * width + c;
            let valid = (
                self.index[i] != none,
                self.index[i + 1] != none,
                self.index[i + width] != none,
                self.index[i + width + 1] != none,
            );
            // a = (r, c), b = (r, c+1), cc = (r+1, c), d = (r+1, c+1).
            let (a, b, cc, d) = ((c, false), (c + 1, false), (c, true), (c + 1, true));
            match valid {
                (true, true, true, true) => {
                    f([a, cc, b]);
                    f([b, cc, d]);
                }
                (true, true, true, false) => f([a, cc, b]),
                (true, true, false, true) => f([a, d, b]),
                (true, false, true, true) => f([a, cc, d]),
                (false, true, true, true) => f([b, cc, d]),
                _ => {}
            }
        }
    }
}

fn check_lengths(width: usize, height: usize, depth: &[f32], normals: &[[f32; 3]]) -> Result<()> {
    let n = width * height;
    if depth.len() != n || normals.len() != n {
        return Err(Error::invalid(format!(
            "mesh: depth has {} values and normals {}: expected {width}×{height} = {n} each",
            depth.len(),
            normals.len()
        )));
    }
    Ok(())
}

/// Checks the inputs of a mesh writer, builds the mesh's indexing and creates the file.
fn start_mesh(
    path: &Path,
    width: usize,
    height: usize,
    depth: &[f32],
    normals: &[[f32; 3]],
) -> Result<(Mesh, Sink)> {
    check_lengths(width, height, depth, normals)?;
    let mesh = Mesh::new(width, height, depth)?;
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    Ok((mesh, Sink { file, offset: 0 }))
}

/// The most rows per band of the mesh writers: bands are formatted in parallel, a few at a
/// time, and written in order, so a writer holds a few bands of text, never the whole file.
const BAND_ROWS: usize = 32;

/// The bytes a mesh writer's bands hold together at most (both groups, formatted and being
/// written), whatever the thread count: wide frames get fewer rows per band and fewer bands
/// per group, so the memory plan's writing figure holds on a machine with many cores.
const BAND_BUFFER_BYTES: usize = 32 << 20;

/// A file written front to back by positioned writes. [`Sink::banded`] formats groups of
/// bands in parallel while the previous group is being written (buffered writes into one file
/// serialise on its inode, so one writer at a time), reusing the bands' buffers.
struct Sink {
    file: std::fs::File,
    /// Bytes written so far (the next write's offset).
    offset: u64,
}

impl Write for Sink {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        use std::os::unix::fs::FileExt;
        self.file.write_all_at(bytes, self.offset)?;
        self.offset += bytes.len() as u64;
        Ok(bytes.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Sink {
    /// Writes the bytes that `band(rows, buffer)` puts at the start of `buffer` for each band
    /// of `rows` (bands of at most [`BAND_ROWS`]), in order; `band` returns how many. Groups of
    /// up to two bands per worker thread are formatted in parallel while the previous group is
    /// written; band and group sizes keep the buffers within [`BAND_BUFFER_BYTES`] when
    /// `bytes_per_row` is right. A buffer keeps its length from band to band (what is beyond
    /// the returned count is stale), so its bytes are zeroed once, not per band.
    fn banded(
        &mut self,
        rows: usize,
        bytes_per_row: usize,
        band: impl Fn(std::ops::Range<usize>, &mut Vec<u8>) -> usize + Sync,
    ) -> std::io::Result<()> {
        use rayon::prelude::*;
        let threads = rayon::current_num_threads().max(1);
        let row_bytes = bytes_per_row.max(1);
        let band_rows = (BAND_BUFFER_BYTES / (4 * threads * row_bytes)).clamp(1, BAND_ROWS);
        let batch = (BAND_BUFFER_BYTES / (2 * band_rows * row_bytes)).clamp(1, 2 * threads);
        let starts: Vec<usize> = (0..rows).step_by(band_rows).collect();
        let mut pending: Vec<(Vec<u8>, usize)> = (0..batch).map(|_| (Vec::new(), 0)).collect();
        let mut spare: Vec<(Vec<u8>, usize)> = (0..batch).map(|_| (Vec::new(), 0)).collect();
        let mut pending_len = 0;
        for group in starts.chunks(batch) {
            let (written, ()) = rayon::join(
                || {
                    pending[..pending_len]
                        .iter()
                        .try_for_each(|(b, n)| self.write_all(&b[..*n]))
                },
                || {
                    spare[..group.len()]
                        .par_iter_mut()
                        .zip(group)
                        .for_each(|((buf, n), &r0)| {
                            let r1 = (r0 + band_rows).min(rows);
                            buf.reserve(((r1 - r0) * bytes_per_row).saturating_sub(buf.len()));
                            *n = band(r0..r1, buf);
                        })
                },
            );
            written?;
            std::mem::swap(&mut pending, &mut spare);
            pending_len = group.len();
        }
        pending[..pending_len]
            .iter()
            .try_for_each(|(b, n)| self.write_all(&b[..*n]))
    }
}

/// A band's text written from the start of its byte buffer at a cursor, mostly by fixed-size
/// copies (no call per piece): [`Text::room`] makes sure of space for the next pieces (the
/// buffer is grown, never shrunk, and bytes past the cursor are stale).
struct Text<'a> {
    buf: &'a mut Vec<u8>,
    pos: usize,
}

/// Room for the text of one f32 in the shortest round-trip form (`zmij`'s buffer), bytes.
const F32_TEXT: usize = 24;

impl<'a> Text<'a> {
    fn new(buf: &'a mut Vec<u8>) -> Text<'a> {
        Text { buf, pos: 0 }
    }

    /// Makes room for at least `n` more bytes after the cursor.
    #[inline]
    fn room(&mut self, n: usize) {
        if self.buf.len() < self.pos + n {
            self.buf.resize(self.pos + n, 0);
        }
    }

    /// Writes all `N` bytes of `bytes` and moves the cursor by `len` (≤ `N`): the rest is
    /// overwritten by what follows.
    #[inline]
    fn put<const N: usize>(&mut self, bytes: &[u8; N], len: usize) {
        self.buf[self.pos..self.pos + N].copy_from_slice(bytes);
        self.pos += len;
    }

    #[inline]
    fn byte(&mut self, b: u8) {
        self.buf[self.pos] = b;
        self.pos += 1;
    }

    /// An f32 as the shortest decimal that reads back as the same value.
    #[inline]
    fn f32(&mut self, v: f32) {
        let mut digits = zmij::Buffer::new();
        let s = digits.format(v).as_bytes();
        self.buf[self.pos..self.pos + s.len()].copy_from_slice(s);
        self.pos += s.len();
    }

    /// `v` with six decimals (within 5e-7 of it) where |v| < 9.9999995, else as
    /// [`Text::f32`]: for the components of unit normals.
    #[inline]
    fn fixed6(&mut self, v: f32) {
        // Rounded half up by truncation (non-negative here; no libm call).
        let scaled = f64::from(v).abs() * 1e6 + 0.5;
        if scaled.is_nan() || scaled >= 1e7 {
            return self.f32(v);
        }
        let mut a = scaled as u32;
        let mut t = [0u8; 16];
        let k = usize::from(v < 0.0 && a != 0);
        t[0] = b'-';
        for j in (0..6).rev() {
            t[k + 2 + j] = b'0' + (a % 10) as u8;
            a /= 10;
        }
        t[k] = b'0' + a as u8;
        t[k + 1] = b'.';
        self.put(&t, k + 8);
    }

    /// The number of bytes written.
    fn finish(self) -> usize {
        self.pos
    }
}

/// "00" to "99".
const PAIRS: [[u8; 2]; 100] = {
    let mut t = [[0u8; 2]; 100];
    let mut i = 0;
    while i < 100 {
        t[i] = [b'0' + (i / 10) as u8, b'0' + (i % 10) as u8];
        i += 1;
    }
    t
};

/// The decimal digits of `v`, left-aligned, and their count (1 to 20).
#[inline]
fn decimal(mut v: u64) -> ([u8; 20], usize) {
    let mut n = 1;
    let mut p = 10u64;
    while n < 20 && v >= p {
        n += 1;
        p = p.saturating_mul(10);
    }
    let mut d = [0u8; 20];
    // Two digits at a time from the right.
    let mut end = n;
    while end >= 2 {
        let pair = PAIRS[(v % 100) as usize];
        d[end - 2] = pair[0];
        d[end - 1] = pair[1];
        v /= 100;
        end -= 2;
    }
    if end == 1 {
        d[0] = b'0' + v as u8;
    }
    (d, n)
}

/// An OBJ face corner `" K//K"` (vertex K with normal K, 1-based) for vertex index `v`
/// (0-based), and its length.
#[inline]
fn corner(v: u32) -> ([u8; 24], u8) {
    let (d, n) = decimal(u64::from(v) + 1);
    let mut t = [0u8; 24];
    t[0] = b' ';
    for k in 0..n {
        t[1 + k] = d[k];
        t[3 + n + k] = d[k];
    }
    t[1 + n] = b'/';
    t[2 + n] = b'/';
    (t, (3 + 2 * n) as u8)
}

/// Writes a binary little-endian PLY mesh of `depth` (NaN = no vertex) with per-vertex
/// `normals`.
pub fn write_mesh_ply(
    path: &Path,
    width: usize,
    height: usize,
    depth: &[f32],
    normals: &[[f32; 3]],
) -> Result<()> {
    write_mesh_ply_camera(path, width, height, depth, normals, None)
}

/// The vertex of pixel `i` with depth `z`: (col, −row, z) in pixels, or with a camera the point
/// Z · ray in mm in the camera frame (z = −Z).
#[inline]
fn vertex(i: usize, width: usize, z: f32, camera: Option<&Camera>) -> [f32; 3] {
    let (r, c) = ((i / width) as f32, (i % width) as f32);
    match camera {
        None => [c, -r, z],
        Some(k) => {
            let ray = k.ray(c as f64, r as f64);
            let d = z as f64;
            [
                (d * ray[0]) as f32,
                (d * ray[1]) as f32,
                (d * ray[2]) as f32,
            ]
        }
    }
}

/// The units a mesh file's header states.
fn mesh_units(camera: Option<&Camera>) -> &'static str {
    if camera.is_some() {
        "x y z in mm, camera frame (camera at the origin)"
    } else {
        "x = col, y = -row, z = depth (pixels)"
    }
}

/// [`write_mesh_ply`]; with a `camera`, `depth` is Z in mm along the optical axis and the
/// vertices are the points Z · ray in mm in the camera frame.
pub fn write_mesh_ply_camera(
    path: &Path,
    width: usize,
    height: usize,
    depth: &[f32],
    normals: &[[f32; 3]],
    camera: Option<&Camera>,
) -> Result<()> {
    let (mesh, mut out) = start_mesh(path, width, height, depth, normals)?;
    let io = |e| Error::io(path, e);
    let units = mesh_units(camera);
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment photostereo: {units}\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices, mesh.faces
    )
    .map_err(io)?;
    out.banded(height, width * 24, |rows, buf| {
        buf.clear();
        for i in rows.start * width..rows.end * width {
            let z = depth[i];
            if z.is_finite() {
                let [x, y, zz] = vertex(i, width, z, camera);
                for v in [x, y, zz, normals[i][0], normals[i][1], normals[i][2]] {
                    buf.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        buf.len()
    })
    .map_err(io)?;
    out.banded(height.saturating_sub(1), width * 26, |rows, buf| {
        buf.clear();
        mesh.for_each_face_in_rows(width, rows, |t| {
            buf.push(3);
            for v in t {
                buf.extend_from_slice(&(v as i32).to_le_bytes());
            }
        });
        buf.len()
    })
    .map_err(io)?;
    out.flush().map_err(io)
}

/// Writes a Wavefront OBJ mesh of `depth` with `vn` normals (faces `v//vn`, 1-based). Vertex
/// coordinates are written as the shortest decimals that read back as the same f32 values;
/// normals' components with six decimals (each within 5e-7 of the f32 value, so a direction
/// within 0.00005°).
#[allow(clippy::needless_range_loop)] // the flat index gives the vertex's column and row too
pub fn write_mesh_obj(
    path: &Path,
    width: usize,
    height: usize,
    depth: &[f32],
    normals: &[[f32; 3]],
) -> Result<()> {
    write_mesh_obj_camera(path, width, height, depth, normals, None)
}

/// [`write_mesh_obj`]; with a `camera`, vertices in mm in the camera frame (see
/// [`write_mesh_ply_camera`]).
pub fn write_mesh_obj_camera(
    path: &Path,
    width: usize,
    height: usize,
    depth: &[f32],
    normals: &[[f32; 3]],
    camera: Option<&Camera>,
) -> Result<()> {
    let (mesh, mut out) = start_mesh(path, width, height, depth, normals)?;
    let io = |e| Error::io(path, e);
    writeln!(
        out,
        "# photostereo mesh: {}; {} vertices, {} faces",
        mesh_units(camera),
        mesh.vertices,
        mesh.faces
    )
    .map_err(io)?;
    // Vertices: "v X Y Z\n".
    out.banded(height, width * 24, |rows, buf| {
        let mut t = Text::new(buf);
        for r in rows {
            // Without a camera, X and Y are the column and minus the row, as integers.
            let (row, row_len) = decimal(r as u64);
            let mut y = [b' '; 24];
            let mut y_len = 1;
            if r > 0 {
                y[1] = b'-';
                y_len = 2;
            }
            y[y_len..y_len + row_len].copy_from_slice(&row[..row_len]);
            y_len += row_len;
            t.room(width * (2 + 20 + 24 + 1 + F32_TEXT + 1) + 24);
            for (c, &z) in depth[r * width..(r + 1) * width].iter().enumerate() {
                if !z.is_finite() {
                    continue;
                }
                t.put(b"v ", 2);
                match camera {
                    None => {
                        let (col, col_len) = decimal(c as u64);
                        t.put(&col, col_len);
                        t.put(&y, y_len);
                        t.byte(b' ');
                        t.f32(z);
                    }
                    Some(_) => {
                        let [x, yy, zz] = vertex(r * width + c, width, z, camera);
                        t.f32(x);
                        t.byte(b' ');
                        t.f32(yy);
                        t.byte(b' ');
                        t.f32(zz);
                    }
                }
                t.byte(b'\n');
            }
        }
        t.finish()
    })
    .map_err(io)?;
    // Normals: "vn X Y Z\n".
    out.banded(height, width * 36, |rows, buf| {
        let mut t = Text::new(buf);
        for r in rows {
            t.room(width * (3 + 3 * (1 + F32_TEXT)) + 24);
            for i in r * width..(r + 1) * width {
                if depth[i].is_finite() {
                    t.put(b"vn", 2);
                    for v in normals[i] {
                        t.byte(b' ');
                        t.fixed6(v);
                    }
                    t.byte(b'\n');
                }
            }
        }
        t.finish()
    })
    .map_err(io)?;
    // Faces: "f A//A B//B C//C\n". Each vertex's corner text is made once per row it is in
    // (two rows of blocks use it) and copied into its faces.
    let longest = 1 + 3 * (3 + 2 * decimal(mesh.vertices as u64).1) + 1;
    out.banded(height.saturating_sub(1), width * 120, |rows, buf| {
        let mut t = Text::new(buf);
        let none = ([0u8; 24], 0u8);
        let corners_of = |r: usize, row: &mut Vec<([u8; 24], u8)>| {
            row.clear();
            row.extend(mesh.index[r * width..(r + 1) * width].iter().map(|&v| {
                if v == u32::MAX {
                    none
                } else {
                    corner(v)
                }
            }));
        };
        let (mut top, mut bottom) = (Vec::with_capacity(width), Vec::with_capacity(width));
        corners_of(rows.start, &mut top);
        for r in rows {
            corners_of(r + 1, &mut bottom);
            t.room(2 * width * longest + 24);
            mesh.for_each_face_in_row(width, r, |f| {
                t.byte(b'f');
                for (c, below) in f {
                    let (text, len) = if below { &bottom[c] } else { &top[c] };
                    t.put(text, usize::from(*len));
                }
                t.byte(b'\n');
            });
            std::mem::swap(&mut top, &mut bottom);
        }
        t.finish()
    })
    .map_err(io)?;
    out.flush().map_err(io)
}

/// Writes everything of a [`Surface`] into `dir`: depth files, `mesh.ply`, `mesh.obj` (when
/// `meshes`), `curl.npy` (float32 (H, W), NaN where undefined) and the discontinuity map when
/// the integrator made one ([`write_discontinuities`]). `normals` are the per-vertex
/// normals (the map that was integrated).
pub fn write_surface(
    dir: &Path,
    surface: &Surface,
    normals: &[[f32; 3]],
    meshes: bool,
) -> Result<()> {
    write_surface_camera(dir, surface, normals, meshes, None)
}

/// [`write_surface`]; with a `camera` the depth is Z in mm and the meshes are in mm in the
/// camera frame.
pub fn write_surface_camera(
    dir: &Path,
    surface: &Surface,
    normals: &[[f32; 3]],
    meshes: bool,
    camera: Option<&Camera>,
) -> Result<()> {
    let d = &surface.depth;
    let (depth, curl) = rayon::join(
        || write_depth(dir, d.width, d.height, &d.values),
        || write_npy_f32(&dir.join("curl.npy"), &[d.height, d.width], &surface.curl),
    );
    depth.and(curl)?;
    if let Some(jumps) = &d.discontinuities {
        write_discontinuities(dir, d.width, d.height, jumps)?;
    }
    if meshes {
        let (w, h) = (d.width, d.height);
        // Two files: one's page-cache copies overlap the other's formatting.
        let (ply, obj) = rayon::join(
            || write_mesh_ply_camera(&dir.join("mesh.ply"), w, h, &d.values, normals, camera),
            || write_mesh_obj_camera(&dir.join("mesh.obj"), w, h, &d.values, normals, camera),
        );
        ply.and(obj)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A depth map over more rows than one band, with holes, and its expected mesh by the
    /// definition (vertices in row-major order of the finite depths; triangles per 2×2 block).
    fn fixture() -> (usize, usize, Vec<f32>, Vec<[f32; 3]>) {
        let (w, h) = (7, 3 * BAND_ROWS + 5);
        let depth: Vec<f32> = (0..w * h)
            .map(|i| {
                if i % 11 == 3 || i % 17 == 0 {
                    f32::NAN
                } else {
                    (i as f32 * 0.37).sin() * 1e-3 + i as f32 * 0.25
                }
            })
            .collect();
        let normals: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let a = i as f32 * 0.61;
                [
                    0.6 * a.cos(),
                    -0.8 * a.sin(),
                    (0.36 + 0.28 * a.sin().powi(2)).sqrt(),
                ]
            })
            .collect();
        (w, h, depth, normals)
    }

    /// The expected triangles, straight from the rule in the module's doc comment.
    fn expected_faces(w: usize, h: usize, depth: &[f32]) -> Vec<[u64; 3]> {
        let mut index = vec![None; w * h];
        let mut next = 0u64;
        for (i, z) in depth.iter().enumerate() {
            if z.is_finite() {
                index[i] = Some(next);
                next += 1;
            }
        }
        let mut faces = Vec::new();
        for r in 0..h - 1 {
            for c in 0..w - 1 {
                let i = r * w + c;
                let [a, b, cc, d] = [i, i + 1, i + w, i + w + 1].map(|j| index[j]);
                match (a, b, cc, d) {
                    (Some(a), Some(b), Some(cc), Some(d)) => {
                        faces.push([a, cc, b]);
                        faces.push([b, cc, d]);
                    }
                    (Some(a), Some(b), Some(cc), None) => faces.push([a, cc, b]),
                    (Some(a), Some(b), None, Some(d)) => faces.push([a, d, b]),
                    (Some(a), None, Some(cc), Some(d)) => faces.push([a, cc, d]),
                    (None, Some(b), Some(cc), Some(d)) => faces.push([b, cc, d]),
                    _ => {}
                }
            }
        }
        faces
    }

    /// The banded, parallel OBJ writer writes every vertex, normal and face in order; vertex
    /// coordinates read back as the same f32 values, normals' components within 5e-7.
    #[test]
    fn obj_matches_the_definition() {
        let (w, h, depth, normals) = fixture();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.obj");
        write_mesh_obj(&path, w, h, &depth, &normals).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let (mut v, mut vn, mut f) = (Vec::new(), Vec::new(), Vec::new());
        for line in text.lines() {
            let t: Vec<&str> = line.split_whitespace().collect();
            match t[0] {
                "v" => v.push([t[1], t[2], t[3]].map(|x| x.parse::<f32>().unwrap())),
                "vn" => vn.push([t[1], t[2], t[3]].map(|x| x.parse::<f64>().unwrap())),
                "f" => f.push([t[1], t[2], t[3]].map(|x| {
                    let (a, b) = x.split_once("//").unwrap();
                    assert_eq!(a, b);
                    a.parse::<u64>().unwrap() - 1
                })),
                _ => assert!(line.starts_with('#')),
            }
        }
        let finite: Vec<usize> = (0..w * h).filter(|&i| depth[i].is_finite()).collect();
        assert_eq!(v.len(), finite.len());
        assert_eq!(vn.len(), finite.len());
        for (k, &i) in finite.iter().enumerate() {
            assert_eq!(v[k], [(i % w) as f32, -((i / w) as f32), depth[i]]);
            for (got, want) in vn[k].iter().zip(normals[i]) {
                assert!(
                    (got - f64::from(want)).abs() <= 5e-7 + 1e-15,
                    "{got} vs {want}"
                );
            }
        }
        assert_eq!(f, expected_faces(w, h, &depth));
    }

    /// A frame wide enough that the band buffers' bound cuts the bands below [`BAND_ROWS`]
    /// rows, and differently for one thread and for eight: the same bytes either way, and the
    /// faces of the definition.
    #[test]
    fn wide_frames_write_the_same_bytes_at_any_thread_count() {
        let (w, h) = (12_000, 7);
        let depth: Vec<f32> = (0..w * h)
            .map(|i| {
                if i % 13 == 5 {
                    f32::NAN
                } else {
                    i as f32 * 0.5
                }
            })
            .collect();
        let normals = vec![[0.0f32, 0.0, 1.0]; w * h];
        let dir = tempfile::tempdir().unwrap();
        let write = |threads: usize, name: &str| {
            let path = dir.path().join(name);
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| write_mesh_obj(&path, w, h, &depth, &normals))
                .unwrap();
            std::fs::read(&path).unwrap()
        };
        let (one, eight) = (write(1, "one.obj"), write(8, "eight.obj"));
        assert!(one == eight, "the files differ");
        let faces: Vec<[u64; 3]> = String::from_utf8(one)
            .unwrap()
            .lines()
            .filter_map(|l| l.strip_prefix("f "))
            .map(|l| {
                let t: Vec<u64> = l
                    .split_whitespace()
                    .map(|x| x.split_once("//").unwrap().0.parse::<u64>().unwrap() - 1)
                    .collect();
                [t[0], t[1], t[2]]
            })
            .collect();
        assert_eq!(faces, expected_faces(w, h, &depth));
    }

    /// Decimal digits as `itoa` gives them.
    #[test]
    fn decimal_digits() {
        let mut cases = vec![0u64, 1, 9, 10, 99, 100, 101, 999_999, 1_000_000, u64::MAX];
        cases.extend((0..64).map(|k| 1u64 << k));
        cases.extend((0..20).map(|k| 10u64.pow(k) - 1));
        for v in cases {
            let (d, n) = decimal(v);
            assert_eq!(&d[..n], itoa::Buffer::new().format(v).as_bytes());
        }
    }

    /// Six-decimal text of normal components: rounded to the nearest 1e-6, no "-0", and the
    /// shortest round-trip form where six decimals do not fit one integer digit.
    #[test]
    fn fixed_decimals_of_normal_components() {
        let text = |v: f32| {
            let mut buf = Vec::new();
            let mut t = Text::new(&mut buf);
            t.room(64);
            t.fixed6(v);
            let n = t.finish();
            String::from_utf8(buf[..n].to_vec()).unwrap()
        };
        assert_eq!(text(0.0), "0.000000");
        assert_eq!(text(-0.0), "0.000000");
        assert_eq!(text(-4e-7), "0.000000");
        assert_eq!(text(-6e-7), "-0.000001");
        assert_eq!(text(1.0), "1.000000");
        assert_eq!(text(-0.70710677), "-0.707107");
        assert_eq!(text(0.25), "0.250000");
        assert_eq!(text(9.999999), "9.999999");
        assert_eq!(text(10.0), "10.0");
        assert_eq!(text(-123.25), "-123.25");
        assert_eq!(text(f32::NAN), "NaN");
        // Every value in a sweep reads back within 5e-7.
        for k in -20_000..=20_000 {
            let v = k as f32 * 4.99e-5 + 1.3e-7;
            let back: f64 = text(v).parse().unwrap();
            assert!((back - f64::from(v)).abs() <= 5e-7 + 1e-15, "{v}: {back}");
        }
    }

    /// The binary PLY holds the same vertices and faces.
    #[test]
    fn ply_matches_the_definition() {
        let (w, h, depth, normals) = fixture();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.ply");
        write_mesh_ply(&path, w, h, &depth, &normals).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let end = b"end_header\n";
        let start = bytes.windows(end.len()).position(|x| x == end).unwrap() + end.len();
        let body = &bytes[start..];
        let finite: Vec<usize> = (0..w * h).filter(|&i| depth[i].is_finite()).collect();
        let f32_at = |o: usize| f32::from_le_bytes(body[o..o + 4].try_into().unwrap());
        for (k, &i) in finite.iter().enumerate() {
            let o = k * 24;
            let got = [0, 1, 2, 3, 4, 5].map(|j| f32_at(o + 4 * j));
            let n = normals[i];
            assert_eq!(
                got,
                [
                    (i % w) as f32,
                    -((i / w) as f32),
                    depth[i],
                    n[0],
                    n[1],
                    n[2]
                ]
            );
        }
        let faces = &body[finite.len() * 24..];
        let expected = expected_faces(w, h, &depth);
        assert_eq!(faces.len(), expected.len() * 13);
        for (rec, e) in faces.chunks_exact(13).zip(&expected) {
            assert_eq!(rec[0], 3);
            let got = [0, 1, 2]
                .map(|j| i32::from_le_bytes(rec[1 + 4 * j..5 + 4 * j].try_into().unwrap()) as u64);
            assert_eq!(&got, e);
        }
    }
}
