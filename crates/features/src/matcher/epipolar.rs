//! Epipolar-constrained matching of unmatched features for triangulation.

use super::{best_two::BestTwo, finalize, pencil::PencilIndex, MatchOptions};
use crate::{hamming, Descriptor, Keypoint};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Chi-square threshold (1 DoF, 95%) on the squared point-to-epipolar-line distance,
/// in units of the keypoint's level variance (ORB-SLAM `CheckDistEpipolarLine`).
const CHI2_1DOF_95: f64 = 3.84;

/// Matches free features of view 1 to free features of view 2 under the epipolar
/// constraint — ORB-SLAM `SearchForTriangulation`, but comparing every feature near the
/// epipolar line (found through an index of the pencil of epipolar lines) rather than only
/// those under the same vocabulary node, which drops the pairs whose descriptors fall under
/// different nodes (fr1/rpy monocular inline, 7 feature budgets: mean ATE 2.6 -> 3.4 cm).
///
/// `f21` maps view-1 pixels to view-2 epipolar lines: `x2^T F21 x1 = 0` with homogeneous
/// undistorted pixels. A candidate `(i1, i2)` (both `free`) is kept when
/// - its Hamming distance is `<= opts.max_distance` (ORB-SLAM: [`super::TH_LOW`]);
/// - if `epipole2 = Some((ex, ey))` (the projection of camera 1's centre into view 2, px):
///   `|kp2 - e|^2 >= 100 * scale(kp2.octave)` with `scale = sqrt(sigma2)` — ORB-SLAM's
///   rule (it uses the scale factor, not its square), rejecting points too close to the
///   epipole to triangulate. ORB-SLAM skips this test when either feature has stereo
///   depth; pass `None` then;
/// - the squared distance of `kp2` to the line `F21 x1` is `< 3.84 * sigma2[kp2.octave]`.
///
/// Per `i1` the closest valid candidate wins; with `opts.nn_ratio = Some(r)` it must also
/// satisfy `best < r * second` (ORB-SLAM applies no ratio here). Each `i2` is used at most
/// once (smallest distance, ties: lowest `i1`). With `opts.check_orientation`, pairs whose
/// `kp1.angle_deg - kp2.angle_deg` falls outside the 3 dominant rotation bins are dropped.
///
/// Returns pairs `(i1, i2)` sorted by `i1`. Features with an octave beyond `sigma2`, a
/// missing `free` flag, or beyond the shorter of their keypoint/descriptor slices are
/// skipped. Parallel over view-1 features; deterministic.
#[allow(clippy::too_many_arguments)] // mirrors ORB-SLAM's inputs; grouping would add a type only used here
pub fn search_for_triangulation(
    kps1: &[Keypoint],
    desc1: &[Descriptor],
    free1: &[bool],
    kps2: &[Keypoint],
    desc2: &[Descriptor],
    free2: &[bool],
    f21: &Matrix3<f64>,
    sigma2: &[f64],
    epipole2: Option<(f64, f64)>,
    opts: &MatchOptions,
) -> Vec<(usize, usize)> {
    let n2 = kps2.len().min(desc2.len());
    // View-2 candidates that pass the per-feature tests, indexed so that each epipolar line
    // visits only those near it.
    let mut candidates2 = PencilIndex::default();
    for (i2, s2) in free_candidates(&kps2[..n2], free2, sigma2, epipole2) {
        let kp2 = &kps2[i2];
        let (x, y) = (f64::from(kp2.x), f64::from(kp2.y));
        candidates2.push(i2, x, y, CHI2_1DOF_95 * s2);
    }
    candidates2.build(f21);

    best_near(
        (kps1, desc1, free1),
        (kps2, desc2),
        opts,
        |i1, near, out| {
            let kp1 = &kps1[i1];
            let line = f21 * Vector3::new(f64::from(kp1.x), f64::from(kp1.y), 1.0);
            let norm2 = line.x * line.x + line.y * line.y;
            if !(norm2 > 0.0 && norm2.is_finite()) {
                return;
            }
            candidates2.near_line(&line, norm2, near);
            out.extend(near.iter().map(|&k| candidates2.index[k]));
        },
    )
}

/// One keyframe's side of [`search_for_triangulation_rays`]: keypoints, descriptors, which
/// are free (no map point yet) and unit rays, one per keypoint.
pub type RayView<'a> = (
    &'a [Keypoint],
    &'a [Descriptor],
    &'a [bool],
    &'a [Vector3<f64>],
);

