//! Area lights: emitting surfaces, sampled by area and converted to solid angle at the point
//! they light (pbrt-v4's `DiffuseAreaLight`: the light samples its shape, `SampleLi`, and gives
//! the density of any point on it, `PDF_Li`, for multiple importance sampling).
//!
//! An emitting mesh object is one area light whose triangles are chosen separately (each is a
//! light of its own for selection, by its power); an emitting analytic shape is one light.
//! Everything is in world space or carries its placement, so sampling reads nothing else.

use super::{area_to_solid_angle, luminance, LightSample};
use crate::geometry::triangle::TriangleGeom;
use crate::geometry::Analytic;
use crate::material::Emission;
use crate::sampling::warp::uniform_triangle;
use crate::texture::Texture;
use glam::{Affine3A, Mat3A, Vec2, Vec3A};
use std::f32::consts::PI;

/// An emitting surface: one mesh object's triangles or one analytic shape.
#[derive(Clone, Debug)]
pub struct AreaLight {
    /// What the surface emits.
    pub emission: Emission,
    /// Where it emits from.
    pub shape: Emitter,
}

/// The geometry of an [`AreaLight`].
#[derive(Clone, Debug)]
pub enum Emitter {
    /// The world-space triangles of an emitting mesh object, by triangle index.
    Triangles {
        /// Corners, normal and area of each triangle.
        tris: Vec<TriangleLight>,
        /// Per triangle, the texture coordinates of its corners in sets 0 and 1; empty unless
        /// the emission is textured.
        uvs: Vec<[[Vec2; 3]; 2]>,
    },
    /// An analytic shape in its object space, placed in the world.
    Shape(Box<PlacedShape>),
}

/// A world-space emitting triangle.
#[derive(Clone, Copy, Debug)]
pub struct TriangleLight {
    /// Its corners.
    pub geom: TriangleGeom,
    /// Unit geometric normal (front side).
    pub ng: Vec3A,
    /// Area.
    pub area: f32,
}

/// An analytic shape and its object-to-world transform.
#[derive(Clone, Debug)]
pub struct PlacedShape {
    /// The shape in object space.
    pub shape: Analytic,
    /// Object to world.
    pub to_world: Affine3A,
    /// Inverse transpose of the linear part: transforms normals.
    pub normal_matrix: Mat3A,
    /// |det| of the linear part: with |M⁻ᵀn| it scales areas.
    pub det: f32,
}

impl AreaLight {
    /// Emitted power of triangle `prim` (or of the shape), for choosing lights: luminance ×
    /// area × π (2π for two-sided emitters). The area of a shape under a non-uniform scale is
    /// estimated with |det|^(2/3) (exact for uniform scales).
    pub fn power(&self, prim: u32) -> f32 {
        let scale = if self.emission.two_sided {
            2.0 * PI
        } else {
            PI
        };
        let lum = luminance(self.emission.radiance);
        let area = match &self.shape {
            Emitter::Triangles { tris, .. } => tris[prim as usize].area,
            Emitter::Shape(s) => s.shape.area() * s.det.powf(2.0 / 3.0),
        };
        lum * area * scale
    }

    /// The share of the surface there at a point sampled with texture coordinates `uv`
    /// ([`crate::material::Coverage`]): the alpha of a MASK or BLEND mesh, which rays that
    /// find the surface pass by the intersection's alpha test; 1 for analytic shapes, which
    /// that test does not look at.
    #[inline]
    pub fn coverage(&self, textures: &[Texture], uv: &[Vec2; 2]) -> f32 {
        match self.shape {
            Emitter::Triangles { .. } => self.emission.coverage(textures, uv),
            Emitter::Shape(_) => 1.0,
        }
    }

    /// Samples a point on triangle `prim` (or on the shape) uniformly by area: (point, front
    /// normal, texture coordinates, density per unit area).
    #[inline]
    pub fn sample_point(&self, prim: u32, u: Vec2) -> Option<(Vec3A, Vec3A, [Vec2; 2], f32)> {
        match &self.shape {
            Emitter::Triangles { tris, uvs } => {
                let lt = tris.get(prim as usize)?;
                let (b1, b2) = uniform_triangle(u);
                // Texture coordinates only when the emission looks them up.
                let uv = match uvs.get(prim as usize) {
                    Some(c) if self.emission.reads_uv() => {
                        let b0 = 1.0 - b1 - b2;
                        c.map(|[c0, c1, c2]| c0 * b0 + c1 * b1 + c2 * b2)
                    }
                    _ => [Vec2::ZERO; 2],
                };
                Some((lt.geom.point(b1, b2), lt.ng, uv, 1.0 / lt.area))
            }
            Emitter::Shape(s) => {
                let ss = s.shape.sample(u)?;
                let n_world = s.normal_matrix * ss.n;
                // Area scale of the affine map for a surface element with normal n: |det|·|M⁻ᵀn|.
                let jac = s.det * n_world.length();
                let n = n_world.normalize_or(Vec3A::Y);
                let pl = s.to_world.transform_point3a(ss.p);
                Some((pl, n, [Vec2::ZERO; 2], ss.pdf_area / jac))
            }
        }
    }

