//! What one render adds to a built [`Scene`]: the settings, the camera set up for the image
//! size, the environment (the scene's own, none, or one the job brings) and the distribution
//! that picks lights, which depends on that environment. Cheap to make (the light distribution
//! is linear in the number of lights), so a scene built once serves every job on it.

use super::bodies::Starts;
use super::{ObjectKind, Scene, SceneCamera, SceneError};
use crate::camera::{Camera, Projection};
use crate::film::FilterSampler;
use crate::geometry::{Aabb, Interaction};
use crate::light::{show_number, Environment, Light, LightSample, LightSet, MAX_RADIANCE};
use crate::settings::EnvironmentChoice;
use crate::{RenderSettings, SettingsError};
use glam::{Mat4, Vec2, Vec3, Vec3A};
use std::sync::Arc;

/// A render of a [`Scene`] with given settings: everything that depends on the job rather than
/// on the scene's bytes. [`crate::render`], [`crate::render_tile`] and the integrators take it
/// beside the scene.
#[derive(Clone, Debug)]
pub struct RenderJob {
    /// The settings, validated.
    pub settings: RenderSettings,
    /// The camera, for the settings' image size.
    pub camera: Camera,
    /// Draws pixel-filter offsets.
    pub(crate) filter: FilterSampler,
    /// The light arriving from infinitely far away, if any.
    environment: Option<Arc<Environment>>,
    /// Chooses among the scene's lights and the environment.
    lights: LightSet,
    /// What an integrator computes once for the whole job and reuses in every tile of it
    /// (`sppm`'s photon maps); shared by clones, emptied when the environment changes.
    pub(crate) cache: Arc<JobCache>,
    /// The bodies around the camera and the lights, where paths start.
    pub(crate) starts: Arc<Starts>,
}

/// Values computed once per job and kept for its other tiles, by key, up to
/// [`JobCache::BUDGET`] bytes: beyond it a value is not kept, and whoever needs it computes it
/// again, to the same bits (a value depends only on the job and its key). Nothing is evicted:
/// the tiles of a job ask for the same keys in the same order, a pattern that evicting the
/// oldest would turn into a miss on every request.
#[derive(Default)]
pub struct JobCache {
    /// Bytes kept, and the values by key.
    entries: std::sync::Mutex<(usize, Vec<(u64, CachedValue)>)>,
}

/// A value of [`JobCache`], of any type.
type CachedValue = Arc<dyn std::any::Any + Send + Sync>;

impl std::fmt::Debug for JobCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let e = self.entries.lock().unwrap_or_else(|e| e.into_inner());
        write!(f, "JobCache({} values, {} bytes)", e.1.len(), e.0)
    }
}

impl JobCache {
    /// Bytes of values kept per job.
    pub const BUDGET: usize = 256 << 20;

    /// The value kept under `key`, if any (and of type `T`).
    pub(crate) fn get<T: Send + Sync + 'static>(&self, key: u64) -> Option<Arc<T>> {
        let e = self.entries.lock().unwrap_or_else(|e| e.into_inner());
        let v = e.1.iter().find(|(k, _)| *k == key)?.1.clone();
        v.downcast::<T>().ok()
    }

    /// Keeps `value` (of `bytes` bytes) under `key` if the budget allows and the key is new.
    /// The lock is held only here and in [`JobCache::get`], never while a value is computed.
    pub(crate) fn insert<T: Send + Sync + 'static>(&self, key: u64, value: Arc<T>, bytes: usize) {
        let mut e = self.entries.lock().unwrap_or_else(|e| e.into_inner());
        if e.0 + bytes > Self::BUDGET || e.1.iter().any(|(k, _)| *k == key) {
            return;
        }
        e.0 += bytes;
        e.1.push((key, value));
    }

    /// Bytes kept.
    pub fn bytes(&self) -> usize {
        self.entries.lock().unwrap_or_else(|e| e.into_inner()).0
    }
}

/// Why `sppm` refuses a scene whose unbounded plane a directional light or an environment
/// lights: their photons start on a disk of the bounding sphere of the finite objects and never
/// reach the plane beyond it, so the plane's share of indirect light would be missing from the
/// image (without an error). `path` and `bdpt` render such scenes.
const SPPM_UNBOUNDED: &str = "sppm cannot render an unbounded plane lit by a directional light \
     or an environment (its photons start on a disk around the scene's finite objects and never \
     reach the plane beyond it): use path or bdpt (volpath if the scene has media), or a \
     rectangle for the plane";

