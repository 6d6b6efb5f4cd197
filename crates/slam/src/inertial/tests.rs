//! Unit tests of the system's inertial state.

use super::*;

fn config() -> InertialConfig {
    InertialConfig::new(ImuParams::euroc(), Isometry3::identity())
}

fn sample(t_s: f64) -> ImuSample {
    ImuSample::new(t_s, Vector3::zeros(), Vector3::new(0.0, 0.0, 9.81))
}

#[test]
fn validates_the_configuration() {
    assert!(config().validate().is_ok());
    let mut c = config();
    c.alignment_fraction = 0.0;
    assert!(
        matches!(c.validate(), Err(SlamError::InvalidConfig(m)) if m.contains("alignment_fraction"))
    );
    let mut c = config();
    c.num_poses_threshold = 2;
    assert!(
        matches!(c.validate(), Err(SlamError::InvalidConfig(m)) if m.contains("num_poses_threshold"))
    );
    let mut c = config();
    c.T_b_c.translation.vector.x = f64::NAN;
    assert!(c.validate().is_err());
    let mut c = config();
    c.params.rate_hz = -1.0;
    assert!(c.validate().is_err());
    let mut c = config();
    c.imu_time_offset_s = f64::INFINITY;
    assert!(
        matches!(c.validate(), Err(SlamError::InvalidConfig(m)) if m.contains("imu_time_offset_s"))
    );
}

#[test]
fn samples_move_to_the_camera_clock() {
    // The IMU clock runs 12 ms ahead: t_imu = t_cam + 0.012.
    let mut c = config();
    c.imu_time_offset_s = 0.012;
    let mut inertial = Inertial::new(c, InertialTuning::default(), false).unwrap();
    inertial.add(&[sample(1.012), sample(1.017)]).unwrap();
    let stamps: Vec<f64> = inertial.samples.iter().map(|s| s.t_s).collect();
    assert!((stamps[0] - 1.0).abs() < 1e-12 && (stamps[1] - 1.005).abs() < 1e-12);
    // Order is checked on the camera clock too.
    let err = inertial.add(&[sample(1.016)]).unwrap_err();
    assert!(err.to_string().contains("last sample added"), "{err}");
}

#[test]
fn a_stored_map_s_imu_state_comes_back_and_resumes_after_the_gap() {
    let mut inertial = Inertial::new(config(), InertialTuning::default(), true).unwrap();
    let samples: Vec<ImuSample> = (0..200).map(|i| sample(f64::from(i) * 0.005)).collect();
    inertial.add(&samples).unwrap();
    let (kf, velocity) = (KeyFrameId(7), Vector3::new(0.2, 0.0, 0.1));
    let bias = Bias::new(Vector3::new(0.01, 0.0, 0.0), Vector3::zeros());
    inertial
        .per_map
        .states
        .insert(kf, KeyFrameState { velocity, bias });
    inertial.per_map.status = AlignmentStatus::Aligned(InertialAlignment {
        scale: 1.0,
        refinement: 2,
        map_rescaled: false,
        gravity_w: Vector3::new(0.0, 0.0, -9.81),
        R_w_g: UnitQuaternion::identity(),
        gyro_bias: bias.gyro,
        accel_bias: bias.accel,
        keyframes: vec![(kf, 0.5)],
        velocities: vec![velocity],
        timestamp: 0.5,
        acceleration_excitation: 1.0,
    });
    // Stored: the system's part (samples) stays, the map's leaves with it.
    let stored = inertial.take_map_state();
    assert!(stored.is_aligned() && !inertial.is_aligned());
    assert!(inertial.per_map.states.is_empty() && inertial.samples.len() == 200);
    // Brought back and resumed at 0.6 s: its states and alignment return, the samples
    // of the gap go (but the one bracketing 0.6 s), and the next keyframe's state waits
    // for `resume`, with the map's newest biases.
    inertial.restore_map_state(stored);
    assert!(inertial.is_aligned() && !inertial.resuming());
    inertial.resume_at(0.6);
    assert!(inertial.resuming());
    assert!((inertial.samples[0].t_s - 0.6).abs() < 1e-12);
    inertial.resume(KeyFrameId(9), Vector3::new(0.0, 0.3, 0.0));
    assert!(!inertial.resuming());
    let (newest, v, b) = inertial.newest_state().unwrap();
    assert_eq!(
        (newest, v, b),
        (KeyFrameId(9), Vector3::new(0.0, 0.3, 0.0), bias)
    );
    // A map never aligned does not wait for a velocity.
    inertial.clear_map();
    inertial.resume_at(0.7);
    assert!(!inertial.resuming());
}

