//! Which solid transmissive bodies a path is inside, so that a body's Beer–Lambert absorption
//! attenuates every stretch of a path within it: the stretch to an object immersed in it (a
//! lamp in tinted glass, a stone in coloured water) as well as the stretch to its own surface.
//!
//! A body is the inside of a surface whose material is solid and transmissive
//! ([`Material::body`](crate::material::Material::body): a `dielectric` that is not thin, a
//! `rough_dielectric`, a glTF transmissive material with a volume). Bodies are known by their
//! material: a body split into several objects of one material (a glTF mesh in several
//! primitives) is one body, and a body of some material inside another of the same material
//! means nothing physical.
//!
//! A path keeps [`Bodies`], the bodies it is inside, innermost last:
//! - leaving a body's surface into it pushes the body; leaving it outwards removes it;
//! - a stretch that ends on a body's surface from within was inside that body, whatever the
//!   path had kept (a camera in water, a path whose outer bodies were forgotten): that body
//!   becomes the innermost, and bodies kept inside it are dropped;
//! - a stretch that ends on a body's surface from without was not inside it (an open surface
//!   that a path entered but never left): the body is removed.
//!
//! So the stack mends itself, and where bodies are closed and do not overlap it is exact.
//! Where a path starts, the bodies around its first point are found by probe rays walked from
//! it out of the scene ([`Bodies::around`]): once per job for the camera (from the lens
//! centre: an orthographic view or a lens that straddles a body's surface is taken as a
//! whole on one side), and once per light for the light paths of `bdpt` and `sppm` (from one
//! point of an emitting surface: an emitter that straddles a body's surface is taken as wholly
//! on the side of that point).
//!
//! In `volpath`, a body whose surface bounds a medium of its own (an `interior`) absorbs
//! through that medium alone; the stack keeps that per object, in the entry's top bit.

use super::Scene;
use crate::geometry::{offset_ray_origin, Interaction, Ray};
use crate::light::Light;
use crate::sampling::detmath::exp3;
use glam::Vec3A;

/// How deep bodies nest before the outermost is forgotten (a glass of water with an ice
/// cube with a bubble is three).
const NESTING: usize = 4;

/// The directions of the probe rays of [`Bodies::around`] (normalised where used): near the
/// six axis directions, where openings usually face (a glass open at the top, a tube open
/// at its ends), and tilted off every axis and diagonal so that they rarely run along the
/// faces, edges and corners of boxes built on the axes.
const PROBES: [Vec3A; 6] = [
    Vec3A::new(0.97, 0.17, 0.13),
    Vec3A::new(-0.95, 0.21, -0.19),
    Vec3A::new(0.15, 0.98, -0.11),
    Vec3A::new(-0.18, -0.96, 0.2),
    Vec3A::new(0.12, -0.2, 0.97),
    Vec3A::new(-0.21, 0.14, -0.96),
];

/// The surfaces one probe ray may cross before its answer is given up as unknown.
const PROBE_STEPS: usize = 4096;

/// The top bit of a stack entry: the body's object bounds an `interior` medium.
const WITH_MEDIUM: u32 = 1 << 31;

/// Whether two stack entries are the same body (the same material).
#[inline]
fn same(a: u32, b: u32) -> bool {
    (a ^ b) & !WITH_MEDIUM == 0
}

/// The materials of the bodies a path is inside, innermost last, each with the
/// [`WITH_MEDIUM`] bit of the object the path entered it by (see the module).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Bodies {
    len: u8,
    materials: [u32; NESTING],
}

impl Bodies {
    fn kept(&self) -> &[u32] {
        &self.materials[..self.len as usize]
    }

    /// The innermost body's material.
    #[inline]
    fn innermost(&self) -> Option<u32> {
        self.kept().last().copied()
    }

    fn push(&mut self, m: u32) {
        if self.len as usize == NESTING {
            self.materials.copy_within(1.., 0);
            self.len -= 1;
        }
        self.materials[self.len as usize] = m;
        self.len += 1;
    }

    /// Removes the innermost entry of `m`, if any.
    fn remove(&mut self, m: u32) {
        if let Some(i) = self.kept().iter().rposition(|&k| same(k, m)) {
            self.materials.copy_within(i + 1..self.len as usize, i);
            self.len -= 1;
        }
    }