    /// Samples a point on triangle `prim` (or on the shape) uniformly by area, as seen from
    /// `p`: its radiance towards `p` and the solid-angle density at `p` (selection excluded).
    #[inline]
    pub fn sample(
        &self,
        prim: u32,
        p: Vec3A,
        u: Vec2,
        textures: &[Texture],
    ) -> Option<LightSample> {
        let (pl, ng, uv, pdf_area) = self.sample_point(prim, u)?;
        let to = pl - p;
        let d2 = to.length_squared();
        if !(d2 > 0.0) || !(pdf_area > 0.0) || !pdf_area.is_finite() {
            return None;
        }
        let dist = d2.sqrt();
        let wi_light = to / dist;
        let li =
            self.emission.radiance(textures, ng, &uv, -wi_light) * self.coverage(textures, &uv);
        let cos_l = ng.dot(-wi_light).abs();
        let pdf = area_to_solid_angle(pdf_area, d2, cos_l);
        if pdf <= 0.0 || !pdf.is_finite() {
            return None;
        }
        Some(LightSample {
            wi: to.normalize(),
            li,
            pdf,
            dist,
            delta: false,
            p_light: pl,
            n_light: ng,
        })
    }

    /// Solid-angle density (selection excluded) with which [`AreaLight::sample`] from `from`
    /// gives the point `p_light`, with front normal `n_light`, of triangle `prim` (or of the
    /// shape).
    #[inline]
    pub fn pdf(&self, prim: u32, p_light: Vec3A, n_light: Vec3A, from: Vec3A) -> f32 {
        let pdf_area = self.pdf_area(prim, n_light);
        if pdf_area == 0.0 {
            return 0.0;
        }
        let to = p_light - from;
        area_to_solid_angle(
            pdf_area,
            to.length_squared(),
            n_light.dot(to.normalize_or_zero()),
        )
    }

    /// Density per unit area with which [`AreaLight::sample_point`] gives a point of triangle
    /// `prim` (or of the shape) whose front normal is `n_light`.
    #[inline]
    pub fn pdf_area(&self, prim: u32, n_light: Vec3A) -> f32 {
        match &self.shape {
            Emitter::Triangles { tris, .. } => match tris.get(prim as usize) {
                Some(lt) => 1.0 / lt.area,
                None => 0.0,
            },
            Emitter::Shape(s) => {
                let n_obj = s.to_world.matrix3.transpose() * n_light;
                // |M⁻ᵀ n_obj| with n_obj unit: recover from the world normal.
                let n_obj = n_obj.normalize_or(Vec3A::Y);
                let jac = s.det * (s.normal_matrix * n_obj).length();
                1.0 / (s.shape.area() * jac)
            }
        }
    }

