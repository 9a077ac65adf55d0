//! The static and moving content of a synthetic scene: a fractal height-field terrain (mesh and
//! exact height lookup on its triangles), a non-periodic patchwork texture made of real photos,
//! a photo atlas for boxes, and box objects (buildings, driving cars, optional markers) with their
//! poses at any time. Everything is a pure function of the seed and the photos.

use super::math::{Noise, Rng, V3};
use keyframer::error::{Error, Result};
use std::path::Path;

/// Terrain half size (metres): the terrain covers [-HALF, HALF]² in x and y.
pub const HALF: f64 = 260.0;
/// Grid cells per side.
pub const CELLS: usize = 256;
/// Cells per side of a terrain chunk (the unit of view culling).
pub const CHUNK: usize = 16;
/// Indices per chunk.
pub const CHUNK_INDICES: u32 = (CHUNK * CHUNK * 6) as u32;
/// Terrain texture size (texels per side).
pub const TERRAIN_TEX: u32 = 4096;
/// Object atlas size (texels per side, four photos in quadrants).
pub const ATLAS_TEX: u32 = 1024;

/// Photos (Debian opencv-doc examples) blended into the terrain texture; aerial ones twice.
pub const TERRAIN_PHOTOS: &[&str] = &[
    "aero1.jpg",
    "aero3.jpg",
    "aero1.jpg",
    "aero3.jpg",
    "home.jpg",
    "stuff.jpg",
    "graf1.png",
    "leuvenA.jpg",
    "ela_original.jpg",
    "aloeL.jpg",
    "fruits.jpg",
    "orange.jpg",
    "butterfly.jpg",
    "squirrel_cls.jpg",
    "starry_night.jpg",
    "building.jpg",
];
/// Photos of the object atlas quadrants: building facades (0, 1), car bodies (2, 3).
pub const ATLAS_PHOTOS: &[&str] = &["building.jpg", "home.jpg", "baboon.jpg", "graf1.png"];

/// The fractal height field.
#[derive(Debug, Clone)]
pub struct Terrain {
    /// Heights at the (CELLS+1)² grid vertices, row-major, row = y index.
    pub heights: Vec<f32>,
}

impl Terrain {
    /// Smooth hills of a few tens of metres from `seed`.
    pub fn new(seed: u64) -> Terrain {
        let n = Noise(seed ^ 0x007E_77A1);
        let ridge = Noise(seed ^ 0x0004_1D6E);
        let verts = CELLS + 1;
        let mut heights = Vec::with_capacity(verts * verts);
        for j in 0..verts {
            for i in 0..verts {
                let (x, y) = grid_xy(i, j);
                let hills = 26.0 * n.fbm(x / 120.0, y / 120.0, 5);
                let bumps = 4.0 * ridge.fbm(x / 25.0, y / 25.0, 3);
                heights.push((hills + bumps) as f32);
            }
        }
        Terrain { heights }
    }

    /// The same terrain levelled within `radius` metres of (`x`, `y`) to the height there,
    /// blending back into the hills over the next `blend` metres (a street on flat ground).
    pub fn levelled(mut self, (x, y): (f64, f64), radius: f64, blend: f64) -> Terrain {
        let level = self.height(x, y);
        let verts = CELLS + 1;
        for j in 0..verts {
            for i in 0..verts {
                let (gx, gy) = grid_xy(i, j);
                let d = (gx - x).hypot(gy - y);
                let u = ((d - radius) / blend).clamp(0.0, 1.0);
                let w = u * u * (3.0 - 2.0 * u);
                let h = &mut self.heights[j * verts + i];
                *h = (level + w * (*h as f64 - level)) as f32;
            }
        }
        self
    }

    fn h(&self, i: usize, j: usize) -> f64 {
        self.heights[j * (CELLS + 1) + i] as f64
    }

