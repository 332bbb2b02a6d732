//! Standard tile pyramids of an 8-bit RGB image, for viewers of large images: Deep Zoom
//! (`.dzi`, which OpenSeadragon reads and OpenLIME's `deepzoom1px` layout) and IIIF Image API
//! 3.0 level-0 static tiles (`info.json` and the tiles at the paths a client requests). Levels
//! are made by the viewer pyramid's halving ([`crate::io::viewer::pyramid::halve_u8`]).
//!
//! Deep Zoom: levels 0…L with L = ⌈log2 max(W, H)⌉; level L is the image, level k is
//! ⌈W / 2^(L−k)⌉ × ⌈H / 2^(L−k)⌉ (level 0 is 1 × 1). Level k is cut into tiles of T × T pixels,
//! each widened by the overlap O on the sides that have a neighbour: tile (col, row) covers
//! x from col·T − O (0 for col 0) to min((col + 1)·T + O, width), and y alike. Files:
//! `NAME.dzi` (XML: `Image` with `Format`, `Overlap`, `TileSize`, and `Size` with `Width`,
//! `Height`) and `NAME_files/k/col_row.FORMAT`.
//!
//! IIIF level 0: scale factors s = 1, 2, 4, … up to the first at which the image fits one tile;
//! at scale s, tile (col, row) is the full-resolution region x = col·T·s, y = row·T·s,
//! w = min(T·s, W − x), h = min(T·s, H − y), delivered at ⌈w / s⌉ × ⌈h / s⌉, at
//! `x,y,w,h/W',H'/0/default.jpg` (region `full` as well when the tile is the whole image);
//! each level's whole image is at `full/W',H'/0/default.jpg` (the `sizes` of `info.json`).
//! JPEG is the format every level-0 service delivers.

use crate::base::error::{Error, Result};
use crate::io::imageio::write_png8;
use crate::io::viewer::pyramid::halve_u8;
use serde_json::{json, Value};
use std::borrow::Cow;
use std::path::Path;

/// Deep Zoom's tile side by default (256 with a one-pixel overlap on each side).
pub const DZI_TILE: usize = 254;
/// Deep Zoom's overlap by default, pixels.
pub const DZI_OVERLAP: usize = 1;
/// IIIF tile side.
pub const IIIF_TILE: usize = 512;
/// JPEG quality of IIIF tiles.
const JPEG_QUALITY: u8 = 90;

/// The levels of an image from full size down (each [`halve_u8`] of the previous) until
/// `done(width, height)`.
/// The full-size level is the caller's image, not a copy.
fn levels(
    w: usize,
    h: usize,
    rgb: &[u8],
    done: impl Fn(usize, usize) -> bool,
) -> Vec<(usize, usize, Cow<'_, [u8]>)> {
    let mut out = vec![(w, h, Cow::Borrowed(rgb))];
    loop {
        let (lw, lh, last) = out.last().expect("one level");
        if done(*lw, *lh) {
            return out;
        }
        let (nw, nh, next) = halve_u8(*lw, *lh, 3, last);
        out.push((nw, nh, Cow::Owned(next)));
    }
}

/// The `x0..x1` × `y0..y1` window of an RGB image `w` wide.
fn crop(w: usize, rgb: &[u8], (x0, x1): (usize, usize), (y0, y1): (usize, usize)) -> Vec<u8> {
    let mut out = Vec::with_capacity((x1 - x0) * (y1 - y0) * 3);
    for y in y0..y1 {
        out.extend_from_slice(&rgb[(y * w + x0) * 3..(y * w + x1) * 3]);
    }
    out
}

fn check(w: usize, h: usize, rgb: &[u8], tile: usize) -> Result<()> {
    if w == 0 || h == 0 || rgb.len() != w * h * 3 || tile == 0 {
        return Err(Error::invalid(format!(
            "tile pyramid of a {w} × {h} RGB image from {} bytes, tiles of {tile}",
            rgb.len()
        )));
    }
    Ok(())
}

