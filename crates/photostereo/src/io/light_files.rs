//! Light files (CONVENTIONS.md, "Capture layouts"): directions (N rows `x y z`, optionally after
//! a count line) and intensities (N rows `R G B` or one value each), read with the size limits
//! of [`crate::io::limits`] and written in the DiLiGenT layout. Messages name the file and line.

use crate::base::error::{Error, Result};
use crate::io::limits::read_text;
use crate::model::lights::{normalise_direction, Lights};
use crate::scene::Rig;
use std::path::Path;

/// Reads directions from a text file: either the DiLiGenT layout (N rows `x y z`) or the
/// list layout (a first line with the count N, then N rows). Blank lines and lines starting
/// with `#` are skipped. Directions are normalised; a zero direction is an error.
pub fn read_directions(path: &Path) -> Result<Lights> {
    parse_directions(&read_text(path)?, path)
}

/// [`read_directions`] on text already read; `path` names the
/// source in messages.
pub fn parse_directions(text: &str, path: &Path) -> Result<Lights> {
    let rows = parse_rows(text, path, &[3], None)?;
    let mut dirs = Vec::with_capacity(rows.len());
    let mut renormalised = 0;
    for (line, row) in &rows {
        let d = [row[0], row[1], row[2]];
        dirs.push(
            normalise_direction(d, &mut renormalised).map_err(|m| Error::parse(path, *line, m))?,
        );
    }
    Ok(Lights {
        intensities: vec![[1.0; 3]; dirs.len()],
        directions: dirs,
        renormalised,
        near: None,
        camera: None,
    })
}

/// Reads per-light intensities (rows of 3 values R G B, or 1 value for all channels) and
/// attaches them to `lights`. The row count must equal the light count.
pub fn read_intensities(lights: Lights, path: &Path) -> Result<Lights> {
    let values = read_intensity_rows(path, Some(lights.len()))?;
    if values.len() != lights.len() {
        return Err(Error::file(
            path,
            format!(
                "{} intensity rows for {} light directions",
                values.len(),
                lights.len()
            ),
        ));
    }
    lights.with_intensities(values)
}

/// Writes the directions in the DiLiGenT layout (N rows `x y z`).
pub fn write_directions(lights: &Lights, path: &Path) -> Result<()> {
    let mut s = String::new();
    for d in &lights.directions {
        s.push_str(&format!("{:.6} {:.6} {:.6}\n", d[0], d[1], d[2]));
    }
    std::fs::write(path, s).map_err(|e| Error::io(path, e))
}

/// Writes the intensities in the DiLiGenT layout (N rows `R G B`).
pub fn write_intensities(lights: &Lights, path: &Path) -> Result<()> {
    let mut s = String::new();
    for v in &lights.intensities {
        s.push_str(&format!("{:.6} {:.6} {:.6}\n", v[0], v[1], v[2]));
    }
    std::fs::write(path, s).map_err(|e| Error::io(path, e))
}

/// Reads an intensity file: rows of 3 values R G B or 1 value for all channels, each positive.
/// `lights` (the light count, when known) decides whether an ambiguous first line holding one
/// whole number is a count line.
pub fn read_intensity_rows(path: &Path, lights: Option<usize>) -> Result<Vec<[f64; 3]>> {
    parse_intensity_rows(&read_text(path)?, path, lights)
}

/// [`read_intensity_rows`] on text already read; `path` names the source in messages.
pub fn parse_intensity_rows(
    text: &str,
    path: &Path,
    lights: Option<usize>,
) -> Result<Vec<[f64; 3]>> {
    let rows = parse_rows(text, path, &[1, 3], lights)?;
    let mut values = Vec::with_capacity(rows.len());
    for (line, row) in &rows {
        let v = if row.len() == 1 {
            [row[0]; 3]
        } else {
            [row[0], row[1], row[2]]
        };
        if v.iter()
            .any(|x| !crate::model::lights::intensity_in_range(*x))
        {
            let [lo, hi] = crate::model::lights::INTENSITY_RANGE;
            return Err(Error::parse(
                path,
                *line,
                format!("intensity {row:?}: expected positive values in [{lo:e}, {hi:e}]"),
            ));
        }
        values.push(v);
    }
    Ok(values)
}

