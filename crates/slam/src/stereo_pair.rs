//! An unrectified stereo pair: the first camera's keypoints get depth by matching into the
//! second camera along epipolar curves on unit rays and triangulating, for any camera model
//! and any relative pose, with no rectification (no resampling of the images).
//!
//! The candidates are those of keyframe triangulation ([`search_for_triangulation_rays`]:
//! the right keypoint's ray within the level's angular error of the epipolar plane, each
//! right keypoint used once), the closest descriptor winning with no ratio test, as in the
//! rectified matcher (a ratio test only cost points, docs/benchmarks.md); a match is kept when the
//! triangulated point lies in front of both cameras, reprojects within the level's
//! chi-square bound in both and is seen under at least one pixel of parallax (as the
//! rectified matcher's least disparity).

use ferroslam_features::matcher::{TH_HIGH, TH_LOW};
use ferroslam_features::{search_for_triangulation_rays, Descriptor, Keypoint, MatchOptions};
use ferroslam_geometry::camera::CameraModel;
use ferroslam_geometry::triangulation::{essential_matrix, triangulate_rays};
use ferroslam_optim::robust::CHI2_MONO;
use nalgebra::{Isometry3, Vector2, Vector3};

use crate::error::SlamError;

/// The second camera of an unrectified pair and where it is.
#[derive(Clone, Debug)]
#[allow(non_snake_case)]
pub struct UnrectifiedPair {
    /// The right camera, raw (its own model and distortion).
    pub right: CameraModel,
    /// Pose of the right camera in the left (tracked) camera: `p_left = T_left_right p_right`,
    /// metres.
    pub T_left_right: Isometry3<f64>,
}

/// One camera's side of the matching: raw keypoints (pixels), descriptors.
pub type PairSide<'a> = (&'a [Keypoint], &'a [Descriptor]);

impl UnrectifiedPair {
    /// A pair after checking it: a right camera of the left one's size and a baseline.
    ///
    /// # Errors
    /// `InvalidConfig` naming the problem.
    #[allow(non_snake_case)]
    pub fn new(
        left: &CameraModel,
        right: CameraModel,
        T_left_right: Isometry3<f64>,
    ) -> Result<Self, SlamError> {
        if left.size() != right.size() {
            let ((lw, lh), (rw, rh)) = (left.size(), right.size());
            return Err(SlamError::InvalidConfig(format!(
                "the cameras of a stereo pair must have one image size, got {lw}x{lh} and \
                 {rw}x{rh}"
            )));
        }
        let baseline = T_left_right.translation.vector.norm();
        if !(baseline.is_finite() && baseline > 1e-6) {
            return Err(SlamError::InvalidConfig(format!(
                "the cameras of a stereo pair must be apart: T_left_right has a baseline of \
                 {baseline} m"
            )));
        }
        Ok(Self {
            right,
            T_left_right,
        })
    }

    /// Distance between the camera centres, metres.
    pub fn baseline_m(&self) -> f64 {
        self.T_left_right.translation.vector.norm()
    }

