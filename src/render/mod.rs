//! Offline pictures of a run: the boundary surface rasterised into a
//! z-buffer (no GPU, no window), flat shaded, faces opened by cuts in a
//! second colour, optionally coloured by von Mises stress with a legend,
//! over the scene's ground plane. The camera is fitted to the first frame
//! and kept, so the frames of a run make a steady animation.
//!
//! The view is orthographic, from 60° left of the first horizontal axis and
//! 25° above the horizon, with `up` pointing up on screen (against gravity
//! in a scene). A face is a cut face when its rest position does not lie on
//! the first frame's boundary: cuts only open faces inside the body.

mod font;
mod raster;

use std::path::Path;

use cleave_kernels::vec3::{add, bounding_box, cross, dot, norm, point_triangle_distance, scale, sub};

use crate::io::IoError;
use crate::mesh::Plane;

pub use raster::Image;
use raster::Raster;

/// One frame's boundary surface.
#[derive(Clone, Copy, Debug)]
pub struct Surface<'a> {
    /// Rest positions of the nodes (m).
    pub rest: &'a [[f64; 3]],
    /// Current positions of the nodes (m).
    pub positions: &'a [[f64; 3]],
    /// Boundary triangles (node ids), outward.
    pub triangles: &'a [[u32; 3]],
    /// Von Mises stress per node (Pa), to colour by.
    pub stress: Option<&'a [f64]>,
}

/// Colours (linear 0..1 RGB).
const BODY: [f64; 3] = [0.60, 0.67, 0.78];
const CUT: [f64; 3] = [0.95, 0.55, 0.20];
const GROUND_LIGHT: [f64; 3] = [0.86, 0.86, 0.84];
const GROUND_DARK: [f64; 3] = [0.76, 0.76, 0.74];
const BACKGROUND: [u8; 3] = [250, 250, 250];

/// Renders the frames of one run (see module docs).
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Renderer {
    camera: Camera,
    original: OriginalSurface,
    ground: Vec<([[f64; 3]; 3], [f64; 3])>,
}

impl Renderer {
    /// A renderer whose camera frames `first` in a `width x height` image,
    /// with `up` (any length) pointing up on screen and the plane `ground`
    /// (if any) drawn under the body.
    pub fn new(first: &Surface<'_>, up: [f64; 3], ground: Option<Plane>, width: u32, height: u32) -> Self {
        // frame the body and its shadow straight down on the ground, where
        // pieces will land
        let mut framed = first.positions.to_vec();
        if let Some(p) = &ground {
            let n = normalize(p.normal);
            framed.extend(first.positions.iter().map(|x| sub(*x, scale(n, dot(sub(*x, p.point), n)))));
        }
        let camera = Camera::fit(&framed, up, width, height);
        let original = OriginalSurface::new(first.rest, first.triangles);
        let ground = ground.map(|p| ground_tiles(&p, first.positions)).unwrap_or_default();
        Renderer { camera, original, ground }
    }

    /// Pixels per metre of the fitted camera.
    pub fn pixels_per_metre(&self) -> f64 {
        self.camera.scale
    }

    /// The picture of `surface`: ground, body (cut faces in the second
    /// colour, or by stress), and the stress legend when coloured by stress.
    pub fn render(&self, surface: &Surface<'_>) -> Image {
        let cam = &self.camera;
        let mut raster = Raster::new(cam.width, cam.height, BACKGROUND);
        for (tri, colour) in &self.ground {
            raster.triangle(tri.map(|p| cam.project(p)), shade(cam, tri, *colour));
        }
        let most = surface.stress.map(stress_scale);
        for t in surface.triangles {
            let tri = t.map(|v| surface.positions[v as usize]);
            let colour = match (surface.stress, most) {
                (Some(s), Some(most)) if most > 0.0 => {
                    colour_map(t.iter().map(|&v| s[v as usize]).sum::<f64>() / (3.0 * most))
                }
                _ if self.original.contains(t.map(|v| surface.rest[v as usize])) => BODY,
                _ => CUT,
            };
            raster.triangle(tri.map(|p| cam.project(p)), shade(cam, &tri, colour));
        }
        let mut image = raster.into_image();
        if let Some(most) = most {
            legend(&mut image, most);
        }
        image
    }
}

/// An orthographic camera.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
struct Camera {
    center: [f64; 3],
    right: [f64; 3],
    up: [f64; 3],
    forward: [f64; 3],
    /// Direction to the light: over the viewer's left shoulder.
    light: [f64; 3],
    /// Pixels per metre.
    scale: f64,
    width: u32,
    height: u32,
}

