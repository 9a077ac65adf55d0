//! Camera path for the report: camera centres (e.g. from a COLMAP model) projected on their two
//! principal axes, segments coloured by the spacing to the previous camera, as an inline SVG.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use std::fmt::{self, Write};

/// One camera: the frame it was taken from and its centre in world coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct PathPoint {
    /// Frame index in the input.
    pub frame: usize,
    /// Camera centre (world coordinates, e.g. COLMAP's -R^T t).
    pub centre: [f64; 3],
}

/// Camera centres of a reconstruction, in any order (drawn in frame order).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CameraPath {
    /// The cameras.
    pub points: Vec<PathPoint>,
    /// The centres are east/north/up metres (a georegistered model): drawn east to the right,
    /// north up, instead of on their principal axes.
    pub north_up: bool,
}

/// Numbers the camera-path section reports.
#[derive(Debug, Clone, PartialEq)]
pub struct PathStats {
    /// Number of cameras.
    pub cameras: usize,
    /// Mean distance between consecutive cameras (frame order).
    pub mean_spacing: f64,
    /// Coefficient of variation (standard deviation / mean) of those distances.
    pub cv_spacing: f64,
}

const SIZE: f64 = 520.0;
const PAD: f64 = 30.0;

impl CameraPath {
    /// Points sorted by frame.
    fn sorted(&self) -> Vec<&PathPoint> {
        let mut v: Vec<&PathPoint> = self.points.iter().collect();
        v.sort_by_key(|p| p.frame);
        v
    }

    /// Distances between consecutive cameras in frame order.
    pub fn spacings(&self) -> Vec<f64> {
        self.sorted()
            .windows(2)
            .map(|w| crate::colmap::align::dist(&w[0].centre, &w[1].centre))
            .collect()
    }

    /// Count, mean spacing and its coefficient of variation (`None` below two cameras).
    pub fn stats(&self) -> Option<PathStats> {
        let d = self.spacings();
        if d.is_empty() {
            return None;
        }
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / d.len() as f64;
        Some(PathStats {
            cameras: self.points.len(),
            mean_spacing: mean,
            cv_spacing: if mean > 0.0 { var.sqrt() / mean } else { 0.0 },
        })
    }

    /// The centres projected on the two principal axes (largest spread first), in frame order.
    /// Each axis is the covariance's eigenvector with the sign that makes its largest component
    /// (the first of equal ones) positive, so the plot never comes out mirrored by chance.
    pub fn projected(&self) -> Vec<(usize, f64, f64)> {
        let pts = self.sorted();
        if pts.is_empty() {
            return Vec::new();
        }
        if self.north_up {
            return pts
                .iter()
                .map(|p| (p.frame, p.centre[0], p.centre[1]))
                .collect();
        }
        let n = pts.len() as f64;
        let centres: Vec<Vector3<f64>> = pts.iter().map(|p| Vector3::from(p.centre)).collect();
        let mean = centres.iter().sum::<Vector3<f64>>() / n;
        let cov = centres
            .iter()
            .map(|c| (c - mean) * (c - mean).transpose() / n)
            .sum::<Matrix3<f64>>();
        let (a, b) = principal_axes(cov);
        pts.iter()
            .zip(&centres)
            .map(|(p, c)| (p.frame, (c - mean).dot(&a), (c - mean).dot(&b)))
            .collect()
    }

    /// The path as an inline SVG with a colour-scale legend.
    pub fn svg(&self) -> String {
        let mut s = String::new();
        // Writing to a String cannot fail.
        let _ = self.write_svg(&mut s);
        s
    }

    fn write_svg(&self, s: &mut String) -> fmt::Result {
        let (p, d) = (self.projected(), self.spacings());
        let (width, cameras) = (SIZE + 200.0, p.len()); // the plot, then a 200 wide legend
        writeln!(
            s,
            r#"<svg id="camera-path" width="{width}" height="{SIZE}" font-family="sans-serif" font-size="11" data-cameras="{cameras}">"#
        )?;
        writeln!(
            s,
            r##"<rect width="{SIZE}" height="{SIZE}" fill="#fafafa" stroke="#999"/>"##
        )?;
        write_path(s, &p, &d)?;
        write_legend(s, &d, self.north_up)?;
        writeln!(s, "</svg>")
    }
}

/// Smallest and largest value (infinities when there is none).
pub(super) fn bounds(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let inf = f64::INFINITY;
    v.fold((inf, -inf), |(a, b), x| (a.min(x), b.max(x)))
}

/// Maps projected coordinates into the plot square, centred, same scale on both axes.
pub(super) fn plot_transform(p: &[(usize, f64, f64)]) -> impl Fn(f64, f64) -> (f64, f64) {
    let (minx, maxx) = bounds(p.iter().map(|q| q.1));
    let (miny, maxy) = bounds(p.iter().map(|q| q.2));
    let span = (maxx - minx).max(maxy - miny).max(1e-12);
    let k = (SIZE - 2.0 * PAD) / span;
    let (cx, cy) = ((minx + maxx) / 2.0, (miny + maxy) / 2.0);
    move |x: f64, y: f64| (SIZE / 2.0 + (x - cx) * k, SIZE / 2.0 - (y - cy) * k)
}