    /// Depth (metres along the left camera's z axis) of every left keypoint matched into the
    /// right image, 0 where none is (the RGB-D convention for "no measurement").
    /// `sigma2` holds the pyramid's level variances.
    pub fn depths(
        &self,
        left_camera: &CameraModel,
        (left_kps, left_desc): PairSide<'_>,
        (right_kps, right_desc): PairSide<'_>,
        sigma2: &[f64],
    ) -> Vec<f32> {
        let rays = |camera: &CameraModel, kps: &[Keypoint]| -> Vec<Vector3<f64>> {
            kps.iter()
                .map(|k| {
                    camera
                        .unproject_raw(&Vector2::new(f64::from(k.x), f64::from(k.y)))
                        .unwrap_or_else(|| Vector3::repeat(f64::NAN))
                })
                .collect()
        };
        let (rays_l, rays_r) = (rays(left_camera, left_kps), rays(&self.right, right_kps));
        let T_right_left = self.T_left_right.inverse();
        let essential = essential_matrix(&Isometry3::identity(), &T_right_left);
        let opts = MatchOptions {
            max_distance: (TH_HIGH + TH_LOW) / 2,
            nn_ratio: None,
            check_orientation: false,
        };
        let rad_per_px = (1.0 / left_camera.fx(), 1.0 / self.right.fx());
        let pairs = search_for_triangulation_rays(
            (left_kps, left_desc, &vec![true; left_kps.len()], &rays_l),
            (right_kps, right_desc, &vec![true; right_kps.len()], &rays_r),
            &essential,
            sigma2,
            rad_per_px.1,
            None,
            &opts,
        );
        let mut depth = vec![0.0f32; left_kps.len()];
        for (i, j) in pairs {
            let level = |k: &Keypoint| sigma2.get(usize::from(k.octave)).copied();
            let (Some(s_l), Some(s_r)) = (level(&left_kps[i]), level(&right_kps[j])) else {
                continue;
            };
            let Some(p_l) = triangulate_rays(
                &Isometry3::identity(),
                &T_right_left,
                &rays_l[i],
                &rays_r[j],
            ) else {
                continue;
            };
            let p_r = T_right_left * nalgebra::Point3::from(p_l);
            let fits = |ray: &Vector3<f64>, p: &Vector3<f64>, s2: f64, rad: f64| {
                let sin2 = ray.cross(&p.normalize()).norm_squared();
                sin2 < CHI2_MONO * s2 * rad * rad
            };
            let parallax = p_l
                .normalize()
                .dot(&p_r.coords.normalize())
                .clamp(-1.0, 1.0)
                .acos();
            if p_l.z > 0.0
                && fits(&rays_l[i], &p_l, s_l, rad_per_px.0)
                && fits(&rays_r[j], &p_r.coords, s_r, rad_per_px.1)
                && parallax >= rad_per_px.0
            {
                depth[i] = p_l.z as f32;
            }
        }
        depth
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ferroslam_features::ScalePyramid;
    use ferroslam_geometry::camera::{KannalaBrandtCamera, PinholeCamera, RadTan};
    use nalgebra::{Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn keypoint(uv: Vector2<f64>) -> Keypoint {
        Keypoint {
            x: uv.x as f32,
            y: uv.y as f32,
            octave: 0,
            angle_deg: 0.0,
            response: 1.0,
        }
    }

    /// Random points seen by a distorted pinhole and a fisheye 11 cm to its right, turned by
    /// a few degrees, with unique random descriptors: every point's depth comes back.
    #[test]
    fn depths_of_a_distorted_pinhole_and_a_fisheye_are_the_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let left = CameraModel::from(
            PinholeCamera::new(
                458.7,
                457.3,
                367.2,
                248.4,
                RadTan {
                    k1: -0.28,
                    k2: 0.07,
                    p1: 0.0002,
                    p2: 0.00002,
                    k3: 0.0,
                },
                752,
                480,
            )
            .unwrap(),
        );
        let right = CameraModel::from(
            KannalaBrandtCamera::new(
                300.0,
                300.0,
                376.0,
                240.0,
                [0.01, -0.005, 0.001, 0.0],
                752,
                480,
            )
            .unwrap(),
        );
        let T_left_right = Isometry3::from_parts(
            Translation3::new(0.11, 0.001, -0.002),
            UnitQuaternion::from_euler_angles(0.01, -0.03, 0.02),
        );
        let pair = UnrectifiedPair::new(&left, right, T_left_right).unwrap();
        let T_right_left = T_left_right.inverse();
        let (mut kl, mut kr, mut dl, mut dr, mut truth) = (vec![], vec![], vec![], vec![], vec![]);
        while truth.len() < 200 {
            let p = Vector3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(1.0..8.0),
            );
            let p_r = (T_right_left * nalgebra::Point3::from(p)).coords;
            let (Some(ul), Some(ur)) = (left.project_raw(&p), right.project_raw(&p_r)) else {
                continue;
            };
            let inside =
                |uv: Vector2<f64>| (0.0..752.0).contains(&uv.x) && (0.0..480.0).contains(&uv.y);
            if !(inside(ul) && inside(ur)) {
                continue;
            }
            let d: Descriptor = std::array::from_fn(|_| rng.random());
            kl.push(keypoint(ul));
            kr.push(keypoint(ur));
            dl.push(d);
            dr.push(d);
            truth.push(p.z);
        }
        // The right list in another order: matching must not rely on indices.
        kr.reverse();
        dr.reverse();
        let sigma2 = ScalePyramid::new(1.2, 8).unwrap().sigma2;
        let depths = pair.depths(&left, (&kl, &dl), (&kr, &dr), &sigma2);
        let matched = depths.iter().filter(|&&d| d > 0.0).count();
        assert!(matched >= 195, "{matched} of 200 matched");
        for (d, z) in depths.iter().zip(&truth).filter(|(d, _)| **d > 0.0) {
            // Keypoints are f32 pixels: depth to 1e-4 relative.
            assert!((f64::from(*d) - z).abs() < 1e-4 * z, "{d} vs {z}");
        }
    }

    #[test]
    fn a_pair_needs_one_size_and_a_baseline() {
        let camera = |w| {
            CameraModel::from(
                PinholeCamera::new(400.0, 400.0, 320.0, 240.0, RadTan::default(), w, 480).unwrap(),
            )
        };
        let at = |x| Isometry3::translation(x, 0.0, 0.0);
        let err = UnrectifiedPair::new(&camera(640), camera(752), at(0.1)).unwrap_err();
        assert!(err.to_string().contains("640x480 and 752x480"), "{err}");
        let err = UnrectifiedPair::new(&camera(640), camera(640), at(0.0)).unwrap_err();
        assert!(err.to_string().contains("baseline of 0 m"), "{err}");
    }
}
