//! Test grids shared by the integration benchmark and the `integrate_scaling` example.

/// An irregular n × n mask with two components: two overlapping discs with a hole and a notch,
/// plus a separate blob.
pub fn irregular_mask(n: usize) -> Vec<bool> {
    let f = n as f64;
    (0..n * n)
        .map(|i| {
            let (r, c) = ((i / n) as f64 / f, (i % n) as f64 / f);
            let a = (c - 0.35).hypot(r - 0.45) < 0.3;
            let b = (c - 0.7).hypot(r - 0.55) < 0.25;
            let hole = (c - 0.35).hypot(r - 0.4) < 0.05;
            let notch = (r - 0.5).abs() < 0.02 && c > 0.4 && c < 0.6;
            let blob = (c - 0.9).hypot(r - 0.12) < 0.07;
            ((a || b) && !hole && !notch) || blob
        })
        .collect()
}