    /// Height of the rendered surface at (x, y): interpolated on the same two triangles per cell
    /// as the mesh (clamped to the terrain).
    pub fn height(&self, x: f64, y: f64) -> f64 {
        let cell = 2.0 * HALF / CELLS as f64;
        let gx = ((x + HALF) / cell).clamp(0.0, CELLS as f64 - 1e-9);
        let gy = ((y + HALF) / cell).clamp(0.0, CELLS as f64 - 1e-9);
        let (i, j) = (gx.floor() as usize, gy.floor() as usize);
        let (u, v) = (gx - i as f64, gy - j as f64);
        let (h00, h10) = (self.h(i, j), self.h(i + 1, j));
        let (h01, h11) = (self.h(i, j + 1), self.h(i + 1, j + 1));
        if u >= v {
            h00 + u * (h10 - h00) + v * (h11 - h10)
        } else {
            h00 + v * (h01 - h00) + u * (h11 - h01)
        }
    }

    /// Mesh vertices (position, normal, uv in the terrain texture) and triangle indices matching
    /// [`Terrain::height`].
    pub fn mesh(&self) -> (Vec<Vertex>, Vec<u32>) {
        let verts = CELLS + 1;
        let cell = 2.0 * HALF / CELLS as f64;
        let mut v = Vec::with_capacity(verts * verts);
        for j in 0..verts {
            for i in 0..verts {
                let (x, y) = grid_xy(i, j);
                let hx = self.h((i + 1).min(CELLS), j) - self.h(i.saturating_sub(1), j);
                let hy = self.h(i, (j + 1).min(CELLS)) - self.h(i, j.saturating_sub(1));
                let dx = cell * ((i + 1).min(CELLS) - i.saturating_sub(1)) as f64;
                let dy = cell * ((j + 1).min(CELLS) - j.saturating_sub(1)) as f64;
                let nrm = V3(-hx / dx, -hy / dy, 1.0).unit();
                v.push(Vertex {
                    pos: [x as f32, y as f32, self.h(i, j) as f32],
                    normal: [nrm.0 as f32, nrm.1 as f32, nrm.2 as f32],
                    uv: [i as f32 / CELLS as f32, 1.0 - j as f32 / CELLS as f32],
                });
            }
        }
        // Indices grouped by chunk (row-major chunks of CHUNK² cells) so that the renderer can
        // draw only the chunks in view.
        let mut idx = Vec::with_capacity(CELLS * CELLS * 6);
        for cj in 0..CELLS / CHUNK {
            for ci in 0..CELLS / CHUNK {
                for j in cj * CHUNK..(cj + 1) * CHUNK {
                    for i in ci * CHUNK..(ci + 1) * CHUNK {
                        let a = (j * verts + i) as u32;
                        let (b, c, d) = (a + 1, a + 1 + verts as u32, a + verts as u32);
                        idx.extend_from_slice(&[a, b, c, a, c, d]);
                    }
                }
            }
        }
        (v, idx)
    }
}

impl Terrain {
    /// Bounding boxes (min, max corners) of the mesh chunks, in index-buffer order; chunk `k`
    /// owns indices `k * CHUNK_INDICES .. (k + 1) * CHUNK_INDICES`.
    pub fn chunk_bounds(&self) -> Vec<(V3, V3)> {
        let mut out = Vec::new();
        for cj in 0..CELLS / CHUNK {
            for ci in 0..CELLS / CHUNK {
                let (mut lo, mut hi) = (f64::MAX, f64::MIN);
                for j in cj * CHUNK..=(cj + 1) * CHUNK {
                    for i in ci * CHUNK..=(ci + 1) * CHUNK {
                        lo = lo.min(self.h(i, j));
                        hi = hi.max(self.h(i, j));
                    }
                }
                let (x0, y0) = grid_xy(ci * CHUNK, cj * CHUNK);
                let (x1, y1) = grid_xy((ci + 1) * CHUNK, (cj + 1) * CHUNK);
                out.push((V3(x0, y0, lo), V3(x1, y1, hi)));
            }
        }
        out
    }
}

fn grid_xy(i: usize, j: usize) -> (f64, f64) {
    let cell = 2.0 * HALF / CELLS as f64;
    (-HALF + i as f64 * cell, -HALF + j as f64 * cell)
}

/// A mesh vertex as the render pipeline reads it.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    /// Position (metres; world for the terrain, object-local for boxes).
    pub pos: [f32; 3],
    /// Unit normal in the same frame.
    pub normal: [f32; 3],
    /// Texture coordinate.
    pub uv: [f32; 2],
}