/// The segments coloured by their spacing `d`, the cameras, and labels on the first and last.
fn write_path(s: &mut String, p: &[(usize, f64, f64)], d: &[f64]) -> fmt::Result {
    let ((lo, hi), to) = (bounds(d.iter().copied()), plot_transform(p));
    for (i, w) in p.windows(2).enumerate() {
        let (x1, y1) = to(w[0].1, w[0].2);
        let (x2, y2) = to(w[1].1, w[1].2);
        let t = if hi > lo {
            (d[i] - lo) / (hi - lo)
        } else {
            0.5
        };
        let (colour, a, b, len) = (scale_colour(t), w[0].0, w[1].0, d[i]);
        writeln!(
            s,
            r#"<line class="seg" x1="{x1:.1}" y1="{y1:.1}" x2="{x2:.1}" y2="{y2:.1}" stroke="{colour}" stroke-width="3" stroke-linecap="round"><title>frames {a}–{b}: spacing {len:.4}</title></line>"#
        )?;
    }
    for &(f, x, y) in p {
        let (x, y) = to(x, y);
        writeln!(
            s,
            r##"<circle class="cam" cx="{x:.1}" cy="{y:.1}" r="2.5" fill="#222"><title>frame {f}</title></circle>"##
        )?;
    }
    if let (Some(first), Some(last)) = (p.first(), p.last()) {
        for (pt, label) in [(first, "first"), (last, "last")] {
            let ((x, y), f) = (to(pt.1, pt.2), pt.0);
            let (x, y) = (x + 5.0, y - 5.0);
            writeln!(
                s,
                r#"<text x="{x:.1}" y="{y:.1}">{label} (frame {f})</text>"#
            )?;
        }
    }
    Ok(())
}

/// The colour scale legend of the spacings `d`, and a note on the axes.
fn write_legend(s: &mut String, d: &[f64], north_up: bool) -> fmt::Result {
    let ((lo, hi), lx) = (bounds(d.iter().copied()), SIZE + 30.0);
    writeln!(
        s,
        r#"<text x="{lx}" y="40">spacing to the previous camera</text>"#
    )?;
    let steps = 20;
    for i in 0..steps {
        let t = 1.0 - i as f64 / (steps - 1) as f64;
        writeln!(
            s,
            r#"<rect x="{lx}" y="{}" width="20" height="10" fill="{}"/>"#,
            50 + i * 10,
            scale_colour(t)
        )?;
    }
    if hi.is_finite() {
        let tx = lx + 26.0;
        writeln!(
            s,
            r#"<text x="{tx}" y="59">{hi:.4} (max)</text><text x="{tx}" y="{}">{lo:.4} (min)</text>"#,
            50 + steps * 10 - 1
        )?;
    }
    let (a, b) = if north_up {
        ("axes: east (right), north (up),", "metres (georegistered)")
    } else {
        ("axes: the two principal", "directions of the centres")
    };
    writeln!(
        s,
        r#"<text x="{lx}" y="{}">{a}</text><text x="{lx}" y="{}">{b}</text>"#,
        50 + steps * 10 + 30,
        50 + steps * 10 + 44
    )
}

/// The eigenvectors of the two largest eigenvalues of a symmetric matrix (nalgebra's symmetric
/// eigen solver), each with its largest component (the first of equal ones) positive; equal
/// eigenvalues are ordered by the index of their vector's largest component. These rules give
/// the orientation the earlier hand-made Jacobi solver gave on near-axis-aligned paths, and one
/// that no longer depends on the solver's iterations.
fn principal_axes(cov: Matrix3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let eig = SymmetricEigen::new(cov);
    let largest = |k: usize| -> usize {
        let v = eig.eigenvectors.column(k);
        (0..3).fold(0, |m, i| if v[i].abs() > v[m].abs() { i } else { m })
    };
    let vals = eig.eigenvalues;
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| vals[b].total_cmp(&vals[a]));
    // Equal spreads (a circle) have no preferred axes: take the one nearest the lower world axis
    // first, as the earlier solver did, rather than whatever order the solver returns.
    let tol = 1e-9 * vals.amax();
    for i in [0, 1, 0] {
        let (a, b) = (order[i], order[i + 1]);
        if (vals[a] - vals[b]).abs() <= tol && largest(b) < largest(a) {
            order.swap(i, i + 1);
        }
    }
    let axis = |k: usize| {
        let v: Vector3<f64> = eig.eigenvectors.column(k).into();
        if v[largest(k)] < 0.0 {
            -v
        } else {
            v
        }
    };
    (axis(order[0]), axis(order[1]))
}

