//! Match pairs of a rig export for COLMAP's `matches_importer`: the sequential matcher orders
//! images by name, which in the rig layout (`<view>/<frame>`) puts each view's whole sequence
//! before the next view's, so faces of one keyframe never meet. Here every view of keyframe `a`
//! is paired with every view of keyframes `a..=a + window` (each pair once, never an image with
//! itself), keyframes in file-name order. Pure function of the names.

use std::collections::BTreeMap;

/// The pairs (`view/frame` names, COLMAP's image names) for `images` (`view/frame` names in
/// any order) with `window` following keyframes.
pub fn pairs(images: &[String], window: usize) -> Vec<(String, String)> {
    let mut frames: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for name in images {
        let frame = name.rsplit('/').next().unwrap_or(name);
        frames.entry(frame).or_default().push(name);
    }
    let frames: Vec<Vec<&str>> = frames
        .into_values()
        .map(|mut v| {
            v.sort_unstable();
            v
        })
        .collect();
    let mut out = Vec::new();
    for (a, views) in frames.iter().enumerate() {
        for (i, x) in views.iter().enumerate() {
            for y in &views[i + 1..] {
                out.push((x.to_string(), y.to_string()));
            }
            for later in frames.iter().skip(a + 1).take(window) {
                for y in later {
                    out.push((x.to_string(), y.to_string()));
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::pairs;

    #[test]
    fn every_view_meets_the_views_of_its_keyframe_and_the_next_ones() {
        let names: Vec<String> = ["right", "front"]
            .iter()
            .flat_map(|v| ["b.jpg", "a.jpg", "c.jpg"].map(|f| format!("{v}/{f}")))
            .collect();
        let p = pairs(&names, 1);
        let has = |x: &str, y: &str| {
            p.iter()
                .any(|(a, b)| (a == x && b == y) || (a == y && b == x))
        };
        assert!(has("front/a.jpg", "right/a.jpg"));
        assert!(has("front/a.jpg", "right/b.jpg") && has("right/a.jpg", "front/b.jpg"));
        assert!(has("front/b.jpg", "front/c.jpg"));
        assert!(!has("front/a.jpg", "front/c.jpg"), "outside the window");
        // Each keyframe: 1 pair inside, 4 with the next: 2 * (1 + 4) + 1.
        assert_eq!(p.len(), 11, "{p:?}");
        let mut seen = std::collections::HashSet::new();
        for (a, b) in &p {
            assert_ne!(a, b);
            assert!(seen.insert((a.min(b), a.max(b))), "{a} {b} twice");
        }
    }
}