/// Writes the Deep Zoom pyramid of the RGB image `rgb` (`w × h`, rows from the top) as `dzi`
/// (a path ending in `.dzi`) and `<stem>_files/`, PNG tiles; returns the number of levels
/// and tiles.
pub fn write_deep_zoom(
    dzi: &Path,
    (w, h): (usize, usize),
    rgb: &[u8],
    tile: usize,
    overlap: usize,
) -> Result<(usize, usize)> {
    check(w, h, rgb, tile)?;
    let stem = dzi
        .file_stem()
        .and_then(|s| s.to_str())
        .ok_or_else(|| Error::file(dzi, "a Deep Zoom file needs a name"))?;
    let files = dzi.with_file_name(format!("{stem}_files"));
    let levels = levels(w, h, rgb, |a, b| a == 1 && b == 1);
    let top = levels.len() - 1;
    let mut count = 0;
    for (i, (lw, lh, img)) in levels.iter().enumerate() {
        let dir = files.join((top - i).to_string());
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        for row in 0..lh.div_ceil(tile) {
            for col in 0..lw.div_ceil(tile) {
                let xs = (
                    (col * tile).saturating_sub(overlap),
                    ((col + 1) * tile + overlap).min(*lw),
                );
                let ys = (
                    (row * tile).saturating_sub(overlap),
                    ((row + 1) * tile + overlap).min(*lh),
                );
                let path = dir.join(format!("{col}_{row}.png"));
                write_png8(&path, xs.1 - xs.0, ys.1 - ys.0, 3, &crop(*lw, img, xs, ys))?;
                count += 1;
            }
        }
    }
    let xml = format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<Image xmlns=\"http://schemas.microsoft.com/deepzoom/2008\" \
         Format=\"png\" Overlap=\"{overlap}\" TileSize=\"{tile}\">\n  <Size Width=\"{w}\" Height=\"{h}\"/>\n</Image>\n"
    );
    super::write_file(dzi, &[xml.as_bytes()])?;
    Ok((levels.len(), count))
}

/// Writes the IIIF Image API 3.0 level-0 static tiles of the RGB image `rgb` into `dir`, with
/// `id` (the URI the folder is served at) in `info.json`; returns `info.json`.
pub fn write_iiif(
    dir: &Path,
    id: &str,
    (w, h): (usize, usize),
    rgb: &[u8],
    tile: usize,
) -> Result<Value> {
    check(w, h, rgb, tile)?;
    let levels = levels(w, h, rgb, |a, b| a <= tile && b <= tile);
    let mut sizes = Vec::new();
    for (k, (lw, lh, img)) in levels.iter().enumerate() {
        let s = 1usize << k;
        let size = format!("{lw},{lh}");
        write_jpeg(
            &dir.join(format!("full/{size}/0/default.jpg")),
            *lw,
            *lh,
            img,
        )?;
        sizes.push(json!({ "width": lw, "height": lh }));
        let span = tile * s;
        for row in 0..h.div_ceil(span) {
            for col in 0..w.div_ceil(span) {
                let (x, y) = (col * span, row * span);
                let (rw, rh) = (span.min(w - x), span.min(h - y));
                let (tw, th) = (rw.div_ceil(s), rh.div_ceil(s));
                let (lx, ly) = (x / s, y / s);
                let pixels = crop(*lw, img, (lx, lx + tw), (ly, ly + th));
                let path = dir.join(format!("{x},{y},{rw},{rh}/{tw},{th}/0/default.jpg"));
                write_jpeg(&path, tw, th, &pixels)?;
            }
        }
    }
    sizes.reverse();
    let info = json!({
        "@context": "http://iiif.io/api/image/3/context.json",
        "id": id,
        "type": "ImageService3",
        "protocol": "http://iiif.io/api/image",
        "profile": "level0",
        "width": w,
        "height": h,
        "sizes": sizes,
        "tiles": [{
            "width": tile,
            "height": tile,
            "scaleFactors": (0..levels.len()).map(|k| 1usize << k).collect::<Vec<_>>(),
        }],
    });
    let text = serde_json::to_string_pretty(&info)
        .map_err(|e| Error::invalid(format!("info.json: {e}")))?;
    super::write_file(&dir.join("info.json"), &[text.as_bytes()])?;
    Ok(info)
}

/// Writes the IIIF level-0 tiles ([`write_iiif`], tiles of [`IIIF_TILE`]) of the 8-bit image
/// file `image` into `dir`, with the service URI `id`; returns `info.json`.
pub fn write_iiif_of(image: &Path, dir: &Path, id: &str) -> Result<Value> {
    let img = crate::io::imageio::read_image(image)?;
    if img.channels != 3 || img.bit_depth != 8 {
        return Err(Error::file(image, "expected an 8-bit RGB image"));
    }
    // Samples are bytes / 255: back to the bytes exactly.
    let rgb: Vec<u8> = img
        .data
        .iter()
        .map(|&v| (v * 255.0).round() as u8)
        .collect();
    write_iiif(dir, id, (img.width, img.height), &rgb, IIIF_TILE)
}

/// Writes an RGB JPEG (creating its folder).
fn write_jpeg(path: &Path, w: usize, h: usize, rgb: &[u8]) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut out = std::io::BufWriter::new(file);
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, JPEG_QUALITY)
        .encode(rgb, w as u32, h as u32, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::file(path, format!("JPEG encoding failed: {e}")))
}