/// Blue (t = 0, small spacing) through green to yellow (t = 1, large spacing).
pub fn scale_colour(t: f64) -> String {
    let stops = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = t.clamp(0.0, 1.0) * (stops.len() - 1) as f64;
    let i = (t.floor() as usize).min(stops.len() - 2);
    let f = t - i as f64;
    let c: Vec<u8> = (0..3)
        .map(|j| (stops[i][j] + (stops[i + 1][j] - stops[i][j]) * f).round() as u8)
        .collect();
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 40 points on a circle of radius 2 in a plane tilted by 0.6 rad about x, with a small
    /// wobble along the plane's normal.
    fn tilted_circle() -> CameraPath {
        let (s2, c2) = (0.6f64.sin(), 0.6f64.cos());
        let points = (0..40usize)
            .map(|i| {
                let a = i as f64 / 40.0 * std::f64::consts::TAU;
                let (u, w) = (2.0 * a.cos(), 2.0 * a.sin());
                let e = 0.01 * (3.0 * a).sin();
                let centre = [u, w * c2 - e * s2, w * s2 + e * c2];
                PathPoint {
                    frame: i * 5,
                    centre,
                }
            })
            .collect();
        CameraPath {
            points,
            north_up: false,
        }
    }

    #[test]
    fn principal_axes_recover_a_tilted_plane_path() {
        let (n, path) = (40, tilted_circle());
        let p = path.projected();
        assert_eq!(p.len(), n);
        for &(_, x, y) in &p {
            let r = (x * x + y * y).sqrt();
            assert!((r - 2.0).abs() < 0.02, "radius {r} off the circle");
        }
        let st = path.stats().unwrap();
        assert!(st.cv_spacing < 0.01, "equal steps: cv {}", st.cv_spacing);
        let expect = 2.0 * 2.0 * (std::f64::consts::PI / n as f64).sin();
        assert!((st.mean_spacing - expect).abs() < 0.01 * expect);
    }

    #[test]
    fn georegistered_path_is_drawn_east_right_north_up() {
        let path = CameraPath {
            points: vec![
                PathPoint {
                    frame: 0,
                    centre: [0.0, 0.0, 30.0],
                },
                PathPoint {
                    frame: 1,
                    centre: [0.0, 50.0, 31.0],
                },
            ],
            north_up: true,
        };
        assert_eq!(path.projected(), [(0, 0.0, 0.0), (1, 0.0, 50.0)]);
        let svg = path.svg();
        assert!(svg.contains("east (right), north (up)"), "{svg}");
        // The second camera, north of the first, is drawn above it.
        let to = plot_transform(&path.projected());
        assert!(to(0.0, 50.0).1 < to(0.0, 0.0).1);
    }

    #[test]
    fn orientation_is_that_of_the_earlier_jacobi_solver() {
        // First and last projected centres as the hand-made Jacobi solver gave them: the plot
        // must not come out mirrored or turned with nalgebra's eigenvectors.
        let near =
            |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9;
        let ends = |p: &CameraPath| {
            let v = p.projected();
            ((v[0].1, v[0].2), (v[v.len() - 1].1, v[v.len() - 1].2))
        };
        let helix = CameraPath {
            points: (0..60)
                .step_by(5)
                .map(|k| {
                    let a = k as f64 * 0.05;
                    PathPoint {
                        frame: k,
                        centre: [3.0 * a.cos(), 3.0 * a.sin(), 0.2 * a],
                    }
                })
                .collect(),
            north_up: false,
        };
        let line = CameraPath {
            points: (0..10)
                .map(|i| PathPoint {
                    frame: i,
                    centre: [
                        i as f64 * 0.3 + 1.0,
                        -(i as f64) * 0.8,
                        0.05 * (i % 2) as f64,
                    ],
                })
                .collect(),
            north_up: false,
        };
        // A circle: two equal principal spreads, the tie broken towards the lower world axis.
        let circle = tilted_circle();
        for (name, path, first, last) in [
            (
                "helix",
                &helix,
                (2.955339690225598, -1.4165516218319585),
                (-2.9553396902255984, -1.4165516218319587),
            ),
            (
                "line",
                &line,
                (3.84483997683643, -0.018181103389232567),
                (-3.8448399768364285, 0.018181103389232567),
            ),
            (
                "circle",
                &circle,
                (2.0, 0.0),
                (1.9753766811902753, -0.31286893008046224),
            ),
        ] {
            let (f, l) = ends(path);
            assert!(near(f, first) && near(l, last), "{name}: {f:?} {l:?}");
        }
    }

    #[test]
    fn colour_scale_ends() {
        assert_eq!(scale_colour(0.0), "#440154");
        assert_eq!(scale_colour(1.0), "#fde725");
        assert_eq!(scale_colour(7.0), "#fde725");
    }
}
