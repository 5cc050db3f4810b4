//! Cameras: pinhole, thin lens (depth of field) and orthographic.
//!
//! Camera space looks down −Z with +Y up (as glTF). Pixel (0, 0) is the top-left corner.

use crate::geometry::Ray;
use crate::sampling::warp::concentric_disk;
use glam::{Affine3A, Mat4, Vec2, Vec3, Vec3A};

/// The narrowest vertical field of view a perspective camera may have, degrees.
pub const MIN_FOV_DEGREES: f32 = 1e-3;

/// The smallest lens radius of a thin-lens camera (0, a pinhole, is allowed).
pub const MIN_APERTURE: f32 = 1e-9;

/// How the camera projects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// A pinhole or thin-lens perspective camera.
    Perspective {
        /// Vertical field of view, radians.
        yfov: f32,
        /// Lens radius in metres (0 = pinhole).
        aperture_radius: f32,
        /// Distance to the plane in focus, metres.
        focus_distance: f32,
    },
    /// A parallel projection.
    Orthographic {
        /// Half the height of the view, metres (glTF `ymag`).
        half_height: f32,
    },
}

impl Projection {
    /// Checks the parameters: a field of view of at least [`MIN_FOV_DEGREES`] and below 180°,
    /// a finite aperture of 0 (a pinhole) or at least [`MIN_APERTURE`], a finite non-negative
    /// focus distance, positive when the aperture is, and a positive finite orthographic half
    /// height. The error is the field's name (as the
    /// JSON format spells it) and a message that names it too.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        match *self {
            Projection::Perspective {
                yfov,
                aperture_radius,
                focus_distance,
            } => {
                if !(yfov > 0.0 && yfov < std::f32::consts::PI) {
                    return Err((
                        "fov",
                        format!(
                            "fov must be between 0 and 180 degrees, got {}",
                            yfov.to_degrees()
                        ),
                    ));
                }
                // A narrower view's film area (or a smaller lens's area) is so small that the
                // importance `bdpt` joins light paths with, its reciprocal, overflows.
                if yfov < MIN_FOV_DEGREES.to_radians() {
                    return Err((
                        "fov",
                        format!(
                            "fov must be at least {MIN_FOV_DEGREES} degrees, got {}",
                            yfov.to_degrees()
                        ),
                    ));
                }
                if aperture_radius > 0.0 && aperture_radius < MIN_APERTURE {
                    return Err((
                        "aperture",
                        format!(
                            "aperture must be 0 (a pinhole) or at least {MIN_APERTURE:e}, got \
                             {aperture_radius:e}"
                        ),
                    ));
                }
                if !(aperture_radius.is_finite() && aperture_radius >= 0.0) {
                    return Err((
                        "aperture",
                        format!(
                            "aperture must be finite and non-negative (0 is a pinhole), got \
                             {aperture_radius}"
                        ),
                    ));
                }
                let focus_ok = focus_distance.is_finite()
                    && if aperture_radius > 0.0 {
                        focus_distance > 0.0
                    } else {
                        focus_distance >= 0.0
                    };
                if !focus_ok {
                    return Err((
                        "focus_distance",
                        format!(
                            "focus_distance must be finite and positive (non-negative for a \
                             pinhole), got {focus_distance}"
                        ),
                    ));
                }
            }
            Projection::Orthographic { half_height } => {
                if !(half_height.is_finite() && half_height > 0.0) {
                    return Err((
                        "half_height",
                        format!("half_height must be positive and finite, got {half_height}"),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// A camera set up for one image size.
#[derive(Clone, Debug)]
pub struct Camera {
    to_world: Affine3A,
    from_world: Affine3A,
    projection: Projection,
    /// Half-extent of the image plane at distance 1 (perspective) or in metres (orthographic).
    half: Vec2,
    width: f32,
    height: f32,
}

/// A camera frame without shear. A parent's non-uniform scale over a rotated camera node
/// (in a glTF file) shears the node's frame, and [`Camera::new`], which keeps the rotation
/// `to_scale_rotation_translation` finds (it assumes no shear), would look elsewhere (29° off
/// in one file). A camera looks along its frame's −Z as transformed (glTF's rule, and what a
/// rasterizer's view matrix does): where the rotation found differs from that by more than
/// about a fifth of a degree, this gives the frame that looks along it, its up as near the
/// frame's +Y as that allows, at the same place; other frames are returned as they are.
pub fn unsheared(transform: Mat4) -> Mat4 {
    let (_, rot, trans) = transform.to_scale_rotation_translation();
    let fwd = (-transform.z_axis.truncate()).normalize_or_zero();
    let right = fwd.cross(transform.y_axis.truncate()).normalize_or_zero();
    if fwd == Vec3::ZERO
        || right == Vec3::ZERO
        || (rot.normalize() * -Vec3::Z).dot(fwd) > 1.0 - 1e-5
    {
        return transform;
    }
    let up = right.cross(fwd);
    Mat4::from_cols(
        right.extend(0.0),
        up.extend(0.0),
        (-fwd).extend(0.0),
        trans.extend(1.0),
    )
}

impl Camera {
    /// A camera placed by `transform` (camera to world, looking down −Z) with `projection`,
    /// rendering a `width × height` image. The image's aspect ratio wins over any the scene
    /// file gives (the vertical field of view is kept).
    pub fn new(transform: Mat4, projection: Projection, width: u32, height: u32) -> Self {
        let aspect = width as f32 / height as f32;
        // Keep only rotation and translation: scale on a camera node would distort rays.
        let (_, rot, trans) = transform.to_scale_rotation_translation();
        let to_world = Affine3A::from_rotation_translation(rot.normalize(), trans);
        let half_h = match projection {
            Projection::Perspective { yfov, .. } => (yfov * 0.5).tan(),
            Projection::Orthographic { half_height } => half_height,
        };
        Self {
            to_world,
            from_world: to_world.inverse(),
            projection,
            half: Vec2::new(half_h * aspect, half_h),
            width: width as f32,
            height: height as f32,
        }
    }

    /// The primary ray through film position `film` (in pixels, continuous) with lens sample
    /// `lens` ∈ [0,1)² (ignored by pinhole and orthographic cameras). Directions are unit.
    #[inline]
    pub fn generate_ray(&self, film: Vec2, lens: Vec2) -> Ray {
        let ndc_x = (2.0 * film.x / self.width - 1.0) * self.half.x;
        let ndc_y = (1.0 - 2.0 * film.y / self.height) * self.half.y;
        let (o, d) = match self.projection {
            Projection::Perspective {
                aperture_radius,
                focus_distance,
                ..
            } => {
                let d = Vec3A::new(ndc_x, ndc_y, -1.0);
                if aperture_radius > 0.0 && focus_distance > 0.0 {
                    let focus = d * focus_distance;
                    let l = concentric_disk(lens) * aperture_radius;
                    let o = Vec3A::new(l.x, l.y, 0.0);
                    // A focus so far that the length overflows (about 1e19) is aimed at from
                    // the unit distance (`normalize` divides: keep it where it works, for the
                    // bits every image has had).
                    let to = focus - o;
                    if to.length_squared().is_finite() {
                        (o, to.normalize())
                    } else {
                        (o, (d - o / focus_distance).normalize())
                    }
                } else {
                    (Vec3A::ZERO, d.normalize())
                }
            }
            Projection::Orthographic { .. } => (Vec3A::new(ndc_x, ndc_y, 0.0), -Vec3A::Z),
        };
        Ray::new(
            self.to_world.transform_point3a(o),
            self.to_world.transform_vector3a(d).normalize(),
        )
    }
}

/// A point on the camera's lens sampled towards a point of the scene (pbrt-v4's
/// `Camera::SampleWi`), for light paths joined to the camera.
#[derive(Clone, Copy, Debug)]
pub struct CameraSample {
    /// Where on the film (in pixels) the light arrives.
    pub raster: Vec2,
    /// Importance emitted towards the point, We.
    pub we: f32,
    /// Solid-angle density of the direction towards the lens, seen from the point.
    pub pdf: f32,
    /// The point on the lens.
    pub p: Vec3A,
}

impl Camera {
    /// Whether the camera is a perspective one (pinhole or thin lens): only those emit
    /// importance that light paths can reach; an orthographic camera's is a delta.
    pub fn is_perspective(&self) -> bool {
        matches!(self.projection, Projection::Perspective { .. })
    }

    /// Lens radius and focus distance (zero radius: a pinhole).
    #[inline]
    fn lens(&self) -> (f32, f32) {
        match self.projection {
            Projection::Perspective {
                aperture_radius,
                focus_distance,
                ..
            } if aperture_radius > 0.0 && focus_distance > 0.0 => (aperture_radius, focus_distance),
            _ => (0.0, 1.0),
        }
    }

    /// Lens area (1 for a pinhole, as pbrt-v4) and film area at distance 1.
    #[inline]
    fn areas(&self) -> (f32, f32) {
        let (r, _) = self.lens();
        let lens_area = if r > 0.0 {
            std::f32::consts::PI * r * r
        } else {
            1.0
        };
        (lens_area, 4.0 * self.half.x * self.half.y)
    }

    /// Importance We of the ray leaving the lens point `o` in unit direction `d` (towards the
    /// scene) and the film position it belongs to, or `None` outside the image (pbrt-v4's
    /// `PerspectiveCamera::We`). Perspective cameras only.
    #[inline]
    pub fn we(&self, o: Vec3A, d: Vec3A) -> Option<(f32, Vec2)> {
        if !self.is_perspective() {
            return None;
        }
        let dc = self.from_world.transform_vector3a(d);
        let cos = -dc.z;
        if !(cos > 0.0) {
            return None;
        }
        let (r, focus) = self.lens();
        let pd = if r > 0.0 {
            let oc = self.from_world.transform_point3a(o);
            (oc + dc * (focus / cos)) / focus
        } else {
            dc / cos
        };
        let x = (pd.x / self.half.x + 1.0) * 0.5 * self.width;
        let y = (1.0 - pd.y / self.half.y) * 0.5 * self.height;
        if !(x >= 0.0 && x < self.width && y >= 0.0 && y < self.height) {
            return None;
        }
        let (lens_area, film_area) = self.areas();
        let cos2 = cos * cos;
        Some((1.0 / (film_area * lens_area * cos2 * cos2), Vec2::new(x, y)))
    }

    /// Densities (per lens area, per solid angle) with which [`Camera::generate_ray`] gives a
    /// ray from the lens along the unit direction `d` (pbrt-v4's `PDF_We`).
    #[inline]
    pub fn pdf_we(&self, o: Vec3A, d: Vec3A) -> (f32, f32) {
        if self.we(o, d).is_none() {
            return (0.0, 0.0);
        }
        let cos = -self.from_world.transform_vector3a(d).z;
        let (lens_area, film_area) = self.areas();
        (1.0 / lens_area, 1.0 / (film_area * cos * cos * cos))
    }

    /// Samples a point on the lens as seen from the scene point `p` (pbrt-v4's `SampleWi`).
    #[inline]
    pub fn sample_wi(&self, p: Vec3A, u: Vec2) -> Option<CameraSample> {
        let (r, _) = self.lens();
        let lc = if r > 0.0 {
            let l = concentric_disk(u) * r;
            Vec3A::new(l.x, l.y, 0.0)
        } else {
            Vec3A::ZERO
        };
        let pl = self.to_world.transform_point3a(lc);
        let to = pl - p;
        let d2 = to.length_squared();
        if !(d2 > 0.0) {
            return None;
        }
        let wi = to / d2.sqrt();
        let (we, raster) = self.we(pl, -wi)?;
        let forward = self.to_world.transform_vector3a(-Vec3A::Z).normalize();
        let cos = forward.dot(wi).abs();
        let (lens_area, _) = self.areas();
        let pdf = d2 / (cos * lens_area);
        if !(pdf > 0.0) || !pdf.is_finite() {
            return None;
        }
        Some(CameraSample {
            raster,
            we,
            pdf,
            p: pl,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(projection: Projection) -> Camera {
        let transform = Mat4::from_translation(glam::Vec3::new(0.0, 0.0, 5.0));
        Camera::new(transform, projection, 200, 100)
    }

    #[test]
    fn a_camera_under_a_non_uniform_scale_looks_along_its_transformed_axis() {
        // A parent scaled (1, 3, 1) over a camera node turned 30° about x: a sheared frame.
        let m =
            Mat4::from_scale(Vec3::new(1.0, 3.0, 1.0)) * Mat4::from_rotation_x(30f32.to_radians());
        let c = Camera::new(
            unsheared(m),
            Projection::Perspective {
                yfov: 1.0,
                aperture_radius: 0.0,
                focus_distance: 1.0,
            },
            200,
            100,
        );
        let centre = c.generate_ray(Vec2::new(100.0, 50.0), Vec2::ZERO);
        let want = Vec3A::from((-m.z_axis.truncate()).normalize());
        assert!((centre.d - want).length() < 1e-5, "{} vs {want}", centre.d);
        // Up stays up: the top of the image is above the centre.
        let top = c.generate_ray(Vec2::new(100.0, 0.0), Vec2::ZERO);
        assert!(top.d.y > centre.d.y);
        // A frame without shear (rotation, uniform or mirrored scale, translation) is kept.
        for scale in [Vec3::splat(2.0), Vec3::new(-1.0, 2.0, 0.5)] {
            let m = Mat4::from_scale_rotation_translation(
                scale,
                glam::Quat::from_euler(glam::EulerRot::YXZ, 0.7, -0.3, 0.2),
                Vec3::new(1.0, 2.0, 3.0),
            );
            assert_eq!(unsheared(m), m);
        }
    }

    #[test]
    fn centre_ray_looks_down_minus_z() {
        let c = cam(Projection::Perspective {
            yfov: 1.0,
            aperture_radius: 0.0,
            focus_distance: 1.0,
        });
        let r = c.generate_ray(Vec2::new(100.0, 50.0), Vec2::ZERO);
        assert!((r.d - (-Vec3A::Z)).length() < 1e-6 && (r.o.z - 5.0).abs() < 1e-6);
        // The top edge of the image is yfov/2 above the axis; the aspect ratio widens x.
        let top = c.generate_ray(Vec2::new(100.0, 0.0), Vec2::ZERO);
        assert!((top.d.y.atan2(-top.d.z) - 0.5).abs() < 1e-5);
        let right = c.generate_ray(Vec2::new(200.0, 50.0), Vec2::ZERO);
        assert!((right.d.x / -right.d.z - 2.0 * 0.5f32.tan()).abs() < 1e-5);
    }

    #[test]
    fn thin_lens_rays_meet_on_the_focus_plane() {
        let c = cam(Projection::Perspective {
            yfov: 1.0,
            aperture_radius: 0.2,
            focus_distance: 3.0,
        });
        let film = Vec2::new(130.0, 20.0);
        let pin = c.generate_ray(film, Vec2::splat(0.5));
        let target = pin.at(3.0 / -pin.d.z);
        for u in [Vec2::new(0.1, 0.9), Vec2::new(0.8, 0.3)] {
            let r = c.generate_ray(film, u);
            assert!(r.o != pin.o);
            let p = r.at((r.o.z - target.z) / -r.d.z);
            assert!((p - target).length() < 1e-4, "{p} vs {target}");
        }
    }

    #[test]
    fn a_focus_too_far_to_square_still_aims_every_ray() {
        let lens = |focus_distance: f32| {
            cam(Projection::Perspective {
                yfov: 1.0,
                aperture_radius: 0.01,
                focus_distance,
            })
        };
        let film = Vec2::new(130.0, 20.0);
        for u in [Vec2::new(0.1, 0.9), Vec2::new(0.8, 0.3)] {
            let far = lens(1e20).generate_ray(film, u);
            assert!(
                far.d.is_finite() && (far.d.length() - 1.0).abs() < 1e-6,
                "{}",
                far.d
            );
            // Aimed as a focus of 1e18 aims it, to within rounding.
            let near = lens(1e18).generate_ray(film, u);
            assert!((far.d - near.d).length() < 1e-6, "{} vs {}", far.d, near.d);
        }
    }

    #[test]
    fn orthographic_rays_are_parallel() {
        let c = cam(Projection::Orthographic { half_height: 2.0 });
        let a = c.generate_ray(Vec2::new(0.0, 0.0), Vec2::ZERO);
        let b = c.generate_ray(Vec2::new(200.0, 100.0), Vec2::ZERO);
        assert_eq!(a.d, b.d);
        assert!((a.o - Vec3A::new(-4.0, 2.0, 5.0)).length() < 1e-5);
    }
}