impl Camera {
    /// Frames `points` with a margin.
    fn fit(points: &[[f64; 3]], up: [f64; 3], width: u32, height: u32) -> Self {
        let up = normalize(if norm(up) > 0.0 { up } else { [0.0, 0.0, 1.0] });
        // horizontal axes: world x (or y) with the up part taken out
        let pick = if up[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        let a = normalize(sub(pick, scale(up, dot(pick, up))));
        let b = cross(up, a);
        let (az, el) = ((-60.0f64).to_radians(), 25.0f64.to_radians());
        let eye = add(add(scale(a, el.cos() * az.cos()), scale(b, el.cos() * az.sin())), scale(up, el.sin()));
        let forward = scale(eye, -1.0);
        let right = normalize(cross(forward, up));
        let screen_up = cross(right, forward);
        let light = normalize(add(add(scale(right, -0.4), scale(screen_up, 0.6)), scale(forward, -0.7)));
        let (lo, hi) = bounds(points);
        let center = scale(add(lo, hi), 0.5);
        let (mut ex, mut ey) = (1e-12f64, 1e-12f64);
        for p in points {
            let d = sub(*p, center);
            ex = ex.max(dot(d, right).abs());
            ey = ey.max(dot(d, screen_up).abs());
        }
        let scale = 0.5 / 1.6 * (f64::from(width) / ex).min(f64::from(height) / ey);
        Camera { center, right, up: screen_up, forward, light, scale, width, height }
    }

    /// Pixel coordinates (x right, y down) and depth (m, larger is farther).
    fn project(&self, p: [f64; 3]) -> [f64; 3] {
        let d = sub(p, self.center);
        [
            0.5 * f64::from(self.width) + self.scale * dot(d, self.right),
            0.5 * f64::from(self.height) - self.scale * dot(d, self.up),
            dot(d, self.forward),
        ]
    }
}

/// Flat shading of a triangle: ambient plus a two-sided diffuse term from
/// a light over the viewer's left shoulder.
fn shade(cam: &Camera, tri: &[[f64; 3]; 3], colour: [f64; 3]) -> [u8; 3] {
    let n = cross(sub(tri[1], tri[0]), sub(tri[2], tri[0]));
    let lit = if norm(n) > 0.0 { dot(normalize(n), cam.light).abs() } else { 0.0 };
    let k = 0.35 + 0.65 * lit;
    colour.map(|c| (255.0 * (k * c).clamp(0.0, 1.0)).round() as u8)
}

/// The top of the stress colour scale (Pa): the 98th percentile of the
/// nodal values, so that a few hot nodes do not darken the rest (those
/// above it take the top colour).
fn stress_scale(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    let k = (0.98 * (v.len() - 1) as f64).round() as usize;
    let (_, top, _) = v.select_nth_unstable_by(k, f64::total_cmp);
    *top
}

/// A perceptually ordered colour map (viridis, by five of its stops) at
/// `t` in 0..1.
fn colour_map(t: f64) -> [f64; 3] {
    const STOPS: [[f64; 3]; 5] = [
        [0.267, 0.005, 0.329],
        [0.229, 0.322, 0.546],
        [0.128, 0.567, 0.551],
        [0.369, 0.789, 0.383],
        [0.993, 0.906, 0.144],
    ];
    let x = t.clamp(0.0, 1.0) * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f64;
    std::array::from_fn(|c| STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f)
}

/// The colour bar of the stress map at the right edge, labelled `0` at the
/// bottom and `most` (Pa) at the top.
fn legend(image: &mut Image, most: f64) {
    let (w, h) = (image.width(), image.height());
    let (x0, top, bottom) = (w.saturating_sub(60), h / 6, h - h / 6);
    for y in top..bottom {
        let c = colour_map(f64::from(bottom - y) / f64::from(bottom - top)).map(|v| (255.0 * v).round() as u8);
        for x in x0..x0 + 16 {
            image.set(x, y, c);
        }
    }
    let label = format!("{most:.2e} Pa");
    let width = font::width(&label, 2);
    font::draw(image, &label, w.saturating_sub(width + 6), top.saturating_sub(22), 2);
    font::draw(image, "0", x0, bottom + 6, 2);
    font::draw(image, "von Mises", w.saturating_sub(font::width("von Mises", 2) + 6), top.saturating_sub(44), 2);
}

/// The ground plane as a checkerboard of tiles around the body's footprint.
fn ground_tiles(plane: &Plane, points: &[[f64; 3]]) -> Vec<([[f64; 3]; 3], [f64; 3])> {
    let n = normalize(plane.normal);
    let (lo, hi) = bounds(points);
    let center = scale(add(lo, hi), 0.5);
    let foot = sub(center, scale(n, dot(sub(center, plane.point), n)));
    let radius = 1.2 * norm(sub(hi, lo)).max(1e-3);
    let pick = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let a = normalize(sub(pick, scale(n, dot(pick, n))));
    let b = cross(n, a);
    let tiles = 12;
    let size = 2.0 * radius / f64::from(tiles);
    let mut out = Vec::with_capacity(2 * (tiles * tiles) as usize);
    for i in 0..tiles {
        for j in 0..tiles {
            let at = |u: u32, v: u32| {
                let (s, t) = (-radius + size * f64::from(u), -radius + size * f64::from(v));
                add(foot, add(scale(a, s), scale(b, t)))
            };
            let colour = if (i + j) % 2 == 0 { GROUND_LIGHT } else { GROUND_DARK };
            out.push(([at(i, j), at(i + 1, j), at(i + 1, j + 1)], colour));
            out.push(([at(i, j), at(i + 1, j + 1), at(i, j + 1)], colour));
        }
    }
    out
}

/// The first frame's boundary at rest, to tell original faces from cut
/// ones: triangles hashed by the grid cells their bounding boxes touch.
#[derive(serde::Serialize, serde::Deserialize)]
struct OriginalSurface {
    triangles: Vec<[[f64; 3]; 3]>,
    cells: rustc_hash::FxHashMap<[i64; 3], Vec<u32>>,
    cell: f64,
    tolerance: f64,
}

impl OriginalSurface {
    fn new(rest: &[[f64; 3]], triangles: &[[u32; 3]]) -> Self {
        let triangles: Vec<[[f64; 3]; 3]> = triangles.iter().map(|t| t.map(|v| rest[v as usize])).collect();
        let (lo, hi) = bounds(rest);
        let diagonal = norm(sub(hi, lo)).max(1e-12);
        let mean_edge = triangles.iter().map(|t| norm(sub(t[1], t[0]))).sum::<f64>() / triangles.len().max(1) as f64;
        let cell = (2.0 * mean_edge).max(1e-6 * diagonal);
        let mut cells: rustc_hash::FxHashMap<[i64; 3], Vec<u32>> = Default::default();
        for (i, t) in triangles.iter().enumerate() {
            let (a, b) = bounds(t);
            let (ka, kb) = (key(a, cell), key(b, cell));
            for x in ka[0]..=kb[0] {
                for y in ka[1]..=kb[1] {
                    for z in ka[2]..=kb[2] {
                        cells.entry([x, y, z]).or_default().push(i as u32);
                    }
                }
            }
        }
        OriginalSurface { triangles, cells, cell, tolerance: 1e-7 * diagonal }
    }

