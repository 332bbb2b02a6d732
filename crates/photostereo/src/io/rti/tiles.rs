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
//! each level's whole image up to [`IIIF_FULL_BYTES`] is at `full/W',H'/0/default.jpg` (the
//! `sizes` of `info.json`).
//!
//! Both are written from the image's rows, top to bottom ([`TilePyramid`]), holding about a
//! tile's height of rows per level: images of any size are tiled in memory proportional to
//! their width.
//! JPEG is the format every level-0 service delivers.

use crate::base::error::{Error, Result};
use crate::io::imageio::write_png8;
use crate::io::viewer::pyramid::halve_u8;
use serde_json::{json, Value};
use std::path::Path;

/// Deep Zoom's tile side by default (256 with a one-pixel overlap on each side).
pub const DZI_TILE: usize = 254;
/// Deep Zoom's overlap by default, pixels.
pub const DZI_OVERLAP: usize = 1;
/// IIIF tile side.
pub const IIIF_TILE: usize = 512;
/// JPEG quality of IIIF tiles.
const JPEG_QUALITY: u8 = 90;

/// Bytes of a level's whole image up to which IIIF's `full/W',H'` image of the level is
/// written (and listed in `sizes`): the encoder takes a whole image, so larger levels are
/// served by their tiles alone, as level 0 allows.
pub const IIIF_FULL_BYTES: usize = 16 << 20;

/// Rows a level of a [`TilePyramid`] reserves beyond its tile height (and twice the Deep Zoom
/// overlap): the rows pushed at once (a PNG band, 64) and those waiting to be halved.
const SLACK_ROWS: usize = 128;

/// Bytes per column of the frame a [`TilePyramid`] of the default tiles and the PNG encoder of
/// its image hold at most: each level reserves 3 bytes × (tile + 2 overlap + 128)
/// rows, the levels together about twice the first (IIIF's 512-row tiles the tallest), and the
/// encoder two bands of 64 rows.
pub const BYTES_PER_COLUMN: u64 =
    (3 * 2 * (IIIF_TILE + 2 * DZI_OVERLAP + SLACK_ROWS) + 3 * 2 * 64) as u64;

/// Where a pyramid's Deep Zoom tiles go.
struct DziOut {
    /// `NAME.dzi`.
    path: std::path::PathBuf,
    /// `NAME_files/`.
    files: std::path::PathBuf,
    tile: usize,
    overlap: usize,
    /// Tiles written.
    count: usize,
}

/// Where a pyramid's IIIF level-0 tiles go.
struct IiifOut {
    dir: std::path::PathBuf,
    /// The service's URI.
    id: String,
    /// The full-size image's width and height.
    size: (usize, usize),
    tile: usize,
    /// Levels the IIIF service has (scale factors 1, 2, … 2^(levels − 1)).
    levels: usize,
}

/// One level of a pyramid, its rows held from `first` while a tile or the next level still
/// needs them.
struct Level {
    w: usize,
    h: usize,
    /// Level row of `rows`' first row.
    first: usize,
    /// Rows `first..first + rows.len() / (3 w)`, RGB.
    rows: Vec<u8>,
    /// Next Deep Zoom tile row to write, next IIIF tile row, next row of the level below.
    dzi_next: usize,
    iiif_next: usize,
    halve_next: usize,
    /// The whole level while it is small enough for IIIF's `full` image.
    full: Option<Vec<u8>>,
}

impl Level {
    fn end(&self) -> usize {
        self.first + self.rows.len() / (3 * self.w)
    }
    /// Rows `y0..y1` (held).
    fn window(&self, y0: usize, y1: usize) -> &[u8] {
        let row = 3 * self.w;
        &self.rows[(y0 - self.first) * row..(y1 - self.first) * row]
    }
}

/// Deep Zoom and IIIF level-0 pyramids of one RGB image written from its rows, top to bottom
/// ([`TilePyramid::push`]): each level holds only the rows its unfinished tiles and the level
/// below still need (about a tile's height plus the rows pushed at once), so that an image of
/// any size is tiled in memory proportional to its width. Levels are the image's successive
/// [`halve_u8`] halvings, row pair by row pair.
pub struct TilePyramid {
    levels: Vec<Level>,
    dzi: Option<DziOut>,
    iiif: Option<IiifOut>,
}

