//! What the classes ask for (F&P04 §4.2): the pixels to trace next, and the complex
//! triangles whose interior is filled along their rupture once their contour is traced.

use super::samples::SampleSet;
use super::Mesh;
use crate::progressive::complex::{ContourWalker, FULL_TRACE_BELOW};
use crate::progressive::mesh::orphan_of;
use crate::progressive::TriangleClass;
use crate::scene::ObjectId;
use rayon::prelude::*;

/// One iteration's work.
#[derive(Default)]
pub(super) struct Plan {
    /// Pixel indices to trace, untraced, without duplicates.
    pub work: Vec<usize>,
    /// Triangles (of the current mesh) to fill directionally after the trace.
    pub complex: Vec<usize>,
}

impl Plan {
    /// Plans the next trace. A final triangle may be demoted first:
    /// - a triangle with a pixel on an object none of its vertices lies on cannot shade that
    ///   pixel from its own object (mesh::gouraud): it is not final, whatever its distance,
    ///   and the pixel (an *orphan*) is traced;
    /// - noise the reconstruction could not average away without bias (an unresolved
    ///   vertex) is error the frame-to-frame distance cannot see, since both frames carry
    ///   it: refined there, down to F&P04's smallest triangles (below them vertices are
    ///   pixels apart, and what stays unresolved is an image border, a silhouette or an
    ///   outlier path that more vertices around it do not fix).
    ///
    /// Then smooth triangles get their untraced pixel nearest the centroid, complex ones
    /// their contour (and their every pixel when smaller than [`FULL_TRACE_BELOW`]).
    pub(super) fn new(
        samples: &mut SampleSet,
        mesh: &Mesh,
        classes: &mut [TriangleClass],
        ids: &[ObjectId],
        contours: &mut ContourWalker,
    ) -> Self {
        let orphans: Vec<Option<usize>> = mesh
            .tris
            .par_iter()
            .enumerate()
            .map(|(t, tr)| orphan_of(tr, &mesh.raster, t, &samples.traced, ids))
            .collect();
        let mut work = Vec::new();
        let mut complex = Vec::new();
        for (t, tr) in mesh.tris.iter().enumerate() {
            if let Some(i) = orphans[t] {
                samples.push(i, &mut work);
                if classes[t] == TriangleClass::Final {
                    classes[t] = TriangleClass::Smooth;
                }
            }
            if classes[t] == TriangleClass::Final
                && tr.longest_edge() >= FULL_TRACE_BELOW
                && !samples.is_resolved(tr)
            {
                classes[t] = TriangleClass::Smooth;
            }
            match classes[t] {
                TriangleClass::Final => {}
                TriangleClass::Smooth => samples.push_centre(tr, &mesh.raster, t, &mut work),
                TriangleClass::Complex => {
                    let mut added = 0;
                    for c in contours.walk(tr) {
                        added += usize::from(samples.push(samples.index(c.p), &mut work));
                    }
                    if tr.longest_edge() < FULL_TRACE_BELOW {
                        for &i in mesh.raster.pixels_of(t) {
                            samples.push(i as usize, &mut work);
                        }
                    } else {
                        if added == 0 {
                            samples.push_centre(tr, &mesh.raster, t, &mut work);
                        }
                        complex.push(t);
                    }
                }
            }
        }
        samples.unqueue(&work);
        Self { work, complex }
    }

    /// Whether tracing every untraced pixel of the triangles still open costs less than
    /// another iteration of the loop's own work, and if so makes that the plan.
    ///
    /// An iteration re-triangulates, reconstructs, shades and judges the whole image,
    /// whatever it traces: about [`ITERATION_COST_IN_SAMPLES`] path samples per image
    /// pixel. Near the end the loop traces a handful of pixels per iteration for several
    /// iterations; tracing what is left whole ends it at once, and every pixel it adds is
    /// the reference's own (so the picture can only come closer to it). The rule counts
    /// samples, not seconds, so a render is the same on any machine at any load. `open` is
    /// [`open_pixels`] of the same classes, counted once per iteration for the statistics.
    pub(super) fn finish_if_cheaper(
        &mut self,
        samples: &SampleSet,
        mesh: &Mesh,
        classes: &[TriangleClass],
        open: u64,
        samples_per_pixel: u32,
    ) -> bool {
        let affordable = endgame_pixels(samples.n as u64, samples_per_pixel);
        if open == 0 || open as f64 > affordable.floor() {
            return false;
        }
        self.work = untraced_open(samples, mesh, classes).collect();
        self.complex.clear();
        true
    }
}

/// Untraced pixels of the triangles not final, by triangle.
fn untraced_open<'a>(
    samples: &'a SampleSet,
    mesh: &'a Mesh,
    classes: &'a [TriangleClass],
) -> impl Iterator<Item = usize> + 'a {
    classes
        .iter()
        .enumerate()
        .filter(|(_, &c)| c != TriangleClass::Final)
        .flat_map(|(t, _)| mesh.raster.pixels_of(t))
        .map(|&i| i as usize)
        .filter(|&i| !samples.traced[i])
}

/// How many pixels [`Plan::finish_if_cheaper`] would trace: what the loop may still trace
/// ([`crate::progressive::IterationStats::open_pixels`]).
pub(super) fn open_pixels(samples: &SampleSet, mesh: &Mesh, classes: &[TriangleClass]) -> u64 {
    untraced_open(samples, mesh, classes).count() as u64
}

/// At most how many open pixels [`Plan::finish_if_cheaper`] traces at once in an image of
/// `pixels` pixels at `samples_per_pixel`: one iteration's cost
/// ([`ITERATION_COST_IN_SAMPLES`] per image pixel) in pixels traced. The time left
/// ([`crate::progressive::eta`]) predicts the end of a render with it.
#[must_use]
pub fn endgame_pixels(pixels: u64, samples_per_pixel: u32) -> f64 {
    ITERATION_COST_IN_SAMPLES * pixels as f64 / f64::from(samples_per_pixel.max(1))
}

/// What one iteration of the loop's own work (triangulation, reconstruction, shading and
/// the vision model, all over the whole image) costs, in path samples per image pixel.
/// Measured on a 451² corpus scene at 9 spp: ~65 ms an iteration against 0.26 µs a
/// sample, 1.2 samples per pixel; scenes with dearer paths make it smaller, so 1 errs
/// towards tracing.
pub(super) const ITERATION_COST_IN_SAMPLES: f64 = 1.0;
