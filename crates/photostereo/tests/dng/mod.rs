//! A minimal DNG writer for tests, from the specifications (TIFF 6.0 §2 for the container,
//! DNG 1.4 §4-6 for the tags): one uncompressed 16-bit CFA image in IFD 0, little-endian.

/// What a test DNG holds.
pub struct Dng {
    pub width: u32,
    pub height: u32,
    /// Samples in row order, `width × height`.
    pub samples: Vec<u16>,
    /// The 2×2 CFA pattern in row order (0 red, 1 green, 2 blue), e.g. `[0, 1, 1, 2]` (RGGB).
    pub cfa: [u8; 4],
    /// Black level of each of the 2×2 sites (BlackLevelRepeatDim 2×2), row order.
    pub black: [u16; 4],
    pub white: u16,
    /// AsShotNeutral: the camera's white balance, which the reader must not apply.
    pub neutral: [f64; 3],
}

struct Entry {
    tag: u16,
    kind: u16,
    count: u32,
    bytes: Vec<u8>,
}

fn shorts(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn longs(v: &[u32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn rationals(v: &[(u32, u32)]) -> Vec<u8> {
    v.iter()
        .flat_map(|(n, d)| [n.to_le_bytes(), d.to_le_bytes()].concat())
        .collect()
}

fn srationals(v: &[(i32, i32)]) -> Vec<u8> {
    v.iter()
        .flat_map(|(n, d)| [n.to_le_bytes(), d.to_le_bytes()].concat())
        .collect()
}

fn ascii(s: &str) -> (u32, Vec<u8>) {
    let mut b = s.as_bytes().to_vec();
    b.push(0);
    (b.len() as u32, b)
}

impl Dng {
    /// The file's bytes.
    pub fn bytes(&self) -> Vec<u8> {
        let (w, h) = (self.width, self.height);
        let e = |tag, kind, count, bytes| Entry {
            tag,
            kind,
            count,
            bytes,
        };
        let (n_make, make) = ascii("Photostereo");
        let (n_model, model) = ascii("Test Bayer");
        let (n_unique, unique) = ascii("Photostereo Test Bayer");
        let neutral: Vec<(u32, u32)> = self
            .neutral
            .iter()
            .map(|v| ((v * 10000.0).round() as u32, 10000))
            .collect();
        // XYZ → camera for D65, roughly sRGB's inverse; only its presence matters here.
        let matrix = [
            (32404, 10000),
            (-15371, 10000),
            (-4985, 10000),
            (-9692, 10000),
            (18760, 10000),
            (415, 10000),
            (556, 10000),
            (-2040, 10000),
            (10572, 10000),
        ];
        let mut entries = [
            e(254, 4, 1, longs(&[0])),
            e(256, 4, 1, longs(&[w])),
            e(257, 4, 1, longs(&[h])),
            e(258, 3, 1, shorts(&[16])),
            e(259, 3, 1, shorts(&[1])),
            e(262, 3, 1, shorts(&[32803])),
            e(271, 2, n_make, make),
            e(272, 2, n_model, model),
            e(273, 4, 1, longs(&[0])), // patched below
            e(274, 3, 1, shorts(&[1])),
            e(277, 3, 1, shorts(&[1])),
            e(278, 4, 1, longs(&[h])),
            e(279, 4, 1, longs(&[w * h * 2])),
            e(284, 3, 1, shorts(&[1])),
            e(33421, 3, 2, shorts(&[2, 2])),
            e(33422, 1, 4, self.cfa.to_vec()),
            e(50706, 1, 4, vec![1, 4, 0, 0]),
            e(50707, 1, 4, vec![1, 1, 0, 0]),
            e(50708, 2, n_unique, unique),
            e(50710, 1, 3, vec![0, 1, 2]),
            e(50711, 3, 1, shorts(&[1])),
            e(50713, 3, 2, shorts(&[2, 2])),
            e(50714, 3, 4, shorts(&self.black)),
            e(50717, 3, 1, shorts(&[self.white])),
            e(50721, 10, 9, srationals(&matrix)),
            e(50728, 5, 3, rationals(&neutral)),
            e(50778, 3, 1, shorts(&[21])),
        ];
        entries.sort_by_key(|e| e.tag);
        // Layout: header (8), IFD (2 + 12 n + 4), the values that do not fit in 4 bytes,
        // then the strip.
        let ifd_len = 2 + 12 * entries.len() + 4;
        let mut extra = Vec::new();
        let mut offsets = Vec::new();
        let extra_at = 8 + ifd_len;
        for en in &entries {
            if en.bytes.len() > 4 {
                offsets.push(Some(extra_at + extra.len()));
                extra.extend_from_slice(&en.bytes);
                if extra.len() % 2 == 1 {
                    extra.push(0);
                }
            } else {
                offsets.push(None);
            }
        }
        let strip_at = (extra_at + extra.len()) as u32;
        let mut out = b"II*\0".to_vec();
        out.extend_from_slice(&8u32.to_le_bytes());
        out.extend_from_slice(&(entries.len() as u16).to_le_bytes());
        for (en, off) in entries.iter().zip(&offsets) {
            out.extend_from_slice(&en.tag.to_le_bytes());
            out.extend_from_slice(&en.kind.to_le_bytes());
            out.extend_from_slice(&en.count.to_le_bytes());
            let mut value = match off {
                Some(o) => (*o as u32).to_le_bytes().to_vec(),
                None if en.tag == 273 => strip_at.to_le_bytes().to_vec(),
                None => en.bytes.clone(),
            };
            value.resize(4, 0);
            out.extend_from_slice(&value);
        }
        out.extend_from_slice(&0u32.to_le_bytes());
        out.extend_from_slice(&extra);
        out.extend_from_slice(&shorts(&self.samples));
        out
    }
}

/// A DNG whose half-size reading is `rgb` (`w × h` pixels, 3 channels in [0, 1]): each pixel
/// becomes a 2×2 block of the pattern `cfa`, both greens the pixel's green, each sample
/// `black + v × (white − black)` rounded.
pub fn mosaic(w: usize, h: usize, rgb: &[f32], cfa: [u8; 4], black: [u16; 4], white: u16) -> Dng {
    let (mw, mh) = (2 * w, 2 * h);
    let mut samples = vec![0u16; mw * mh];
    for y in 0..mh {
        for x in 0..mw {
            let site = (y % 2) * 2 + x % 2;
            let c = cfa[site] as usize;
            let v = rgb[((y / 2) * w + x / 2) * 3 + c].clamp(0.0, 1.0) as f64;
            let b = black[site] as f64;
            samples[y * mw + x] = (b + v * (white as f64 - b)).round() as u16;
        }
    }
    Dng {
        width: mw as u32,
        height: mh as u32,
        samples,
        cfa,
        black,
        white,
        neutral: [0.5, 1.0, 0.6],
    }
}