/// Refuses `sppm` where it cannot render the scene (see [`SPPM_UNBOUNDED`]).
fn check_sppm_lighting(
    scene: &Scene,
    settings: &RenderSettings,
    environment: bool,
) -> Result<(), SceneError> {
    let directional = scene
        .lights
        .iter()
        .any(|l| matches!(l, Light::Directional { .. }));
    if settings.integrator == crate::IntegratorKind::Sppm
        && (environment || directional)
        && scene.aggregate.has_unbounded()
    {
        return Err(SceneError::Invalid(format!(
            "render setting integrator: {SPPM_UNBOUNDED}"
        )));
    }
    Ok(())
}

/// What of a scene decides whether `sppm` can render it under given settings, known from its
/// description before it is built ([`crate::scene::SceneDesc::sppm_facts`]): a farm's
/// coordinator keeps it with a scene and refuses a job its workers would refuse.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SppmFacts {
    /// An unbounded shape (a plane).
    pub unbounded: bool,
    /// A directional light.
    pub directional_light: bool,
    /// An environment of the scene's own.
    pub environment: bool,
    /// That environment is the default one a loader added to an unlit scene.
    pub default_environment: bool,
}

impl SppmFacts {
    /// Refuses `sppm` where a render with `settings` would be refused: the message, for the
    /// setting `integrator`.
    pub fn check(&self, settings: &RenderSettings) -> Result<(), String> {
        // The environment the job would have, as [`RenderJob::new`] chooses it.
        let environment = match &settings.environment {
            // The default light is dropped when the job turns it off.
            None => self.environment && (settings.default_light || !self.default_environment),
            Some(EnvironmentChoice::None) => false,
            Some(_) => true,
        };
        if settings.integrator == crate::IntegratorKind::Sppm
            && (environment || self.directional_light)
            && self.unbounded
        {
            return Err(SPPM_UNBOUNDED.to_string());
        }
        Ok(())
    }
}

impl RenderJob {
    /// The job rendering `scene` with `settings`: the camera the settings name (the scene's
    /// first, or one framing the scene if it has none) and the scene's environment, but for
    /// the default light a loader added when [`RenderSettings::default_light`] is off.
    pub fn new(scene: &Scene, settings: &RenderSettings) -> Result<RenderJob, SceneError> {
        settings
            .validate()
            .map_err(|e| SceneError::Invalid(format!("render setting {e}")))?;
        let names: Vec<&str> = scene.cameras.iter().map(|c| c.name.as_str()).collect();
        let camera = match pick_camera(&names, settings.camera.as_deref())
            .map_err(|e| SceneError::Invalid(format!("render setting {e}")))?
        {
            Some(i) => scene.cameras[i].clone(),
            None => default_camera(&scene.bounds),
        };
        let camera = Camera::new(
            camera.transform,
            camera.projection,
            settings.width,
            settings.height,
        );
        let environment = match &settings.environment {
            None if scene.default_environment && !settings.default_light => None,
            None => scene.environment.clone(),
            Some(EnvironmentChoice::None) => None,
            Some(EnvironmentChoice::Constant(c)) => {
                // Each of them finite and non-negative (the settings are valid): their product
                // must not be too bright either.
                let (c, strength) = (Vec3A::from(*c), settings.environment_strength);
                if f64::from(c.max_element()) * f64::from(strength) > f64::from(MAX_RADIANCE) {
                    return Err(invalid(format!(
                        "render setting environment: {},{},{} times environment_strength {} \
                         must be at most 1e30 in every channel (the largest radiance raytile \
                         takes)",
                        show_number(c.x),
                        show_number(c.y),
                        show_number(c.z),
                        show_number(strength)
                    )));
                }
                Some(Arc::new(Environment::constant(c * strength)))
            }
            Some(EnvironmentChoice::Map(path)) => {
                return Err(invalid(format!(
                    "environment {path}: a map is read from files (RenderJob::with_files, in \
                     the builder)"
                )))
            }
        };
        let eye = camera
            .generate_ray(
                Vec2::new(settings.width as f32, settings.height as f32) * 0.5,
                Vec2::splat(0.5),
            )
            .o;
        let starts = Arc::new(Starts::new(scene, eye));
        let job = RenderJob {
            starts,
            settings: settings.clone(),
            camera,
            filter: FilterSampler::new(settings.filter),
            environment: None,
            lights: LightSet::default(),
            cache: Arc::default(),
        };
        job.with_environment(scene, environment)
    }

    /// This job with `environment` in place of the one it had (`None`: no environment), and
    /// the light distribution that goes with it: how a job brings an environment of its own.
    /// Refused where the job's integrator cannot render the scene under it (sppm and an
    /// unbounded plane).
    pub fn with_environment(
        mut self,
        scene: &Scene,
        environment: Option<Arc<Environment>>,
    ) -> Result<Self, SceneError> {
        check_sppm_lighting(scene, &self.settings, environment.is_some())?;
        let power = environment.as_ref().map(|e| e.power(scene.radius));
        self.lights = LightSet::new(&scene.lights, scene.radius, power);
        self.environment = environment;
        self.cache = Arc::default();
        Ok(self)
    }