    /// Makes `m` the innermost body: drops what is kept inside it, or pushes it.
    fn enter(&mut self, m: u32) {
        match self.kept().iter().rposition(|&k| same(k, m)) {
            Some(i) => {
                self.len = i as u8 + 1;
                self.materials[i] = m;
            }
            None => self.push(m),
        }
    }

    /// The absorption coefficient (per unit length) of the innermost body: zero outside every
    /// body. With `media` (in `volpath`), a body whose surface bounds a medium absorbs
    /// nothing itself: the medium stands for its inside.
    #[inline]
    pub(crate) fn sigma(&self, scene: &Scene, media: bool) -> Vec3A {
        match self.innermost() {
            Some(m) => scene.body_absorption(m, media),
            None => Vec3A::ZERO,
        }
    }

    /// A stretch travelled along `d` has ended on `it`: returns the absorption coefficient
    /// along it, and mends the stack by which side of a body's surface the stretch ended on.
    #[inline]
    pub(crate) fn arrive(
        &mut self,
        scene: &Scene,
        it: &Interaction,
        d: Vec3A,
        media: bool,
    ) -> Vec3A {
        if let Some(m) = scene.body_key(it.object) {
            if it.ng.dot(d) > 0.0 {
                self.enter(m);
            } else {
                self.remove(m);
            }
        }
        self.sigma(scene, media)
    }

    /// The path leaves `it` along `wi`: into the body behind the surface, or out of it.
    #[inline]
    pub(crate) fn leave(&mut self, scene: &Scene, it: &Interaction, wi: Vec3A) {
        if let Some(m) = scene.body_key(it.object) {
            if it.ng.dot(wi) >= 0.0 {
                self.remove(m);
            } else if !self.innermost().is_some_and(|k| same(k, m)) {
                // Into the body: nested in what is kept (a body of a material kept further
                // out is a new body inside the others, not that one).
                self.push(m);
            }
        }
    }

    /// The transmittance to infinity from inside these bodies (a path that escapes the scene
    /// from inside an open body): 0 in the channels the innermost absorbs, else 1.
    #[inline]
    pub(crate) fn escape(&self, scene: &Scene, media: bool) -> Vec3A {
        if scene.absorbs {
            beer(self.sigma(scene, media), f32::INFINITY)
        } else {
            Vec3A::ONE
        }
    }

    /// The absorption coefficient along a stretch that leaves `it` along `wi` (a shadow ray's),
    /// for a path that arrived there with these bodies.
    #[inline]
    pub(crate) fn sigma_leaving(
        &self,
        scene: &Scene,
        it: &Interaction,
        wi: Vec3A,
        media: bool,
    ) -> Vec3A {
        let mut b = *self;
        b.leave(scene, it, wi);
        b.sigma(scene, media)
    }

    /// The bodies around the point `p`, outermost first: those that every probe ray from `p`
    /// finds around it (see [`probe`]). Rays in six directions must agree, so that an open
    /// surface (a lampshade open below, a tube open at its ends, a glass sheet) does not put
    /// the point inside it. Nothing when the scene has no absorbing body.
    pub(crate) fn around(scene: &Scene, p: Vec3A) -> Bodies {
        let mut found = Bodies::default();
        if !scene.absorbs {
            return found;
        }
        let mut agreed: Option<Vec<u32>> = None;
        for d in PROBES {
            let Some(list) = probe(scene, p, d.normalize()) else {
                continue;
            };
            agreed = Some(match agreed {
                None => list,
                Some(a) => {
                    let n = a.iter().zip(&list).take_while(|(x, y)| x == y).count();
                    a[..n].to_vec()
                }
            });
        }
        for m in agreed.unwrap_or_default() {
            found.push(m);
        }
        found
    }
}

/// The bodies one probe ray from `p` along `d` finds around `p`, outermost first: a body
/// whose surface the ray crosses from within before it has entered that body encloses `p`
/// (bodies it enters and leaves again do not). `None` if the ray crosses more than
/// [`PROBE_STEPS`] surfaces: no answer.
fn probe(scene: &Scene, p: Vec3A, d: Vec3A) -> Option<Vec<u32>> {
    let mut enclosing: Vec<u32> = Vec::new();
    let mut entered: Vec<u32> = Vec::new();
    let mut ray = Ray::new(p, d);
    for _ in 0..PROBE_STEPS {
        let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
            enclosing.reverse();
            return Some(enclosing);
        };
        let it = scene.interaction(&ray, &hit);
        if let Some(m) = scene.body_key(it.object) {
            if it.ng.dot(d) < 0.0 {
                entered.push(m);
            } else if let Some(i) = entered.iter().rposition(|&k| same(k, m)) {
                entered.remove(i);
            } else if !enclosing.iter().any(|&k| same(k, m)) {
                enclosing.push(m);
            }
        }
        ray = Ray::new(offset_ray_origin(it.p, it.ng, d), d);
    }
    None
}

