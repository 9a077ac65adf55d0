//! `every-nth`: keep every Nth candidate, starting with the first.

use super::{Applied, Flag, FlagValues, Step};
use crate::error::{Error, Result};

/// `--every N`.
pub const FLAGS: &[Flag] = &[Flag::value::<usize>("every", "N", "Keep every Nth frame")
    .conflicts("fps")
    .sets("every-nth", "n")];

/// The step when `--every` is given.
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>> {
    Ok(v.get("every")?.map(|n| Step::EveryNth { n }))
}

/// Every `n`th element of `candidates`, starting with the first.
pub fn every_nth(candidates: &[usize], n: usize) -> Result<Vec<usize>> {
    if n == 0 {
        return Err(Error::step("every-nth", "N must be at least 1"));
    }
    Ok(candidates.iter().step_by(n).copied().collect())
}

/// The step on `keys`.
pub fn apply(keys: &mut Vec<usize>, n: usize) -> Result<Applied> {
    *keys = every_nth(keys, n)?;
    Ok(Applied::EveryNth { n })
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