#[test]
fn implausible_alignments_name_the_sensor() {
    let plausible = ferroslam_imu::alignment::Alignment {
        scale: 1.0,
        gravity_w: Vector3::new(0.0, 0.0, -9.81),
        R_w_gravity: UnitQuaternion::identity(),
        gyro_bias: Vector3::new(-0.003, 0.021, 0.08),
        accel_bias: Vector3::zeros(),
        accel_bias_estimated: false,
        velocities: vec![Vector3::new(0.3, 0.0, 0.1); 3],
        acceleration_excitation: 1.0,
    };
    let tuning = InertialTuning::default();
    assert_eq!(check_plausible(&plausible, &tuning), Ok(()));
    let constant_gyro = ferroslam_imu::alignment::Alignment {
        gyro_bias: Vector3::new(0.0, 0.0, 3.0),
        ..plausible.clone()
    };
    assert!(check_plausible(&constant_gyro, &tuning)
        .unwrap_err()
        .starts_with("gyroscope: matching the rotation vision sees needs a gyro bias of 3.00"));
    let fast = ferroslam_imu::alignment::Alignment {
        velocities: vec![Vector3::new(442.0, 0.0, 0.0)],
        ..plausible.clone()
    };
    assert!(check_plausible(&fast, &tuning)
        .unwrap_err()
        .contains("442 m/s"));
    let biased = ferroslam_imu::alignment::Alignment {
        accel_bias: Vector3::new(0.0, 5.0, 0.0),
        ..plausible
    };
    assert!(check_plausible(&biased, &tuning)
        .unwrap_err()
        .starts_with("accelerometer"));
}

#[test]
fn window_is_the_rounded_up_fraction() {
    let c = config();
    assert_eq!(c.window(20), 18);
    assert_eq!(c.window(21), 19);
    let mut c = config();
    c.alignment_fraction = 1.0;
    assert_eq!(c.window(20), 20);
}

#[test]
fn bad_samples_are_refused_and_leave_the_buffer_unchanged() {
    let mut inertial = Inertial::new(config(), InertialTuning::default(), false).unwrap();
    inertial.add(&[sample(0.0), sample(0.005)]).unwrap();
    let err = inertial.add(&[sample(0.01), sample(0.008)]).unwrap_err();
    assert!(err.to_string().contains("not after"), "{err}");
    let err = inertial.add(&[sample(0.005)]).unwrap_err();
    assert!(err.to_string().contains("last sample added"), "{err}");
    let mut nan = sample(0.02);
    nan.accel_m_s2.x = f64::NAN;
    let err = inertial.add(&[nan]).unwrap_err();
    assert!(err.to_string().contains("non-finite"), "{err}");
    let mut degrees = sample(0.02);
    degrees.gyro_rad_s.z = 90.0;
    let err = inertial.add(&[degrees]).unwrap_err();
    assert!(err.to_string().contains("deg/s"), "{err}");
    let mut g = sample(0.02);
    g.accel_m_s2.z = 1.0;
    let err = inertial.add(&[g]).unwrap_err();
    assert!(err.to_string().contains("in g"), "{err}");
    assert_eq!(inertial.samples.len(), 2);
    inertial.add(&[sample(0.01)]).unwrap();
    assert_eq!(inertial.samples.len(), 3);
}

#[test]
fn refinements_follow_the_first_alignment_then_stop() {
    let mut inertial = Inertial::new(config(), InertialTuning::default(), false).unwrap();
    assert_eq!(inertial.next_refinement(), Some(0));
    let aligned = |refinement| {
        AlignmentStatus::Aligned(InertialAlignment {
            scale: 1.0,
            refinement,
            map_rescaled: false,
            gravity_w: Vector3::new(0.0, 0.0, -9.81),
            R_w_g: UnitQuaternion::identity(),
            gyro_bias: Vector3::zeros(),
            accel_bias: Vector3::zeros(),
            keyframes: Vec::new(),
            velocities: Vec::new(),
            timestamp: 0.0,
            acceleration_excitation: 1.0,
        })
    };
    for (refinement, next) in [(0, Some(0)), (1, Some(1)), (2, None)] {
        inertial.per_map.status = aligned(refinement);
        assert_eq!(
            inertial.next_refinement(),
            next,
            "after refinement {refinement}"
        );
    }
}

#[test]
fn scaling_a_pose_scales_the_camera_centre() {
    let T_c_w = Isometry3::new(Vector3::new(1.0, -2.0, 0.5), Vector3::new(0.3, 0.1, -0.2));
    let scaled = scale_translation(&T_c_w, 2.5);
    let centre = |T: &Isometry3<f64>| T.inverse().translation.vector;
    assert!((centre(&scaled) - centre(&T_c_w) * 2.5).norm() < 1e-12);
}
