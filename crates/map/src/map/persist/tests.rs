//! Round trips, truncation, corruption, version and magic checks of map files.

mod rig;

use approx::assert_relative_eq;
use nalgebra::{Isometry3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{fnv1a64, CHECKSUM_LEN, FORMAT_VERSION, HEADER_LEN, OLDEST_READABLE_VERSION};
use crate::test_support::{map_with_colored_keyframes, map_with_keyframes, observe_all};
use crate::{KeyFrameId, Map, MapError, MapPointId};

/// [`uncolored_sample_map`] as the build of format version 3 saved it.
const SAMPLE_MAP_V3: &[u8] = include_bytes!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/data/sample_map_v3.fslam"
));

/// [`uncolored_sample_map`] with an RGB-D pinhole camera record, as the build of format
/// version 4 saved it (before camera records named their model).
const SAMPLE_MAP_V4_RIG: &[u8] = include_bytes!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/data/sample_map_v4_rig.fslam"
));

/// Five keyframes with coloured keypoints, mono and stereo points, connections, refreshed
/// point summaries and counters, a moved pose, a fused point, a culled keyframe, a point
/// without observations (nor colour) and one keyframe read by a rolling shutter.
fn sample_map() -> (Map, Vec<KeyFrameId>) {
    let (mut map, kfs) = sample_map_from(map_with_colored_keyframes(5, 60));
    let kf = map.keyframes.get_mut(&kfs[1]).unwrap();
    let features = std::sync::Arc::make_mut(&mut kf.features);
    features.time_offsets_s = (0..features.len())
        .map(|i| 1e-4 * i as f64 - 3e-3)
        .collect();
    features.xi_dot = nalgebra::Vector6::new(0.1, -0.2, 0.05, 0.9, -1.4, 0.3);
    (map, kfs)
}

/// [`sample_map`] without colours.
fn uncolored_sample_map() -> (Map, Vec<KeyFrameId>) {
    sample_map_from(map_with_keyframes(5, 60))
}

fn sample_map_from((mut map, kfs): (Map, Vec<KeyFrameId>)) -> (Map, Vec<KeyFrameId>) {
    for i in 0..20 {
        observe_all(&mut map, &kfs[..3], i);
    }
    for i in 20..40 {
        observe_all(&mut map, &kfs[1..], i);
    }
    for i in 40..45 {
        observe_all(&mut map, &[kfs[0], kfs[4]], i);
    }
    for &kf in &kfs {
        map.update_connections(kf).unwrap();
    }
    for (n, mp) in map.map_point_ids().into_iter().enumerate() {
        map.update_normal_and_depth(mp).unwrap();
        map.compute_distinctive_descriptor(mp).unwrap();
        map.increase_visible(mp, 3 + n as u32).unwrap();
        map.increase_found(mp, n as u32 % 3).unwrap();
    }
    let fused = map.keyframe(kfs[0]).unwrap().map_point(41).unwrap();
    let into = map.keyframe(kfs[0]).unwrap().map_point(43).unwrap();
    map.replace_map_point(fused, into).unwrap();
    map.set_keyframe_pose(
        kfs[3],
        Isometry3::new(Vector3::new(0.1, -3.0, 0.2), Vector3::new(0.3, 0.2, -0.1)),
    )
    .unwrap();
    assert!(map.set_keyframe_bad(kfs[2]));
    map.create_map_point(Vector3::new(1.0, 2.0, 3.0), kfs[1])
        .unwrap();
    map.check_consistency().unwrap();
    (map, kfs)
}

fn to_bytes(map: &Map) -> Vec<u8> {
    let mut bytes = Vec::new();
    map.save(&mut bytes).unwrap();
    bytes
}

fn load(bytes: &[u8]) -> Result<Map, MapError> {
    Map::load(&mut &bytes[..])
}

/// Recomputes the trailing checksum, so that content corruption reaches the decoder.
fn reseal(bytes: &mut [u8]) {
    let body = bytes.len() - CHECKSUM_LEN;
    let checksum = fnv1a64(&[&bytes[..body]]);
    bytes[body..].copy_from_slice(&checksum.to_le_bytes());
}

