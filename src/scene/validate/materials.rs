//! The `materials` section of scene-format.md, textures included.

use super::*;

/// Materials in name order (the `BTreeMap`'s), so `MaterialId`s do not depend on how the
/// document was written or serialised.
pub(super) fn check_materials(
    cx: &mut Ctx,
    m: &BTreeMap<String, MaterialDoc>,
) -> (Vec<Material>, Vec<String>) {
    let mut out = Vec::with_capacity(m.len());
    let mut names = Vec::with_capacity(m.len());
    for (name, md) in m {
        out.push(check_material(cx, &format!("materials.{name}"), md));
        names.push(name.clone());
    }
    (out, names)
}

/// One material, each of its fields in range.
fn check_material(cx: &mut Ctx, p: &str, md: &MaterialDoc) -> Material {
    match md {
        MaterialDoc::Diffuse(d) => Material::Diffuse {
            albedo: colour_or_texture(
                cx,
                p,
                ("diffuse", "albedo"),
                d.albedo.as_ref(),
                d.texture.as_ref(),
            ),
        },
        MaterialDoc::Glossy(g) => {
            let albedo = cx.colour01(&format!("{p}.albedo"), g.albedo);
            cx.in_unit(&format!("{p}.roughness"), g.roughness);
            Material::Glossy {
                albedo,
                roughness: g.roughness,
            }
        }
        MaterialDoc::Conductor(c) => {
            let eta = cx.nonneg3(&format!("{p}.eta"), c.eta);
            let k = cx.nonneg3(&format!("{p}.k"), c.k);
            // η = k = 0 makes the complex Fresnel 0/0 at normal incidence.
            if eta.max_element() <= 0.0 && k.max_element() <= 0.0 {
                cx.err(&format!("{p}.eta"), "eta and k must not both be zero");
            }
            cx.in_unit(&format!("{p}.roughness"), c.roughness);
            Material::Conductor {
                eta,
                k,
                roughness: c.roughness,
            }
        }
        MaterialDoc::MetallicRoughness(m) => {
            let base = cx.colour01(&format!("{p}.base_color"), m.base_color);
            let base_color = match &m.texture {
                Some(t) => check_texture(cx, &format!("{p}.texture"), t),
                None => Texture::Constant(base),
            };
            cx.in_unit(&format!("{p}.metallic"), m.metallic);
            cx.in_unit(&format!("{p}.roughness"), m.roughness);
            Material::MetallicRoughness {
                base_color,
                metallic: m.metallic,
                roughness: m.roughness,
            }
        }
        MaterialDoc::CoatedDiffuse(c) => {
            let reflectance = colour_or_texture(
                cx,
                p,
                ("coated_diffuse", "reflectance"),
                c.reflectance.as_ref(),
                c.texture.as_ref(),
            );
            cx.in_unit(&format!("{p}.roughness"), c.roughness);
            cx.positive(&format!("{p}.ior"), c.ior);
            Material::CoatedDiffuse {
                reflectance,
                roughness: c.roughness,
                ior: c.ior,
            }
        }
        MaterialDoc::Mirror(r) => Material::Mirror {
            reflectance: cx.colour01(&format!("{p}.reflectance"), r.reflectance),
        },
        MaterialDoc::Dielectric(d) => {
            cx.positive(&format!("{p}.ior"), d.ior);
            let tint = cx.colour01(&format!("{p}.tint"), d.tint.unwrap_or([1.0; 3]));
            Material::Dielectric { ior: d.ior, tint }
        }
        MaterialDoc::Emissive(e) => Material::Emissive {
            radiance: cx.emission3(&format!("{p}.radiance"), e.radiance),
            two_sided: e.two_sided,
        },
    }
}

/// A colour given either as a constant (`field` of a `kind` material, in [0, 1]) or as a
/// `texture`: exactly one of the two.
fn colour_or_texture(
    cx: &mut Ctx,
    p: &str,
    (kind, field): (&str, &str),
    colour: Option<&V3>,
    texture: Option<&TextureDoc>,
) -> Texture {
    match (colour, texture) {
        (Some(a), None) => Texture::Constant(cx.colour01(&format!("{p}.{field}"), *a)),
        (None, Some(t)) => check_texture(cx, &format!("{p}.texture"), t),
        (Some(_), Some(_)) => {
            cx.err(p, format!("give either {field} or texture, not both"));
            Texture::Constant(Vec3::ZERO)
        }
        (None, None) => {
            cx.err(
                &format!("{p}.{field}"),
                format!("missing: a {kind} material needs `{field}` or `texture`"),
            );
            Texture::Constant(Vec3::ZERO)
        }
    }
}

fn check_texture(cx: &mut Ctx, p: &str, t: &TextureDoc) -> Texture {
    let (f, checker) = match t {
        TextureDoc::Checker(f) => (f, true),
        TextureDoc::Noise(f) => (f, false),
        TextureDoc::Image(i) => return check_image_texture(cx, p, i),
    };
    cx.positive(&format!("{p}.scale"), f.scale);
    let a = cx.colour01(&format!("{p}.a"), f.a);
    let b = cx.colour01(&format!("{p}.b"), f.b);
    if checker {
        Texture::Checker {
            scale: f.scale,
            a,
            b,
        }
    } else {
        Texture::Noise {
            scale: f.scale,
            a,
            b,
        }
    }
}

/// An image texture: its mapping checked, its image decoded (once per distinct data and
/// encoding) within the document's texel limit.
fn check_image_texture(cx: &mut Ctx, p: &str, t: &ImageTextureDoc) -> Texture {
    let factor = cx.colour01(&format!("{p}.factor"), t.factor);
    for (name, v) in [("uv_scale", t.uv_scale), ("uv_offset", t.uv_offset)] {
        for (i, x) in v.iter().enumerate() {
            cx.finite(&format!("{p}.{name}[{i}]"), *x);
        }
    }
    let key = {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        t.data.hash(&mut h);
        (h.finish(), t.encoding)
    };
    let image = match cx.image_index.get(&key) {
        Some(&i) => i,
        // No image is decoded for a document already too large.
        None if !cx.too_large.is_empty() => 0,
        None => {
            let budget = MAX_TEXTURE_PIXELS.saturating_sub(cx.texels);
            match crate::scene::image::decode(&t.data, t.encoding, budget) {
                Ok(img) => {
                    cx.texels += u64::from(img.width) * u64::from(img.height);
                    let i = cx.images.len() as u32;
                    cx.images.push(Arc::new(img));
                    cx.image_index.insert(key, i);
                    i
                }
                Err(ImageError::TooLarge(m)) => {
                    cx.limit(&format!("{p}.data"), m);
                    0
                }
                Err(ImageError::Invalid(m)) => {
                    cx.err(&format!("{p}.data"), m);
                    0
                }
            }
        }
    };
    Texture::Image(ImageMap {
        image,
        factor,
        wrap: match t.wrap {
            WrapDoc::Repeat => Wrap::Repeat,
            WrapDoc::Clamp => Wrap::Clamp,
            WrapDoc::Mirror => Wrap::Mirror,
            WrapDoc::Black => Wrap::Black,
        },
        scale: Vec2::from(t.uv_scale),
        offset: Vec2::from(t.uv_offset),
    })
}