/// Beer–Lambert transmittance over `dist` with absorption coefficient `sigma`: 0 over an
/// infinite distance in the channels that absorb, 1 in those that do not.
#[inline]
pub(crate) fn beer(sigma: Vec3A, dist: f32) -> Vec3A {
    if dist.is_finite() {
        exp3(-sigma * dist)
    } else {
        Vec3A::select(sigma.cmpeq(Vec3A::ZERO), Vec3A::ONE, Vec3A::ZERO)
    }
}

impl Scene {
    /// The stack entry of `object` if it bounds a body: its material, with [`WITH_MEDIUM`]
    /// if the object bounds an `interior` medium.
    #[inline]
    pub(crate) fn body_key(&self, object: u32) -> Option<u32> {
        let o = &self.objects[object as usize];
        let interior = o.media.is_some_and(|[inside, _]| inside.is_some());
        let flag = if interior { WITH_MEDIUM } else { 0 };
        self.materials[o.material as usize]
            .body
            .then_some(o.material | flag)
    }

    /// The absorption coefficient inside the body of stack entry `k` (see [`Bodies::sigma`]).
    #[inline]
    fn body_absorption(&self, k: u32, media: bool) -> Vec3A {
        if media && k & WITH_MEDIUM != 0 {
            Vec3A::ZERO
        } else {
            self.materials[(k & !WITH_MEDIUM) as usize].absorption
        }
    }
}

/// Where a job's paths start: the bodies around the camera, and (found when first asked: only
/// `bdpt` and `sppm` start paths at lights) around each light.
#[derive(Debug, Default)]
pub(crate) struct Starts {
    camera: Bodies,
    lights: std::sync::OnceLock<LightStarts>,
}

/// The bodies around the lights.
#[derive(Debug, Default)]
struct LightStarts {
    /// By [`AreaLight`](crate::light::AreaLight), around a point of its surface.
    area: Vec<Bodies>,
    /// Point and spot lights inside some body, by index in [`Scene::lights`].
    points: Vec<(usize, Bodies)>,
}

impl LightStarts {
    fn new(scene: &Scene) -> LightStarts {
        if !scene.absorbs {
            return LightStarts::default();
        }
        let area = scene
            .area_lights
            .iter()
            .map(|al| match al.sample_point(0, glam::Vec2::splat(0.5)) {
                Some((p, ng, ..)) => Bodies::around(scene, offset_ray_origin(p, ng, ng)),
                None => Bodies::default(),
            })
            .collect();
        let points = scene
            .lights
            .iter()
            .enumerate()
            .filter_map(|(i, l)| match *l {
                Light::Point { position, .. } | Light::Spot { position, .. } => {
                    let b = Bodies::around(scene, position);
                    (b != Bodies::default()).then_some((i, b))
                }
                _ => None,
            })
            .collect();
        LightStarts { area, points }
    }
}

impl Starts {
    /// The bodies around `eye` (the camera's centre); empty when the scene has no absorbing
    /// body.
    pub(crate) fn new(scene: &Scene, eye: Vec3A) -> Starts {
        Starts {
            camera: Bodies::around(scene, eye),
            lights: std::sync::OnceLock::new(),
        }
    }

    /// The bodies around the camera.
    #[inline]
    pub(crate) fn camera(&self) -> Bodies {
        self.camera
    }

