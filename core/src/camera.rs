//! Cameras: pinhole, thin lens (depth of field) and orthographic.
//!
//! Camera space looks down −Z with +Y up (as glTF). Pixel (0, 0) is the top-left corner.

use crate::geometry::Ray;
use crate::sampling::warp::concentric_disk;
use glam::{Affine3A, Mat4, Vec2, Vec3A};

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

/// A camera set up for one image size.
#[derive(Clone, Debug)]
pub struct Camera {
    to_world: Affine3A,
    projection: Projection,
    /// Half-extent of the image plane at distance 1 (perspective) or in metres (orthographic).
    half: Vec2,
    width: f32,
    height: f32,
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
                    (o, (focus - o).normalize())
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

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(projection: Projection) -> Camera {
        let transform = Mat4::from_translation(glam::Vec3::new(0.0, 0.0, 5.0));
        Camera::new(transform, projection, 200, 100)
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
    fn orthographic_rays_are_parallel() {
        let c = cam(Projection::Orthographic { half_height: 2.0 });
        let a = c.generate_ray(Vec2::new(0.0, 0.0), Vec2::ZERO);
        let b = c.generate_ray(Vec2::new(200.0, 100.0), Vec2::ZERO);
        assert_eq!(a.d, b.d);
        assert!((a.o - Vec3A::new(-4.0, 2.0, 5.0)).length() < 1e-5);
    }
}