    /// The environment, if any.
    #[inline]
    pub fn environment(&self) -> Option<&Environment> {
        self.environment.as_deref()
    }

    /// Bytes of values the job keeps for its other tiles ([`JobCache`]).
    pub fn cache_bytes(&self) -> usize {
        self.cache.bytes()
    }

    /// The light distribution: the scene's lights by index, then the environment.
    #[inline]
    pub fn lights(&self) -> &LightSet {
        &self.lights
    }

    /// Samples light `index` of [`RenderJob::lights`] from the point `p` with `u`.
    #[inline]
    pub(crate) fn sample_light(
        &self,
        scene: &Scene,
        index: usize,
        p: Vec3A,
        u: Vec2,
    ) -> Option<LightSample> {
        match scene.lights.get(index) {
            Some(&Light::Area { light, prim, .. }) => {
                scene.area_lights[light as usize].sample(prim, p, u, &scene.textures)
            }
            Some(l) => l.sample_delta(p),
            None => {
                let (wi, li, pdf) = self.environment.as_ref()?.sample(u)?;
                Some(LightSample {
                    wi,
                    li,
                    pdf,
                    dist: f32::INFINITY,
                    delta: false,
                    p_light: p + wi,
                    n_light: Vec3A::ZERO,
                })
            }
        }
    }

    /// Solid-angle density with which light sampling (selection included) would have produced
    /// the point `it` on an emitter, seen from `from`.
    #[inline]
    pub(crate) fn area_light_pdf(&self, scene: &Scene, it: &Interaction, from: Vec3A) -> f32 {
        let o = &scene.objects[it.object as usize];
        if o.light_base == u32::MAX {
            return 0.0;
        }
        let li = o.light_base
            + if matches!(o.kind, ObjectKind::Mesh { .. }) {
                it.prim
            } else {
                0
            };
        let pmf = self.lights.pmf(li as usize);
        let Some(&Light::Area { light, prim, .. }) = scene.lights.get(li as usize) else {
            return 0.0;
        };
        pmf * scene.area_lights[light as usize].pdf(prim, it.p, it.ng, from)
    }
}

fn invalid(msg: impl Into<String>) -> SceneError {
    SceneError::Invalid(msg.into())
}

/// The camera a render with the `camera` setting `sel` uses, as an index into the scene's cameras
/// (their `names`, in order): the camera of that name, else the one of that index (a string of
/// digits is a name first); the first when `sel` is `None`; `None` for a scene without cameras
/// rendered without a choice (a camera framing the scene). A camera the scene does not have is
/// an error naming the `camera` setting and listing the cameras.
pub fn pick_camera(
    names: &[impl AsRef<str>],
    sel: Option<&str>,
) -> Result<Option<usize>, SettingsError> {
    let Some(sel) = sel else {
        return Ok((!names.is_empty()).then_some(0));
    };
    if let Some(i) = names.iter().position(|n| n.as_ref() == sel) {
        return Ok(Some(i));
    }
    if let Some(i) = sel.parse::<usize>().ok().filter(|&i| i < names.len()) {
        return Ok(Some(i));
    }
    let message = if names.is_empty() {
        format!(
            "the scene has no camera, so there is none named or numbered '{sel}' (leave it \
             out to render from a camera framing the scene)"
        )
    } else {
        const SHOWN: usize = 20;
        let mut list: Vec<String> = names
            .iter()
            .take(SHOWN)
            .enumerate()
            .map(|(i, n)| format!("{i}: '{}'", n.as_ref()))
            .collect();
        if names.len() > SHOWN {
            list.push(format!("and {} more", names.len() - SHOWN));
        }
        format!(
            "the scene has no camera named or numbered '{sel}' (its cameras: {})",
            list.join(", ")
        )
    };
    Err(SettingsError {
        field: "camera",
        message,
    })
}