/// Reads a whitespace-separated numeric table. Each data row must have one of `widths` numbers,
/// all finite. A first line holding a single whole number is a count line (the list layout)
/// when the rows after it are wider, or, where one-number rows are data too, when it equals the
/// number of rows after it and `expected` (the light count, when known) says so; a count line
/// that disagrees with the rows is an error naming both numbers. A leading UTF-8 byte-order
/// mark is ignored. Returns (1-based line, values) pairs; `path` names the source in messages.
pub fn parse_rows(
    text: &str,
    path: &Path,
    widths: &[usize],
    expected: Option<usize>,
) -> Result<Vec<(usize, Vec<f64>)>> {
    let mut rows: Vec<(usize, Vec<f64>)> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim().trim_start_matches('\u{feff}');
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut vals = Vec::new();
        for tok in line.split(|c: char| c.is_whitespace() || c == ',') {
            if tok.is_empty() {
                continue;
            }
            let v: f64 = tok.parse().map_err(|_| {
                Error::parse(
                    path,
                    i + 1,
                    format!("'{}' is not a number", tok.escape_debug()),
                )
            })?;
            if !v.is_finite() {
                return Err(Error::parse(path, i + 1, format!("'{tok}' is not finite")));
            }
            vals.push(v);
        }
        rows.push((i + 1, vals));
    }
    if let Some((line, first)) = rows.first() {
        let line = *line;
        let whole = first.len() == 1 && first[0] >= 0.0 && first[0].fract() == 0.0;
        let following = rows.len() - 1;
        let wider_after = rows.get(1).is_some_and(|(_, r)| r.len() > 1);
        let count_line = if !whole {
            false
        } else if !widths.contains(&1) || wider_after {
            true
        } else {
            // One-number rows are data too: a count line only when it is consistent.
            first[0] as usize == following && expected.is_none_or(|n| n == following)
        };
        if count_line {
            let announced = first[0];
            if announced != following as f64 {
                return Err(Error::file(
                    path,
                    format!(
                        "the count line (line {line}) announces {announced} rows but {following} follow"
                    ),
                ));
            }
            rows.remove(0);
        }
    }
    if rows.is_empty() {
        return Err(Error::file(path, "no data rows"));
    }
    for (line, vals) in &rows {
        if !widths.contains(&vals.len()) {
            let want = widths
                .iter()
                .map(|w| w.to_string())
                .collect::<Vec<_>>()
                .join(" or ");
            return Err(Error::parse(
                path,
                *line,
                format!(
                    "expected exactly {want} finite numbers, found {}",
                    vals.len()
                ),
            ));
        }
    }
    Ok(rows)
}

/// A light rig by name as `--rig` takes it: a built-in rig ([`Rig::parse`]) or, failing that,
/// the path of an existing light file, whose directions make the rig.
pub fn parse_rig(s: &str) -> Result<Rig> {
    match Rig::parse(s) {
        Ok(rig) => Ok(rig),
        Err(e) => {
            let path = Path::new(s);
            if !path.is_file() {
                return Err(e);
            }
            Ok(Rig::Given {
                name: s.to_string(),
                lights: read_directions(path)?,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(text: &str) -> tempfile::NamedTempFile {
        let f = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(f.path(), text).unwrap();
        f
    }

    #[test]
    fn reads_both_layouts_and_normalises() {
        let a = write("0 0 2\n1 0 1\n0 1 1\n");
        let l = read_directions(a.path()).unwrap();
        assert_eq!(l.len(), 3);
        assert_eq!(l.renormalised, 3);
        assert!((l.directions[1][0] - 0.5f64.sqrt()).abs() < 1e-12);
        let b = write("3\n0 0 1\n1 0 1\n0 1 1\n");
        assert_eq!(read_directions(b.path()).unwrap().len(), 3);
    }

    #[test]
    fn bad_rows_name_the_line() {
        let f = write("0 0 1\n1 0\n0 1 1\n");
        let e = read_directions(f.path()).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("exactly 3"), "{e}");
        let f = write("0 0 1\n0 0 0\n0 1 1\n");
        let e = read_directions(f.path()).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("zero"), "{e}");
        let f = write("0 0 1\nnan 0 1\n");
        let e = read_directions(f.path()).unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
    }

    #[test]
    fn intensities_must_be_positive() {
        let l = Lights::new(&[[1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [-1.0, 0.0, 1.0]]).unwrap();
        let f = write("1 1 1\n0 1 1\n1 1 1\n");
        let e = read_intensities(l.clone(), f.path())
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("positive"), "{e}");
        let f = write("2\n1\n1\n");
        let l2 = read_intensities(l, f.path()).unwrap();
        assert_eq!(l2.intensities[0], [2.0; 3]);
    }
}
