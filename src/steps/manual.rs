//! Manual edits: add and remove keyframes by index after the automatic samplers ran.

use super::{Applied, Flag, FlagValues, Inputs, Step};
use crate::error::{Error, Result};

/// `--add`, `--remove`.
pub const FLAGS: &[Flag] = &[
    Flag::value::<usize>(
        "add",
        "I,J,..",
        "Frames to add after sampling (comma-separated indices)",
    )
    .list()
    .sets("manual", "add"),
    Flag::value::<usize>(
        "remove",
        "I,J,..",
        "Frames to remove after sampling (comma-separated indices)",
    )
    .list()
    .sets("manual", "remove"),
];

/// The step when `--add` or `--remove` is given.
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>> {
    let (add, remove) = (v.list("add")?, v.list("remove")?);
    Ok((!add.is_empty() || !remove.is_empty()).then_some(Step::Manual { add, remove }))
}

/// The step on `keys`.
pub fn apply(
    at: &Inputs,
    keys: &mut Vec<usize>,
    add: &[usize],
    remove: &[usize],
) -> Result<Applied> {
    *keys = manual(keys, add, remove, at.frame_count)?;
    Ok(Applied::Manual {
        add: add.to_vec(),
        remove: remove.to_vec(),
    })
}

/// `keyframes` plus `add` minus `remove`, sorted and distinct; indices must exist in the input.
pub fn manual(
    keyframes: &[usize],
    add: &[usize],
    remove: &[usize],
    frame_count: usize,
) -> Result<Vec<usize>> {
    if let Some(&bad) = add.iter().find(|&&i| i >= frame_count) {
        let msg = format!("cannot add frame {bad}: the input has {frame_count} frames");
        return Err(Error::step("manual", msg));
    }
    let mut out: Vec<usize> = keyframes
        .iter()
        .chain(add)
        .copied()
        .filter(|i| !remove.contains(i))
        .collect();
    out.sort_unstable();
    out.dedup();
    Ok(out)
}

#[cfg(test)]
mod tests {
    #[test]
    fn add_and_remove() {
        let k = super::manual(&[0, 10, 20], &[5, 10], &[20], 30).unwrap();
        assert_eq!(k, vec![0, 5, 10]);
        assert!(super::manual(&[0], &[30], &[], 30).is_err());
    }
}