    /// The bodies around light `index` of [`Scene::lights`] (none for lights at infinity,
    /// which are outside every body).
    pub(crate) fn light(&self, scene: &Scene, index: usize) -> Bodies {
        if !scene.absorbs {
            return Bodies::default();
        }
        let starts = self.lights.get_or_init(|| LightStarts::new(scene));
        match scene.lights.get(index) {
            Some(&Light::Area { light, .. }) => {
                starts.area.get(light as usize).copied().unwrap_or_default()
            }
            Some(Light::Point { .. } | Light::Spot { .. }) => starts
                .points
                .binary_search_by_key(&index, |&(i, _)| i)
                .map_or(Bodies::default(), |k| starts.points[k].1),
            _ => Bodies::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::json::parse_json;
    use std::path::Path;

    fn load(json: &str) -> Scene {
        let desc = parse_json(json, Path::new("."), Path::new("test.json")).unwrap();
        Scene::build(&desc).unwrap()
    }

    fn stack(ms: &[u32]) -> Bodies {
        let mut b = Bodies::default();
        for &m in ms {
            b.push(m);
        }
        b
    }

    #[test]
    fn the_stack_pushes_enters_and_removes_by_material() {
        let mut b = stack(&[1, 2]);
        b.enter(3);
        assert_eq!(b.kept(), &[1, 2, 3]);
        // Entering a body already kept drops what was kept inside it.
        b.enter(1);
        assert_eq!(b.kept(), &[1]);
        let mut b = stack(&[1, 2, 1]);
        b.remove(1);
        assert_eq!(b.kept(), &[1, 2], "the innermost entry goes");
        b.remove(7);
        assert_eq!(b.kept(), &[1, 2], "a body not kept: nothing to remove");
        // Deeper than NESTING: the outermost is forgotten.
        let b = stack(&[1, 2, 3, 4, 5]);
        assert_eq!(b.kept(), &[2, 3, 4, 5]);
        assert_eq!(b.innermost(), Some(5));
    }

    /// Water (material 0) in a box, a glass marble (material 1) in it, a stone and a lamp:
    /// the bodies around points found by the probe, and as a path meets the surfaces.
    const NESTED: &str = r#"{
      "materials": {
        "water": {"type": "dielectric", "ior": 1.33, "absorption": [0.5, 1, 2]},
        "marble": {"type": "dielectric", "ior": 1.5},
        "stone": {"type": "diffuse"},
        "lamp": {"type": "emitter", "emission": [1, 1, 1]}
      },
      "objects": [
        {"shape": {"type": "box", "min": [-1, -1, -1], "max": [1, 1, 1]}, "material": "water"},
        {"shape": {"type": "sphere", "center": [0.5, 0, 0], "radius": 0.3}, "material": "marble"},
        {"shape": {"type": "sphere", "center": [-0.5, 0, 0], "radius": 0.2}, "material": "stone"},
        {"shape": {"type": "sphere", "center": [0, 0.5, 0], "radius": 0.1}, "material": "lamp"}
      ],
      "camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]}
    }"#;

    #[test]
    fn the_probe_finds_the_bodies_around_a_point() {
        let scene = load(NESTED);
        let (water, marble) = (scene.objects[0].material, scene.objects[1].material);
        assert!(scene.absorbs);
        let around = |p: [f32; 3]| Bodies::around(&scene, Vec3A::from_array(p));
        assert_eq!(around([0.0, 0.0, 5.0]).kept(), &[] as &[u32]);
        assert_eq!(around([0.0, -0.5, 0.0]).kept(), &[water]);
        assert_eq!(around([0.5, 0.0, 0.0]).kept(), &[water, marble]);
        // Beside the stone and below the lamp, which are not bodies.
        assert_eq!(around([-0.5, -0.5, 0.0]).kept(), &[water]);
        assert_eq!(around([0.0, 0.3, 0.0]).kept(), &[water]);
        // Below the box, the probe enters and leaves it: not inside.
        assert_eq!(around([0.0, -3.0, 0.0]).kept(), &[] as &[u32]);
        // A job finds the camera outside and the lamp in the water.
        let job = crate::RenderJob::new(&scene, &crate::RenderSettings::default()).unwrap();
        assert_eq!(job.starts.camera(), Bodies::default());
        assert_eq!(job.starts.light(&scene, 0).kept(), &[water]);
    }

    #[test]
    fn a_path_keeps_the_bodies_it_crosses_and_mends_what_it_missed() {
        let scene = load(NESTED);
        let (water, marble) = (scene.objects[0].material, scene.objects[1].material);
        let sigma_water = Vec3A::new(0.5, 1.0, 2.0);
        let hit = |o: [f32; 3], d: [f32; 3]| {
            let ray = Ray::new(Vec3A::from_array(o), Vec3A::from_array(d));
            let h = scene.intersect(&ray, f32::INFINITY).unwrap();
            (scene.interaction(&ray, &h), ray.d)
        };
        let mut b = Bodies::default();
        // From the camera into the water: the stretch outside absorbs nothing.
        let (top, d) = hit([0.5, 0.0, 5.0], [0.0, 0.0, -1.0]);
        assert_eq!(b.arrive(&scene, &top, d, false), Vec3A::ZERO);
        b.leave(&scene, &top, d);
        assert_eq!(b.kept(), &[water]);
        // On to the marble: a stretch in water.
        let (m, d) = hit([0.5, 0.0, 0.9], [0.0, 0.0, -1.0]);
        assert_eq!(b.arrive(&scene, &m, d, false), sigma_water);
        b.leave(&scene, &m, d);
        assert_eq!(b.kept(), &[water, marble]);
        // Through the clear marble: nothing absorbed inside it.
        let (m2, d) = hit([0.5, 0.0, 0.0], [0.0, 0.0, -1.0]);
        assert_eq!(b.arrive(&scene, &m2, d, false), Vec3A::ZERO);
        b.leave(&scene, &m2, d);
        assert_eq!(b.kept(), &[water]);
        // A shadow ray from the stone (in water) to the lamp: absorbed by the water.
        let (stone, _) = hit([-0.5, 0.5, 0.0], [0.0, -1.0, 0.0]);
        let up = Vec3A::Y;
        assert_eq!(b.sigma_leaving(&scene, &stone, up, false), sigma_water);
        // A camera that starts in the water unknown to the path: the stretch to the water's
        // surface from within is the water's, and the path is then in it.
        let mut lost = Bodies::default();
        let (wall, d) = hit([0.0, -0.5, 0.0], [0.0, -1.0, 0.0]);
        assert_eq!(lost.arrive(&scene, &wall, d, false), sigma_water);
        assert_eq!(lost.kept(), &[water]);
        // A path that thinks it is in water but meets the water from without is not.
        let mut wrong = stack(&[water]);
        let (top, d) = hit([0.0, 0.0, 5.0], [0.0, 0.0, -1.0]);
        assert_eq!(wrong.arrive(&scene, &top, d, false), Vec3A::ZERO);
        assert_eq!(wrong.kept(), &[] as &[u32]);
    }

    #[test]
    fn a_path_into_a_body_of_a_material_kept_further_out_nests_it() {
        // A marble of the glass (material 1) in water (2) in a glass block: refracting into
        // the marble nests a new glass body; it does not drop the water.
        let scene = load(NESTED);
        let water = scene.objects[0].material;
        let ray = Ray::new(Vec3A::new(0.5, 0.0, 0.9), Vec3A::NEG_Z);
        let marble = scene.interaction(&ray, &scene.intersect(&ray, f32::INFINITY).unwrap());
        let glass = scene.objects[1].material;
        let mut b = stack(&[glass, water]);
        b.leave(&scene, &marble, Vec3A::NEG_Z);
        assert_eq!(b.kept(), &[glass, water, glass]);
        b.leave(&scene, &marble, Vec3A::Z);
        assert_eq!(b.kept(), &[glass, water]);
    }

    #[test]
    fn an_open_surface_does_not_put_a_point_inside_it() {
        // A lamp in a glass tube open at both ends (a cylinder has no caps): rays sideways
        // leave the tube from within, rays along it escape; the probes must agree, so the
        // lamp is outside every body. A closed sphere around it counts.
        let scene = load(
            r#"{
          "materials": {"glass": {"type": "dielectric", "absorption": [1, 1, 1]},
                        "tint": {"type": "dielectric", "absorption": [2, 2, 2]}},
          "objects": [
            {"shape": {"type": "cylinder", "radius": 0.5, "y_min": -1, "y_max": 1},
             "material": "glass"},
            {"shape": {"type": "sphere", "center": [3, 0, 0], "radius": 0.5}, "material": "tint"}
          ],
          "camera": {"position": [0, 0, 5], "look_at": [0, 0, 0]}
        }"#,
        );
        let tint = scene.objects[1].material;
        assert_eq!(Bodies::around(&scene, Vec3A::ZERO).kept(), &[] as &[u32]);
        assert_eq!(
            Bodies::around(&scene, Vec3A::new(3.0, 0.1, 0.0)).kept(),
            &[tint]
        );
    }

    #[test]
    fn beer_over_an_infinite_distance_keeps_the_channels_that_do_not_absorb() {
        let t = beer(Vec3A::new(0.0, 1.0, 0.0), f32::INFINITY);
        assert_eq!(t, Vec3A::new(1.0, 0.0, 1.0));
        assert_eq!(beer(Vec3A::splat(2.0), 0.5), exp3(Vec3A::splat(-1.0)));
    }
}
