//! Complex triangles (F&P04 §4.2, spec vision-model.md §4.4): contour walk, rupture
//! pixels, and directional interpolation along the least-discrepancy direction.

use super::mesh::Tri;
use crate::raster::{PixelCoord, Rgb};

/// Triangles whose longest edge is below this many pixels are traced completely (F&P04).
pub const FULL_TRACE_BELOW: f64 = 5.0;

/// A reusable "seen" stamp per pixel, so contour walks have no duplicate pixels without
/// allocating a set per triangle.
pub struct Stamp {
    mark: Vec<u32>,
    cur: u32,
}

impl Stamp {
    #[must_use]
    pub fn new(n: usize) -> Self {
        Self {
            mark: vec![0; n],
            cur: 0,
        }
    }
    fn next(&mut self) {
        self.cur = self.cur.wrapping_add(1);
        if self.cur == 0 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.cur = 1;
        }
    }
    /// True the first time `i` is seen since the last `next`.
    fn first(&mut self, i: usize) -> bool {
        let fresh = self.mark[i] != self.cur;
        self.mark[i] = self.cur;
        fresh
    }
}

/// One contour pixel: which edge it was walked on (0: v0→v1, 1: v1→v2, 2: v2→v0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContourPixel {
    pub p: PixelCoord,
    pub edge: u8,
}

