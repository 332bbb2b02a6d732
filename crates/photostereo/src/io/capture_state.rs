//! A capture's whole state as bytes, and back: what the Python package pickles, so that a
//! capture shipped to another process (Dask, Ray) is the same capture there — its samples, mask,
//! lights with their near model, and camera — not a distant-light approximation of it.
//!
//! Layout: the magic line `photostereo capture 1\n`, the JSON header's length (u64, little
//! endian), the JSON header (sizes, lights, camera, sources, notes; every number of the lights
//! as the bits of its `f64`, so that it comes back exactly), the mask (one byte a frame pixel),
//! then the intensity-normalised samples of the mask pixels as little-endian `f32`
//! (`[pixel][light][channel]`, as [`Capture::samples_whole`] gives them).

use crate::base::error::{Error, Result};
use crate::model::capture::{Capture, CaptureParts};
use crate::model::lightmodel::{Camera, NearLights};
use crate::model::lights::Lights;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

const MAGIC: &[u8] = b"photostereo capture 1\n";

/// An `f64` as its bits (JSON numbers would not come back to the last bit).
type Bits = u64;

#[derive(Serialize, Deserialize)]
struct Header {
    width: usize,
    height: usize,
    channels: usize,
    bit_depth: u8,
    directions: Vec<[Bits; 3]>,
    intensities: Vec<[Bits; 3]>,
    renormalised: usize,
    /// fx, fy, cx, cy and the mean distance of distant lights seen through a camera.
    camera: Option<([Bits; 4], Bits)>,
    near: Option<Near>,
    sources: Vec<String>,
    notes: Vec<String>,
}

#[derive(Serialize, Deserialize)]
struct Near {
    camera: [Bits; 4],
    positions: Vec<[Bits; 3]>,
    axes: Vec<[Bits; 3]>,
    anisotropy: Vec<Bits>,
    mean_distance: Bits,
}

fn bits<const N: usize>(v: &[[f64; N]]) -> Vec<[Bits; N]> {
    v.iter().map(|r| r.map(f64::to_bits)).collect()
}

fn floats<const N: usize>(v: Vec<[Bits; N]>) -> Vec<[f64; N]> {
    v.into_iter().map(|r| r.map(f64::from_bits)).collect()
}

fn intrinsics(c: &Camera) -> [Bits; 4] {
    [c.fx, c.fy, c.cx, c.cy].map(f64::to_bits)
}

fn camera(k: [Bits; 4]) -> Result<Camera> {
    let [fx, fy, cx, cy] = k.map(f64::from_bits);
    Camera::new(fx, fy, cx, cy)
}

/// The capture as bytes (tiles are read into one block of samples).
pub fn to_bytes(c: &Capture) -> Result<Vec<u8>> {
    let l = &c.lights;
    let header = Header {
        width: c.width,
        height: c.height,
        channels: c.channels,
        bit_depth: c.bit_depth,
        directions: bits(&l.directions),
        intensities: bits(&l.intensities),
        renormalised: l.renormalised,
        camera: l.camera.map(|(k, d)| (intrinsics(&k), d.to_bits())),
        near: l.near.as_deref().map(|n| Near {
            camera: intrinsics(&n.camera),
            positions: bits(&n.positions),
            axes: bits(&n.axes),
            anisotropy: n.anisotropy.iter().map(|v| v.to_bits()).collect(),
            mean_distance: n.mean_distance.to_bits(),
        }),
        sources: c.sources.iter().map(|p| p.display().to_string()).collect(),
        notes: c.notes.clone(),
    };
    let json = serde_json::to_vec(&header).map_err(|e| Error::invalid(e.to_string()))?;
    let samples = c.samples_whole()?;
    let mut out =
        Vec::with_capacity(MAGIC.len() + 8 + json.len() + c.mask.len() + 4 * samples.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(&json);
    out.extend(c.mask.iter().map(|&m| m as u8));
    for v in samples {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}

/// The capture [`to_bytes`] wrote. Errors when the bytes are not such a state.
pub fn from_bytes(bytes: &[u8]) -> Result<Capture> {
    let bad = |m: &str| Error::invalid(format!("not a photostereo capture state: {m}"));
    let rest = bytes.strip_prefix(MAGIC).ok_or_else(|| bad("no header"))?;
    let (len, rest) = rest.split_at_checked(8).ok_or_else(|| bad("truncated"))?;
    let len = u64::from_le_bytes(len.try_into().expect("8 bytes")) as usize;
    let (json, rest) = rest.split_at_checked(len).ok_or_else(|| bad("truncated"))?;
    let h: Header = serde_json::from_slice(json).map_err(|e| bad(&e.to_string()))?;
    let frame = h.width.checked_mul(h.height).ok_or_else(|| bad("size"))?;
    let (mask, rest) = rest
        .split_at_checked(frame)
        .ok_or_else(|| bad("truncated"))?;
    let mask: Vec<bool> = mask.iter().map(|&m| m != 0).collect();
    let pixels = crate::model::capture::mask_pixel_indices(&mask);
    if rest.len() != 4 * pixels.len() * h.directions.len() * h.channels {
        return Err(bad("the samples do not match the sizes"));
    }
    let samples = rest
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let near = match h.near {
        Some(n) => Some(Arc::new(NearLights::restore(
            camera(n.camera)?,
            floats(n.positions),
            floats(n.axes),
            n.anisotropy.into_iter().map(f64::from_bits).collect(),
            f64::from_bits(n.mean_distance),
        )?)),
        None => None,
    };
    let lights = Lights {
        directions: floats(h.directions),
        intensities: floats(h.intensities),
        renormalised: h.renormalised,
        near,
        camera: match h.camera {
            Some((k, d)) => Some((camera(k)?, f64::from_bits(d))),
            None => None,
        },
    };
    Ok(Capture::from_parts(CaptureParts {
        width: h.width,
        height: h.height,
        channels: h.channels,
        bit_depth: h.bit_depth,
        lights,
        mask,
        pixels,
        samples,
        store: None,
        sources: h.sources.into_iter().map(Into::into).collect(),
        notes: h.notes,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::capture::Stack;
    use ndarray::Array4;

    #[test]
    fn a_near_capture_comes_back_the_same() {
        let camera = Camera::new(100.0, 100.0, 3.5, 2.5).unwrap();
        let positions = vec![
            [60.0, 0.0, 0.0],
            [-30.0, 52.0, 0.0],
            [-30.0, -52.0, 0.0],
            [0.0, 60.0, -10.0],
        ];
        let model = NearLights::new(camera, positions, None, Some(vec![1.0; 4]), 300.0).unwrap();
        let mut lights = Lights::new(&model.centre_directions()).unwrap();
        lights.near = Some(Arc::new(model));
        let stack = Array4::from_shape_fn((4, 6, 8, 3), |(k, r, c, j)| {
            0.1 + 0.01 * (k + r + c + j) as f32
        });
        let mut mask = ndarray::Array2::from_elem((6, 8), true);
        mask[[0, 0]] = false;
        let c = Capture::from_stack(Stack::F32(stack.view()), lights, Some(mask.view())).unwrap();
        let back = from_bytes(&to_bytes(&c).unwrap()).unwrap();
        assert_eq!(back.lights, c.lights);
        assert_eq!(back.mask, c.mask);
        assert_eq!(back.pixels, c.pixels);
        assert_eq!(back.samples, c.samples);
        assert_eq!(back.lights.perspective(), c.lights.perspective());
        assert!(from_bytes(b"something else").is_err());
        let bytes = to_bytes(&c).unwrap();
        assert!(from_bytes(&bytes[..bytes.len() - 1]).is_err());
    }
}