/// Every public observable of the two maps is equal.
fn assert_same(a: &Map, b: &Map) {
    assert_eq!(a.pyramid(), b.pyramid());
    assert_eq!(a.origin(), b.origin());
    assert_eq!(a.keyframe_ids(), b.keyframe_ids());
    assert_eq!(a.map_point_ids(), b.map_point_ids());
    for (x, y) in a.keyframes().zip(b.keyframes()) {
        assert_eq!(x.id(), y.id());
        assert_eq!(x.timestamp(), y.timestamp());
        assert_eq!(x.frame_index(), y.frame_index());
        assert_eq!(x.T_c_w(), y.T_c_w());
        let (f, g) = (x.features(), y.features());
        assert_eq!(f.keypoints, g.keypoints);
        assert_eq!(f.descriptors, g.descriptors);
        assert_eq!(f.depth, g.depth);
        assert_eq!(f.u_right, g.u_right);
        assert_eq!(f.colors, g.colors);
        assert_eq!(f.time_offsets_s, g.time_offsets_s);
        assert_eq!(f.xi_dot, g.xi_dot);
        assert_eq!(f.camera_starts, g.camera_starts);
        assert_eq!(f.grids.len(), g.grids.len());
        for k in 0..f.num_cameras() {
            assert_eq!(f.grid(k).bounds(), g.grid(k).bounds());
            let near = |h: &crate::FrameFeatures| {
                let local = &h.keypoints[h.camera_range(k)];
                h.grid(k)
                    .features_in_area(local, 20.0, 10.0, 8.0, None, None)
            };
            assert_eq!(near(f), near(g));
        }
        assert_eq!(x.map_points(), y.map_points());
        assert_eq!(x.covisibles(), y.covisibles());
        assert_eq!(a.covisibles(x.id()), b.covisibles(y.id()));
        assert_eq!(x.parent(), y.parent());
        assert_eq!(x.children(), y.children());
    }
    for (p, q) in a.map_points().zip(b.map_points()) {
        assert_eq!(p.id(), q.id());
        assert_eq!(p.position(), q.position());
        assert_eq!(p.normal(), q.normal());
        assert_eq!(p.min_distance(), q.min_distance());
        assert_eq!(p.max_distance(), q.max_distance());
        assert_eq!(p.descriptor(), q.descriptor());
        assert_eq!(p.observations(), q.observations());
        assert_eq!(p.num_observations(), q.num_observations());
        assert_eq!(p.reference_keyframe(), q.reference_keyframe());
        assert_eq!(p.first_keyframe(), q.first_keyframe());
        assert_eq!((p.visible(), p.found()), (q.visible(), q.found()));
        assert_eq!(p.color(), q.color());
    }
    // Every id ever allocated (and some never): tombstones resolve alike.
    for id in 0..64 {
        let (ka, kb) = (KeyFrameId(id), MapPointId(id));
        assert_eq!(a.resolve_keyframe_pose(ka), b.resolve_keyframe_pose(ka));
        assert_eq!(a.resolve_map_point(kb), b.resolve_map_point(kb));
    }
}

#[test]
fn round_trip_restores_every_observable() {
    let (mut map, kfs) = sample_map();
    let colored = map.map_points().filter(|p| p.color().is_some()).count();
    assert!(
        colored > 0 && colored < map.num_map_points(),
        "{colored} coloured points"
    );
    let rolling = map
        .keyframes()
        .filter(|k| !k.features().time_offsets_s.is_empty());
    assert_eq!(rolling.count(), 1);
    let bytes = to_bytes(&map);
    let mut loaded = load(&bytes).unwrap();
    loaded.check_consistency().unwrap();
    assert_same(&map, &loaded);
    // Tombstones survive: the culled keyframe's pose and the fused point still resolve.
    assert!(loaded.keyframe(kfs[2]).is_none());
    assert!(loaded.resolve_keyframe_pose(kfs[2]).is_some());
    assert_eq!(
        to_bytes(&loaded),
        bytes,
        "saving a loaded map gives the same bytes"
    );

    // Both maps keep evolving identically, ids included.
    for m in [&mut map, &mut loaded] {
        let kf = m.insert_keyframe(
            9.0,
            9,
            Isometry3::identity(),
            m.keyframe(kfs[1]).unwrap().features().clone(),
        );
        for i in 20..40 {
            let mp = m.keyframe(kfs[1]).unwrap().map_point(i).unwrap();
            m.add_observation(mp, kf, i).unwrap();
        }
        m.update_connections(kf).unwrap();
        assert!(m.set_keyframe_bad(kfs[3]));
    }
    assert_same(&map, &loaded);
    loaded.check_consistency().unwrap();
}