    /// Whether the triangle `t` (rest positions) lies on the original
    /// boundary (its centroid within tolerance of an original triangle).
    fn contains(&self, t: [[f64; 3]; 3]) -> bool {
        let q = scale(add(add(t[0], t[1]), t[2]), 1.0 / 3.0);
        self.cells.get(&key(q, self.cell)).is_some_and(|list| {
            list.iter().any(|&i| point_triangle_distance(q, &self.triangles[i as usize]) <= self.tolerance)
        })
    }
}

fn key(p: [f64; 3], cell: f64) -> [i64; 3] {
    p.map(|c| (c / cell).floor() as i64)
}

/// Writes `image` as an 8-bit RGB PNG, creating its folder.
pub fn write_png(path: &Path, image: &Image) -> Result<(), IoError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
    }
    let file = std::fs::File::create(path).map_err(|e| IoError::os(path, e))?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), image.width(), image.height());
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let os = |e: png::EncodingError| IoError::os(path, std::io::Error::other(e));
    let mut writer = encoder.write_header().map_err(os)?;
    writer.write_image_data(image.pixels()).map_err(os)?;
    writer.finish().map_err(os)
}

/// The bounding box of `points`, the origin when there are none.
fn bounds(points: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    if points.is_empty() {
        return ([0.0; 3], [0.0; 3]);
    }
    bounding_box(points)
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let n = norm(a);
    if n > 0.0 {
        scale(a, 1.0 / n)
    } else {
        a
    }
}
