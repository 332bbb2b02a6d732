//! Numbers as people read them: an `f32` written as the shortest decimal that reads back as it
//! (0.1, not 0.10000000149011612), and names whose embedded numbers sort by value.

/// Serialises an `f32` as the shortest decimal that reads back as it (0.1, not the
/// 0.10000000149011612 of its exact value in f64): parameters appear as they were given.
pub fn serialize_f32<S: serde::Serializer>(v: &f32, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(f32_as_given(*v))
}

/// The `f64` whose shortest decimal equals the `f32`'s (see [`serialize_f32`]).
pub fn f32_as_given(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(v as f64)
}

/// Compares names so that embedded numbers sort by value ("a.2" before "a.10").
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    let (mut x, mut y) = (a.chars().peekable(), b.chars().peekable());
    loop {
        match (x.peek().copied(), y.peek().copied()) {
            (None, None) => return std::cmp::Ordering::Equal,
            (None, Some(_)) => return std::cmp::Ordering::Less,
            (Some(_), None) => return std::cmp::Ordering::Greater,
            (Some(p), Some(q)) if p.is_ascii_digit() && q.is_ascii_digit() => {
                let mut na = String::new();
                while let Some(c) = x.peek().copied().filter(char::is_ascii_digit) {
                    na.push(c);
                    x.next();
                }
                let mut nb = String::new();
                while let Some(c) = y.peek().copied().filter(char::is_ascii_digit) {
                    nb.push(c);
                    y.next();
                }
                let (ta, tb) = (na.trim_start_matches('0'), nb.trim_start_matches('0'));
                let o = ta.len().cmp(&tb.len()).then_with(|| ta.cmp(tb));
                if o != std::cmp::Ordering::Equal {
                    return o;
                }
            }
            (Some(p), Some(q)) => {
                if p != q {
                    return p.cmp(&q);
                }
                x.next();
                y.next();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn natural_order() {
        let mut v = vec!["c.10.png", "c.2.png", "c.0.png", "c.1.png", "b.png"];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(
            v,
            vec!["b.png", "c.0.png", "c.1.png", "c.2.png", "c.10.png"]
        );
    }
}
