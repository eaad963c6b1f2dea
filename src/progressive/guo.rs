//! Guo 1998 baseline pieces (vision-model.md §4.3, §4.4): Mitchell's contrast test as the
//! classification oracle and the least-discrepancy direction by minimum discrepancy.

use super::complex::{Boundary, ContourPixel};
use crate::raster::Rgb;
use crate::scene::ObjectId;

/// Mitchell (1987) contrast thresholds, R/G/B (spec §4.3).
pub const CONTRAST: [f32; 3] = [0.4, 0.3, 0.6];

/// What the display shows for a linear value: × exposure, clamped to [0, 1] (NaN → 0).
#[must_use]
pub fn displayed(c: Rgb, exposure: f32) -> Rgb {
    let v = c * exposure;
    Rgb::new(clamp01(v.x), clamp01(v.y), clamp01(v.z))
}

fn clamp01(v: f32) -> f32 {
    if v.is_nan() {
        0.0
    } else {
        v.clamp(0.0, 1.0)
    }
}

/// Spec §4.3: edge if C_r > 0.4 ∨ C_g > 0.3 ∨ C_b > 0.6 with C = (max−min)/(max+min) over
/// the samples (displayed linear RGB; C = 0 when max + min = 0), or when the samples hit
/// different objects (the optional id test, catches same-colour silhouettes).
#[must_use]
pub fn is_edge(samples: impl IntoIterator<Item = (Rgb, ObjectId)>, exposure: f32) -> bool {
    Contrast::of(samples, exposure).is_some_and(|c| c.exceeds(1.0))
}

/// Our stopping rule for Guo's baseline (Guo 1998 stops at a sampling budget, which a
/// service user cannot know): a triangle no longer than [`CALM_EDGE`] whose samples show
/// less than half of Mitchell's contrast thresholds, on one object, is final (the driver
/// checks the size). Without it Guo refined every smooth triangle until every pixel was
/// traced, 1.2–1.9× the reference's time on unseen scenes.
#[must_use]
pub fn is_calm(samples: impl IntoIterator<Item = (Rgb, ObjectId)>, exposure: f32) -> bool {
    Contrast::of(samples, exposure).is_some_and(|c| !c.exceeds(CALM))
}

/// Mitchell's test assumes exact samples; a Monte Carlo estimate differs from its
/// neighbour by noise alone, and in dark regions that noise passes the contrast
/// thresholds (the contrast is relative). Each sample is moved towards the samples' mean
/// by up to twice its standard error (per channel, never past the mean): what remains is
/// contrast the noise does not explain. An exact oracle (variance 0) is unchanged.
#[must_use]
pub fn noise_discounted(
    samples: impl IntoIterator<Item = (Rgb, Rgb, ObjectId)>,
) -> Vec<(Rgb, ObjectId)> {
    let samples: Vec<(Rgb, Rgb, ObjectId)> = samples.into_iter().collect();
    if samples.is_empty() {
        return Vec::new();
    }
    let mean = samples.iter().map(|s| s.0).sum::<Rgb>() / samples.len() as f32;
    samples
        .into_iter()
        .map(|(v, var, id)| {
            let reach = var.map(f32::sqrt) * 2.0;
            let d = v - mean;
            let shrunk = d.signum() * (d.abs() - reach).max(Rgb::ZERO);
            let moved = mean + shrunk;
            // Unknown noise (∞): the sample says nothing beyond its object.
            (if moved.is_finite() { moved } else { mean }, id)
        })
        .collect()
}

/// Share of Mitchell's thresholds below which [`is_calm`] holds.
pub const CALM: f32 = 0.5;

/// Longest edge (pixels) of a triangle Guo's baseline may leave final: three samples of a
/// larger one say little about what lies between them.
pub const CALM_EDGE: f64 = 6.0;

/// Mitchell's per-channel contrast of a set of samples, and whether they span objects.
struct Contrast {
    c: Rgb,
    ids_differ: bool,
}

impl Contrast {
    /// `None` for no samples.
    fn of(samples: impl IntoIterator<Item = (Rgb, ObjectId)>, exposure: f32) -> Option<Self> {
        let mut lo = Rgb::splat(f32::INFINITY);
        let mut hi = Rgb::splat(f32::NEG_INFINITY);
        let mut first_id = None;
        let mut ids_differ = false;
        for (c, id) in samples {
            let d = displayed(c, exposure);
            lo = lo.min(d);
            hi = hi.max(d);
            match first_id {
                None => first_id = Some(id),
                Some(f) => ids_differ |= f != id,
            }
        }
        first_id?;
        let c = |h: f32, l: f32| if h + l > 0.0 { (h - l) / (h + l) } else { 0.0 };
        Some(Self {
            c: Rgb::new(c(hi.x, lo.x), c(hi.y, lo.y), c(hi.z, lo.z)),
            ids_differ,
        })
    }

    /// Spans objects, or passes `scale` × Mitchell's threshold in any channel.
    fn exceeds(&self, scale: f32) -> bool {
        self.ids_differ
            || self.c.x > CONTRAST[0] * scale
            || self.c.y > CONTRAST[1] * scale
            || self.c.z > CONTRAST[2] * scale
    }
}

