//! `every-nth`: keep every Nth candidate, starting with the first.

use crate::error::{Error, Result};

/// Every `n`th element of `candidates`, starting with the first.
pub fn every_nth(candidates: &[usize], n: usize) -> Result<Vec<usize>> {
    if n == 0 {
        return Err(Error::Plugin {
            plugin: "every-nth",
            msg: "N must be at least 1".into(),
        });
    }
    Ok(candidates.iter().step_by(n).copied().collect())
}

#[cfg(test)]
mod tests {
    #[test]
    fn steps_from_first() {
        let c: Vec<usize> = (20..=60).collect();
        let k = super::every_nth(&c, 7).unwrap();
        assert_eq!(k, vec![20, 27, 34, 41, 48, 55]);
    }
}
