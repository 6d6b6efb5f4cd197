//! Cross-module tests on synthetic maps: covisibility against a naive count, spanning tree
//! repair, point removal and fusion, and random (seeded) operation sequences that must keep
//! every invariant.

use approx::assert_relative_eq;
use ferroslam_features::{hamming, ImageBounds, Keypoint, ScalePyramid};
use ferroslam_map::{FrameFeatures, KeyFrameId, Map, MapPointId, COVISIBILITY_THRESHOLD};
use nalgebra::{Isometry3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const KEYPOINTS: usize = 300;

fn random_features(rng: &mut ChaCha8Rng) -> FrameFeatures {
    let keypoints = (0..KEYPOINTS)
        .map(|_| Keypoint {
            x: rng.random_range(0.0..640.0),
            y: rng.random_range(0.0..480.0),
            octave: rng.random_range(0..8),
            angle_deg: rng.random_range(0.0..360.0),
            response: 1.0,
        })
        .collect();
    let descriptors = (0..KEYPOINTS).map(|_| rng.random()).collect();
    let stereo: Vec<bool> = (0..KEYPOINTS).map(|_| rng.random_bool(0.5)).collect();
    let depth = stereo.iter().map(|&s| if s { 2.0 } else { -1.0 }).collect();
    let u_right = stereo
        .iter()
        .map(|&s| if s { 100.0 } else { -1.0 })
        .collect();
    let bounds = ImageBounds {
        min_x: 0.0,
        max_x: 640.0,
        min_y: 0.0,
        max_y: 480.0,
    };
    FrameFeatures::new(keypoints, descriptors, depth, u_right, bounds).unwrap()
}

fn insert_random_keyframe(map: &mut Map, rng: &mut ChaCha8Rng, index: usize) -> KeyFrameId {
    let t_w_c = Isometry3::new(
        Vector3::new(0.3 * index as f64, rng.random_range(-0.1..0.1), 0.0),
        Vector3::new(0.0, rng.random_range(-0.2..0.2), 0.0),
    );
    let features = random_features(rng);
    map.insert_keyframe(index as f64 * 0.1, index, t_w_c.inverse(), features)
}

/// A random free keypoint of `kf`, if one is found quickly.
fn free_slot(map: &Map, kf: KeyFrameId, rng: &mut ChaCha8Rng) -> Option<usize> {
    let frame = map.keyframe(kf)?;
    (0..20)
        .map(|_| rng.random_range(0..frame.features().len()))
        .find(|&i| frame.map_point(i).is_none())
}

/// Creates a point seen by `observers` (reference first) at random free keypoints.
fn create_point(
    map: &mut Map,
    rng: &mut ChaCha8Rng,
    observers: &[KeyFrameId],
) -> Option<MapPointId> {
    let position = Vector3::new(
        rng.random_range(-2.0..2.0),
        rng.random_range(-2.0..2.0),
        rng.random_range(2.0..8.0),
    );
    let mp = map.create_map_point(position, observers[0]).ok()?;
    for &kf in observers {
        if let Some(index) = free_slot(map, kf, rng) {
            map.add_observation(mp, kf, index).unwrap();
        }
    }
    map.update_normal_and_depth(mp).unwrap();
    map.compute_distinctive_descriptor(mp).unwrap();
    Some(mp)
}

/// `n_kf` keyframes in time order and `n_points` points, each seen by 2..=`window` consecutive
/// keyframes ending at a random one; `update_connections` runs as each keyframe "arrives".
fn synthetic_map(seed: u64, n_kf: usize, n_points: usize, window: usize) -> (Map, ChaCha8Rng) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut map = Map::new(ScalePyramid::default());
    let kfs: Vec<_> = (0..n_kf)
        .map(|i| insert_random_keyframe(&mut map, &mut rng, i))
        .collect();
    let per_kf = n_points.div_ceil(n_kf);
    for (last, &kf) in kfs.iter().enumerate() {
        for _ in 0..per_kf {
            let len = rng.random_range(2..=window).min(last + 1);
            let mut observers: Vec<_> = kfs[last + 1 - len..=last].to_vec();
            observers.rotate_left(rng.random_range(0..len));
            create_point(&mut map, &mut rng, &observers);
        }
        map.update_connections(kf).unwrap();
    }
    (map, rng)
}

fn naive_shared(map: &Map, a: KeyFrameId, b: KeyFrameId) -> usize {
    map.map_points()
        .filter(|p| p.observations().contains_key(&a) && p.observations().contains_key(&b))
        .count()
}

fn assert_weights_match_naive(map: &Map) {
    for a in map.keyframe_ids() {
        for (b, weight) in map.covisibles(a) {
            assert_eq!(weight, naive_shared(map, a, b), "edge {a}-{b}");
        }
    }
}

fn assert_tree_reaches_origin(map: &Map) {
    let origin = map.origin().unwrap();
    for kf in map.keyframe_ids() {
        let mut current = kf;
        for _ in 0..map.num_keyframes() {
            match map.keyframe(current).unwrap().parent() {
                Some(p) => current = p,
                None => break,
            }
        }
        assert_eq!(current, origin, "{kf} does not reach the origin");
    }
}

