//! A z-buffered triangle rasteriser over an RGB image.

/// An 8-bit RGB image, rows top to bottom.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Image {
    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The pixels, `3 width height` bytes, row after row from the top.
    pub fn pixels(&self) -> &[u8] {
        &self.rgb
    }

    /// The colour at `(x, y)` (from the top left).
    pub fn get(&self, x: u32, y: u32) -> [u8; 3] {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Sets `(x, y)` to `c`; outside the image, nothing.
    pub fn set(&mut self, x: u32, y: u32, c: [u8; 3]) {
        if x < self.width && y < self.height {
            let i = 3 * (y as usize * self.width as usize + x as usize);
            self.rgb[i..i + 3].copy_from_slice(&c);
        }
    }
}

/// An image and its depth buffer.
pub(super) struct Raster {
    image: Image,
    depth: Vec<f64>,
}

impl Raster {
    /// A `width x height` raster filled with `background`, infinitely deep.
    pub fn new(width: u32, height: u32, background: [u8; 3]) -> Self {
        let n = width as usize * height as usize;
        Raster {
            image: Image { width, height, rgb: background.iter().copied().cycle().take(3 * n).collect() },
            depth: vec![f64::INFINITY; n],
        }
    }

    /// Fills the triangle of pixel-space corners `(x, y, depth)` with
    /// `colour` where it is nearer than what is there: pixel centres
    /// inside (either winding), depth interpolated linearly.
    pub fn triangle(&mut self, p: [[f64; 3]; 3], colour: [u8; 3]) {
        let area = edge(p[0], p[1], p[2]);
        if !(area.abs() > 0.0) || p.iter().flatten().any(|v| !v.is_finite()) {
            return;
        }
        let (w, h) = (f64::from(self.image.width), f64::from(self.image.height));
        let lo = |k: usize| p.iter().map(|q| q[k]).fold(f64::INFINITY, f64::min);
        let hi = |k: usize| p.iter().map(|q| q[k]).fold(f64::NEG_INFINITY, f64::max);
        let (x0, x1) = (lo(0).max(0.0).floor() as u32, hi(0).min(w - 1.0).ceil().max(0.0) as u32);
        let (y0, y1) = (lo(1).max(0.0).floor() as u32, hi(1).min(h - 1.0).ceil().max(0.0) as u32);
        for y in y0..=y1.min(self.image.height.saturating_sub(1)) {
            for x in x0..=x1.min(self.image.width.saturating_sub(1)) {
                let q = [f64::from(x) + 0.5, f64::from(y) + 0.5, 0.0];
                let b = [edge(p[1], p[2], q) / area, edge(p[2], p[0], q) / area, edge(p[0], p[1], q) / area];
                if b.iter().any(|&v| v < 0.0) {
                    continue;
                }
                let z = b[0] * p[0][2] + b[1] * p[1][2] + b[2] * p[2][2];
                let i = y as usize * self.image.width as usize + x as usize;
                if z < self.depth[i] {
                    self.depth[i] = z;
                    self.image.set(x, y, colour);
                }
            }
        }
    }

    pub fn into_image(self) -> Image {
        self.image
    }
}

/// Twice the signed area of `(a, b, c)` in the pixel plane.
fn edge(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}
