//! Natural ordering of file names: runs of digits compare by value, so `img2` sorts before `img10`.
//!
//! Hand-made on purpose: the order of an image folder decides its frame indices, which existing
//! projects store, so it must never change. The maintained crates were checked against it and
//! none gives exactly this order: it compares text case-insensitively (ASCII) yet stays a total
//! order (names equal but for case or leading zeros fall back to a bytewise comparison of the
//! whole names: `IMG2` < `img002` < `img02` < `img2`), and digit runs of any length compare by
//! value without overflow. `natord::compare` and `alphanumeric-sort` are case-sensitive (`IMG1`
//! before `a`); `natord::compare_ignore_case` orders `img02b` before `IMG1` and calls
//! `img2`/`IMG2` equal (the folder's listing order would then decide); `lexical-sort` orders
//! `img2` before `img02` and overflows on a 24-digit run.

use std::cmp::Ordering;

/// Compares two names naturally (digit runs by value, text case-insensitively, then bytewise).
pub fn natural_cmp(a: &str, b: &str) -> Ordering {
    let (mut x, mut y) = (a.as_bytes(), b.as_bytes());
    loop {
        match (x.first(), y.first()) {
            (None, None) => return a.cmp(b),
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(c), Some(d)) if c.is_ascii_digit() && d.is_ascii_digit() => {
                let (nx, rx) = split_digits(x);
                let (ny, ry) = split_digits(y);
                let (tx, ty) = (trim_zeros(nx), trim_zeros(ny));
                let ord = tx.len().cmp(&ty.len()).then_with(|| tx.cmp(ty));
                if ord != Ordering::Equal {
                    return ord;
                }
                (x, y) = (rx, ry);
            }
            (Some(c), Some(d)) => {
                let ord = c.to_ascii_lowercase().cmp(&d.to_ascii_lowercase());
                if ord != Ordering::Equal {
                    return ord;
                }
                (x, y) = (&x[1..], &y[1..]);
            }
        }
    }
}

fn split_digits(s: &[u8]) -> (&[u8], &[u8]) {
    let n = s.iter().take_while(|c| c.is_ascii_digit()).count();
    s.split_at(n)
}

fn trim_zeros(s: &[u8]) -> &[u8] {
    let n = s.iter().take_while(|&&c| c == b'0').count();
    &s[n..]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digits_by_value() {
        let mut v = vec!["img10.png", "img2.png", "IMG1.png", "img02b.png", "a.png"];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(
            v,
            vec!["a.png", "IMG1.png", "img2.png", "img02b.png", "img10.png"]
        );
    }
}
