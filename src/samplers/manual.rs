//! Manual edits: add and remove keyframes by index after the automatic samplers ran.

use crate::error::{Error, Result};

/// `keyframes` plus `add` minus `remove`, sorted and distinct; indices must exist in the input.
pub fn manual(
    keyframes: &[usize],
    add: &[usize],
    remove: &[usize],
    frame_count: usize,
) -> Result<Vec<usize>> {
    if let Some(&bad) = add.iter().find(|&&i| i >= frame_count) {
        return Err(Error::Plugin {
            plugin: "manual",
            msg: format!("cannot add frame {bad}: the input has {frame_count} frames"),
        });
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