    /// Bytes held, for cache budgets.
    pub fn memory_bytes(&self) -> usize {
        std::mem::size_of::<Self>()
            + match &self.shape {
                Emitter::Triangles { tris, uvs } => {
                    tris.capacity() * std::mem::size_of::<TriangleLight>()
                        + uvs.capacity() * std::mem::size_of::<[[Vec2; 3]; 2]>()
                }
                Emitter::Shape(_) => std::mem::size_of::<PlacedShape>(),
            }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{plane, sphere, Ray};
    use crate::sampling::hash_u32;
    use glam::Mat4;

    fn rnd(i: u32) -> f32 {
        (hash_u32(i) >> 8) as f32 / (1u32 << 24) as f32
    }

    fn emission() -> Emission {
        Emission {
            radiance: Vec3A::new(1.0, 2.0, 3.0),
            two_sided: true,
            texture: None,
            coverage: None,
        }
    }

    fn placed(shape: Analytic, transform: Mat4) -> AreaLight {
        let to_world = Affine3A::from_mat4(transform);
        AreaLight {
            emission: emission(),
            shape: Emitter::Shape(Box::new(PlacedShape {
                shape,
                to_world,
                normal_matrix: to_world.inverse().matrix3.transpose(),
                det: to_world.matrix3.determinant().abs(),
            })),
        }
    }

    fn triangle(corners: [Vec3A; 3]) -> AreaLight {
        let geom = TriangleGeom::new(corners);
        AreaLight {
            emission: emission(),
            shape: Emitter::Triangles {
                tris: vec![TriangleLight {
                    geom,
                    ng: geom.normal().normalize(),
                    area: 0.5 * geom.normal().length(),
                }],
                uvs: vec![],
            },
        }
    }

    /// The lights the tests run on: a triangle, and transformed analytic shapes (a non-uniform
    /// scale changes the area element over the surface, which both densities must follow).
    fn lights() -> Vec<(&'static str, AreaLight)> {
        let squash = Mat4::from_translation(glam::Vec3::new(0.3, 2.0, -0.2))
            * Mat4::from_rotation_x(0.4)
            * Mat4::from_scale(glam::Vec3::new(1.5, 1.0, 0.5));
        vec![
            (
                "triangle",
                triangle([
                    Vec3A::new(-1.0, 2.0, -0.5),
                    Vec3A::new(1.0, 2.2, -0.4),
                    Vec3A::new(0.2, 1.8, 1.0),
                ]),
            ),
            (
                "sphere",
                placed(
                    Analytic::Sphere(sphere::Sphere {
                        center: Vec3A::ZERO,
                        radius: 0.5,
                    }),
                    squash,
                ),
            ),
            (
                "disk",
                placed(
                    Analytic::Disk(plane::Disk {
                        center: Vec3A::ZERO,
                        normal: Vec3A::Y,
                        radius: 0.7,
                    }),
                    squash,
                ),
            ),
            (
                "rectangle",
                placed(
                    Analytic::Rectangle(plane::Rectangle {
                        corner: Vec3A::new(-0.5, 0.0, -0.5),
                        edge_u: Vec3A::new(0.0, 0.0, 1.0),
                        edge_v: Vec3A::new(1.0, 0.0, 0.0),
                    }),
                    squash,
                ),
            ),
        ]
    }

    #[test]
    fn the_sampled_density_is_the_density_of_the_sampled_point() {
        let from = Vec3A::new(0.1, -0.3, 0.2);
        for (name, light) in lights() {
            for i in 0..200 {
                let u = Vec2::new(rnd(2 * i), rnd(2 * i + 1));
                let s = light.sample(0, from, u, &[]).unwrap();
                assert!(!s.delta && s.dist.is_finite() && s.li == emission().radiance);
                assert!((s.wi - (s.p_light - from).normalize()).length() < 1e-6);
                let pdf = light.pdf(0, s.p_light, s.n_light, from);
                assert!(
                    (pdf - s.pdf).abs() <= 1e-4 * s.pdf,
                    "{name}: sampled {} evaluated {pdf}",
                    s.pdf
                );
            }
        }
    }

    /// Where a ray from `from` along `d` meets the light first, and the normal there.
    fn hit(light: &AreaLight, from: Vec3A, d: Vec3A) -> Option<(Vec3A, Vec3A)> {
        match &light.shape {
            Emitter::Triangles { tris, .. } => {
                let lt = tris[0];
                let (t, _, _) = lt.geom.intersect(from, d, 0.0, f32::INFINITY)?;
                Some((from + d * t, lt.ng))
            }
            Emitter::Shape(s) => {
                let to_object = s.to_world.inverse();
                let (o, od) = (
                    to_object.transform_point3a(from),
                    to_object.transform_vector3a(d),
                );
                let t = s.shape.intersect(o, od, 0.0, f32::INFINITY)?;
                let h = s.shape.hit(o, od, t);
                let n = (s.normal_matrix * h.n).normalize();
                Some((Ray::new(from, d).at(t), n))
            }
        }
    }

    #[test]
    fn the_density_integrates_to_one_over_the_solid_angle_of_a_flat_light() {
        // Monte Carlo over uniform directions: ∫ pdf dω = 1 for a light seen once from every
        // direction that meets it (flat lights; a sphere also shows its back to the sampler).
        let from = Vec3A::new(0.1, -0.3, 0.2);
        let n = 400_000u32;
        for (name, light) in lights().into_iter().filter(|(n, _)| *n != "sphere") {
            let mut sum = 0.0f64;
            for i in 0..n {
                let d =
                    crate::sampling::warp::uniform_sphere(Vec2::new(rnd(2 * i), rnd(2 * i + 1)));
                if let Some((p, ng)) = hit(&light, from, d) {
                    sum += light.pdf(0, p, ng, from) as f64;
                }
            }
            let integral = sum / n as f64 / crate::sampling::warp::UNIFORM_SPHERE_PDF as f64;
            assert!(
                (integral - 1.0).abs() < 0.02,
                "{name}: ∫ pdf dω = {integral}"
            );
        }
    }

    /// Gives the triangle of [`triangle`] texture coordinates with u = 0.9 at corner 1 and 0.1
    /// at corners 0 and 2 (v = 0.5), in both sets: a point's u is 0.1 + 0.8 × its x.
    fn spread_u(light: &mut AreaLight) {
        let Emitter::Triangles { uvs, .. } = &mut light.shape else {
            unreachable!()
        };
        uvs.push(
            [[
                Vec2::new(0.1, 0.5),
                Vec2::new(0.9, 0.5),
                Vec2::new(0.1, 0.5),
            ]; 2],
        );
    }

    #[test]
    fn one_sided_lights_are_dark_from_behind_and_textured_ones_read_their_uvs() {
        let mut light = triangle([
            Vec3A::new(0.0, 1.0, 0.0),
            Vec3A::new(1.0, 1.0, 0.0),
            Vec3A::new(0.0, 1.0, 1.0),
        ]);
        light.emission.two_sided = false;
        // Its normal is −Y (corners counter-clockwise seen from below): lit below, dark above.
        let u = Vec2::new(0.3, 0.6);
        let below = light.sample(0, Vec3A::new(0.2, 0.0, 0.2), u, &[]).unwrap();
        let above = light.sample(0, Vec3A::new(0.2, 2.0, 0.2), u, &[]).unwrap();
        assert_eq!(below.li, emission().radiance);
        assert_eq!(above.li, Vec3A::ZERO);
        // A texture whose left half is black and right half white, addressed by set 0.
        let tex = Texture::new(
            2,
            1,
            &[[0.0; 4], [1.0; 4]],
            false,
            crate::texture::TextureLookup::default(),
        );
        light.emission.texture = Some(crate::texture::TexSlot::new(0, 0, glam::Mat3::IDENTITY));
        // The sampled point's x is its barycentric weight of corner 1, so its u is 0.1 + 0.8 x.
        spread_u(&mut light);
        let textures = [tex];
        let mut lit = 0;
        for i in 0..64 {
            let u = Vec2::new(rnd(2 * i), rnd(2 * i + 1));
            let s = light
                .sample(0, Vec3A::new(0.2, 0.0, 0.2), u, &textures)
                .unwrap();
            let x = s.p_light.x;
            let white = 0.1 + 0.8 * x >= 0.5;
            assert_eq!(s.li != Vec3A::ZERO, white, "x = {x}");
            lit += usize::from(white);
        }
        assert!(lit > 0 && lit < 64);
    }

    /// A MASK emitter's light samples carry nothing where its alpha cuts it out, and a BLEND
    /// one's carry alpha of its radiance: as much as the rays that find it (the intersection
    /// passes them through by the same alpha). Analytic shapes, which the alpha test does not
    /// look at, keep all of it.
    #[test]
    fn alpha_emitters_give_light_samples_their_coverage() {
        use crate::material::{AlphaMode, Coverage};
        use crate::texture::{TexSlot, TextureLookup};
        // Alpha 0 on the left half, 1 on the right half.
        let tex = Texture::new(
            2,
            1,
            &[[1.0, 1.0, 1.0, 0.0], [1.0; 4]],
            false,
            TextureLookup::default(),
        );
        let textures = [tex];
        let mut light = triangle([
            Vec3A::new(0.0, 1.0, 0.0),
            Vec3A::new(1.0, 1.0, 0.0),
            Vec3A::new(0.0, 1.0, 1.0),
        ]);
        spread_u(&mut light);
        let from = Vec3A::new(0.2, 0.0, 0.2);
        light.emission.coverage = Some(Coverage {
            mode: AlphaMode::Mask(0.5),
            alpha: 1.0,
            texture: Some(TexSlot::new(0, 0, glam::Mat3::IDENTITY)),
        });
        let mut kept = 0;
        for i in 0..64 {
            let u = Vec2::new(rnd(2 * i), rnd(2 * i + 1));
            let s = light.sample(0, from, u, &textures).unwrap();
            let there = 0.1 + 0.8 * s.p_light.x >= 0.5;
            assert_eq!(
                s.li,
                if there {
                    emission().radiance
                } else {
                    Vec3A::ZERO
                }
            );
            kept += usize::from(there);
        }
        assert!(kept > 0 && kept < 64);
        light.emission.coverage = Some(Coverage {
            mode: AlphaMode::Blend,
            alpha: 0.3,
            texture: None,
        });
        let s = light
            .sample(0, from, Vec2::new(0.3, 0.4), &textures)
            .unwrap();
        assert!(
            (s.li - emission().radiance * 0.3).abs().max_element() < 1e-6,
            "{}",
            s.li
        );
        let mut ball = placed(
            Analytic::Sphere(sphere::Sphere {
                center: Vec3A::ZERO,
                radius: 0.5,
            }),
            Mat4::IDENTITY,
        );
        ball.emission.coverage = light.emission.coverage;
        let s = ball
            .sample(0, Vec3A::new(0.0, 3.0, 0.0), Vec2::new(0.3, 0.4), &[])
            .unwrap();
        assert_eq!(s.li, emission().radiance);
    }
}
