//! A small deterministic random number generator (the renderer's noise, calibration draws): PCG32 (O'Neill's
//! XSH-RR output on a 64-bit LCG) with Box–Muller normal deviates. Every (seed, stream) pair
//! gives its own reproducible sequence, so rendering can be split over lights and rows in
//! parallel and still produce the same bytes for the same seed.

/// PCG32 generator: 64-bit state, one of 2^63 streams.
#[derive(Clone, Debug)]
pub struct Pcg32 {
    state: u64,
    inc: u64,
    /// The second deviate of the last Box–Muller pair, if unused.
    spare_normal: Option<f64>,
}

const MULTIPLIER: u64 = 6_364_136_223_846_793_005;

impl Pcg32 {
    /// The generator for `seed` and `stream` (any values; streams are independent sequences).
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut rng = Pcg32 {
            state: 0,
            inc: (stream << 1) | 1,
            spare_normal: None,
        };
        rng.next_u32();
        rng.state = rng.state.wrapping_add(splitmix64(seed));
        rng.next_u32();
        rng
    }

    /// The next uniformly distributed 32-bit value.
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(MULTIPLIER).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// A uniform value in [0, 1) with 53 random bits.
    pub fn next_f64(&mut self) -> f64 {
        let hi = (self.next_u32() as u64) << 21;
        let lo = (self.next_u32() >> 11) as u64;
        (hi | lo) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A standard normal deviate (mean 0, variance 1) by the polar form of the Box–Muller
    /// transform (Marsaglia): a uniform point in the unit disc gives two deviates without
    /// trigonometric functions.
    pub fn next_normal(&mut self) -> f64 {
        if let Some(z) = self.spare_normal.take() {
            return z;
        }
        loop {
            let x = 2.0 * self.next_f64() - 1.0;
            let y = 2.0 * self.next_f64() - 1.0;
            let s = x * x + y * y;
            if s > 0.0 && s < 1.0 {
                let f = (-2.0 * s.ln() / s).sqrt();
                self.spare_normal = Some(y * f);
                return x * f;
            }
        }
    }
}

/// SplitMix64 finaliser: spreads nearby seeds (0, 1, 2…) over the whole state space.
pub fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pcg32_matches_the_reference_sequence() {
        // Reference: pcg32_srandom_r(&rng, 42, 54) of the PCG C library prints
        // 0xa15c02b7 0x7b47f409 0xba1d3330 … Our seeding passes the seed through SplitMix64,
        // so reproduce the raw reference by seeding the state directly.
        let mut rng = Pcg32 {
            state: 0,
            inc: (54u64 << 1) | 1,
            spare_normal: None,
        };
        rng.next_u32();
        rng.state = rng.state.wrapping_add(42);
        rng.next_u32();
        let got: Vec<u32> = (0..3).map(|_| rng.next_u32()).collect();
        assert_eq!(got, vec![0xa15c02b7, 0x7b47f409, 0xba1d3330]);
    }

    #[test]
    fn normal_deviates_have_unit_variance() {
        let mut rng = Pcg32::new(7, 3);
        let n = 200_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let z = rng.next_normal();
            s += z;
            s2 += z * z;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.015, "variance {var}");
    }

    #[test]
    fn streams_differ_and_repeat() {
        let a: Vec<u32> = {
            let mut r = Pcg32::new(1, 0);
            (0..4).map(|_| r.next_u32()).collect()
        };
        let b: Vec<u32> = {
            let mut r = Pcg32::new(1, 1);
            (0..4).map(|_| r.next_u32()).collect()
        };
        let a2: Vec<u32> = {
            let mut r = Pcg32::new(1, 0);
            (0..4).map(|_| r.next_u32()).collect()
        };
        assert_ne!(a, b);
        assert_eq!(a, a2);
    }
}
