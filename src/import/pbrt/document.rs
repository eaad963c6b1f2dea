//! The scene document made from what was read: the camera (and the mirror that makes
//! pbrt's left-handed view Glimpse's), lights and objects in Glimpse's world, emissive
//! materials for area lights, and the render settings.

use glam::{DMat3, DMat4, DVec3};

use super::{Emission, ImportError, Imported, Importer, Prim};
use crate::scene::doc::{
    CameraDoc, DiffuseDoc, EmissiveDoc, LightDoc, MaterialDoc, MeshDoc, ObjectDoc, RenderDoc,
    SceneDoc, SphereDoc,
};

impl Importer<'_> {
    /// The scene document: materials, objects (world space, mirrored when pbrt's camera
    /// is the mirror image of Glimpse's), lights, camera and settings.
    pub(super) fn finish(mut self, name: &str) -> Result<Imported, ImportError> {
        let (camera, mirror) = self.camera_doc();
        let mirrored = mirror != DMat4::IDENTITY;
        if mirrored {
            self.mirror_lights(&mirror);
        }
        let (objects, reflective_lights) = self.objects(&mirror, mirrored);
        if reflective_lights {
            self.warnings.push(format!("{name}: area lights' own surfaces reflect nothing in Glimpse (pbrt adds their material's reflection)"));
        }
        let doc = SceneDoc {
            materials: self.materials,
            objects,
            lights: self.lights,
            render: RenderDoc {
                samples_per_pixel: self.spp,
                sampler: self.sampler,
                max_bounces: self.max_depth,
                ..RenderDoc::default()
            },
            ..crate::import::document(name, self.size.0, self.size.1, camera)
        };
        Ok(Imported {
            doc,
            warnings: self.warnings,
        })
    }

    /// The document's camera, and the mirror applied to the whole world: when pbrt's
    /// camera-to-world keeps handedness, its left-handed view is the mirror image of
    /// Glimpse's (right = forward × up), so the world is mirrored across the camera's
    /// vertical plane. Without a `Camera`, a placeholder the document's validation refuses.
    fn camera_doc(&self) -> (CameraDoc, DMat4) {
        let Some((cam_from_world, fov)) = self.camera else {
            let camera = CameraDoc {
                position: [0.0; 3],
                look_at: [0.0, 0.0, -1.0],
                up: [0.0, 1.0, 0.0],
                fov_y: 0.0,
            };
            return (camera, DMat4::IDENTITY);
        };
        let world_from_cam = cam_from_world.inverse();
        let (w, h) = (self.size.0 as f64, self.size.1 as f64);
        let fov_y = if w >= h {
            fov
        } else {
            // fov is the shorter (horizontal) axis's.
            2.0 * ((fov.to_radians() * 0.5).tan() * h / w).atan().to_degrees()
        };
        let lin = DMat3::from_mat4(world_from_cam);
        let mirror = if lin.determinant() > 0.0 {
            world_from_cam * DMat4::from_scale(DVec3::new(-1.0, 1.0, 1.0)) * cam_from_world
        } else {
            DMat4::IDENTITY
        };
        let wfc = mirror * world_from_cam;
        let eye = wfc.transform_point3(DVec3::ZERO);
        let fwd = wfc.transform_vector3(DVec3::Z).normalize();
        let up = wfc.transform_vector3(DVec3::Y).normalize();
        let camera = CameraDoc {
            position: eye.as_vec3().to_array(),
            look_at: (eye + fwd).as_vec3().to_array(),
            up: up.as_vec3().to_array(),
            fov_y: fov_y as f32,
        };
        (camera, mirror)
    }

    /// Each light placed again from its frame in pbrt's world, through `m`.
    fn mirror_lights(&mut self, m: &DMat4) {
        for (l, (at, dir)) in self.lights.iter_mut().zip(&self.light_frames) {
            match l {
                LightDoc::Point(pl) => {
                    pl.position = m
                        .transform_point3(at.unwrap_or_default())
                        .as_vec3()
                        .to_array()
                }
                LightDoc::Directional(d) => {
                    d.direction = m
                        .transform_vector3(dir.unwrap_or(DVec3::Z))
                        .as_vec3()
                        .to_array()
                }
                LightDoc::Spot(sl) => {
                    sl.position = m
                        .transform_point3(at.unwrap_or_default())
                        .as_vec3()
                        .to_array();
                    sl.direction = m
                        .transform_vector3(dir.unwrap_or(DVec3::Z))
                        .as_vec3()
                        .to_array();
                }
                LightDoc::Environment(_) => {}
            }
        }
    }

    /// The document's objects, and whether an area light's surface has a material that
    /// reflects (Glimpse's emissive surfaces reflect nothing).
    fn objects(&mut self, mirror: &DMat4, mirrored: bool) -> (Vec<ObjectDoc>, bool) {
        let mut emissive: Vec<(Emission, String)> = Vec::new();
        let mut reflective_lights = false;
        let mut objects = Vec::with_capacity(self.prims.len());
        for prim in std::mem::take(&mut self.prims) {
            let (material, emission) = match &prim {
                Prim::Mesh {
                    material, emission, ..
                }
                | Prim::Sphere {
                    material, emission, ..
                } => (material.clone(), emission.clone()),
            };
            let black = matches!(
                self.materials.get(&material),
                Some(MaterialDoc::Diffuse(DiffuseDoc {
                    albedo: Some([0.0, 0.0, 0.0]),
                    ..
                }))
            );
            reflective_lights |= emission.is_some() && !black;
            let material = match emission {
                None => material,
                Some(e) => self.emissive_material(e, &mut emissive),
            };
            objects.push(object_doc(prim, material, mirror, mirrored));
        }
        (objects, reflective_lights)
    }

    /// The emissive material for emission `e`: one per distinct emission, numbered in the
    /// order first met (`emissive` holds those made so far).
    fn emissive_material(&mut self, e: Emission, emissive: &mut Vec<(Emission, String)>) -> String {
        if let Some((_, n)) = emissive.iter().find(|(x, _)| *x == e) {
            return n.clone();
        }
        let n = format!("emission-{}", emissive.len() + 1);
        self.materials.insert(
            n.clone(),
            MaterialDoc::Emissive(EmissiveDoc {
                radiance: e.radiance.map(|c| c as f32),
                two_sided: e.two_sided,
            }),
        );
        emissive.push((e, n.clone()));
        n
    }
}