/// A default camera framing `bounds` from +Z, for scenes without one.
fn default_camera(bounds: &Aabb) -> SceneCamera {
    let (center, radius) =
        if bounds.min.is_finite() && bounds.max.is_finite() && bounds.min.cmple(bounds.max).all() {
            (
                bounds.center(),
                (bounds.diagonal().length() * 0.5).max(1e-3),
            )
        } else {
            (Vec3A::ZERO, 1.0)
        };
    let yfov = 45f32.to_radians();
    let dist = radius / (yfov * 0.5).sin();
    SceneCamera {
        name: "default".into(),
        transform: Mat4::from_translation(Vec3::from(center + Vec3A::Z * dist)),
        projection: Projection::Perspective {
            yfov,
            aperture_radius: 0.0,
            focus_distance: dist,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ray;
    use crate::sampling::hash_u32;
    use crate::scene::desc::*;
    use glam::Mat4;

    fn rnd(i: u32) -> f32 {
        (hash_u32(i) >> 8) as f32 / (1u32 << 24) as f32
    }

    /// Emitters of both kinds: a two-triangle mesh lamp, a squashed emissive sphere, and a
    /// point light; a floor to stand on.
    fn lit_scene() -> Scene {
        let mut lamp = MaterialDesc::new(
            "lamp",
            BsdfDesc::Diffuse {
                albedo: Vec3::ZERO,
                texture: None,
            },
        );
        lamp.emission = Vec3::new(4.0, 3.0, 2.0);
        let mut ball = lamp.clone();
        ball.emission = Vec3::new(1.0, 1.0, 5.0);
        let desc = SceneDesc {
            materials: vec![lamp, ball],
            meshes: vec![MeshDesc {
                name: "lamp".into(),
                positions: vec![
                    Vec3::new(-1.0, 2.0, -1.0),
                    Vec3::new(1.0, 2.0, -1.0),
                    Vec3::new(1.0, 2.0, 1.0),
                    Vec3::new(-1.0, 2.0, 1.0),
                ],
                // Facing down (−Y), towards the points the test samples from.
                colors: Vec::new(),
                indices: vec![[0, 1, 2], [0, 2, 3]],
                ..Default::default()
            }],
            objects: vec![
                ObjectDesc {
                    name: "lamp".into(),
                    shape: ShapeDesc::Mesh { mesh: 0 },
                    material: 0,
                    transform: Mat4::IDENTITY,
                    media: None,
                },
                ObjectDesc {
                    name: "ball".into(),
                    shape: ShapeDesc::Sphere {
                        center: Vec3::ZERO,
                        radius: 0.3,
                    },
                    material: 1,
                    transform: Mat4::from_translation(Vec3::new(1.5, 0.5, 0.0))
                        * Mat4::from_scale(Vec3::new(1.0, 2.0, 1.0)),
                    media: None,
                },
            ],
            lights: vec![LightDesc::Point {
                position: Vec3::new(0.0, 3.0, 0.0),
                intensity: Vec3::ONE,
                range: f32::INFINITY,
            }],
            ..Default::default()
        };
        Scene::build(&desc).unwrap()
    }

    #[test]
    fn the_mis_density_of_a_hit_emitter_is_the_density_light_sampling_gave_it() {
        let scene = lit_scene();
        let job = RenderJob::new(&scene, &RenderSettings::default()).unwrap();
        assert_eq!(job.lights().len(), 4, "point, two triangles, the sphere");
        let from = Vec3A::new(0.2, -0.5, 0.3);
        let mut checked = 0;
        for i in 0..400 {
            let pick = Vec2::new(rnd(3 * i), rnd(3 * i + 1));
            let (index, pmf, u) = job.lights().choose_in(pick, rnd(3 * i + 2)).unwrap();
            let Some(s) = job.sample_light(&scene, index, from, u) else {
                continue;
            };
            if s.delta {
                assert!(matches!(scene.lights[index], Light::Point { .. }));
                continue;
            }
            // Trace towards the sampled point: the emitter hit there must give the same
            // density (selection included) to the path tracer's MIS.
            let ray = Ray::new(from, s.wi);
            let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
                panic!("light sample {i} points at nothing");
            };
            if (ray.at(hit.t) - s.p_light).length() > 1e-3 {
                continue; // the sphere's far side, behind its near side
            }
            let it = scene.interaction(&ray, &hit);
            let pdf = job.area_light_pdf(&scene, &it, from);
            assert!(
                (pdf - s.pdf * pmf).abs() <= 1e-3 * pdf,
                "sample {i} of light {index}: {pdf} vs {}",
                s.pdf * pmf
            );
            assert_eq!(scene.emitted(&it, -s.wi), s.li);
            checked += 1;
        }
        assert!(checked > 200, "{checked}");
    }

    #[test]
    fn the_environment_is_the_jobs_and_the_light_distribution_follows_it() {
        let scene = lit_scene();
        let settings = RenderSettings::default();
        let job = RenderJob::new(&scene, &settings).unwrap();
        assert!(job.environment().is_none());
        let env = Arc::new(Environment::constant(Vec3A::splat(0.5)));
        let job = job.with_environment(&scene, Some(env)).unwrap();
        assert_eq!(job.lights().len(), 5);
        assert_eq!(job.lights().environment(), Some(4));
        let s = job
            .sample_light(&scene, 4, Vec3A::ZERO, Vec2::new(0.3, 0.7))
            .unwrap();
        assert!(!s.delta && !s.dist.is_finite() && s.li == Vec3A::splat(0.5));
        let job = job.with_environment(&scene, None).unwrap();
        assert_eq!(job.lights().len(), 4);
        assert!(job
            .sample_light(&scene, 4, Vec3A::ZERO, Vec2::ZERO)
            .is_none());
    }
}
