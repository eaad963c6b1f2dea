//! Triangle distances and the three classes of F&P04 §4.2.

use super::mesh::Raster;
use super::TriangleClass;

/// Mean of the block map over each triangle's pixels (F&P04 §4.2), in f64. A non-finite
/// distance counts as +∞ (never final); a triangle that owns no pixel gets 0.
#[must_use]
pub fn triangle_distances(raster: &Raster, map: &[f32]) -> Vec<f64> {
    raster.triangle_means(map, |d| {
        if d.is_finite() {
            f64::from(d)
        } else {
            f64::INFINITY
        }
    })
}

/// T1 after the guard of vision-model.md §2.9: never below T0·(1+1e-3), so a zero first
/// map (black scene) or a user T1 ≤ T0 cannot invert the classes. Non-finite → T0 guard.
#[must_use]
pub fn guarded_t1(t0: f64, t1: f64) -> f64 {
    let floor = t0 * (1.0 + 1e-3);
    if t1.is_finite() {
        t1.max(floor)
    } else {
        floor
    }
}

/// Final if d < T0 (strict, so T0 = 0 makes nothing final), smooth if T0 ≤ d < T1,
/// complex if d ≥ T1.
#[must_use]
pub fn classify(d: f64, t0: f64, t1: f64) -> TriangleClass {
    if d < t0 {
        TriangleClass::Final
    } else if d < t1 {
        TriangleClass::Smooth
    } else {
        TriangleClass::Complex
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progressive::mesh::{rasterise, Tri};
    use crate::raster::PixelCoord;

    #[test]
    fn classes_follow_the_thresholds_and_never_invert() {
        assert_eq!(classify(0.5, 1.0, 3.0), TriangleClass::Final);
        assert_eq!(classify(1.0, 1.0, 3.0), TriangleClass::Smooth);
        assert_eq!(classify(3.0, 1.0, 3.0), TriangleClass::Complex);
        assert_eq!(
            classify(0.0, 0.0, guarded_t1(0.0, 0.0)),
            TriangleClass::Complex
        );
        assert_eq!(classify(f64::INFINITY, 1.0, 2.0), TriangleClass::Complex);
        let t1 = guarded_t1(1.0, 0.2);
        assert!(t1 > 1.0);
        assert_eq!(classify(1.0, 1.0, t1), TriangleClass::Smooth);
        assert_eq!(guarded_t1(1.0, f64::NAN), 1.001);
    }

    #[test]
    fn triangle_distance_is_the_mean_over_owned_pixels() {
        let p = PixelCoord::new;
        let tris = vec![
            Tri {
                v: [p(0, 0), p(3, 0), p(0, 3)],
            },
            Tri {
                v: [p(3, 0), p(3, 3), p(0, 3)],
            },
        ];
        let tris: Vec<Tri> = tris
            .into_iter()
            .map(|t| {
                if t.area2() > 0.0 {
                    t
                } else {
                    Tri {
                        v: [t.v[0], t.v[2], t.v[1]],
                    }
                }
            })
            .collect();
        let r = rasterise(&tris, 4, 4);
        // Distance 2 on the upper-left half (x + y < 3), 4 elsewhere, NaN nowhere.
        let map: Vec<f32> = (0..16)
            .map(|i| if (i % 4) + (i / 4) < 3 { 2.0 } else { 4.0 })
            .collect();
        let d = triangle_distances(&r, &map);
        assert_eq!(d[0], 2.0 * 6.0 / 10.0 + 4.0 * 4.0 / 10.0); // owns 10 pixels incl. diagonal
        assert_eq!(d[1], 4.0);
        let mut m2 = map.clone();
        m2[15] = f32::NAN;
        assert!(triangle_distances(&r, &m2)[1].is_infinite());
    }
}
