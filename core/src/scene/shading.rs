//! Shading: from a hit to the surface point's [`Interaction`] (position, normals with
//! interpolation and normal mapping, tangent, texture coordinates), and from there to what the
//! point's material gives: its [`Bsdf`] and its emitted radiance.

use super::aggregate::Prim;
use super::{Object, ObjectKind, Scene};
use crate::geometry::triangle::{Mesh, TriangleGeom};
use crate::geometry::{Hit, Interaction, Ray};
use crate::material::{Bsdf, Material};
use glam::{Vec2, Vec3A};

impl Scene {
    /// Full surface details for a hit of `ray`.
    #[inline]
    pub fn interaction(&self, ray: &Ray, hit: &Hit) -> Interaction {
        let o = &self.objects[hit.object as usize];
        match &o.kind {
            ObjectKind::Analytic(a) => {
                let lo = o.to_object.transform_point3a(ray.o);
                let ld = o.to_object.transform_vector3a(ray.d);
                let lh = a.hit(lo, ld, hit.t);
                let n = (o.normal_matrix * lh.n).normalize_or(Vec3A::Y);
                let dpdu = o.to_world.transform_vector3a(lh.dpdu);
                Interaction {
                    p: o.to_world.transform_point3a(lh.p),
                    ng: n,
                    ns: n,
                    dpdu,
                    uv: [lh.uv, lh.uv],
                    t: hit.t,
                    object: hit.object,
                    prim: 0,
                    color: Vec3A::ONE,
                }
            }
            ObjectKind::Mesh { mesh, .. } => {
                self.mesh_interaction(o, &self.meshes[*mesh as usize], hit)
            }
        }
    }

    fn mesh_interaction(&self, o: &Object, m: &Mesh, hit: &Hit) -> Interaction {
        let mat = &self.materials[o.material as usize];
        let (b1, b2) = (hit.b1, hit.b2);
        // Texture coordinates only for materials that look textures up (nothing else reads them).
        let uv = if mat.reads_uv() {
            m.uvs_at(hit.prim, b1, b2)
        } else {
            [Vec2::ZERO; 2]
        };
        // A flattened triangle: its world-space corners and normal are at hand (the BVH slot).
        let agg = &self.aggregate;
        if let Some(&Prim::Tri { lane, count, .. }) = agg.prims.get(hit.slot as usize) {
            let shading = agg.tri_shading[hit.slot as usize];
            if shading.w != 0.0 && mat.slots.normal.is_none() {
                let geom = agg.tri_geom(hit.slot, lane, count);
                let ng = Vec3A::from_vec4(shading);
                return Interaction {
                    p: geom.point(b1, b2),
                    ng,
                    ns: ng,
                    // Shading frames need no tangent (every BSDF is isotropic); only normal
                    // mapping does, and it takes the path below.
                    dpdu: geom.e1,
                    uv,
                    t: hit.t,
                    object: hit.object,
                    prim: hit.prim,
                    color: m.color_at(hit.prim, b1, b2),
                };
            }
        }
        let [ia, ib, ic] = m.indices[hit.prim as usize];
        let b0 = 1.0 - b1 - b2;
        let [p0, p1, p2] = m.corners(hit.prim as usize);
        let geom = TriangleGeom::new([p0, p1, p2]);
        // Point from barycentrics in object space, then to world: accurate to a few ulps.
        let p = o.to_world.transform_point3a(geom.point(b1, b2));
        // The inverse transpose maps the object-space front normal to the world front side even
        // when the transform mirrors (a mirrored winding flips e1×e2 in world space, not this).
        let ng = (o.normal_matrix * geom.normal()).normalize_or(Vec3A::Y);
        let ns = if m.normals.is_empty() {
            ng
        } else {
            let n = m.normals[ia as usize] * b0
                + m.normals[ib as usize] * b1
                + m.normals[ic as usize] * b2;
            let n = (o.normal_matrix * n).normalize_or(ng);
            if n.is_finite() {
                n
            } else {
                ng
            }
        };
        // Tangent: from vertex tangents, else from the uv parameterisation.
        let mut tangent_sign = 1.0;
        let dpdu_obj = if !m.tangents.is_empty() {
            let t = |i: u32| {
                let [x, y, z, w] = m.tangents[i as usize];
                (Vec3A::new(x, y, z), w)
            };
            let (ta, wa) = t(ia);
            tangent_sign = if wa < 0.0 { -1.0 } else { 1.0 };
            ta * b0 + t(ib).0 * b1 + t(ic).0 * b2
        } else if !m.uvs[0].is_empty() {
            let (uv0, uv1, uv2) = (
                m.uvs[0][ia as usize],
                m.uvs[0][ib as usize],
                m.uvs[0][ic as usize],
            );
            let (d1, d2) = (uv1 - uv0, uv2 - uv0);
            let det = d1.x * d2.y - d1.y * d2.x;
            if det.abs() > 1e-12 {
                (geom.e1 * d2.y - geom.e2 * d1.y) / det
            } else {
                geom.e1
            }
        } else {
            geom.e1
        };
        let dpdu = o.to_world.transform_vector3a(dpdu_obj);
        if mat.slots.normal.is_some() && o.to_world.matrix3.determinant() < 0.0 {
            // The bitangent is n × t · w in the mesh's own space (glTF 2.0, 3.7.2.1). A
            // mirroring transform maps a cross product to minus the cross product of the
            // mapped vectors, so the world n × t needs the other sign.
            tangent_sign = -tangent_sign;
        }
        let mut ns = mat.shading_normal(&self.textures, &uv, ns, dpdu, tangent_sign);
        if ns.dot(ng) < 0.0 {
            // Interpolated normals disagreeing with the winding: the winding defines the front
            // side (glTF), so bring the shading normal over to it.
            ns = -ns;
        }
        Interaction {
            p,
            ng,
            ns,
            dpdu,
            uv,
            t: hit.t,
            object: hit.object,
            prim: hit.prim,
            color: m.color_at(hit.prim, b1, b2),
        }
    }

