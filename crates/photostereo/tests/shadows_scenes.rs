//! Height fields shared by the shadow tests (a module of the `shadows*` test targets).
//! (Also built as its own, empty test target.)
#![allow(dead_code)]

/// A height field with its mask and analytic normals.
pub struct Field {
    pub name: &'static str,
    pub width: usize,
    pub height: usize,
    pub depth: Vec<f32>,
    pub mask: Vec<bool>,
}

/// Heights from a function of (x, y) with x = col − centre, y = centre − row.
fn from_fn(name: &'static str, size: usize, f: impl Fn(f64, f64) -> f64) -> Field {
    let c = (size as f64 - 1.0) / 2.0;
    let mut depth = vec![0f32; size * size];
    for row in 0..size {
        for col in 0..size {
            depth[row * size + col] = f(col as f64 - c, c - row as f64) as f32;
        }
    }
    Field {
        name,
        width: size,
        height: size,
        depth,
        mask: vec![true; size * size],
    }
}

/// A square block of height `h` (side size/3) on a plane: vertical walls on four sides.
pub fn block(size: usize, h: f64) -> Field {
    let half = size as f64 / 6.0;
    from_fn("block", size, |x, y| {
        if x.abs() < half && y.abs() < half {
            h
        } else {
            0.0
        }
    })
}

/// A spherical cap of radius r cut at height `cut` below its top on a plane at 0.
pub fn sphere_cap(size: usize) -> Field {
    let r = 0.3 * size as f64;
    let below = 0.4 * r;
    from_fn("sphere cap", size, |x, y| {
        let rr = x * x + y * y;
        if rr < r * r {
            ((r * r - rr).sqrt() - below).max(0.0)
        } else {
            0.0
        }
    })
}

/// A spherical bowl (cavity) in a plane at 0: the rim meets the plane at 60°.
pub fn bowl(size: usize) -> Field {
    let r = 0.4 * size as f64;
    let above = 0.5 * r;
    from_fn("bowl", size, |x, y| {
        let rr = x * x + y * y;
        if rr < r * r {
            -((r * r - rr).sqrt() - above).max(0.0)
        } else {
            0.0
        }
    })
}

/// Deterministic pseudo-random numbers in [0, 1) (64-bit LCG).
pub struct Lcg(pub u64);
impl Lcg {
    pub fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A sum of Gaussian bumps and dents (amplitudes −6..14 px, widths 4..12 px).
pub fn bumps(size: usize, seed: u64) -> Field {
    let mut rng = Lcg(seed);
    let s = size as f64;
    let bumps: Vec<[f64; 4]> = (0..12)
        .map(|_| {
            [
                (rng.uniform() - 0.5) * s,
                (rng.uniform() - 0.5) * s,
                -6.0 + 20.0 * rng.uniform(),
                4.0 + 8.0 * rng.uniform(),
            ]
        })
        .collect();
    from_fn("bumps", size, move |x, y| {
        bumps
            .iter()
            .map(|b| {
                let d2 = (x - b[0]).powi(2) + (y - b[1]).powi(2);
                b[2] * (-d2 / (2.0 * b[3] * b[3])).exp()
            })
            .sum()
    })
}

/// `bumps` with holes in the mask (a disc and a stripe) and NaN heights outside.
pub fn bumps_with_holes(size: usize, seed: u64) -> Field {
    let mut f = bumps(size, seed);
    f.name = "bumps with holes";
    let c = size as f64 / 2.0;
    for row in 0..size {
        for col in 0..size {
            let (x, y) = (col as f64 - 0.6 * c, row as f64 - 0.7 * c);
            let hole = x * x + y * y < (0.15 * size as f64).powi(2)
                || (row as f64 - 0.3 * size as f64).abs() < 2.0 && col < size / 2;
            if hole {
                let i = row * size + col;
                f.mask[i] = false;
                f.depth[i] = f32::NAN;
            }
        }
    }
    f
}

/// Lights at every tilt of `tilts_deg` (0° = +x, counter-clockwise) and slant of `slants_deg`.
pub fn lights(tilts_deg: &[f64], slants_deg: &[f64]) -> Vec<[f64; 3]> {
    let mut out = Vec::new();
    for &s in slants_deg {
        for &t in tilts_deg {
            let (s, t) = (s.to_radians(), t.to_radians());
            out.push([s.sin() * t.cos(), s.sin() * t.sin(), s.cos()]);
        }
    }
    out
}

/// Share of mask pixels where the two maps agree, and the IoU of their shadowed sets (1 when
/// both are empty).
pub fn agreement(a: &[bool], b: &[bool], mask: &[bool]) -> (f64, f64) {
    let (mut same, mut n, mut inter, mut uni) = (0usize, 0usize, 0usize, 0usize);
    for i in 0..mask.len() {
        if !mask[i] {
            continue;
        }
        n += 1;
        same += (a[i] == b[i]) as usize;
        inter += (a[i] && b[i]) as usize;
        uni += (a[i] || b[i]) as usize;
    }
    (
        same as f64 / n.max(1) as f64,
        if uni == 0 {
            1.0
        } else {
            inter as f64 / uni as f64
        },
    )
}