#[test]
fn covisibility_matches_a_naive_count() {
    let (mut map, _) = synthetic_map(7, 5, 200, 5);
    assert_eq!((map.num_keyframes(), map.num_map_points()), (5, 200));
    for kf in map.keyframe_ids() {
        map.update_connections(kf).unwrap();
    }
    map.check_consistency().unwrap();
    assert_weights_match_naive(&map);
    let ids = map.keyframe_ids();
    for &a in &ids {
        let covisibles = map.covisibles(a);
        assert!(
            covisibles.windows(2).all(|w| w[0].1 >= w[1].1),
            "sorted by weight"
        );
        for &b in ids.iter().filter(|&&b| b != a) {
            if naive_shared(&map, a, b) >= COVISIBILITY_THRESHOLD {
                assert!(
                    covisibles.iter().any(|&(k, _)| k == b),
                    "{a}-{b} should be connected"
                );
            }
        }
    }
    assert_tree_reaches_origin(&map);
}

#[test]
fn culling_keyframes_keeps_the_tree_connected() {
    for seed in 0..10 {
        let (mut map, mut rng) = synthetic_map(seed, 12, 600, 4);
        assert_tree_reaches_origin(&map);
        let poses: Vec<_> = map.keyframes().map(|f| (f.id(), *f.T_c_w())).collect();
        for _ in 0..6 {
            let ids = map.keyframe_ids();
            let victim = ids[rng.random_range(1..ids.len())];
            assert!(map.set_keyframe_bad(victim));
            assert!(map.keyframe(victim).is_none() && !map.keyframe_ids().contains(&victim));
            map.check_consistency()
                .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            assert_tree_reaches_origin(&map);
        }
        assert!(!map.set_keyframe_bad(map.origin().unwrap()));
        // Poses did not change, so culled keyframes resolve to their original poses.
        for (kf, pose) in poses {
            let resolved = map.resolve_keyframe_pose(kf).unwrap();
            assert_relative_eq!(
                resolved.to_homogeneous(),
                pose.to_homogeneous(),
                epsilon = 1e-9
            );
        }
    }
}

#[test]
fn erasing_down_to_one_observation_removes_the_point() {
    let (mut map, mut rng) = synthetic_map(3, 5, 200, 5);
    let kfs = map.keyframe_ids();
    let mp = create_point(&mut map, &mut rng, &kfs[..2]).unwrap();
    assert_eq!(map.map_point(mp).unwrap().observations().len(), 2);
    let index = map.map_point(mp).unwrap().observation(kfs[1]).unwrap();
    assert!(map.erase_observation(mp, kfs[0]));
    assert!(map.map_point(mp).is_none() && map.is_map_point_bad(mp));
    assert_eq!(map.keyframe(kfs[1]).unwrap().map_point(index), None);
    assert!(!map.erase_observation(mp, kfs[1]));
    map.check_consistency().unwrap();
    assert_weights_match_naive(&map);
}

#[test]
fn points_seen_by_lists_each_live_point_once_in_order_of_first_sight() {
    let (map, _) = synthetic_map(5, 6, 300, 3);
    let kfs = map.keyframe_ids();
    let order = [kfs[3], kfs[1], kfs[2]];
    let mut want: Vec<MapPointId> = Vec::new();
    for &kf in &order {
        let frame = map.keyframe(kf).unwrap();
        for m in (0..frame.features().len()).filter_map(|i| frame.map_point(i)) {
            if !want.contains(&m) {
                want.push(m);
            }
        }
    }
    assert!(want.len() > 50);
    let got = map.points_seen_by(order.iter().copied().chain([KeyFrameId(9999)]));
    assert_eq!(got, want);
}

#[test]
fn replacing_merges_observations() {
    let (mut map, mut rng) = synthetic_map(11, 5, 200, 5);
    let kfs = map.keyframe_ids();
    let old = create_point(&mut map, &mut rng, &[kfs[0], kfs[1], kfs[2]]).unwrap();
    let new = create_point(&mut map, &mut rng, &[kfs[2], kfs[3], kfs[4]]).unwrap();
    let old_obs = map.map_point(old).unwrap().observations().clone();
    let new_obs = map.map_point(new).unwrap().observations().clone();
    map.replace_map_point(old, new).unwrap();

    let merged = map.map_point(new).unwrap().observations().clone();
    let mut expected = old_obs.clone();
    expected.extend(new_obs.iter()); // `new` keeps its own keypoint where both were seen
    assert_eq!(merged, expected);
    assert_eq!(
        map.keyframe(kfs[2]).unwrap().map_point(old_obs[&kfs[2]]),
        None
    );
    assert_eq!(map.resolve_map_point(old), Some(new));
    map.check_consistency().unwrap();
    assert_weights_match_naive(&map);
}