/// The contour of `tri` in counter-clockwise ("trigonometric") order: a Bresenham walk of
/// each edge without its end vertex (the next edge starts there), skipping pixels already
/// walked (slivers whose edges share pixels). Starts at `v[0]`.
pub fn contour(tri: &Tri, width: u32, stamp: &mut Stamp, out: &mut Vec<ContourPixel>) {
    out.clear();
    stamp.next();
    for e in 0..3 {
        let (a, b) = (tri.v[e], tri.v[(e + 1) % 3]);
        let (mut x, mut y) = (i64::from(a.x), i64::from(a.y));
        let (x1, y1) = (i64::from(b.x), i64::from(b.y));
        let dx = (x1 - x).abs();
        let dy = -(y1 - y).abs();
        let sx = if x < x1 { 1 } else { -1 };
        let sy = if y < y1 { 1 } else { -1 };
        let mut err = dx + dy;
        while (x, y) != (x1, y1) {
            let i = y as usize * width as usize + x as usize;
            if stamp.first(i) {
                out.push(ContourPixel {
                    p: PixelCoord::new(x as u32, y as u32),
                    edge: e as u8,
                });
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }
}

/// [`contour`] with its own stamp and buffer, reused from triangle to triangle.
pub struct ContourWalker {
    stamp: Stamp,
    buf: Vec<ContourPixel>,
    width: u32,
}

impl ContourWalker {
    /// A walker over an image `width` pixels wide holding `n` pixels.
    #[must_use]
    pub fn new(width: u32, n: usize) -> Self {
        Self {
            stamp: Stamp::new(n),
            buf: Vec::new(),
            width,
        }
    }

    /// The contour of `tri` ([`contour`]), valid until the next walk.
    pub fn walk(&mut self, tri: &Tri) -> &[ContourPixel] {
        contour(tri, self.width, &mut self.stamp, &mut self.buf);
        &self.buf
    }
}

/// Where a line meets the contour: (line parameter t, edge index, edge parameter s).
pub type Hit = (f64, usize, f64);

/// The contour's values as a function on the triangle boundary (spec §4.4 `I_∂(u)`):
/// per edge, the contour pixels projected onto the edge (parameter s ∈ [0, 1]) with their
/// colours, linearly interpolated between consecutive ones.
pub struct Boundary {
    pts: [(f64, f64); 3],
    /// Per edge: (s, colour), sorted by s, including both end vertices.
    edges: [Vec<(f64, Rgb)>; 3],
}

impl Boundary {
    /// `value(p)` is the colour of pixel p (traced). The vertices are traced by construction.
    pub fn new(tri: &Tri, contour: &[ContourPixel], value: impl Fn(PixelCoord) -> Rgb) -> Self {
        let pts = tri.v.map(|p| (f64::from(p.x), f64::from(p.y)));
        let mut edges: [Vec<(f64, Rgb)>; 3] = Default::default();
        for (e, list) in edges.iter_mut().enumerate() {
            list.push((0.0, value(tri.v[e])));
            list.push((1.0, value(tri.v[(e + 1) % 3])));
        }
        for c in contour {
            let e = c.edge as usize;
            let (a, b) = (pts[e], pts[(e + 1) % 3]);
            let (ex, ey) = (b.0 - a.0, b.1 - a.1);
            let len2 = ex * ex + ey * ey;
            if len2 <= 0.0 {
                continue;
            }
            let s = (((f64::from(c.p.x) - a.0) * ex + (f64::from(c.p.y) - a.1) * ey) / len2)
                .clamp(0.0, 1.0);
            edges[e].push((s, value(c.p)));
        }
        for list in &mut edges {
            list.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
        Self { pts, edges }
    }

    /// Boundary value at parameter s on edge e.
    #[must_use]
    pub fn at(&self, e: usize, s: f64) -> Rgb {
        let list = &self.edges[e];
        let k = list.partition_point(|q| q.0 <= s);
        if k == 0 {
            return list[0].1;
        }
        if k >= list.len() {
            return list[list.len() - 1].1;
        }
        let (s0, c0) = list[k - 1];
        let (s1, c1) = list[k];
        if s1 - s0 <= 0.0 {
            return c0;
        }
        let t = ((s - s0) / (s1 - s0)) as f32;
        c0 * (1.0 - t) + c1 * t
    }

    /// Intersections of the line `x + t·d` with the triangle: (t_min, edge, s) and
    /// (t_max, edge, s). f64 with an epsilon relative to the triangle size (spec §4.4).
    #[must_use]
    pub fn chord(&self, x: (f64, f64), d: (f64, f64)) -> Option<(Hit, Hit)> {
        let size = self.size();
        let eps = 1e-9 * size.max(1.0);
        let mut lo: Option<Hit> = None;
        let mut hi: Option<Hit> = None;
        for e in 0..3 {
            let (a, b) = (self.pts[e], self.pts[(e + 1) % 3]);
            let (ex, ey) = (b.0 - a.0, b.1 - a.1);
            // x + t d = a + s e  →  solve with 2-D cross products.
            let den = d.0 * ey - d.1 * ex;
            if den.abs() <= eps * (ex.abs() + ey.abs()).max(1e-300) {
                continue;
            }
            let (wx, wy) = (a.0 - x.0, a.1 - x.1);
            let t = (wx * ey - wy * ex) / den;
            let s = (wx * d.1 - wy * d.0) / den;
            let tol = eps / (ex * ex + ey * ey).sqrt().max(1e-300);
            if s < -tol || s > 1.0 + tol {
                continue;
            }
            let s = s.clamp(0.0, 1.0);
            if lo.is_none_or(|l| t < l.0) {
                lo = Some((t, e, s));
            }
            if hi.is_none_or(|h| t > h.0) {
                hi = Some((t, e, s));
            }
        }
        Some((lo?, hi?))
    }

    fn size(&self) -> f64 {
        let mut m: f64 = 0.0;
        for e in 0..3 {
            let (a, b) = (self.pts[e], self.pts[(e + 1) % 3]);
            m = m.max((a.0 - b.0).abs()).max((a.1 - b.1).abs());
        }
        m
    }

    /// Directional interpolation (spec §4.4): intersect the line through x parallel to d
    /// with the contour at a (distance t_a) and b (t_b); I = (t_b I(a) + t_a I(b)) / (t_a + t_b).
    #[must_use]
    pub fn directional(&self, x: (f64, f64), d: (f64, f64)) -> Option<Rgb> {
        let ((t0, e0, s0), (t1, e1, s1)) = self.chord(x, d)?;
        let (ta, tb) = ((-t0).max(0.0), t1.max(0.0));
        let sum = ta + tb;
        if sum.is_nan() || sum <= 1e-12 {
            return None;
        }
        let (ia, ib) = (self.at(e0, s0), self.at(e1, s1));
        Some((ia * tb as f32 + ib * ta as f32) / sum as f32)
    }
}

/// How many times the mean contour jump the largest jump must be to count as a rupture.
/// A clean edge crossing a contour of n pixels gives two jumps of J and a mean of ≈ 2J/n,
/// a ratio of n/2 (≥ 7 for the ≥ 15-pixel contours of interpolated triangles); the largest
/// of n noise jumps is typically only ≈ 3 × their mean.
pub const RUPTURE_CONTRAST: f32 = 4.0;

/// The rupture direction of F&P04 §4.2: walking the contour counter-clockwise, the two
/// pixels with the largest colour jump to their predecessor (at least 2 steps apart, spec
/// §4.4 guard); the segment joining them is the least-discrepancy direction. `None` when
/// every jump is zero (fall back to Gouraud) or the contour is too short.
#[must_use]
pub fn rupture_direction(contour: &[ContourPixel], colours: &[Rgb]) -> Option<(f64, f64)> {
    let n = contour.len();
    if n < 4 || colours.len() != n {
        return None;
    }
    let jump = |i: usize| (colours[i] - colours[(i + n - 1) % n]).length();
    let mut i1 = 0;
    let mut best = -1.0f32;
    for i in 0..n {
        let j = jump(i);
        if j > best {
            best = j;
            i1 = i;
        }
    }
    if best.is_nan() || best <= 0.0 {
        return None;
    }
    // [D] A rupture must stand out from the contour's ordinary variation: on a Monte
    // Carlo contour the largest jump is often just noise, and a direction picked from
    // noise draws streaks. Below RUPTURE_CONTRAST × the mean jump, keep Gouraud.
    let mean = (0..n).map(jump).sum::<f32>() / n as f32;
    if best < RUPTURE_CONTRAST * mean {
        return None;
    }
    let mut i2 = None;
    let mut best2 = -1.0f32;
    for i in 0..n {
        let gap = (i + n - i1) % n;
        if gap.min(n - gap) < 2 {
            continue;
        }
        let j = jump(i);
        if j > best2 {
            best2 = j;
            i2 = Some(i);
        }
    }
    let (a, b) = (contour[i1].p, contour[i2?].p);
    let d = (
        f64::from(b.x) - f64::from(a.x),
        f64::from(b.y) - f64::from(a.y),
    );
    (d.0 != 0.0 || d.1 != 0.0).then_some(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(a: (u32, u32), b: (u32, u32), c: (u32, u32)) -> Tri {
        Tri {
            v: [
                PixelCoord::new(a.0, a.1),
                PixelCoord::new(b.0, b.1),
                PixelCoord::new(c.0, c.1),
            ],
        }
    }

    #[test]
    fn contour_walk_has_no_duplicates_and_visits_every_vertex() {
        let t = tri((0, 0), (10, 0), (0, 7));
        let mut st = Stamp::new(11 * 8);
        let mut c = Vec::new();
        contour(&t, 11, &mut st, &mut c);
        let mut ps: Vec<_> = c.iter().map(|q| q.p).collect();
        assert_eq!(ps[0], PixelCoord::new(0, 0));
        assert!(ps.contains(&PixelCoord::new(10, 0)) && ps.contains(&PixelCoord::new(0, 7)));
        // edge 0 has 10 pixels, edge 2 has 7, the diagonal max(10, 7) = 10 pixels.
        assert_eq!(ps.len(), 10 + 10 + 7);
        ps.sort();
        ps.dedup();
        assert_eq!(ps.len(), 27);
        // 8-connected walk: consecutive pixels are neighbours.
        for w in c.windows(2) {
            let (a, b) = (w[0].p, w[1].p);
            assert!(a.x.abs_diff(b.x) <= 1 && a.y.abs_diff(b.y) <= 1);
        }
    }

    /// A step edge along x = 4.5 through a triangle: the rupture pixels sit on both sides of
    /// it, the direction is vertical, and directional interpolation keeps the step sharp
    /// where Gouraud would smear it.
    #[test]
    fn rupture_finds_a_vertical_step_and_interpolates_it_sharply() {
        let (w, h) = (10u32, 10u32);
        let t = tri((0, 0), (9, 0), (9, 9));
        let t = if t.area2() > 0.0 {
            t
        } else {
            tri((0, 0), (9, 9), (9, 0))
        };
        let f = |p: PixelCoord| if p.x >= 5 { Rgb::ONE } else { Rgb::ZERO };
        let mut st = Stamp::new((w * h) as usize);
        let mut c = Vec::new();
        contour(&t, w, &mut st, &mut c);
        let cols: Vec<Rgb> = c.iter().map(|q| f(q.p)).collect();
        let d = rupture_direction(&c, &cols).expect("a step has ruptures");
        assert!(
            d.0.abs() < 0.5 * d.1.abs(),
            "direction {d:?} should be near vertical"
        );
        let b = Boundary::new(&t, &c, f);
        // Pixel (7, 3) is inside and right of the step; (3, 1) left of it.
        let right = b.directional((7.0, 3.0), d).expect("inside");
        let left = b.directional((3.0, 1.0), d).expect("inside");
        assert!(right.x > 0.9, "{right:?}");
        assert!(left.x < 0.1, "{left:?}");
    }

    #[test]
    fn constant_contour_has_no_rupture_and_directional_reproduces_linear() {
        let t = tri((0, 0), (8, 0), (0, 8));
        let mut st = Stamp::new(81);
        let mut c = Vec::new();
        contour(&t, 9, &mut st, &mut c);
        let cols = vec![Rgb::splat(0.5); c.len()];
        assert_eq!(rupture_direction(&c, &cols), None);
        // Uniform small noise (every jump the same size): no jump stands out.
        let noisy: Vec<Rgb> = (0..c.len())
            .map(|i| Rgb::splat(0.5 + 0.05 * (i % 2) as f32))
            .collect();
        assert_eq!(rupture_direction(&c, &noisy), None);
        let lin = |p: PixelCoord| Rgb::splat(p.x as f32 + 2.0 * p.y as f32);
        let b = Boundary::new(&t, &c, lin);
        let v = b.directional((2.0, 3.0), (1.0, 0.0)).expect("inside");
        // Horizontal chord from (0,3) to (5,3): both on straight edges, linear field exact
        // up to the pixel rounding of the diagonal (at most one pixel's worth, 1.0).
        assert!((v.x - 8.0).abs() < 1.01, "{v:?}");
    }
}