/// [`search_for_triangulation`] on unit rays, for cameras without an image plane (a fisheye
/// whose field of view may exceed 180 degrees).
///
/// `rays1[i]` / `rays2[i]` are the unit rays of the keypoints (camera frames; a non-finite
/// ray is never matched) and `e21 = [t21]x R21` the essential matrix with
/// `p_c2 = R21 p_c1 + t21`. The epipolar test is angular: `kp2`'s ray must lie within the
/// angle `asin(sqrt(3.84 * sigma2[kp2.octave]) * rad_per_px)` of the epipolar plane
/// `E21 r1` (ORB-SLAM's pixel test, with `rad_per_px` about `1 / fx`). The epipole test
/// (`epipole2`, pixels of the keypoints) and the matching rules are those of
/// [`search_for_triangulation`].
pub fn search_for_triangulation_rays(
    (kps1, desc1, free1, rays1): RayView<'_>,
    (kps2, desc2, free2, rays2): RayView<'_>,
    e21: &Matrix3<f64>,
    sigma2: &[f64],
    rad_per_px: f64,
    epipole2: Option<(f64, f64)>,
    opts: &MatchOptions,
) -> Vec<(usize, usize)> {
    let n2 = kps2.len().min(desc2.len()).min(rays2.len());
    // (i2, ray, squared sine bound) of the view-2 features passing the per-feature tests.
    let candidates2: Vec<_> = free_candidates(&kps2[..n2], free2, sigma2, epipole2)
        .filter(|&(i2, _)| rays2[i2].iter().all(|v| v.is_finite()))
        .map(|(i2, s2)| (i2, rays2[i2], CHI2_1DOF_95 * s2 * rad_per_px * rad_per_px))
        .collect();
    let n1 = kps1.len().min(rays1.len());
    best_near(
        (&kps1[..n1], desc1, free1),
        (kps2, desc2),
        opts,
        |i1, _, out| {
            let normal = e21 * rays1[i1];
            let norm2 = normal.norm_squared();
            if !(norm2 > 0.0 && norm2.is_finite()) {
                return;
            }
            out.extend(
                candidates2
                    .iter()
                    .filter(|(_, ray, bound)| {
                        let d = ray.dot(&normal);
                        d * d < bound * norm2
                    })
                    .map(|(i2, _, _)| *i2),
            );
        },
    )
}

/// The free view-2 features, with their level variance, that have one in `sigma2` and lie
/// far enough from the epipole (see [`search_for_triangulation`]).
fn free_candidates<'a>(
    kps2: &'a [Keypoint],
    free2: &'a [bool],
    sigma2: &'a [f64],
    epipole2: Option<(f64, f64)>,
) -> impl Iterator<Item = (usize, f64)> + 'a {
    kps2.iter().enumerate().filter_map(move |(i2, kp2)| {
        if !free2.get(i2).copied().unwrap_or(false) {
            return None;
        }
        let &s2 = sigma2.get(usize::from(kp2.octave))?;
        let (x, y) = (f64::from(kp2.x), f64::from(kp2.y));
        let far_from_epipole = epipole2.is_none_or(|(ex, ey)| {
            let (dx, dy) = (ex - x, ey - y);
            dx * dx + dy * dy >= 100.0 * s2.sqrt()
        });
        far_from_epipole.then_some((i2, s2))
    })
}