#[test]
fn distinctive_descriptor_is_the_medoid_and_geometry_matches() {
    let (map, _) = synthetic_map(5, 5, 200, 5);
    for point in map.map_points() {
        let descriptors: Vec<_> = point
            .observations()
            .iter()
            .map(|(&kf, &i)| map.keyframe(kf).unwrap().features().descriptors[i])
            .collect();
        let median = |d: &[u8; 32]| {
            let mut v: Vec<u32> = descriptors.iter().map(|o| hamming(d, o)).collect();
            v.sort();
            v[(v.len() - 1) / 2]
        };
        let best = descriptors.iter().map(median).min().unwrap();
        assert_eq!(median(point.descriptor()), best);
        assert!(descriptors.contains(point.descriptor()));

        let rays = point
            .observations()
            .keys()
            .map(|&kf| (point.position() - map.keyframe(kf).unwrap().camera_center()).normalize());
        let normal = rays.sum::<Vector3<f64>>().normalize();
        assert_relative_eq!(point.normal(), normal, epsilon = 1e-12);
        let reference = map.keyframe(point.reference_keyframe()).unwrap();
        let octave = reference.features().keypoints[point.observations()[&reference.id()]].octave;
        let distance = (point.position() - reference.camera_center()).norm();
        let scale = map.pyramid().scale.clone();
        assert_relative_eq!(
            point.max_distance(),
            distance * scale[octave as usize],
            epsilon = 1e-12
        );
        assert_relative_eq!(
            point.min_distance(),
            point.max_distance() / scale[7],
            epsilon = 1e-12
        );
    }
}

/// One random mutation; returns its name for failure messages.
fn random_operation(map: &mut Map, rng: &mut ChaCha8Rng, next_frame: &mut usize) -> &'static str {
    let kfs = map.keyframe_ids();
    let mps = map.map_point_ids();
    let pick_kf = |rng: &mut ChaCha8Rng| kfs[rng.random_range(0..kfs.len())];
    match rng.random_range(0..100) {
        0..25 if !mps.is_empty() => {
            let (mp, kf) = (mps[rng.random_range(0..mps.len())], pick_kf(rng));
            if let Some(index) = free_slot(map, kf, rng) {
                // May legitimately fail with AlreadyObserved.
                let _ = map.add_observation(mp, kf, index);
            }
            "add_observation"
        }
        25..40 if !mps.is_empty() => {
            let mp = mps[rng.random_range(0..mps.len())];
            let observers: Vec<_> = map
                .map_point(mp)
                .unwrap()
                .observations()
                .keys()
                .copied()
                .collect();
            if let Some(&kf) = observers.get(rng.random_range(0..observers.len().max(1))) {
                map.erase_observation(mp, kf);
            }
            "erase_observation"
        }
        40..45 if !mps.is_empty() => {
            map.set_map_point_bad(mps[rng.random_range(0..mps.len())]);
            "set_map_point_bad"
        }
        45..55 if mps.len() >= 2 => {
            let (a, b) = (
                mps[rng.random_range(0..mps.len())],
                mps[rng.random_range(0..mps.len())],
            );
            map.replace_map_point(a, b).unwrap();
            "replace_map_point"
        }
        55..70 => {
            map.update_connections(pick_kf(rng)).unwrap();
            "update_connections"
        }
        70..75 if kfs.len() > 3 => {
            map.set_keyframe_bad(pick_kf(rng));
            "set_keyframe_bad"
        }
        75..80 => {
            let kf = insert_random_keyframe(map, rng, *next_frame);
            *next_frame += 1;
            map.update_connections(kf).unwrap();
            "insert_keyframe"
        }
        _ => {
            let len = rng.random_range(2..=kfs.len().min(4));
            let mut observers: Vec<KeyFrameId> = Vec::new();
            for kf in (0..len).map(|_| pick_kf(rng)) {
                if !observers.contains(&kf) {
                    observers.push(kf);
                }
            }
            create_point(map, rng, &observers);
            "create_point"
        }
    }
}

#[test]
fn random_operation_sequences_stay_consistent() {
    for seed in 0..12 {
        let (mut map, mut rng) = synthetic_map(100 + seed, 8, 400, 4);
        let mut next_frame = 8;
        for step in 0..400 {
            let op = random_operation(&mut map, &mut rng, &mut next_frame);
            if let Err(e) = map.check_consistency() {
                panic!("seed {seed}, step {step}, after {op}: {e}");
            }
        }
        assert_weights_match_naive(&map);
        for mp in map.map_point_ids() {
            let point = map.map_point(mp).unwrap();
            for &kf in point.observations().keys() {
                assert!(map.keyframe(kf).is_some());
            }
        }
    }
}

#[test]
fn clear_never_reuses_ids() {
    let (mut map, mut rng) = synthetic_map(1, 3, 30, 3);
    let last = *map.keyframe_ids().last().unwrap();
    map.clear();
    assert_eq!(
        (map.num_keyframes(), map.num_map_points(), map.origin()),
        (0, 0, None)
    );
    let kf = insert_random_keyframe(&mut map, &mut rng, 0);
    assert!(kf > last);
    assert_eq!(map.origin(), Some(kf));
}