#[test]
fn version_3_files_load_as_maps_without_colours_nor_row_times() {
    assert_eq!(SAMPLE_MAP_V3[8..12], 3u32.to_le_bytes());
    let loaded = load(SAMPLE_MAP_V3).unwrap();
    assert_same(&uncolored_sample_map().0, &loaded);
    assert!(loaded.map_points().all(|p| p.color().is_none()));
    assert!(loaded.keyframes().all(|k| k.features().colors.is_none()));
    // One camera per keyframe (as every file before version 8 held).
    assert!(loaded
        .keyframes()
        .all(|k| k.features().camera_starts == [0] && k.features().grids.len() == 1));
    // A global shutter's keyframes (as the version 3 to 5 files held).
    assert!(loaded
        .keyframes()
        .all(|k| k.features().time_offsets_s.is_empty()
            && k.features().xi_dot == nalgebra::Vector6::zeros()));
    // Saved again, it is a current-version file of the same map.
    let bytes = to_bytes(&loaded);
    assert_eq!(bytes[8..12], FORMAT_VERSION.to_le_bytes());
    assert_same(&loaded, &load(&bytes).unwrap());
}

#[test]
fn empty_and_cleared_maps_round_trip() {
    let (mut map, _) = sample_map();
    map.clear();
    let loaded = load(&to_bytes(&map)).unwrap();
    assert_same(&map, &loaded);
    assert_eq!(to_bytes(&loaded), to_bytes(&map));
    let empty = Map::new(ferroslam_features::ScalePyramid::new(1.5, 3).unwrap());
    assert_same(&empty, &load(&to_bytes(&empty)).unwrap());
}