/// The unit box [-0.5, 0.5]³ with per-face normals and uv 0..1 on each face.
pub fn box_mesh() -> (Vec<Vertex>, Vec<u32>) {
    let faces: [([f32; 3], [f32; 3], [f32; 3]); 6] = [
        ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
        ([-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        ([0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
    ];
    let mut v = Vec::new();
    let mut idx = Vec::new();
    for (n, u, w) in faces {
        let base = v.len() as u32;
        for (a, b) in [(-0.5f32, -0.5f32), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)] {
            let p = [
                0.5 * n[0] + a * u[0] + b * w[0],
                0.5 * n[1] + a * u[1] + b * w[1],
                0.5 * n[2] + a * u[2] + b * w[2],
            ];
            v.push(Vertex {
                pos: p,
                normal: n,
                uv: [a + 0.5, 0.5 - b],
            });
        }
        idx.extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    (v, idx)
}

/// What a box is, which decides its material.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// A static textured block.
    Building,
    /// A textured box driving around a closed loop.
    Car,
    /// An unlit flat magenta square at a known position (test aid).
    Marker,
    /// A static block whose faces show the terrain's photo patchwork, each face a part of it no
    /// other wall shows (the walk's street: no two walls alike).
    Wall,
}

/// One box in the scene.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Object {
    /// Its role.
    pub kind: Kind,
    /// Size along its local x (length), y (width), z (height), metres.
    pub size: [f64; 3],
    /// Atlas quadrant of its texture (0..4).
    pub quadrant: u32,
    /// RGB multiplier of its texture (markers: the colour).
    pub tint: [f64; 3],
    /// Static objects: centre (x, y, z) and yaw (radians). Cars: see `path`.
    pub centre: [f64; 3],
    /// Yaw of a static object (radians about +z).
    pub yaw: f64,
    /// Cars: the loop they drive.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path: Option<CarPath>,
}

/// A car's loop: a circle around `centre` of `radius`, at `speed` m/s, starting at polar angle
/// `phase`, counter-clockwise if `ccw`.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct CarPath {
    /// Circle centre (x, y), metres.
    pub centre: [f64; 2],
    /// Radius, metres.
    pub radius: f64,
    /// Speed, m/s.
    pub speed: f64,
    /// Polar angle at t = 0, radians.
    pub phase: f64,
    /// Direction of travel.
    pub ccw: bool,
}

impl Object {
    /// (centre, yaw) at time `t`; cars follow the terrain surface.
    pub fn placement(&self, t: f64, terrain: &Terrain) -> (V3, f64) {
        match &self.path {
            None => (V3(self.centre[0], self.centre[1], self.centre[2]), self.yaw),
            Some(p) => {
                let dir = if p.ccw { 1.0 } else { -1.0 };
                let a = p.phase + dir * p.speed * t / p.radius;
                let (x, y) = (
                    p.centre[0] + p.radius * a.cos(),
                    p.centre[1] + p.radius * a.sin(),
                );
                let z = terrain.height(x, y) + 0.5 * self.size[2] + 0.15;
                (V3(x, y, z), a + dir * std::f64::consts::FRAC_PI_2)
            }
        }
    }
}

/// Buildings, cars and (with `markers`) marker squares laid out near the flight's ground track.
pub fn objects(seed: u64, terrain: &Terrain, track: &[(f64, f64)], markers: bool) -> Vec<Object> {
    let mut rng = Rng::new(seed, 23);
    let mut out = Vec::new();
    let near = |rng: &mut Rng, spread: f64| {
        let (x, y) = if track.is_empty() {
            (0.0, 0.0)
        } else {
            track[(rng.unit() * track.len() as f64) as usize % track.len()]
        };
        let (x, y) = (
            x + rng.range(-spread, spread),
            y + rng.range(-spread, spread),
        );
        (
            x.clamp(-HALF + 20.0, HALF - 20.0),
            y.clamp(-HALF + 20.0, HALF - 20.0),
        )
    };
    for k in 0..7 {
        let (x, y) = near(&mut rng, 45.0);
        let size = [
            rng.range(8.0, 18.0),
            rng.range(8.0, 16.0),
            rng.range(6.0, 18.0),
        ];
        let yaw = rng.range(0.0, std::f64::consts::PI);
        // Sink the block to the lowest terrain under its footprint.
        let r = 0.5 * size[0].hypot(size[1]);
        let mut low = f64::MAX;
        for a in 0..8 {
            let ang = a as f64 * std::f64::consts::FRAC_PI_4;
            low = low.min(terrain.height(x + r * ang.cos(), y + r * ang.sin()));
        }
        low = low.min(terrain.height(x, y)) - 0.5;
        let shade = rng.range(0.8, 1.1);
        out.push(Object {
            kind: Kind::Building,
            size,
            quadrant: k % 2,
            tint: [shade, shade, shade * rng.range(0.9, 1.05)],
            centre: [x, y, low + 0.5 * size[2]],
            yaw,
            path: None,
        });
    }
    let colours = [
        [1.3, 0.5, 0.45],
        [0.5, 0.8, 1.4],
        [1.3, 1.2, 0.4],
        [0.6, 1.25, 0.6],
    ];
    for (k, tint) in colours.iter().enumerate() {
        let (x, y) = near(&mut rng, 15.0);
        out.push(Object {
            kind: Kind::Car,
            size: [4.6, 2.0, 1.6],
            quadrant: 2 + (k as u32 % 2),
            tint: *tint,
            centre: [x, y, 0.0],
            yaw: 0.0,
            path: Some(CarPath {
                centre: [x, y],
                radius: rng.range(15.0, 35.0),
                speed: rng.range(6.0, 12.0),
                phase: rng.range(0.0, std::f64::consts::TAU),
                ccw: rng.unit() < 0.5,
            }),
        });
    }
    if markers {
        for _ in 0..16 {
            let (x, y) = near(&mut rng, 25.0);
            out.push(Object {
                kind: Kind::Marker,
                size: [2.0, 2.0, 0.05],
                quadrant: 0,
                tint: [1.0, 0.0, 1.0],
                centre: [x, y, terrain.height(x, y) + 0.8],
                yaw: 0.0,
                path: None,
            });
        }
    }
    out
}

/// An RGBA8 image with its mip chain (level 0 first).
pub struct MipImage {
    /// Side length of level 0.
    pub size: u32,
    /// Levels, each `size >> k` squared, RGBA8.
    pub levels: Vec<Vec<u8>>,
}

fn load_photo(dir: &Path, name: &str) -> Result<image::RgbImage> {
    let p = dir.join(name);
    image::open(&p)
        .map(|i| i.to_rgb8())
        .map_err(|e| Error::input(&p, format!("cannot read texture photo: {e}")))
}

fn sample(img: &image::RgbImage, x: f64, y: f64) -> [f64; 3] {
    // Mirrored repeat, bilinear.
    let (w, h) = (img.width() as i64, img.height() as i64);
    let fold = |v: i64, n: i64| {
        let m = v.rem_euclid(2 * n);
        if m < n {
            m
        } else {
            2 * n - 1 - m
        }
    };
    let (fx, fy) = (x.floor(), y.floor());
    let (ax, ay) = (x - fx, y - fy);
    let mut out = [0.0; 3];
    for (dx, dy, wgt) in [
        (0, 0, (1.0 - ax) * (1.0 - ay)),
        (1, 0, ax * (1.0 - ay)),
        (0, 1, (1.0 - ax) * ay),
        (1, 1, ax * ay),
    ] {
        let px = img.get_pixel(
            fold(fx as i64 + dx, w) as u32,
            fold(fy as i64 + dy, h) as u32,
        );
        for c in 0..3 {
            out[c] += wgt * px[c] as f64;
        }
    }
    out
}

/// How one patch of the terrain texture maps a photo.
struct Patch {
    photo: usize,
    cos: f64,
    sin: f64,
    scale: f64,
    offset: (f64, f64),
    tint: [f64; 3],
}

/// The terrain texture: a patchwork of photos in irregular (domain-warped Voronoi) cells, each
/// with its own rotation, scale, offset and tint, blended across cell borders, plus a slow
/// colour variation. Nothing repeats periodically.
pub fn terrain_texture(dir: &Path, seed: u64, size: u32) -> Result<MipImage> {
    let photos: Vec<image::RgbImage> = TERRAIN_PHOTOS
        .iter()
        .map(|n| load_photo(dir, n))
        .collect::<Result<_>>()?;
    let mut rng = Rng::new(seed, 31);
    let grid = 10usize;
    let mut seeds = Vec::new();
    let mut patches = Vec::new();
    for gy in 0..grid {
        for gx in 0..grid {
            seeds.push((
                (gx as f64 + rng.range(0.15, 0.85)) / grid as f64,
                (gy as f64 + rng.range(0.15, 0.85)) / grid as f64,
            ));
            let a = rng.range(0.0, std::f64::consts::TAU);
            let t = rng.range(0.85, 1.12);
            patches.push(Patch {
                photo: (gy * grid + gx + (rng.unit() * 3.0) as usize) % photos.len(),
                cos: a.cos(),
                sin: a.sin(),
                scale: rng.range(0.9, 1.5),
                offset: (rng.range(0.0, 2000.0), rng.range(0.0, 2000.0)),
                tint: [
                    t * rng.range(0.9, 1.1),
                    t * rng.range(0.9, 1.1),
                    t * rng.range(0.85, 1.05),
                ],
            });
        }
    }
    let warp = Noise(seed ^ 0x3A2F);
    let tone = Noise(seed ^ 0x70E);
    let n = size as usize;
    // Smooth fields (cell-border warp, brightness, warmth) on a coarse grid, interpolated per texel.
    const STEP: usize = 8;
    let g = n / STEP + 2;
    let mut fields = vec![[0f64; 4]; g * g];
    for gy in 0..g {
        for gx in 0..g {
            let (u, v) = ((gx * STEP) as f64 / n as f64, (gy * STEP) as f64 / n as f64);
            fields[gy * g + gx] = [
                0.035 * warp.fbm(u * 6.0, v * 6.0, 3),
                0.035 * warp.fbm(u * 6.0 + 17.0, v * 6.0 - 9.0, 3),
                1.0 + 0.18 * tone.fbm(u * 14.0, v * 14.0, 4),
                0.06 * tone.fbm(u * 5.0 + 3.0, v * 5.0, 2),
            ];
        }
    }
    let field = |px: usize, py: usize| {
        let (gx, gy) = (px / STEP, py / STEP);
        let (ax, ay) = (
            (px % STEP) as f64 / STEP as f64,
            (py % STEP) as f64 / STEP as f64,
        );
        let (a, b) = (fields[gy * g + gx], fields[gy * g + gx + 1]);
        let (c, d) = (fields[(gy + 1) * g + gx], fields[(gy + 1) * g + gx + 1]);
        let mut out = [0f64; 4];
        for k in 0..4 {
            let top = a[k] + (b[k] - a[k]) * ax;
            let bottom = c[k] + (d[k] - c[k]) * ax;
            out[k] = top + (bottom - top) * ay;
        }
        out
    };
    let mut level0 = vec![0u8; n * n * 4];
    let texel = |px: usize, py: usize| -> [u8; 4] {
        let (u, v) = ((px as f64 + 0.5) / n as f64, (py as f64 + 0.5) / n as f64);
        let [du, dv, g, warm] = field(px, py);
        let (wu, wv) = (u + du, v + dv);
        let (cx, cy) = ((wu * grid as f64) as i64, (wv * grid as f64) as i64);
        let (mut d1, mut i1, mut d2, mut i2) = (f64::MAX, 0usize, f64::MAX, 0usize);
        for oy in -1..=1 {
            for ox in -1..=1 {
                let (gx, gy) = (cx + ox, cy + oy);
                if gx < 0 || gy < 0 || gx >= grid as i64 || gy >= grid as i64 {
                    continue;
                }
                let k = gy as usize * grid + gx as usize;
                let (ex, ey) = (wu - seeds[k].0, wv - seeds[k].1);
                let d = ex * ex + ey * ey;
                if d < d1 {
                    (d2, i2) = (d1, i1);
                    (d1, i1) = (d, k);
                } else if d < d2 {
                    (d2, i2) = (d, k);
                }
            }
        }
        let colour = |k: usize| {
            let p = &patches[k];
            let (x, y) = (px as f64 - n as f64 * 0.5, py as f64 - n as f64 * 0.5);
            let sx = (p.cos * x - p.sin * y) * p.scale + p.offset.0;
            let sy = (p.sin * x + p.cos * y) * p.scale + p.offset.1;
            let c = sample(&photos[p.photo], sx, sy);
            [c[0] * p.tint[0], c[1] * p.tint[1], c[2] * p.tint[2]]
        };
        let t = ((d2.sqrt() - d1.sqrt()) / 0.012).clamp(0.0, 1.0);
        let w1 = 0.5 + 0.5 * t;
        let c1 = colour(i1);
        let c = if w1 < 0.999 {
            let c2 = colour(i2);
            [
                w1 * c1[0] + (1.0 - w1) * c2[0],
                w1 * c1[1] + (1.0 - w1) * c2[1],
                w1 * c1[2] + (1.0 - w1) * c2[2],
            ]
        } else {
            c1
        };
        [
            (c[0] * g * (1.0 + warm)).clamp(0.0, 255.0) as u8,
            (c[1] * g).clamp(0.0, 255.0) as u8,
            (c[2] * g * (1.0 - warm)).clamp(0.0, 255.0) as u8,
            255,
        ]
    };
    let threads = std::thread::available_parallelism()
        .map_or(2, |n| n.get())
        .min(8);
    let rows_per = n.div_ceil(threads);
    std::thread::scope(|sc| {
        for (k, chunk) in level0.chunks_mut(rows_per * n * 4).enumerate() {
            let texel = &texel;
            sc.spawn(move || {
                for (r, row) in chunk.chunks_mut(n * 4).enumerate() {
                    let py = k * rows_per + r;
                    for px in 0..n {
                        row[px * 4..px * 4 + 4].copy_from_slice(&texel(px, py));
                    }
                }
            });
        }
    });
    Ok(with_mips(size, level0))
}

/// The object atlas: four photos, each resized (cover, bilinear) into a quadrant.
pub fn atlas(dir: &Path) -> Result<MipImage> {
    let n = ATLAS_TEX as usize;
    let q = n / 2;
    let mut data = vec![255u8; n * n * 4];
    for (k, name) in ATLAS_PHOTOS.iter().enumerate() {
        let img = load_photo(dir, name)?;
        let scale = img.width().min(img.height()) as f64 / q as f64;
        let (ox, oy) = ((k % 2) * q, (k / 2) * q);
        for y in 0..q {
            for x in 0..q {
                let c = sample(
                    &img,
                    (x as f64 + 0.5) * scale - 0.5,
                    (y as f64 + 0.5) * scale - 0.5,
                );
                let o = ((oy + y) * n + ox + x) * 4;
                for ch in 0..3 {
                    data[o + ch] = c[ch].clamp(0.0, 255.0) as u8;
                }
            }
        }
    }
    Ok(with_mips(ATLAS_TEX, data))
}

fn with_mips(size: u32, level0: Vec<u8>) -> MipImage {
    let mut levels = vec![level0];
    let mut s = size as usize;
    while s > 1 {
        let h = s / 2;
        let prev = &levels[levels.len() - 1];
        let mut next = vec![0u8; h * h * 4];
        for y in 0..h {
            for x in 0..h {
                for c in 0..4 {
                    let at = |xx: usize, yy: usize| prev[(yy * s + xx) * 4 + c] as u32;
                    let sum = at(2 * x, 2 * y)
                        + at(2 * x + 1, 2 * y)
                        + at(2 * x, 2 * y + 1)
                        + at(2 * x + 1, 2 * y + 1);
                    next[(y * h + x) * 4 + c] = ((sum + 2) / 4) as u8;
                }
            }
        }
        levels.push(next);
        s = h;
    }
    MipImage { size, levels }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn height_matches_mesh_vertices_and_has_relief() {
        let t = Terrain::new(5);
        let (v, idx) = t.mesh();
        assert_eq!(idx.len(), CELLS * CELLS * 6);
        for k in [0, 1000, 33_000, v.len() - 1] {
            let p = v[k].pos;
            let h = t.height(p[0] as f64, p[1] as f64);
            assert!(
                (h - p[2] as f64).abs() < 1e-3,
                "vertex {k}: {h} vs {}",
                p[2]
            );
        }
        let lo = t.heights.iter().copied().fold(f32::MAX, f32::min);
        let hi = t.heights.iter().copied().fold(f32::MIN, f32::max);
        assert!(hi - lo > 15.0, "relief {lo}..{hi}");
    }
}