/// The least-discrepancy direction (spec §4.4, Guo-style variant on a triangle contour):
/// θ_j = jπ/N, N = max(8, 2s) (s = longest edge, capped at 64 directions for cost [D]);
/// D(θ) = mean over contour pixels p of ‖I(p) − I_∂(q_θ(p))‖ where q is the other end of
/// the chord through p (chords shorter than 1 px skipped); argmin, ties → smallest j.
/// `colours` are displayed values. `None` when no direction has a usable chord.
#[must_use]
pub fn least_discrepancy_direction(
    boundary: &Boundary,
    contour: &[ContourPixel],
    colours: &[Rgb],
    longest_edge: f64,
) -> Option<(f64, f64)> {
    let n_theta = ((2.0 * longest_edge).ceil() as usize).clamp(8, 64);
    let mut best: Option<(f64, (f64, f64))> = None;
    for j in 0..n_theta {
        let th = j as f64 * std::f64::consts::PI / n_theta as f64;
        let d = (th.cos(), th.sin());
        let mut sum = 0.0f64;
        let mut count = 0usize;
        for (c, &col) in contour.iter().zip(colours) {
            let x = (f64::from(c.p.x), f64::from(c.p.y));
            let Some((lo, hi)) = boundary.chord(x, d) else {
                continue;
            };
            let far = if hi.0.abs() >= lo.0.abs() { hi } else { lo };
            if far.0.abs() < 1.0 {
                continue;
            }
            sum += f64::from((col - boundary.at(far.1, far.2)).length());
            count += 1;
        }
        if count == 0 {
            continue;
        }
        let disc = sum / count as f64;
        if best.is_none_or(|b| disc < b.0) {
            best = Some((disc, d));
        }
    }
    // The failure-mode test of spec §4.4 (junctions: residual too high) is not applied
    // ([D], not done): the traced contour pixels become vertices, so a badly fitted
    // triangle is subdivided and re-judged next iteration anyway.
    best.map(|b| b.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calm_is_well_below_the_edge_thresholds_and_on_one_object() {
        let grey = |v: f32| (Rgb::splat(v), 0);
        assert!(is_calm([grey(0.5), grey(0.55), grey(0.52)], 1.0));
        // Contrast 0.2 in every channel: no edge (G threshold 0.3), but not calm (0.15).
        assert!(!is_calm([grey(0.4), grey(0.6)], 1.0));
        assert!(!is_edge([grey(0.4), grey(0.6)], 1.0));
        assert!(!is_calm([grey(0.5), (Rgb::splat(0.5), 1)], 1.0));
        assert!(!is_calm(std::iter::empty(), 1.0));
    }

    #[test]
    fn noise_explains_away_contrast_within_two_standard_errors() {
        let s = |v: f32, var: f32| (Rgb::splat(v), Rgb::splat(var), 0);
        // 0.4 and 0.6 with σ = 0.1: both reach the mean 0.5.
        let d = noise_discounted([s(0.4, 0.01), s(0.6, 0.01)]);
        assert!(is_calm(d, 1.0));
        // Exact samples keep their contrast.
        let d = noise_discounted([s(0.4, 0.0), s(0.6, 0.0)]);
        assert_eq!(d[0].0, Rgb::splat(0.4));
        // A step far beyond the noise stays an edge.
        let d = noise_discounted([s(0.05, 0.0001), s(0.9, 0.0001)]);
        assert!(is_edge(d, 1.0));
    }
    use crate::progressive::complex::{contour, Stamp};
    use crate::progressive::mesh::Tri;
    use crate::raster::PixelCoord;

    #[test]
    fn mitchell_contrast_thresholds() {
        let g = |v: f32| (Rgb::splat(v), 0u32);
        assert!(!is_edge([g(0.5), g(0.5), g(0.5)], 1.0));
        // C = (0.5-0.3)/(0.8) = 0.25 on every channel: below all three thresholds.
        assert!(!is_edge([g(0.5), g(0.3)], 1.0));
        // Green only: (0.6-0.3)/0.9 = 0.333 > 0.3.
        assert!(is_edge(
            [(Rgb::new(0.5, 0.6, 0.5), 0), (Rgb::new(0.5, 0.3, 0.5), 0)],
            1.0
        ));
        // Black samples: C = 0, not an edge; saturated samples: clamped equal, not an edge.
        assert!(!is_edge([g(0.0), g(0.0)], 1.0));
        assert!(!is_edge([g(5.0), g(50.0)], 1.0));
        // Exposure matters: 0.01 vs 0.001 is contrast 0.82 whatever the exposure, but
        // 2.0 vs 1.0 saturate at exposure 1 and differ at exposure 0.1.
        assert!(!is_edge([g(2.0), g(1.0)], 1.0));
        assert!(is_edge([g(2.0), g(0.5)], 0.1));
        // Same colour, different object.
        assert!(is_edge([(Rgb::ONE * 0.5, 1), (Rgb::ONE * 0.5, 2)], 1.0));
        assert!(!is_edge(std::iter::empty(), 1.0));
    }

    #[test]
    fn ldd_follows_a_diagonal_step() {
        // Step along the line x = y: the least-discrepancy direction is the diagonal (π/4).
        let p = PixelCoord::new;
        let t = Tri {
            v: [p(0, 0), p(12, 0), p(12, 12)],
        };
        let t = if t.area2() > 0.0 {
            t
        } else {
            Tri {
                v: [t.v[0], t.v[2], t.v[1]],
            }
        };
        let f = |q: PixelCoord| {
            if q.x as i64 - q.y as i64 >= 3 {
                Rgb::ONE
            } else {
                Rgb::ZERO
            }
        };
        {
            let tri = t;
            let mut st = Stamp::new(13 * 13);
            let mut c = Vec::new();
            contour(&tri, 13, &mut st, &mut c);
            let cols: Vec<Rgb> = c.iter().map(|q| f(q.p)).collect();
            let b = Boundary::new(&tri, &c, f);
            let d =
                least_discrepancy_direction(&b, &c, &cols, tri.longest_edge()).expect("direction");
            let ang = d.1.atan2(d.0).rem_euclid(std::f64::consts::PI);
            assert!(
                (ang - std::f64::consts::FRAC_PI_4).abs() < 0.2,
                "angle {ang}"
            );
        }
    }
}