impl TilePyramid {
    /// A pyramid of a `w × h` image with Deep Zoom tiles (`dzi`: the `.dzi` path, tile side,
    /// overlap) and/or IIIF tiles (`iiif`: the folder, the service's URI, the tile side).
    pub fn new(
        (w, h): (usize, usize),
        dzi: Option<(&Path, usize, usize)>,
        iiif: Option<(&Path, &str, usize)>,
    ) -> Result<Self> {
        let tiles = [dzi.map(|d| d.1), iiif.map(|f| f.2)];
        if w == 0 || h == 0 || tiles.contains(&Some(0)) {
            return Err(Error::invalid(format!(
                "tile pyramid of a {w} × {h} image in tiles of {tiles:?}"
            )));
        }
        let mut dims = vec![(w, h)];
        while dims.last() != Some(&(1, 1)) {
            let (lw, lh) = *dims.last().expect("one level");
            dims.push(crate::io::viewer::pyramid::half(lw, lh));
        }
        let dzi = match dzi {
            Some((path, tile, overlap)) => {
                let stem = path
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .ok_or_else(|| Error::file(path, "a Deep Zoom file needs a name"))?;
                Some(DziOut {
                    path: path.to_path_buf(),
                    files: path.with_file_name(format!("{stem}_files")),
                    tile,
                    overlap,
                    count: 0,
                })
            }
            None => None,
        };
        let iiif = iiif.map(|(dir, id, tile)| IiifOut {
            dir: dir.to_path_buf(),
            id: id.to_string(),
            size: (w, h),
            tile,
            levels: 1 + dims
                .iter()
                .position(|&(a, b)| a <= tile && b <= tile)
                .expect("the last level is 1 × 1"),
        });
        if dzi.is_none() {
            dims.truncate(iiif.as_ref().map_or(1, |o| o.levels));
        }
        let tallest = dzi
            .as_ref()
            .map_or(0, |d| d.tile + 2 * d.overlap)
            .max(iiif.as_ref().map_or(0, |f| f.tile));
        let levels = dims
            .iter()
            .enumerate()
            .map(|(i, &(lw, lh))| Level {
                w: lw,
                h: lh,
                first: 0,
                rows: Vec::with_capacity((tallest + SLACK_ROWS).min(lh) * 3 * lw),
                dzi_next: 0,
                iiif_next: 0,
                halve_next: 0,
                full: iiif
                    .as_ref()
                    .filter(|o| i < o.levels && lw * lh * 3 <= IIIF_FULL_BYTES)
                    .map(|_| Vec::with_capacity(lw * lh * 3)),
            })
            .collect();
        Ok(TilePyramid { levels, dzi, iiif })
    }

    /// The next whole rows of the full-size image (RGB, `3 w` bytes a row).
    pub fn push(&mut self, rows: &[u8]) -> Result<()> {
        let level = &self.levels[0];
        if rows.len() % (3 * level.w) != 0 || level.end() + rows.len() / (3 * level.w) > level.h {
            return Err(Error::invalid(format!(
                "tile pyramid of a {} × {} RGB image: {} bytes are not the next whole rows",
                level.w,
                level.h,
                rows.len()
            )));
        }
        let mut below = self.add(0, rows)?;
        let mut i = 1;
        while !below.is_empty() && i < self.levels.len() {
            below = self.add(i, &below)?;
            i += 1;
        }
        Ok(())
    }

    /// Adds rows to level `i` and advances it ([`TilePyramid::advance`]).
    fn add(&mut self, i: usize, rows: &[u8]) -> Result<Vec<u8>> {
        let level = &mut self.levels[i];
        level.rows.extend_from_slice(rows);
        if let Some(full) = &mut level.full {
            full.extend_from_slice(rows);
        }
        self.advance(i)
    }

    /// Writes level `i`'s tiles whose rows have all come, makes the rows of the level below
    /// that can be made (returned), and drops the rows nothing needs any more.
    fn advance(&mut self, i: usize) -> Result<Vec<u8>> {
        let top = self.levels.len() - 1;
        let level = &mut self.levels[i];
        let end = level.end();
        let mut keep = end;
        if let Some(d) = &mut self.dzi {
            let (t, o) = (d.tile, d.overlap);
            while level.dzi_next < level.h.div_ceil(t) {
                let r = level.dzi_next;
                let ys = ((r * t).saturating_sub(o), ((r + 1) * t + o).min(level.h));
                if ys.1 > end {
                    break;
                }
                let dir = d.files.join((top - i).to_string());
                std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
                let strip = level.window(ys.0, ys.1);
                for col in 0..level.w.div_ceil(t) {
                    let xs = (
                        (col * t).saturating_sub(o),
                        ((col + 1) * t + o).min(level.w),
                    );
                    let path = dir.join(format!("{col}_{r}.png"));
                    let px = crop(level.w, strip, xs, (0, ys.1 - ys.0));
                    write_png8(&path, xs.1 - xs.0, ys.1 - ys.0, 3, &px)?;
                    d.count += 1;
                }
                level.dzi_next += 1;
            }
            keep = keep.min((level.dzi_next * t).saturating_sub(o));
        }
        if let Some(f) = self.iiif.as_ref().filter(|f| i < f.levels) {
            let t = f.tile;
            while level.iiif_next < level.h.div_ceil(t) {
                let r = level.iiif_next;
                let ys = (r * t, ((r + 1) * t).min(level.h));
                if ys.1 > end {
                    break;
                }
                iiif_tile_row(f, i, level, r, ys)?;
                level.iiif_next += 1;
            }
            keep = keep.min(level.iiif_next * t);
        }
        let mut below = Vec::new();
        if i < top {
            while 2 * level.halve_next < level.h && (2 * level.halve_next + 2).min(level.h) <= end {
                let y0 = 2 * level.halve_next;
                let y1 = (y0 + 2).min(level.h);
                let (_, _, row) = halve_u8(level.w, y1 - y0, 3, level.window(y0, y1));
                below.extend_from_slice(&row);
                level.halve_next += 1;
            }
            keep = keep.min(2 * level.halve_next);
        }
        let drop = keep.max(level.first) - level.first;
        level.rows.drain(..drop * 3 * level.w);
        level.first += drop;
        Ok(below)
    }