/// One primitive as a document object, in Glimpse's world (after `mirror`), each
/// triangle wound so that its geometric normal is pbrt's surface normal.
fn object_doc(p: Prim, material: String, mirror: &DMat4, mirrored: bool) -> ObjectDoc {
    match p {
        Prim::Sphere { center, radius, .. } => ObjectDoc::Sphere(SphereDoc {
            center: mirror.transform_point3(center).as_vec3().to_array(),
            radius: radius as f32,
            material,
            transform: None,
        }),
        Prim::Mesh {
            positions,
            normals,
            uvs,
            mut indices,
            flip,
            ..
        } => {
            for t in &mut indices {
                let [a, b, c] = t.map(|i| positions[i as usize]);
                let winding = (b - a).cross(c - a);
                // pbrt's surface normal for this triangle, in pbrt's world.
                let want = match &normals {
                    Some(ns) => t.iter().map(|&i| ns[i as usize]).sum::<DVec3>(),
                    None if flip => -winding,
                    None => winding,
                };
                // After mirroring, the winding normal reverses; the wanted normal is
                // mirrored as a vector (its side of the surface is kept).
                let agrees = winding.dot(want) >= 0.0;
                if agrees == mirrored {
                    t.swap(1, 2);
                }
            }
            let nm = DMat3::from_mat4(*mirror).inverse().transpose();
            ObjectDoc::Mesh(MeshDoc {
                positions: positions
                    .iter()
                    .map(|&q| mirror.transform_point3(q).as_vec3().to_array())
                    .collect(),
                indices: indices.iter().map(|t| t.map(u64::from)).collect(),
                // A zero normal in a file (it happens) would be refused by validation: the
                // mesh is then shaded with its geometric normals.
                normals: normals
                    .map(|ns| {
                        ns.iter()
                            .map(|&n| (nm * n).normalize_or_zero().as_vec3())
                            .collect::<Vec<_>>()
                    })
                    .filter(|ns| ns.iter().all(|n| n.length_squared() > 0.0 && n.is_finite()))
                    .map(|ns| ns.iter().map(|n| n.to_array()).collect()),
                uvs: uvs.filter(|uv| uv.iter().flatten().all(|c| c.is_finite())),
                material,
                transform: None,
            })
        }
    }
}
