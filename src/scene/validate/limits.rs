//! The size limits (`image`, samples, bounces, objects, triangles), checked before any
//! geometry is built: a server's own (`Limits`), said in the error.

use super::*;

/// Every limit a document's declared sizes can pass; the bounce limit is capped with a
/// warning instead (see below). Whether the geometry (objects, declared triangles) is
/// past its limit: then it is not built at all.
pub(super) fn check_sizes(cx: &mut Ctx, doc: &SceneDoc, limits: &Limits) -> bool {
    let (w, h) = (doc.image.width, doc.image.height);
    for (path, v, max) in [
        ("image.width", w, limits.max_width),
        ("image.height", h, limits.max_height),
    ] {
        if v < 1 {
            cx.err(path, format!("must be ≥ 1, got {v}"));
        } else if v > u64::from(max) {
            cx.limit(path, format!("{v} exceeds this server's limit of {max}"));
        }
    }
    let pixels = w.saturating_mul(h);
    if pixels > limits.max_pixels {
        cx.limit(
            "image",
            format!(
                "{w}×{h} = {pixels} pixels exceeds this server's limit of {} pixels",
                limits.max_pixels
            ),
        );
    }
    let spp = doc.render.samples_per_pixel;
    if spp < 1 {
        cx.err(
            "render.samples_per_pixel",
            format!("must be ≥ 1, got {spp}"),
        );
    } else if spp > u64::from(limits.max_samples_per_pixel) {
        cx.limit(
            "render.samples_per_pixel",
            format!(
                "{spp} exceeds this server's limit of {}",
                limits.max_samples_per_pixel
            ),
        );
    } else {
        let budget = u128::from(spp) * u128::from(pixels);
        if budget > u128::from(limits.max_sample_budget) {
            cx.limit(
                "render.samples_per_pixel",
                format!(
                    "{spp} samples × {pixels} pixels = {budget} samples exceeds this server's limit of {} samples per render",
                    limits.max_sample_budget
                ),
            );
        }
    }
    // A bounce limit above the cap is capped, not refused: scenes people download carry
    // pbrt's `maxdepth 65` or Mitsuba's `max_depth` of 64-100, and Russian roulette
    // (`tracer::integrator`, `RR_START`) already ends nearly every path long before.
    if doc.render.max_bounces > u64::from(limits.max_bounces) {
        cx.warn(
            "render.max_bounces",
            format!(
                "{} is above this server's cap of {}: paths stop after {} bounces (Russian roulette ends nearly all of them long before, so the picture barely changes)",
                doc.render.max_bounces, limits.max_bounces, limits.max_bounces
            ),
        );
    }
    check_geometry_size(cx, doc, limits)
}

/// The objects and the triangles they declare (OBJ files add theirs when loaded), and
/// whether either is past its limit.
fn check_geometry_size(cx: &mut Ctx, doc: &SceneDoc, limits: &Limits) -> bool {
    let too_many = doc.objects.len() > limits.max_objects;
    if too_many {
        cx.limit(
            "objects",
            format!(
                "{} objects exceed this server's limit of {}",
                doc.objects.len(),
                limits.max_objects
            ),
        );
    }
    // Triangle count known before building (OBJ files add theirs when loaded).
    let declared: usize = doc
        .objects
        .iter()
        .map(|o| match o {
            ObjectDoc::Quad(_) => 2,
            ObjectDoc::Box(_) => 12,
            ObjectDoc::Mesh(m) => m.indices.len(),
            ObjectDoc::Sphere(_) | ObjectDoc::Obj(_) => 0,
        })
        .sum();
    if declared > limits.max_triangles {
        cx.limit(
            "objects",
            format!(
                "{declared} triangles exceed this server's limit of {}",
                limits.max_triangles
            ),
        );
    }
    too_many || declared > limits.max_triangles
}
