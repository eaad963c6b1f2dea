use glam::Vec3;
use glimpse::scene::Shape;
use glimpse::tracer::bvh::Geometry;
use glimpse::tracer::camera::Pinhole;
use glimpse::tracer::fixtures::cornell_box;
use glimpse::tracer::sampling::offset_ray_origin;

#[test]
fn scratch() {
    for (sc, off) in [(1.0f32, 0.0f32), (1000.0, 1e5)] {
        let mut s = cornell_box(16, 16, 64, 1, 2);
        for sh in &mut s.shapes {
            if let Shape::Triangles { triangles, .. } = sh {
                for tri in triangles { for p in &mut tri.p { *p = *p * sc + Vec3::splat(off); } }
            }
        }
        s.camera.position = s.camera.position * sc + Vec3::splat(off);
        s.camera.look_at = s.camera.look_at * sc + Vec3::splat(off);
        let g = Geometry::build(&s);
        let cam = Pinhole::new(&s.camera, 16, 16);
        let d = cam.direction(1, 15, glam::Vec2::splat(0.5));
        let h = g.intersect(cam.origin, d, f32::INFINITY, u32::MAX).unwrap();
        let su = g.surface(cam.origin, d, &h);
        let ng = if su.ng.dot(d) > 0.0 { -su.ng } else { su.ng };
        println!("sc {sc}: obj {} t {} p {} ng {}", su.info.object, h.t, (su.p - Vec3::splat(off)) / sc, ng);
        let q = (Vec3::new(0.0, 1.98, 0.0)) * sc + Vec3::splat(off);
        let o = offset_ray_origin(su.p, ng);
        println!("  o - p = {}", o - su.p);
        let wi = (q - su.p).normalize();
        let dist = (q - o).dot(wi);
        match g.intersect(o, wi, dist * 0.9999, h.prim) {
            Some(h2) => { let s2 = g.surface(o, wi, &h2); println!("  blocked by obj {} at t {} of {} p {}", s2.info.object, h2.t, dist, (s2.p - Vec3::splat(off)) / sc); }
            None => println!("  visible"),
        }
    }
}