    /// The material of object `object`.
    #[inline]
    pub(crate) fn material_of(&self, object: u32) -> &Material {
        &self.materials[self.objects[object as usize].material as usize]
    }

    /// Radiance emitted from `it` towards `wo` (unit, pointing away from the surface).
    #[inline]
    pub fn emitted(&self, it: &Interaction, wo: Vec3A) -> Vec3A {
        match &self.material_of(it.object).emission {
            Some(e) => e.radiance(&self.textures, it.ng, &it.uv, wo),
            None => Vec3A::ZERO,
        }
    }

    /// The BSDF at `it`, with every texture looked up.
    #[inline]
    pub fn bsdf(&self, it: &Interaction) -> Bsdf {
        self.material_of(it.object)
            .bsdf_tinted(&self.textures, &it.uv, it.color)
    }

    /// Whether `object`'s material is an interface: a medium boundary rays cross unchanged.
    #[inline]
    pub(crate) fn is_interface(&self, object: u32) -> bool {
        self.has_interfaces && self.material_of(object).interface
    }

    /// The medium a ray is in after leaving the surface of `object` (front normal `ng`) in
    /// direction `w`, having been in `current`: the object's interior or exterior by the side
    /// `w` points to, or `current` if the object bounds no medium.
    #[inline]
    pub(crate) fn medium_after(
        &self,
        object: u32,
        ng: Vec3A,
        w: Vec3A,
        current: Option<u32>,
    ) -> Option<u32> {
        match self.objects[object as usize].media {
            Some([interior, exterior]) => {
                if w.dot(ng) > 0.0 {
                    exterior
                } else {
                    interior
                }
            }
            None => current,
        }
    }