#[test]
fn path_helpers_round_trip_and_report_missing_files() {
    let (map, _) = sample_map();
    let dir = std::env::temp_dir().join(format!("ferroslam-map-persist-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("map.fslam");
    map.save_to_path(&path).unwrap();
    assert_same(&map, &Map::load_from_path(&path).unwrap());

    let mut bytes = std::fs::read(&path).unwrap();
    bytes.push(0);
    std::fs::write(&path, &bytes).unwrap();
    assert!(matches!(
        Map::load_from_path(&path),
        Err(MapError::CorruptMapFile { .. })
    ));

    let missing = Map::load_from_path(dir.join("missing.fslam"));
    assert!(matches!(
        missing,
        Err(MapError::MapFileIo {
            kind: std::io::ErrorKind::NotFound,
            ..
        })
    ));
    // The parent is a file: refused, naming it.
    let unwritable = map.save_to_path(path.join("map.fslam"));
    assert!(
        matches!(&unwritable, Err(MapError::MapFileIo { message, .. }) if message.contains("map.fslam")),
        "{unwritable:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[cfg(unix)]
#[test]
fn save_replaces_a_link_and_load_refuses_a_fifo() {
    let (map, _) = sample_map();
    let dir = std::env::temp_dir().join(format!("ferroslam-map-link-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, b"keep me").unwrap();
    let path = dir.join("map.fslam");
    std::os::unix::fs::symlink(&victim, &path).unwrap();
    map.save_to_path(&path).unwrap();
    assert_eq!(std::fs::read(&victim).unwrap(), b"keep me");
    assert_same(&map, &Map::load_from_path(&path).unwrap());
    // Only the map and the victim are left: no temporary file.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 2);
    // A FIFO would block `open` until a writer came: refused before it is opened.
    let fifo = dir.join("pipe.fslam");
    let status = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(status.success());
    let err = Map::load_from_path(&fifo).unwrap_err();
    assert!(err.to_string().contains("is a FIFO"), "{err}");
    let err = map.save_to_path(&fifo).unwrap_err();
    assert!(err.to_string().contains("refusing to replace it"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn load_consumes_exactly_one_map() {
    let (map, _) = sample_map();
    let mut bytes = to_bytes(&map);
    let one = bytes.len();
    bytes.extend_from_slice(b"next");
    let mut r = &bytes[..];
    Map::load(&mut r).unwrap();
    assert_eq!(r, b"next");
    assert_eq!(bytes.len() - r.len(), one);
}

#[test]
fn every_truncation_fails_cleanly() {
    let (map, kfs) = map_with_keyframes(2, 3);
    let mut map = map;
    observe_all(&mut map, &kfs, 1);
    map.update_connections(kfs[1]).unwrap();
    let bytes = to_bytes(&map);
    for len in 0..bytes.len() {
        match load(&bytes[..len]) {
            Err(MapError::TruncatedMapFile { .. }) => {}
            other => panic!("prefix of {len}/{} bytes: {other:?}", bytes.len()),
        }
    }
}

#[test]
fn every_flipped_byte_is_detected() {
    let (map, kfs) = map_with_keyframes(2, 3);
    let mut map = map;
    observe_all(&mut map, &kfs, 1);
    let bytes = to_bytes(&map);
    for i in 0..bytes.len() {
        let mut bad = bytes.clone();
        bad[i] ^= 0x10;
        let err = load(&bad).expect_err(&format!("flipped byte {i} accepted"));
        let expected = match i {
            0..8 => matches!(err, MapError::NotAMapFile { .. }),
            8..12 => matches!(err, MapError::UnsupportedMapVersion { .. }),
            // Payload length: a longer one runs out of bytes, a shorter one misreads.
            12..HEADER_LEN => matches!(
                err,
                MapError::TruncatedMapFile { .. } | MapError::MapFileChecksum { .. }
            ),
            _ => matches!(err, MapError::MapFileChecksum { .. }),
        };
        assert!(expected, "flipped byte {i}: {err}");
    }
}

#[test]
fn the_rig_round_trips_and_survives_clear() {
    let (mut map, _) = sample_map();
    let rig = crate::Rig {
        sensor: "mono".into(),
        model: crate::Rig::PINHOLE.into(),
        intrinsics: [500.0, 501.0, 320.0, 240.0],
        distortion: [0.1, -0.2, 0.0, 0.001, 0.0],
        width: 640,
        height: 480,
        pair: None,
        cameras: Vec::new(),
    };
    map.set_rig(rig.clone());
    let loaded = load(&to_bytes(&map)).unwrap();
    assert_eq!(loaded.rig(), Some(&rig));
    let paired = crate::Rig {
        sensor: "stereo".into(),
        pair: Some(crate::PairCamera {
            model: "kannala_brandt".into(),
            intrinsics: [284.0, 285.3, 417.2, 400.4],
            distortion: [-0.002, 0.039, -0.038, 0.007, 0.0],
            T_left_right: nalgebra::Isometry3::translation(0.064, 0.001, 0.0),
        }),
        ..rig.clone()
    };
    map.set_rig(paired.clone());
    assert_eq!(load(&to_bytes(&map)).unwrap().rig(), Some(&paired));
    map.set_rig(rig.clone());
    assert_eq!(load(&to_bytes(&sample_map().0)).unwrap().rig(), None);
    map.clear();
    assert_eq!(map.rig(), Some(&rig));
}

#[test]
fn a_version_4_camera_record_loads_as_a_pinhole() {
    let rig = load(SAMPLE_MAP_V4_RIG).unwrap().rig().cloned().unwrap();
    assert_eq!(
        rig,
        crate::Rig {
            sensor: "rgbd".into(),
            model: crate::Rig::PINHOLE.into(),
            intrinsics: [517.3, 516.5, 318.6, 255.3],
            distortion: [0.2624, -0.9531, -0.0054, 0.0026, 1.1633],
            width: 640,
            height: 480,
            pair: None,
            cameras: Vec::new(),
        }
    );
}

#[test]
fn a_fisheye_rig_records_its_model() {
    let (mut map, _) = sample_map();
    let rig = crate::Rig {
        sensor: "rgbd".into(),
        model: "kannala_brandt".into(),
        intrinsics: [190.9, 190.9, 254.9, 256.8],
        distortion: [0.0034, 0.0007, -0.002, 0.0002, 0.0],
        width: 512,
        height: 512,
        pair: None,
        cameras: Vec::new(),
    };
    map.set_rig(rig.clone());
    let bytes = to_bytes(&map);
    assert_eq!(load(&bytes).unwrap().rig(), Some(&rig));
    // Saving the loaded map again gives the same bytes.
    assert_eq!(to_bytes(&load(&bytes).unwrap()), bytes);
}

#[test]
fn wrong_magic_and_version_are_named() {
    let (map, _) = sample_map();
    let mut bytes = to_bytes(&map);
    bytes[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    let err = load(&bytes).unwrap_err();
    assert_eq!(
        err,
        MapError::UnsupportedMapVersion {
            found: FORMAT_VERSION + 1,
            oldest: OLDEST_READABLE_VERSION,
            newest: FORMAT_VERSION
        }
    );
    let message = format!("version {} is not supported", FORMAT_VERSION + 1);
    assert!(err.to_string().contains(&message), "{err}");
    assert!(err.to_string().contains("reads versions 3 to 9"), "{err}");
    // A version 2 file (before the sensor and camera record) is refused, not misread.
    bytes[8..12].copy_from_slice(&2u32.to_le_bytes());
    let err = load(&bytes).unwrap_err();
    assert!(
        err.to_string().contains("version 2 is not supported"),
        "{err}"
    );

    let err = load(b"ply\nformat ascii 1.0\n").unwrap_err();
    assert!(matches!(err, MapError::NotAMapFile { ref found, .. } if found == b"ply\nform"));
    assert!(
        err.to_string().contains("not a ferroslam map file"),
        "{err}"
    );
    assert!(matches!(
        load(b"FSL"),
        Err(MapError::TruncatedMapFile { .. })
    ));
    assert!(matches!(load(b"FSX"), Err(MapError::NotAMapFile { .. })));
}

#[test]
fn huge_declared_lengths_do_not_allocate() {
    let (map, _) = sample_map();
    let mut bytes = to_bytes(&map);
    // The payload length field.
    bytes[12..20].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(matches!(
        load(&bytes),
        Err(MapError::TruncatedMapFile { .. })
    ));

    // The keyframe count, 8 bytes after the KEYF tag and its section length, with a valid
    // checksum so that the decoder sees it.
    let mut bytes = to_bytes(&map);
    let at = bytes.windows(4).position(|w| w == b"KEYF").unwrap() + 12;
    bytes[at..at + 8].copy_from_slice(&(u64::MAX / 2).to_le_bytes());
    reseal(&mut bytes);
    let err = load(&bytes).unwrap_err();
    assert!(
        matches!(&err, MapError::CorruptMapFile { what } if what.contains("items declared")),
        "{err}"
    );
}

#[test]
fn resealed_random_corruption_never_panics() {
    let (map, _) = sample_map();
    let bytes = to_bytes(&map);
    let seed = 7;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut rejected = 0;
    for _ in 0..400 {
        let mut bad = bytes.clone();
        for _ in 0..rng.random_range(1..4) {
            let i = rng.random_range(HEADER_LEN..bytes.len() - CHECKSUM_LEN);
            bad[i] = rng.random();
        }
        reseal(&mut bad);
        // Either a clean error or a map that passes the consistency check (a changed float).
        match load(&bad) {
            Ok(m) => m.check_consistency().unwrap(),
            Err(e) => {
                assert!(!e.to_string().is_empty());
                rejected += 1;
            }
        }
    }
    assert!(rejected > 0, "seed {seed}: no corruption was rejected");
}

#[test]
fn inconsistent_content_is_rejected() {
    // A point whose observation the keyframe slot does not hold: valid encoding, bad map.
    let (mut map, kfs) = map_with_keyframes(2, 4);
    let mp = observe_all(&mut map, &kfs, 2);
    map.keyframes.get_mut(&kfs[1]).unwrap().map_points[2] = None;
    let err = load(&to_bytes(&map)).unwrap_err();
    assert!(
        matches!(&err, MapError::CorruptMapFile { what } if what.contains(&mp.to_string())),
        "{err}"
    );
}

#[test]
fn poses_are_bit_exact() {
    let (mut map, kfs) = map_with_keyframes(1, 2);
    let pose = Isometry3::new(Vector3::new(1e-17, 3.3, -7.0), Vector3::new(0.1, 1.0, 2.9));
    map.set_keyframe_pose(kfs[0], pose).unwrap();
    let loaded = load(&to_bytes(&map)).unwrap();
    let got = loaded.keyframe(kfs[0]).unwrap().T_c_w();
    assert_eq!(got.rotation.coords, pose.rotation.coords);
    assert_relative_eq!(
        got.translation.vector,
        pose.translation.vector,
        epsilon = 0.0
    );
}

/// `edit` applied to the sample map, saved (a valid checksum) and loaded: the error text.
fn load_edited(edit: impl FnOnce(&mut Map, &[KeyFrameId], MapPointId)) -> String {
    let (mut map, kfs) = sample_map();
    let mp = *map.map_points.keys().next().unwrap();
    edit(&mut map, &kfs, mp);
    refused(&map)
}

/// `map` saved (a valid checksum) and loaded: the error text of the refusal.
fn refused(map: &Map) -> String {
    match load(&to_bytes(map)) {
        Err(MapError::CorruptMapFile { what }) => what,
        other => panic!("expected a corrupt map file, got {other:?}"),
    }
}

#[test]
fn non_finite_and_absurd_points_are_refused_naming_the_point() {
    for value in [f64::NAN, f64::INFINITY, 1e300, -2e6] {
        let what =
            load_edited(|map, _, mp| map.map_points.get_mut(&mp).unwrap().position.y = value);
        assert!(what.starts_with("map point MP1: position"), "{what}");
        assert!(what.contains(&format!("{value:?}")), "{what}");
    }
    // 1e6 m itself is still a place.
    let (mut map, _) = sample_map();
    let mp = *map.map_points.keys().next().unwrap();
    map.map_points.get_mut(&mp).unwrap().position.x = super::MAX_COORDINATE_M;
    load(&to_bytes(&map)).unwrap();
    let what = load_edited(|map, _, mp| map.map_points.get_mut(&mp).unwrap().normal.z = f64::NAN);
    assert!(what.starts_with("map point MP1: normal"), "{what}");
    let what =
        load_edited(|map, _, mp| map.map_points.get_mut(&mp).unwrap().max_distance = f64::INFINITY);
    assert!(what.contains("MP1: distance range"), "{what}");
}

#[test]
fn non_finite_and_non_rigid_poses_are_refused_naming_the_keyframe() {
    use nalgebra::{Quaternion, UnitQuaternion};
    let what = load_edited(|map, kfs, _| {
        map.keyframes
            .get_mut(&kfs[1])
            .unwrap()
            .T_c_w
            .translation
            .vector
            .x = f64::NAN
    });
    assert!(
        what.starts_with("keyframe KF1: pose T_c_w translation"),
        "{what}"
    );
    let what = load_edited(|map, kfs, _| {
        map.keyframes.get_mut(&kfs[0]).unwrap().T_c_w.rotation =
            UnitQuaternion::new_unchecked(Quaternion::new(f64::NAN, 0.0, 0.0, 0.0))
    });
    assert!(
        what.starts_with("keyframe KF0: pose T_c_w rotation quaternion"),
        "{what}"
    );
    assert!(what.contains("not finite"), "{what}");
    // A scaled rotation (norm 2): not rigid.
    let what = load_edited(|map, kfs, _| {
        map.keyframes.get_mut(&kfs[3]).unwrap().T_c_w.rotation =
            UnitQuaternion::new_unchecked(Quaternion::new(2.0, 0.0, 0.0, 0.0))
    });
    assert!(
        what.contains("KF3") && what.contains("has norm 2"),
        "{what}"
    );
    // Within the tolerance: loads.
    let (mut map, kfs) = sample_map();
    let q = map
        .keyframes
        .get(&kfs[0])
        .unwrap()
        .T_c_w
        .rotation
        .into_inner()
        * (1.0 + 1e-9);
    map.keyframes.get_mut(&kfs[0]).unwrap().T_c_w.rotation = UnitQuaternion::new_unchecked(q);
    load(&to_bytes(&map)).unwrap();
    let what =
        load_edited(|map, kfs, _| map.keyframes.get_mut(&kfs[1]).unwrap().timestamp = f64::NAN);
    assert!(what.starts_with("keyframe KF1: timestamp"), "{what}");
}

#[test]
fn non_finite_keypoints_and_depths_are_refused() {
    let what = load_edited(|map, kfs, _| {
        let kf = map.keyframes.get_mut(&kfs[0]).unwrap();
        std::sync::Arc::make_mut(&mut kf.features).keypoints[4].x = f32::NAN;
    });
    assert!(what.starts_with("keyframe KF0: keypoint 4"), "{what}");
    let what = load_edited(|map, kfs, _| {
        let kf = map.keyframes.get_mut(&kfs[0]).unwrap();
        std::sync::Arc::make_mut(&mut kf.features).depth[3] = f32::INFINITY;
    });
    assert!(
        what.starts_with("keyframe KF0: depth of keypoint 3"),
        "{what}"
    );
    let what = load_edited(|map, kfs, _| {
        let kf = map.keyframes.get_mut(&kfs[0]).unwrap();
        std::sync::Arc::make_mut(&mut kf.features).time_offsets_s = vec![f64::NAN; 60];
    });
    assert!(
        what.starts_with("keyframe KF0: row time offset of keypoint 0 is NaN"),
        "{what}"
    );
    let what = load_edited(|map, kfs, _| {
        let kf = map.keyframes.get_mut(&kfs[1]).unwrap();
        std::sync::Arc::make_mut(&mut kf.features).xi_dot[4] = f64::INFINITY;
    });
    assert!(what.starts_with("keyframe KF1: readout velocity"), "{what}");
}

mod fuzz {
    //! Seeded, bounded property tests of the codec: any mutation or truncation of a valid
    //! file is a clean `Err` (or, for a changed float, a consistent map); nothing panics.
    use proptest::prelude::*;
    use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};

    use super::*;

    /// A fixed seed (reproducible in CI) and a bounded number of cases (about a second).
    fn runner(cases: u32) -> TestRunner {
        let config = Config {
            cases,
            failure_persistence: None,
            ..Config::default()
        };
        TestRunner::new_with_rng(config, TestRng::from_seed(RngAlgorithm::ChaCha, &[53; 32]))
    }

    fn saved_sample() -> Vec<u8> {
        to_bytes(&sample_map().0)
    }

    /// Loading never panics; what loads is consistent and plausible (it would load again).
    fn check(bytes: &[u8]) {
        if let Ok(map) = load(bytes) {
            map.check_consistency().unwrap();
            load(&to_bytes(&map)).unwrap();
        }
    }

    #[test]
    fn mutated_resealed_files_fail_cleanly() {
        let bytes = saved_sample();
        let n = bytes.len();
        let edits = prop::collection::vec((HEADER_LEN..n - CHECKSUM_LEN, any::<u8>()), 1..8);
        runner(512)
            .run(&(edits, any::<bool>()), |(edits, reseal_it)| {
                let mut bad = bytes.clone();
                edits.iter().for_each(|&(i, b)| bad[i] = b);
                if reseal_it {
                    reseal(&mut bad);
                }
                check(&bad);
                Ok(())
            })
            .unwrap();
    }

    #[test]
    fn truncated_and_extended_files_fail_cleanly() {
        let bytes = saved_sample();
        let n = bytes.len();
        runner(256)
            .run(
                &(0..n, prop::collection::vec(any::<u8>(), 0..64)),
                |(cut, tail)| {
                    let mut bad = bytes[..cut].to_vec();
                    bad.extend_from_slice(&tail);
                    prop_assert!(load(&bad).is_err());
                    Ok(())
                },
            )
            .unwrap();
    }

    #[test]
    fn injected_floats_are_refused_or_plausible() {
        // Any f64 bit pattern written over any 8 aligned-or-not payload bytes, resealed.
        let bytes = saved_sample();
        let n = bytes.len();
        let special = prop_oneof![
            Just(f64::NAN),
            Just(f64::INFINITY),
            Just(f64::NEG_INFINITY),
            Just(1e300),
            Just(-1e300),
            any::<f64>(),
        ];
        runner(512)
            .run(
                &(HEADER_LEN..n - CHECKSUM_LEN - 8, special),
                |(at, value)| {
                    let mut bad = bytes.clone();
                    bad[at..at + 8].copy_from_slice(&value.to_le_bytes());
                    reseal(&mut bad);
                    check(&bad);
                    Ok(())
                },
            )
            .unwrap();
    }

    #[test]
    fn random_bytes_fail_cleanly() {
        runner(256)
            .run(&prop::collection::vec(any::<u8>(), 0..512), |mut bytes| {
                prop_assert!(load(&bytes).is_err());
                // Past the magic and version: the length, sections and checksum are tested.
                if bytes.len() >= HEADER_LEN {
                    bytes[..8].copy_from_slice(super::super::MAGIC);
                    bytes[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
                    prop_assert!(load(&bytes).is_err());
                }
                Ok(())
            })
            .unwrap();
    }
}