    /// Checks that every row came, writes IIIF's `full` images and `info.json` and the `.dzi`
    /// file; returns the Deep Zoom levels and tiles and the IIIF `info.json`.
    pub fn finish(self) -> Result<((usize, usize), Option<Value>)> {
        let (w, h) = (self.levels[0].w, self.levels[0].h);
        if self.levels.iter().any(|l| l.end() != l.h) {
            return Err(Error::invalid(format!(
                "tile pyramid of a {w} × {h} image: {} of its rows given",
                self.levels[0].end()
            )));
        }
        let mut out = (0, 0);
        if let Some(d) = &self.dzi {
            let (t, o) = (d.tile, d.overlap);
            let xml = format!(
                "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<Image xmlns=\"http://schemas.microsoft.com/deepzoom/2008\" \
                 Format=\"png\" Overlap=\"{o}\" TileSize=\"{t}\">\n  <Size Width=\"{w}\" Height=\"{h}\"/>\n</Image>\n"
            );
            super::write_file(&d.path, &[xml.as_bytes()])?;
            out = (self.levels.len(), d.count);
        }
        let Some(f) = &self.iiif else {
            return Ok((out, None));
        };
        let mut sizes = Vec::new();
        for l in self.levels.iter().take(f.levels) {
            if let Some(full) = &l.full {
                let path = f.dir.join(format!("full/{},{}/0/default.jpg", l.w, l.h));
                write_jpeg(&path, l.w, l.h, full)?;
                sizes.push(json!({ "width": l.w, "height": l.h }));
            }
        }
        sizes.reverse();
        let info = json!({
            "@context": "http://iiif.io/api/image/3/context.json",
            "id": f.id,
            "type": "ImageService3",
            "protocol": "http://iiif.io/api/image",
            "profile": "level0",
            "width": w,
            "height": h,
            "sizes": sizes,
            "tiles": [{
                "width": f.tile,
                "height": f.tile,
                "scaleFactors": (0..f.levels).map(|k| 1usize << k).collect::<Vec<_>>(),
            }],
        });
        let text = serde_json::to_string_pretty(&info)
            .map_err(|e| Error::invalid(format!("info.json: {e}")))?;
        super::write_file(&f.dir.join("info.json"), &[text.as_bytes()])?;
        Ok((out, Some(info)))
    }
}

/// Writes IIIF tile row `r` of level `i` (scale factor s = 2^i), whose level rows `ys` are
/// held: tile (col, r) is the full-size region x = col·T·s, y = r·T·s, w = min(T·s, W − x),
/// h = min(T·s, H − y), delivered at ⌈w / s⌉ × ⌈h / s⌉ — the level's pixels from (col·T, r·T).
fn iiif_tile_row(f: &IiifOut, i: usize, level: &Level, r: usize, ys: (usize, usize)) -> Result<()> {
    let s = 1usize << i;
    let span = f.tile * s;
    let (w, h) = f.size;
    let y = r * span;
    let (rh, th) = (span.min(h - y), ys.1 - ys.0);
    let strip = level.window(ys.0, ys.1);
    for col in 0..w.div_ceil(span) {
        let x = col * span;
        let rw = span.min(w - x);
        let (lx, tw) = (col * f.tile, rw.div_ceil(s));
        let pixels = crop(level.w, strip, (lx, lx + tw), (0, th));
        let path = f
            .dir
            .join(format!("{x},{y},{rw},{rh}/{tw},{th}/0/default.jpg"));
        write_jpeg(&path, tw, th, &pixels)?;
    }
    Ok(())
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
    let mut p = TilePyramid::new((w, h), Some((dzi, tile, overlap)), None)?;
    p.push(rgb)?;
    Ok(p.finish()?.0)
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
    let mut p = TilePyramid::new((w, h), None, Some((dir, id, tile)))?;
    p.push(rgb)?;
    Ok(p.finish()?.1.expect("IIIF asked for"))
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