    /// Whether anything but interface surfaces blocks `ray` before `tmax` (interfaces let
    /// light through unchanged): [`Scene::occluded`] when the scene has none.
    #[inline]
    pub(crate) fn occluded_past_interfaces(&self, ray: &Ray, tmax: f32) -> bool {
        if !self.has_interfaces {
            return self.occluded(ray, tmax);
        }
        let mut ray = *ray;
        let mut tmax = tmax;
        // Each step moves past one surface; a bound keeps a degenerate case from looping.
        for _ in 0..256 {
            let Some(hit) = self.intersect(&ray, tmax) else {
                return false;
            };
            if !self.is_interface(hit.object) {
                return true;
            }
            let it = self.interaction(&ray, &hit);
            let next = it.spawn_ray(ray.d);
            tmax -= (next.o - ray.o).dot(ray.d);
            ray = next;
            if !(tmax > 0.0) {
                return false;
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use crate::geometry::Ray;
    use crate::scene::desc::*;
    use crate::Scene;
    use glam::{Mat4, Vec2, Vec3, Vec3A};

    /// One triangle with vertex normals and uvs, placed by `transform`, under a material with
    /// a 2×1 texture (left texel red, right texel blue).
    fn triangle_scene(transform: Mat4, normals: Vec<Vec3>) -> SceneDesc {
        let mut d = SceneDesc::default();
        d.textures.push(TextureDesc {
            name: "t".into(),
            width: 2,
            height: 1,
            texels: vec![[1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0]].into(),
            srgb: false,
            wrap_u: WrapMode::Clamp,
            wrap_v: WrapMode::Clamp,
            bilinear: false,
        });
        d.materials.push(MaterialDesc::new(
            "m",
            BsdfDesc::Diffuse {
                albedo: Vec3::ONE,
                texture: Some(TextureRef::new(0)),
            },
        ));
        d.meshes.push(MeshDesc {
            name: "tri".into(),
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            normals,
            uvs: [
                vec![Vec2::ZERO, Vec2::new(1.0, 0.0), Vec2::new(0.0, 1.0)],
                vec![],
            ],
            colors: Vec::new(),
            indices: vec![[0, 1, 2]],
            ..Default::default()
        });
        d.objects.push(ObjectDesc {
            name: "tri".into(),
            shape: ShapeDesc::Mesh { mesh: 0 },
            material: 0,
            transform,
            media: None,
        });
        d
    }

    #[test]
    fn a_triangle_is_shaded_from_its_barycentrics() {
        let t =
            Mat4::from_translation(Vec3::new(0.0, 0.0, -2.0)) * Mat4::from_scale(Vec3::splat(2.0));
        // Flat, then with vertex normals tilted towards +x at vertex 1.
        let tilted = vec![Vec3::Z, Vec3::new(1.0, 0.0, 1.0).normalize(), Vec3::Z];
        for normals in [vec![], tilted] {
            let flat = normals.is_empty();
            let scene = Scene::build(&triangle_scene(t, normals)).unwrap();
            // Aim at barycentrics (b1, b2) = (0.6, 0.2): world point 2·(0.6, 0.2) − 2 z.
            let target = Vec3A::new(1.2, 0.4, -2.0);
            let ray = Ray::new(Vec3A::new(1.2, 0.4, 1.0), -Vec3A::Z);
            let hit = scene.intersect(&ray, f32::INFINITY).unwrap();
            assert!((hit.t - 3.0).abs() < 1e-5 && (hit.b1 - 0.6).abs() < 1e-5);
            let it = scene.interaction(&ray, &hit);
            assert!((it.p - target).length() < 1e-5, "{}", it.p);
            assert!((it.ng - Vec3A::Z).length() < 1e-6);
            assert!((it.uv[0] - Vec2::new(0.6, 0.2)).length() < 1e-5);
            if flat {
                assert_eq!(it.ns, it.ng);
            } else {
                // Interpolated: 0.2 Z + 0.6 (X + Z)/√2 + 0.2 Z, normalised.
                let n = (Vec3A::Z * 0.4 + Vec3A::new(1.0, 0.0, 1.0).normalize() * 0.6).normalize();
                assert!((it.ns - n).length() < 1e-5, "{}", it.ns);
            }
            // u = 0.6 reads the right texel (blue): the diffuse albedo there.
            assert_eq!(scene.bsdf(&it).albedo(), Vec3A::new(0.0, 0.0, 1.0));
            assert_eq!(scene.emitted(&it, Vec3A::Z), Vec3A::ZERO);
        }
    }

    /// A normal map bends the normal the same way in the world whether the node mirrors the
    /// mesh or not, with supplied tangents (w = ±1) and with tangents from the uvs: the
    /// bitangent is n × t · w in the mesh's own space (glTF 2.0, 3.7.2.1).
    #[test]
    fn a_normal_map_bends_alike_under_a_mirroring_transform() {
        // A texel that leans toward +bitangent: (0, 0.6, 0.8) in tangent space.
        let texel = [0.5, 0.8, 0.9, 1.0];
        for (tangents, w) in [(true, 1.0f32), (true, -1.0), (false, 1.0)] {
            let mut want = None;
            for mirror in [
                Vec3::ONE,
                Vec3::new(-1.0, 1.0, 1.0),
                Vec3::new(1.0, 1.0, -1.0),
            ] {
                let transform = Mat4::from_scale(mirror);
                let mut d = triangle_scene(transform, vec![Vec3::Z; 3]);
                d.textures[0].texels = vec![texel; 2].into();
                d.materials[0].normal_texture = Some((TextureRef::new(0), 1.0));
                if tangents {
                    d.meshes[0].tangents = vec![[1.0, 0.0, 0.0, w]; 3];
                }
                let scene = Scene::build(&d).unwrap();
                // Toward the triangle's front side, wherever the mirror put it.
                let front = Vec3A::from(mirror.z * Vec3::Z);
                let ray = Ray::new(Vec3A::new(0.2 * mirror.x, 0.2, 0.0) + front, -front);
                let hit = scene.intersect(&ray, f32::INFINITY).unwrap();
                let it = scene.interaction(&ray, &hit);
                // The mapped normal in the mesh's own frame: mirrored back by the transform.
                let local = Vec3A::from(mirror) * it.ns;
                let want = *want.get_or_insert(local);
                assert!(
                    (local - want).length() < 1e-5,
                    "tangents {tangents}, w {w}, scale {mirror}: {local} against {want}"
                );
                // Up the mesh's bitangent, n × t · w = +y · w, for supplied tangents; from
                // the uvs the tangent is +x and the bitangent +y.
                assert!((local.y - 0.6 * w).abs() < 1e-2, "{local}");
            }
        }
    }
}
