//! Writing integrated surfaces (CONVENTIONS.md, "The output folder of a run"): `depth.npy`,
//! `depth.exr`, `depth.png`, `mesh.ply`, `mesh.obj` and the integrability map `curl.npy`.
//!
//! Mesh frame: one vertex per pixel with a finite depth, at x = col, y = −row, z = depth (pixel
//! units; x right, y up, z toward the camera), with the pixel's unit normal. Triangles join
//! 4-neighbouring pixels: two per 2×2 block of valid pixels, one when exactly three are valid,
//! wound counter-clockwise seen from the camera (+z).

use crate::error::{Error, Result};
use crate::export::write_npy_f32;
use crate::imageio::{write_exr_grey, write_png16};
use crate::integrate::Surface;
use crate::lightmodel::Camera;
use std::io::{BufWriter, Write};
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
    write_npy_f32(&dir.join("depth.npy"), &[height, width], depth)?;
    write_exr_grey(&dir.join("depth.exr"), width, height, depth)?;
    let (lo, hi) = depth
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let span = if hi > lo { hi - lo } else { 1.0 };
    let png: Vec<u16> = depth
        .iter()
        .map(|&v| {
            if v.is_finite() {
                (((v - lo) / span).clamp(0.0, 1.0) * 65535.0).round() as u16
            } else {
                0
            }
        })
        .collect();
    write_png16(&dir.join("depth.png"), width, height, 1, &png)
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
    fn for_each_face(&self, width: usize, height: usize, mut f: impl FnMut([u32; 3])) {
        let none = u32::MAX;
        for r in 0..height.saturating_sub(1) {
            for c in 0..width.saturating_sub(1) {
                let i = r * width + c;
                let (a, b, cc, d) = (
                    self.index[i],
                    self.index[i + 1],
                    self.index[i + width],
                    self.index[i + width + 1],
                );
                // a = (r, c), b = (r, c+1), cc = (r+1, c), d = (r+1, c+1).
                match (a != none, b != none, cc != none, d != none) {
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
) -> Result<(Mesh, BufWriter<std::fs::File>)> {
    check_lengths(width, height, depth, normals)?;
    let mesh = Mesh::new(width, height, depth)?;
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    Ok((mesh, BufWriter::with_capacity(1 << 20, file)))
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
    let units = if camera.is_some() {
        "x y z in mm, camera frame (camera at the origin)"
    } else {
        "x = col, y = -row, z = depth (pixels)"
    };
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment photostereo: {units}\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices, mesh.faces
    )
    .map_err(io)?;
    for (i, &z) in depth.iter().enumerate() {
        if !z.is_finite() {
            continue;
        }
        let [x, y, zz] = vertex(i, width, z, camera);
        for v in [x, y, zz, normals[i][0], normals[i][1], normals[i][2]] {
            out.write_all(&v.to_le_bytes()).map_err(io)?;
        }
    }
    let mut result = Ok(());
    mesh.for_each_face(width, height, |t| {
        if result.is_err() {
            return;
        }
        let mut rec = [0u8; 13];
        rec[0] = 3;
        for k in 0..3 {
            rec[1 + 4 * k..5 + 4 * k].copy_from_slice(&(t[k] as i32).to_le_bytes());
        }
        result = out.write_all(&rec);
    });
    result.map_err(io)?;
    out.flush().map_err(io)
}

/// Writes a Wavefront OBJ mesh of `depth` with `vn` normals (faces `v//vn`, 1-based).
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
    let units = if camera.is_some() {
        "x y z in mm, camera frame (camera at the origin)"
    } else {
        "x = col, y = -row, z = depth (pixels)"
    };
    writeln!(
        out,
        "# photostereo mesh: {units}; {} vertices, {} faces",
        mesh.vertices, mesh.faces
    )
    .map_err(io)?;
    for (i, &z) in depth.iter().enumerate() {
        if z.is_finite() {
            match camera {
                None => writeln!(out, "v {} {} {}", i % width, -((i / width) as i64), z),
                Some(_) => {
                    let [x, y, zz] = vertex(i, width, z, camera);
                    writeln!(out, "v {x} {y} {zz}")
                }
            }
            .map_err(io)?;
        }
    }
    for (i, &z) in depth.iter().enumerate() {
        if z.is_finite() {
            let n = normals[i];
            writeln!(out, "vn {} {} {}", n[0], n[1], n[2]).map_err(io)?;
        }
    }
    let mut result = Ok(());
    mesh.for_each_face(width, height, |t| {
        if result.is_err() {
            return;
        }
        let (a, b, c) = (t[0] + 1, t[1] + 1, t[2] + 1);
        result = writeln!(out, "f {a}//{a} {b}//{b} {c}//{c}");
    });
    result.map_err(io)?;
    out.flush().map_err(io)
}

/// Writes everything of a [`Surface`] into `dir`: depth files, `mesh.ply`, `mesh.obj` (when
/// `meshes`) and `curl.npy` (float32 (H, W), NaN where undefined). `normals` are the per-vertex
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
    write_depth(dir, d.width, d.height, &d.values)?;
    write_npy_f32(&dir.join("curl.npy"), &[d.height, d.width], &surface.curl)?;
    if meshes {
        let (w, h) = (d.width, d.height);
        write_mesh_ply_camera(&dir.join("mesh.ply"), w, h, &d.values, normals, camera)?;
        write_mesh_obj_camera(&dir.join("mesh.obj"), w, h, &d.values, normals, camera)?;
    }
    Ok(())
}
