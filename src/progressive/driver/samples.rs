//! The traced pixels and what derives from them. Each pixel is traced at most once
//! (F&P04 §4.2); its estimate, the estimate's variance and texture albedo, the value it
//! contributes to the shading ([`crate::progressive::reconstruct`]) and when it was traced live
//! here, one entry per pixel of the image.

use crate::progressive::mesh::{gouraud, Raster, ShadeInput, Tri, Triangulator};
use crate::progressive::reconstruct::{self, vertex_values, Averaging};
use crate::progressive::SampleCell;
use crate::raster::{Image, PixelCoord, Rgb};
use crate::scene::ObjectId;
use crate::tracer::Estimate;

/// Per-pixel state of a render, row-major.
pub(super) struct SampleSet {
    pub w: u32,
    pub h: u32,
    pub n: usize,
    /// Traced estimates, made finite ([`finite`]).
    pub rad: Vec<Rgb>,
    /// Variance of each traced estimate ([`Estimate::variance`]).
    pub variance: Vec<Rgb>,
    /// What each vertex contributes to the shading ([`reconstruct`]).
    pub vertex: Vec<Rgb>,
    /// Surface normal at each pixel centre ([`crate::tracer::PixelOracle::surface_normal`]),
    /// which keeps the reconstruction on one face of an object.
    pub normals: Vec<glam::Vec3>,
    /// Whether each pixel's footprint spans several objects
    /// ([`crate::tracer::PixelOracle::footprint_mixed`]): traced at once, never a vertex
    /// (`driver::Run::first_trace`); empty until the analysis.
    pub mixed: Vec<bool>,
    /// Whether each vertex's reconstruction reached its target count; a triangle with an
    /// unresolved vertex is not final ([`reconstruct`]).
    pub resolved: Vec<bool>,
    /// Texture albedo per pixel (textured scenes only): the
    /// [`crate::tracer::ALBEDO_TAPS`] mean where untraced, the traced estimate's own albedo
    /// where traced (mesh.rs `gouraud`).
    pub albedo: Option<Vec<Option<Rgb>>>,
    pub traced: Vec<bool>,
    /// Paths each estimate averages (the scene's samples per pixel).
    paths: u32,
    /// Iteration at which a pixel was traced (`u32::MAX`: never).
    when: Vec<u32>,
    pub count: u64,
    /// Already in this iteration's work list.
    queued: Vec<bool>,
}

impl SampleSet {
    /// An image of `w` × `h` pixels, none traced yet, whose estimates will each average
    /// `paths` paths.
    pub(super) fn new(w: u32, h: u32, paths: u32) -> Self {
        let n = w as usize * h as usize;
        Self {
            w,
            h,
            n,
            rad: vec![Rgb::ZERO; n],
            variance: vec![Rgb::ZERO; n],
            vertex: vec![Rgb::ZERO; n],
            normals: Vec::new(),
            mixed: Vec::new(),
            resolved: vec![true; n],
            albedo: None,
            traced: vec![false; n],
            paths,
            when: vec![u32::MAX; n],
            count: 0,
            queued: vec![false; n],
        }
    }

    pub(super) fn index(&self, p: PixelCoord) -> usize {
        p.y as usize * self.w as usize + p.x as usize
    }

    pub(super) fn coord(&self, i: usize) -> PixelCoord {
        let w = self.w as usize;
        PixelCoord::new((i % w) as u32, (i / w) as u32)
    }

    pub(super) fn all_traced(&self) -> bool {
        self.count as usize == self.n
    }

    /// Records pixel `i`'s estimate, traced at iteration `iter`.
    pub(super) fn record(&mut self, i: usize, e: Estimate, iter: u32) {
        self.rad[i] = finite(e.radiance);
        self.vertex[i] = self.rad[i];
        self.variance[i] = e.variance;
        if let Some(albedo) = &mut self.albedo {
            albedo[i] = e.albedo;
        }
        self.traced[i] = true;
        self.when[i] = iter;
        self.count += 1;
    }

    /// The traced pixels, in raster order (the metric's seeds).
    pub(super) fn traced_coords(&self) -> Vec<PixelCoord> {
        (0..self.n)
            .filter(|&i| self.traced[i])
            .map(|i| self.coord(i))
            .collect()
    }

    /// The `samples` layer of iteration `iter`.
    pub(super) fn layer(&self, iter: u32) -> Image<SampleCell> {
        let cells = self
            .when
            .iter()
            .map(|&k| match k {
                u32::MAX => SampleCell::Interpolated,
                k if k == iter => SampleCell::New,
                _ => SampleCell::Traced,
            })
            .collect();
        Image::from_vec(self.w, self.h, cells)
            .unwrap_or_else(|| Image::filled(self.w, self.h, SampleCell::Traced))
    }