/// Per free view-1 feature, the best of the view-2 candidates `near(i1, scratch, out)` puts
/// in `out` (see [`search_for_triangulation`] for the rules), one-to-one and sorted by `i1`.
fn best_near<F>(
    (kps1, desc1, free1): (&[Keypoint], &[Descriptor], &[bool]),
    (kps2, desc2): (&[Keypoint], &[Descriptor]),
    opts: &MatchOptions,
    near: F,
) -> Vec<(usize, usize)>
where
    F: Fn(usize, &mut Vec<usize>, &mut Vec<usize>) + Sync,
{
    let n1 = kps1.len().min(desc1.len());
    let n2 = kps2.len().min(desc2.len());
    let mut matches: Vec<_> = (0..n1)
        .into_par_iter()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(scratch, candidates), i1| {
                if !free1.get(i1).copied().unwrap_or(false) {
                    return None;
                }
                candidates.clear();
                near(i1, scratch, candidates);
                let mut best = BestTwo::default();
                for &i2 in candidates.iter() {
                    let d = hamming(&desc1[i1], &desc2[i2]);
                    if d <= opts.max_distance {
                        best.push_unordered(d, i2, kps2[i2].octave);
                    }
                }
                best.accept(opts.max_distance, opts.nn_ratio)
            },
        )
        .collect();
    finalize(&mut matches, n2, opts.check_orientation, |i1, i2| {
        Some(kps1[i1].angle_deg - kps2[i2].angle_deg)
    });
    matches
        .into_iter()
        .enumerate()
        .filter_map(|(i1, m)| m.map(|(i2, _)| (i1, i2)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matcher::test_support::*;
    use crate::ScalePyramid;
    use nalgebra::{Rotation3, Vector2};
    use rand::Rng;

    /// Synthetic two-view setup: pinhole K, p_c2 = R21 p_c1 + t21.
    struct TwoView {
        k: Matrix3<f64>,
        r21: Rotation3<f64>,
        t21: Vector3<f64>,
    }

    impl TwoView {
        fn new() -> Self {
            Self {
                k: Matrix3::new(500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0),
                r21: Rotation3::from_euler_angles(0.02, -0.1, 0.03),
                t21: Vector3::new(-0.3, 0.02, 0.05),
            }
        }

        /// F21 = K^-T [t21]x R21 K^-1.
        fn f21(&self) -> Matrix3<f64> {
            let k_inv = self.k.try_inverse().unwrap_or_else(Matrix3::identity);
            k_inv.transpose() * self.t21.cross_matrix() * self.r21.matrix() * k_inv
        }

        fn project(&self, p_c: &Vector3<f64>) -> Vector2<f64> {
            let uvw = self.k * p_c;
            Vector2::new(uvw.x / uvw.z, uvw.y / uvw.z)
        }

        /// Camera 1's centre projected into view 2.
        fn epipole2(&self) -> (f64, f64) {
            let e = self.project(&self.t21);
            (e.x, e.y)
        }
    }

    fn keypoint(uv: Vector2<f64>, octave: u8) -> Keypoint {
        Keypoint {
            x: uv.x as f32,
            y: uv.y as f32,
            octave,
            angle_deg: 45.0,
            response: 1.0,
        }
    }

    fn line_distance2(f21: &Matrix3<f64>, kp1: &Keypoint, kp2: &Keypoint) -> f64 {
        let l = f21 * Vector3::new(f64::from(kp1.x), f64::from(kp1.y), 1.0);
        let r = l.x * f64::from(kp2.x) + l.y * f64::from(kp2.y) + l.z;
        r * r / (l.x * l.x + l.y * l.y)
    }

    /// Keypoints, descriptors and unit rays of both views, the true pairs and the decoys
    /// (closer descriptors 25 px off the epipolar line) of a random scene.
    struct Scene {
        kps1: Vec<Keypoint>,
        desc1: Vec<Descriptor>,
        rays1: Vec<Vector3<f64>>,
        kps2: Vec<Keypoint>,
        desc2: Vec<Descriptor>,
        rays2: Vec<Vector3<f64>>,
        truth: Vec<(usize, usize)>,
        decoys: Vec<usize>,
    }

    fn scene(view: &TwoView, seed: u64) -> Scene {
        let mut rng = rng(seed);
        let (mut kps1, mut desc1, mut kps2, mut desc2) = (vec![], vec![], vec![], vec![]);
        let (mut rays1, mut rays2) = (vec![], vec![]);
        let mut truth = Vec::new(); // (i1, i2)
        let mut decoys = Vec::new(); // i2 of decoys
        let k_inv = view.k.try_inverse().unwrap();
        let ray = |uv: Vector2<f64>| (k_inv * Vector3::new(uv.x, uv.y, 1.0)).normalize();
        while kps1.len() < 300 {
            let p1 = Vector3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(2.0..8.0),
            );
            let p2 = view.r21 * p1 + view.t21;
            let (uv1, uv2) = (view.project(&p1), view.project(&p2));
            let in_image =
                |uv: &Vector2<f64>| (0.0..640.0).contains(&uv.x) && (0.0..480.0).contains(&uv.y);
            if p2.z < 0.5 || !in_image(&uv1) || !in_image(&uv2) {
                continue;
            }
            let noise = Vector2::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3));
            let d = random_descriptor(&mut rng);
            let i1 = kps1.len();
            kps1.push(keypoint(uv1, rng.random_range(0..8)));
            rays1.push(ray(uv1));
            desc1.push(d);
            let n_bits = rng.random_range(0..15);
            truth.push((i1, kps2.len()));
            kps2.push(keypoint(uv2 + noise, rng.random_range(0..8)));
            rays2.push(ray(uv2 + noise));
            desc2.push(flip_bits(&mut rng, &d, n_bits));
            if i1 % 5 == 0 {
                // A closer descriptor 25 px off the epipolar line: must never be matched.
                let l = view.f21() * Vector3::new(uv1.x, uv1.y, 1.0);
                let normal = Vector2::new(l.x, l.y).normalize();
                decoys.push(kps2.len());
                kps2.push(keypoint(uv2 + 25.0 * normal, 0));
                rays2.push(ray(uv2 + 25.0 * normal));
                desc2.push(flip_bits(&mut rng, &d, 1));
            }
        }
        Scene {
            kps1,
            desc1,
            rays1,
            kps2,
            desc2,
            rays2,
            truth,
            decoys,
        }
    }

    #[test]
    fn rays_find_the_true_pairs_within_the_angular_bound() {
        let view = TwoView::new();
        let s = scene(&view, 31);
        let pyramid = ScalePyramid::default();
        let free1: Vec<bool> = (0..s.kps1.len()).map(|i| i % 7 != 3).collect();
        let free2: Vec<bool> = (0..s.kps2.len()).map(|i| i % 11 != 4).collect();
        let e21 = view.t21.cross_matrix() * view.r21.matrix();
        let got = search_for_triangulation_rays(
            (&s.kps1, &s.desc1, &free1, &s.rays1),
            (&s.kps2, &s.desc2, &free2, &s.rays2),
            &e21,
            &pyramid.sigma2,
            1.0 / 500.0,
            Some(view.epipole2()),
            &MatchOptions::triangulation(),
        );
        let expected: Vec<_> = s
            .truth
            .iter()
            .copied()
            .filter(|&(i1, i2)| free1[i1] && free2[i2])
            .collect();
        assert!(expected.len() > 200);
        assert_eq!(got, expected);
        // Each accepted ray lies within the angular bound of its epipolar plane.
        for &(i1, i2) in &got {
            let n = e21 * s.rays1[i1];
            let sin = s.rays2[i2].dot(&n) / n.norm();
            let bound = CHI2_1DOF_95 * pyramid.sigma2[usize::from(s.kps2[i2].octave)];
            assert!(sin * sin < bound / (500.0 * 500.0));
        }
    }

    #[test]
    fn finds_true_pairs_and_respects_the_epipolar_bound() {
        let seed = 31;
        let view = TwoView::new();
        let pyramid = ScalePyramid::default();
        let Scene {
            kps1,
            desc1,
            kps2,
            desc2,
            truth,
            decoys,
            ..
        } = scene(&view, seed);
        let free1: Vec<bool> = (0..kps1.len()).map(|i| i % 7 != 3).collect();
        let free2: Vec<bool> = (0..kps2.len()).map(|i| i % 11 != 4).collect();
        let f21 = view.f21();
        assert_eq!(decoys.len(), 60);
        for opts in [
            MatchOptions::triangulation(),
            MatchOptions {
                check_orientation: true,
                ..MatchOptions::triangulation()
            },
        ] {
            let got = search_for_triangulation(
                &kps1,
                &desc1,
                &free1,
                &kps2,
                &desc2,
                &free2,
                &f21,
                &pyramid.sigma2,
                Some(view.epipole2()),
                &opts,
            );
            let expected: Vec<_> = truth
                .iter()
                .copied()
                .filter(|&(i1, i2)| free1[i1] && free2[i2])
                .collect();
            assert!(expected.len() > 200);
            assert_eq!(got, expected, "seed {seed}");
            for &(i1, i2) in &got {
                assert!(!decoys.contains(&i2));
                let bound = CHI2_1DOF_95 * pyramid.sigma2[usize::from(kps2[i2].octave)];
                assert!(line_distance2(&f21, &kps1[i1], &kps2[i2]) < bound);
            }
        }
    }

    #[test]
    fn rejects_features_near_the_epipole_and_bad_octaves() {
        let view = TwoView::new();
        let f21 = view.f21();
        let mut rng = rng(32);
        let d = random_descriptor(&mut rng);
        // A view-1 point whose line passes through the epipole (every line does); put kp2 on
        // the line within 5 px of a pretended epipole.
        let p1 = Vector3::new(0.1, 0.2, 4.0);
        let uv1 = view.project(&p1);
        let uv2 = view.project(&(view.r21 * p1 + view.t21));
        let kp1 = [keypoint(uv1, 0)];
        let kp2 = [keypoint(uv2, 0)];
        let all = |n| vec![true; n];
        let search = |eps: Option<(f64, f64)>, sigma2: &[f64]| {
            search_for_triangulation(
                &kp1,
                &[d],
                &all(1),
                &kp2,
                &[d],
                &all(1),
                &f21,
                sigma2,
                eps,
                &MatchOptions::triangulation(),
            )
        };
        let sigma2 = ScalePyramid::default().sigma2;
        assert_eq!(search(None, &sigma2), vec![(0, 0)]);
        assert_eq!(search(Some((uv2.x + 5.0, uv2.y)), &sigma2), vec![]);
        assert_eq!(search(Some((uv2.x + 11.0, uv2.y)), &sigma2), vec![(0, 0)]);
        // An octave beyond the provided level variances is skipped, not a panic.
        assert_eq!(search(None, &[]), vec![]);
        // A zero F (degenerate line) yields nothing.
        let zero = Matrix3::zeros();
        let got = search_for_triangulation(
            &kp1,
            &[d],
            &all(1),
            &kp2,
            &[d],
            &all(1),
            &zero,
            &sigma2,
            None,
            &MatchOptions::triangulation(),
        );
        assert!(got.is_empty());
    }
}