    /// Queues pixel `i` unless it is traced or queued already; whether it was queued.
    pub(super) fn push(&mut self, i: usize, work: &mut Vec<usize>) -> bool {
        if self.traced[i] || self.queued[i] {
            return false;
        }
        self.queued[i] = true;
        work.push(i);
        true
    }

    /// Queues the untraced pixel of triangle `t` nearest its centroid (F&P04: "a new
    /// sample ... in the proximity of its center").
    pub(super) fn push_centre(
        &mut self,
        tri: &Tri,
        raster: &Raster,
        t: usize,
        work: &mut Vec<usize>,
    ) {
        let (cx, cy) = tri.centroid();
        let w = self.w as usize;
        let mut best: Option<(f64, usize)> = None;
        for &i in raster.pixels_of(t) {
            let i = i as usize;
            if self.traced[i] || self.queued[i] {
                continue;
            }
            let (dx, dy) = ((i % w) as f64 - cx, (i / w) as f64 - cy);
            let d = dx * dx + dy * dy;
            if best.is_none_or(|b| d < b.0) {
                best = Some((d, i));
            }
        }
        if let Some((_, i)) = best {
            self.queued[i] = true;
            work.push(i);
        }
    }

    /// Ends an iteration's planning: its work list is about to be traced.
    pub(super) fn unqueue(&mut self, work: &[usize]) {
        for &i in work {
            self.queued[i] = false;
        }
    }

    /// Whether every vertex of `tr` reached its reconstruction's target count.
    pub(super) fn is_resolved(&self, tr: &Tri) -> bool {
        tr.v.iter().all(|&p| self.resolved[self.index(p)])
    }

    /// The frame: Gouraud shading of the vertices' reconstructed values
    /// ([`reconstruct`]), each pixel from the vertices on its own object. Once every pixel
    /// is traced the frame is the traced estimates themselves: the reference.
    pub(super) fn shade(
        &mut self,
        tris: &[Tri],
        raster: &Raster,
        tri: &Triangulator,
        ids: &[ObjectId],
        averaging: Averaging,
        out: &mut [Rgb],
    ) {
        let all = self.all_traced();
        if !all {
            let samples = reconstruct::Samples {
                w: self.w as usize,
                radiance: &self.rad,
                variance: &self.variance,
                ids,
                normals: &self.normals,
                albedo: self.albedo.as_deref(),
                averaging,
                paths: self.paths,
            };
            vertex_values(tris, &samples, &mut self.vertex, &mut self.resolved);
        }
        let input = ShadeInput {
            radiance: &self.rad,
            vertex: (!all).then_some(&self.vertex[..]),
            traced: &self.traced,
            albedo: self.albedo.as_deref(),
            ids: Some(ids),
        };
        gouraud(tris, raster, tri, &input, out);
    }
}

/// A traced value the interpolation can use: NaN → 0, −∞ → 0, +∞ → 1e30 (vision-model.md
/// §2.9 guards). One NaN vertex would otherwise spread over every triangle around it.
/// Finite values pass bit for bit, so T0 = 0 still reproduces the reference exactly.
pub(super) fn finite(c: Rgb) -> Rgb {
    if c.is_finite() {
        return c;
    }
    let f = |v: f32| {
        if v.is_nan() || v == f32::NEG_INFINITY {
            0.0
        } else {
            v.min(1e30)
        }
    };
    Rgb::new(f(c.x), f(c.y), f(c.z))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_estimates_become_usable_and_finite_ones_pass_bit_for_bit() {
        assert_eq!(
            finite(Rgb::new(f32::NAN, f32::NEG_INFINITY, f32::INFINITY)),
            Rgb::new(0.0, 0.0, 1e30)
        );
        let v = Rgb::new(0.1, 3.5e-39, 7.0);
        assert_eq!(
            finite(v).to_array().map(f32::to_bits),
            v.to_array().map(f32::to_bits)
        );
    }

    #[test]
    fn a_pixel_is_queued_once_and_layers_tell_new_from_old() {
        let mut s = SampleSet::new(3, 2, 1);
        let mut work = Vec::new();
        assert!(s.push(4, &mut work));
        assert!(!s.push(4, &mut work), "queued already");
        s.unqueue(&work);
        s.record(4, Estimate::default(), 1);
        assert!(!s.push(4, &mut work), "traced already");
        s.record(0, Estimate::default(), 0);
        let layer = s.layer(1);
        assert_eq!(*layer.get(1, 1), SampleCell::New);
        assert_eq!(*layer.get(0, 0), SampleCell::Traced);
        assert_eq!(*layer.get(2, 0), SampleCell::Interpolated);
        assert_eq!((s.count, s.traced_coords().len()), (2, 2));
    }
}
