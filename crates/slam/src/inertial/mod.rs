//! Visual-inertial initialisation: IMU input, preintegration between keyframes and the
//! camera-IMU alignment (MATLAB `NumPosesThreshold` / `AlignmentFraction`, ORB-SLAM3's
//! first inertial initialisation without its inertial BA).
//!
//! # Frames and units
//!
//! IMU samples are in the body (IMU) frame `b`: gyro rad/s, accelerometer m/s^2 (specific
//! force, a resting IMU reads +9.81 upwards), timestamps in seconds on the camera clock
//! (see [`ferroslam_imu`]). `T_b_c` is the camera pose in the body frame (EuRoC `T_BS` of
//! cam0), metres.
//!
//! # What the alignment changes
//!
//! Once the map holds [`InertialConfig::num_poses_threshold`] keyframes, the most recent
//! [`InertialConfig::alignment_fraction`] of them (by timestamp) are aligned with the IMU
//! preintegrated between them ([`ferroslam_imu::alignment::align`]): gyro bias, gravity
//! direction, scale and keyframe velocities. For a monocular map the map is then RESCALED
//! in place to metres (keyframe translations, points, the frame trajectory and the motion
//! model); maps with depth keep their scale (already metric: the alignment fixes it to 1,
//! as ORB-SLAM3's stereo-inertial initialisation does, so a static start aligns too).
//! The world is NOT rotated: gravity is stored as `gravity_w` and `R_w_g` (gravity-aligned
//! frame, z up, into the map's world), so poses already handed out stay valid.
//! Until then a keyframe is inserted at least every `init_keyframe_interval_s`
//! ([`InertialTuning`], ORB-SLAM3). A failed attempt (no excitation yet, missing IMU data)
//! is retried at the next keyframe.
//!
//! # Refinements
//!
//! As ORB-SLAM3 re-initialises at ~5 s and ~15 s, the alignment is re-run when the keyframes
//! since the first alignment span `refinement_spans_s`, over the keyframes (live or
//! culled) of the newest span, at the poses the map holds now and with the biases found so
//! far as priors. The scale found is relative to the current map, so a monocular map is
//! multiplied by it again (the trajectory stays continuous). A failed refinement keeps the
//! previous alignment and is retried at the next keyframe. After the last refinement the
//! keyframes' velocities and biases are refined by local inertial BA
//! ([`crate::local_inertial_ba`]).

use std::collections::BTreeMap;

use ferroslam_imu::alignment::{align, AlignmentConfig, GRAVITY_M_S2};
use ferroslam_imu::{check_stream, check_units, BiasWalkFactor, ImuError, InertialFactor};
use ferroslam_map::{KeyFrameId, Map, MapError};
use nalgebra::{Isometry3, UnitQuaternion, Vector3};

use crate::config::{InertialTuning, GRAVITY_RANGE_M_S2, MAX_IMU_TIME_OFFSET_S};
use crate::error::SlamError;
use crate::local_inertial_ba::InertialWindow;

pub use ferroslam_imu::{Bias, ImuMeasurement as ImuSample, ImuParams, Preintegrated};

/// Fewest keyframes an alignment runs on: the gyro bias needs two rotations between
/// keyframes and the gravity direction, scale and velocities a third position.
pub const MIN_ALIGNED_KEYFRAMES: usize = 3;
/// Slack of `ceil(alignment_fraction * n)` so that a fraction that is `k / n` up to
/// rounding (0.28 of 25 computes as 7.000000000000001) aligns `k` keyframes, not `k + 1`.
const WINDOW_ROUNDING_SLACK: f64 = 1e-9;

/// IMU setup of a visual-inertial system.
#[derive(Clone, Debug, PartialEq)]
pub struct InertialConfig {
    /// Noise densities and random walks (EuRoC `imu0/sensor.yaml`).
    pub params: ImuParams,
    /// Camera pose in the body (IMU) frame, metres.
    pub T_b_c: Isometry3<f64>,
    /// Keyframes created in the map (culled ones included) before the alignment is
    /// attempted (MATLAB `NumPosesThreshold`).
    pub num_poses_threshold: usize,
    /// Fraction of the keyframes, the most recent ones, the alignment uses (MATLAB
    /// `AlignmentFraction`), in (0, 1].
    pub alignment_fraction: f64,
    /// Magnitude of gravity, m/s^2.
    pub gravity_magnitude: f64,
    /// Constant offset of the IMU clock to the camera clock, seconds: a sample stamped
    /// `t_imu` was measured at camera time `t_imu - imu_time_offset_s` (Kalibr's
    /// `timeshift_cam_imu`, `t_imu = t_cam + shift`). Samples are moved to the camera clock as
    /// they are added.
    pub imu_time_offset_s: f64,
}

impl InertialConfig {
    /// The defaults, the only place they are written (the bindings, `set_imu` and the docs
    /// read them from here): 20 keyframes (MATLAB's `NumPosesThreshold`), the newest 0.9 of
    /// them (`AlignmentFraction`), |g| = [`GRAVITY_M_S2`], clocks in step.
    pub fn new(params: ImuParams, T_b_c: Isometry3<f64>) -> Self {
        Self {
            params,
            T_b_c,
            num_poses_threshold: 20,
            alignment_fraction: 0.9,
            gravity_magnitude: GRAVITY_M_S2,
            imu_time_offset_s: 0.0,
        }
    }

    /// Checks the values; `InvalidConfig` names the first bad one.
    pub fn validate(&self) -> Result<(), SlamError> {
        let bad = |m: String| Err(SlamError::InvalidConfig(m));
        if let Err(e) = self.params.validate() {
            return bad(format!("imu: {e}"));
        }
        let pose = &self.T_b_c;
        if !(pose.translation.vector.iter().all(|v| v.is_finite())
            && pose.rotation.coords.iter().all(|v| v.is_finite()))
        {
            return bad("imu: T_b_c must be finite".into());
        }
        if self.num_poses_threshold < MIN_ALIGNED_KEYFRAMES {
            return bad(format!(
                "imu: num_poses_threshold = {} must be at least {MIN_ALIGNED_KEYFRAMES}",
                self.num_poses_threshold
            ));
        }
        if !(self.alignment_fraction > 0.0 && self.alignment_fraction <= 1.0) {
            return bad(format!(
                "imu: alignment_fraction = {} must be in (0, 1]",
                self.alignment_fraction
            ));
        }
        if self.window(self.num_poses_threshold) < MIN_ALIGNED_KEYFRAMES {
            return bad(format!(
                "imu: alignment_fraction {} of num_poses_threshold {} keyframes leaves fewer \
                 than {MIN_ALIGNED_KEYFRAMES} to align",
                self.alignment_fraction, self.num_poses_threshold
            ));
        }
        let (g_min, g_max) = GRAVITY_RANGE_M_S2;
        if !(g_min..=g_max).contains(&self.gravity_magnitude) {
            return bad(format!(
                "imu: gravity_magnitude = {} must be in [{g_min}, {g_max}] m/s^2",
                self.gravity_magnitude
            ));
        }
        if self.imu_time_offset_s.is_nan() || self.imu_time_offset_s.abs() > MAX_IMU_TIME_OFFSET_S {
            return bad(format!(
                "imu: imu_time_offset_s = {} must be in [-{MAX_IMU_TIME_OFFSET_S}, \
                 {MAX_IMU_TIME_OFFSET_S}] s",
                self.imu_time_offset_s
            ));
        }
        Ok(())
    }

    /// Keyframes aligned out of `n`: `ceil(alignment_fraction * n)`.
    fn window(&self, n: usize) -> usize {
        ((self.alignment_fraction * n as f64 - WINDOW_ROUNDING_SLACK).ceil() as usize).min(n)
    }
}

/// A successful camera-IMU alignment, in the map's world frame `w` after any rescaling.
#[derive(Clone, Debug, PartialEq)]
pub struct InertialAlignment {
    /// Metric length of one unit of the map as it was before this alignment (monocular: the
    /// factor the map was multiplied by, relative for a refinement; with depth: a check,
    /// ideally 1).
    pub scale: f64,
    /// 0 for the first alignment, `k` for the refinement after `refinement_spans_s[k - 1]`
    /// ([`InertialTuning`]).
    pub refinement: usize,
    /// Whether the map was rescaled by [`scale`](Self::scale) (monocular only).
    pub map_rescaled: bool,
    /// Gravity in `w`, m/s^2.
    pub gravity_w: Vector3<f64>,
    /// Gravity-aligned frame `g` (z up, no yaw) into `w`:
    /// `gravity_w = R_w_g * (0, 0, -|g|)`.
    pub R_w_g: UnitQuaternion<f64>,
    /// Gyro bias, rad/s.
    pub gyro_bias: Vector3<f64>,
    /// Accelerometer bias, m/s^2 (the previous alignment's, zero at first, when the window
    /// rotates too little to estimate it).
    pub accel_bias: Vector3<f64>,
    /// The aligned keyframes `(id, timestamp)`, oldest first (some may be culled since).
    pub keyframes: Vec<(KeyFrameId, f64)>,
    /// Body velocity in `w`, m/s, at each of [`keyframes`](Self::keyframes).
    pub velocities: Vec<Vector3<f64>>,
    /// Timestamp of the newest aligned keyframe, seconds.
    pub timestamp: f64,
    /// RMS variation of the world-frame specific force over the window, m/s^2.
    pub acceleration_excitation: f64,
}

/// Where the camera-IMU alignment of the current map stands.
#[derive(Clone, Debug, PartialEq)]
pub enum AlignmentStatus {
    /// Fewer keyframes than `num_poses_threshold` so far.
    Waiting {
        /// Keyframes created in the map so far (culled ones included).
        keyframes: usize,
        /// Keyframes needed.
        needed: usize,
    },
    /// The last attempt failed (retried at the next keyframe).
    Failed {
        /// Keyframes in the attempted window.
        keyframes: usize,
        /// Why, in words.
        reason: String,
    },
    /// Aligned (the map is metric and gravity known).
    Aligned(InertialAlignment),
}

/// Preintegrated IMU of a keyframe since the previous live keyframe.
#[derive(Clone, Debug)]
struct KeyFrameImu {
    previous: KeyFrameId,
    preintegrated: Preintegrated,
}

/// IMU state of a keyframe since the alignment: body velocity in the world (m/s), biases.
#[derive(Clone, Copy, Debug)]
struct KeyFrameState {
    velocity: Vector3<f64>,
    bias: Bias,
}

/// A keyframe of the history, as last seen live.
#[allow(non_snake_case)]
#[derive(Clone, Copy, Debug)]
struct Seen {
    id: KeyFrameId,
    timestamp: f64,
    /// Its pose when last seen live, in the map of that time.
    T_c_w: Isometry3<f64>,
    /// [`Inertial::map_scale`] when last seen live.
    map_scale: f64,
}

/// The inertial state of a system: buffered samples, per-keyframe preintegrations, status.
#[derive(Clone, Debug)]
pub(crate) struct Inertial {
    config: InertialConfig,
    tuning: InertialTuning,
    /// The map is metric (stereo, RGB-D): the alignment keeps its scale.
    known_scale: bool,
    samples: Vec<ImuSample>,
    /// The current map's part.
    per_map: InertialMapState,
    /// Tracking resumed in a stored map: its next keyframe has no IMU link to the ones
    /// before and takes its state from [`Self::resume`].
    resuming: bool,
}

/// What of an [`Inertial`] belongs to one map, kept with it in the atlas: preintegrations,
/// history, scale, alignment and keyframe states (the samples and settings are the system's).
#[derive(Clone, Debug)]
pub(crate) struct InertialMapState {
    keyframes: BTreeMap<KeyFrameId, KeyFrameImu>,
    /// Every keyframe of the map, culled ones too, by id, until the last refinement (since
    /// the first alignment once aligned).
    history: Vec<Seen>,
    /// Product of the rescalings applied to the map (1 with depth).
    map_scale: f64,
    /// Timestamp of the newest keyframe of the first alignment.
    first_aligned_s: Option<f64>,
    /// IMU state of the live keyframes once aligned (set by the alignment, predicted for a
    /// new keyframe, refined by local inertial BA).
    states: BTreeMap<KeyFrameId, KeyFrameState>,
    status: AlignmentStatus,
}

impl InertialMapState {
    /// A new map's: nothing aligned, `needed` keyframes to wait for.
    fn new(needed: usize) -> Self {
        Self {
            keyframes: BTreeMap::new(),
            history: Vec::new(),
            map_scale: 1.0,
            first_aligned_s: None,
            states: BTreeMap::new(),
            status: AlignmentStatus::Waiting {
                keyframes: 0,
                needed,
            },
        }
    }

    /// Whether the map was aligned with the IMU (gravity known in its world).
    pub(crate) fn is_aligned(&self) -> bool {
        matches!(self.status, AlignmentStatus::Aligned(_))
    }
}

impl Inertial {
    /// `known_scale` for a metric map (stereo, RGB-D); `tuning` is the system's (validated
    /// with it).
    pub(crate) fn new(
        config: InertialConfig,
        tuning: InertialTuning,
        known_scale: bool,
    ) -> Result<Self, SlamError> {
        config.validate()?;
        let needed = config.num_poses_threshold;
        Ok(Self {
            config,
            tuning,
            known_scale,
            samples: Vec::new(),
            per_map: InertialMapState::new(needed),
            resuming: false,
        })
    }

    /// Takes the current map's part (the map goes to the atlas), leaving a new map's.
    pub(crate) fn take_map_state(&mut self) -> InertialMapState {
        let fresh = InertialMapState::new(self.config.num_poses_threshold);
        self.resuming = false;
        std::mem::replace(&mut self.per_map, fresh)
    }

    /// Makes a stored map's part current again (see [`Self::take_map_state`]).
    pub(crate) fn restore_map_state(&mut self, state: InertialMapState) {
        self.per_map = state;
        self.resuming = false;
    }

    /// Tracking resumed at `timestamp_s` in the map restored last. The IMU before that spans
    /// the time the map was lost (seconds, nothing to tie it to): no keyframe links across
    /// it, so the samples before are dropped, and the next keyframe's state comes from
    /// [`Self::resume`].
    pub(crate) fn resume_at(&mut self, timestamp_s: f64) {
        self.drop_samples_before(timestamp_s);
        self.resuming = self.is_aligned();
    }

    /// Whether the current map waits for [`Self::resume`].
    pub(crate) fn resuming(&self) -> bool {
        self.resuming
    }

    /// Gives keyframe `kf`, the first since tracking resumed in this map, its IMU state:
    /// `velocity_w` (the body's, in the world, m/s, as tracking measured it with the IMU)
    /// and the map's newest biases; the keyframes after it link to it by IMU.
    pub(crate) fn resume(&mut self, kf: KeyFrameId, velocity_w: Vector3<f64>) {
        let bias = self.bias();
        self.per_map.states.insert(
            kf,
            KeyFrameState {
                velocity: velocity_w,
                bias,
            },
        );
        self.resuming = false;
    }

    pub(crate) fn config(&self) -> &InertialConfig {
        &self.config
    }

    pub(crate) fn tuning(&self) -> &InertialTuning {
        &self.tuning
    }

    pub(crate) fn status(&self) -> &AlignmentStatus {
        &self.per_map.status
    }

    /// Gravity in the map's world, m/s^2, once aligned.
    pub(crate) fn gravity_w(&self) -> Option<Vector3<f64>> {
        match &self.per_map.status {
            AlignmentStatus::Aligned(a) => Some(a.gravity_w),
            _ => None,
        }
    }

    /// The buffered IMU preintegrated from `t0_s` to `t1_s` at the newest keyframe's biases;
    /// `None` if the samples do not cover the interval.
    pub(crate) fn preintegrate(&self, t0_s: f64, t1_s: f64) -> Option<Preintegrated> {
        Preintegrated::between(&self.samples, t0_s, t1_s, self.bias(), &self.config.params).ok()
    }

    /// Whether the camera-IMU alignment has succeeded for the current map.
    pub(crate) fn is_aligned(&self) -> bool {
        self.per_map.is_aligned()
    }

    /// Appends samples after the buffered ones; all or nothing.
    ///
    /// # Errors
    /// `InvalidInput` for a non-finite value, timestamps not strictly increasing (within the
    /// batch or against the last sample added) or units that look like deg/s or g.
    pub(crate) fn add(&mut self, samples: &[ImuSample]) -> Result<(), SlamError> {
        let invalid = |e: ImuError| SlamError::InvalidInput(format!("add_imu: {e}"));
        let offset_s = self.config.imu_time_offset_s;
        let shifted: Vec<ImuSample>;
        let samples = if offset_s == 0.0 {
            samples
        } else {
            shifted = samples
                .iter()
                .map(|s| ImuSample {
                    t_s: s.t_s - offset_s,
                    ..*s
                })
                .collect();
            &shifted
        };
        check_stream(samples).map_err(invalid)?;
        check_units(samples).map_err(invalid)?;
        if let (Some(last), Some(first)) = (self.samples.last(), samples.first()) {
            if first.t_s <= last.t_s {
                return Err(SlamError::InvalidInput(format!(
                    "add_imu: sample 0 at t = {} s is not after the last sample added, at {} s",
                    first.t_s, last.t_s
                )));
            }
        }
        self.samples.extend_from_slice(samples);
        Ok(())
    }

    /// Forgets the map's keyframes and alignment (after a map reset); samples stay.
    pub(crate) fn clear_map(&mut self) {
        self.take_map_state();
    }

    /// Preintegrated IMU of `kf` since the previous live keyframe, if the samples cover it.
    pub(crate) fn preintegrated(&self, kf: KeyFrameId) -> Option<(KeyFrameId, &Preintegrated)> {
        self.per_map
            .keyframes
            .get(&kf)
            .map(|k| (k.previous, &k.preintegrated))
    }

    /// Brings the per-keyframe preintegrations up to date with the live keyframes (new
    /// ones, and the successors of culled ones, integrate from the previous live keyframe),
    /// records new keyframes in the history (and how live ones look now) and drops samples
    /// no interval needs any more.
    pub(crate) fn sync(&mut self, map: &Map) {
        let live = live_keyframes(map);
        let bias = self.bias();
        let mut synced = BTreeMap::new();
        for pair in live.windows(2) {
            let ((a, ta), (b, tb)) = (pair[0], pair[1]);
            let kept = self
                .per_map
                .keyframes
                .remove(&b)
                .filter(|k| k.previous == a);
            let entry = kept.or_else(|| {
                Preintegrated::between(&self.samples, ta, tb, bias, &self.config.params)
                    .ok()
                    .map(|preintegrated| KeyFrameImu {
                        previous: a,
                        preintegrated,
                    })
            });
            if let Some(entry) = entry {
                synced.insert(b, entry);
            }
        }
        self.per_map.keyframes = synced;
        if self.next_refinement().is_some() {
            let last = self.per_map.history.last().map(|k| k.id);
            let mut new: Vec<_> = live.iter().filter(|&&(id, _)| Some(id) > last).collect();
            new.sort_by_key(|&&(id, _)| id);
            self.per_map
                .history
                .extend(new.into_iter().map(|&(id, timestamp)| Seen {
                    id,
                    timestamp,
                    T_c_w: Isometry3::identity(),
                    map_scale: f64::NAN,
                }));
            for seen in &mut self.per_map.history {
                if let Some(kf) = map.keyframe(seen.id) {
                    seen.T_c_w = *kf.T_c_w();
                    seen.map_scale = self.per_map.map_scale;
                }
            }
        }
        let oldest = self.per_map.history.first().map(|k| k.timestamp);
        if let Some(t0) = oldest
            .into_iter()
            .chain(live.first().map(|&(_, t)| t))
            .reduce(f64::min)
        {
            self.drop_samples_before(t0);
        }
    }

    /// Drops the samples before `t_s` but the one at or before it, which brackets an
    /// interval starting at `t_s`.
    fn drop_samples_before(&mut self, t_s: f64) {
        let first = self
            .samples
            .partition_point(|s| s.t_s <= t_s)
            .saturating_sub(1);
        self.samples.drain(..first);
    }

    /// The newest keyframe's biases (local inertial BA refines them), else those of the
    /// current alignment (zero before).
    fn bias(&self) -> Bias {
        if let Some((_, state)) = self.per_map.states.last_key_value() {
            return state.bias;
        }
        match &self.per_map.status {
            AlignmentStatus::Aligned(a) => Bias::new(a.gyro_bias, a.accel_bias),
            _ => Bias::default(),
        }
    }

    /// The window of the newest live keyframes for local inertial BA (see
    /// [`crate::local_inertial_ba`]), once aligned: syncs the preintegrations and gives a new
    /// keyframe the state the IMU predicts from the previous one. `None` before the
    /// alignment or with fewer than two keyframes joined by IMU.
    #[allow(non_snake_case)]
    pub(crate) fn window(&mut self, map: &Map) -> Option<InertialWindow> {
        let gravity_w = self.gravity_w()?;
        // Not before the last refinement: the linear alignment re-estimates gravity and the
        // scale from the visual poses, which inertial BA under the earlier, cruder gravity
        // would bend (a monocular map's scale error grew several times).
        if self.next_refinement().is_some() {
            return None;
        }
        self.sync(map);
        let live = live_keyframes(map);
        self.per_map
            .states
            .retain(|id, _| map.keyframe(*id).is_some());
        let T_c_b = self.config.T_b_c.inverse();
        let R_w_b = |id: KeyFrameId| map.keyframe(id).map(|k| (k.T_w_c() * T_c_b).rotation);
        for &(id, _) in &live {
            let (Some(imu), None) = (
                self.per_map.keyframes.get(&id),
                self.per_map.states.get(&id),
            ) else {
                continue;
            };
            let (Some(previous), Some(R_prev)) =
                (self.per_map.states.get(&imu.previous), R_w_b(imu.previous))
            else {
                continue;
            };
            let delta = imu.preintegrated.corrected(&previous.bias);
            let state = KeyFrameState {
                velocity: previous.velocity + gravity_w * delta.dt + R_prev * delta.delta_v,
                bias: previous.bias,
            };
            self.per_map.states.insert(id, state);
        }
        let mut ids = vec![live.last()?.0];
        while ids.len() < self.tuning.window_keyframes {
            let oldest = *ids.last()?;
            match self.per_map.keyframes.get(&oldest) {
                Some(imu) if self.per_map.states.contains_key(&imu.previous) => {
                    ids.push(imu.previous)
                }
                _ => break,
            }
        }
        if ids.len() < 2 || !self.per_map.states.contains_key(&ids[0]) {
            return None;
        }
        ids.reverse();
        let mut edges = Vec::with_capacity(ids.len() - 1);
        for &id in &ids[1..] {
            let pre = &self.per_map.keyframes.get(&id)?.preintegrated;
            let factor = InertialFactor::new(pre.clone(), gravity_w).ok()?;
            let walk = BiasWalkFactor::new(&self.config.params, pre.dt()).ok()?;
            edges.push((factor, walk));
        }
        Some(InertialWindow {
            T_b_c: self.config.T_b_c,
            velocities: ids
                .iter()
                .map(|id| self.per_map.states[id].velocity)
                .collect(),
            biases: ids.iter().map(|id| self.per_map.states[id].bias).collect(),
            keyframes: ids,
            edges,
        })
    }

    /// The newest keyframe's IMU state `(id, body velocity in the world m/s, biases)`, once
    /// aligned.
    pub(crate) fn newest_state(&self) -> Option<(KeyFrameId, Vector3<f64>, Bias)> {
        let (id, state) = self.per_map.states.last_key_value()?;
        Some((*id, state.velocity, state.bias))
    }

    /// Keeps the states local inertial BA found for `window`'s keyframes.
    pub(crate) fn store(&mut self, window: &InertialWindow) {
        for (k, id) in window.keyframes.iter().enumerate() {
            self.per_map.states.insert(
                *id,
                KeyFrameState {
                    velocity: window.velocities[k],
                    bias: window.biases[k],
                },
            );
        }
    }

    /// Index into `refinement_spans_s` of the next alignment (0 before the first one,
    /// which [`InertialAlignment::refinement`] counts as 0 too), `None` when all are done.
    fn next_refinement(&self) -> Option<usize> {
        match &self.per_map.status {
            AlignmentStatus::Aligned(a) if a.refinement < self.tuning.refinement_spans_s.len() => {
                Some(a.refinement)
            }
            AlignmentStatus::Aligned(_) => None,
            _ => Some(0),
        }
    }

    /// Syncs the preintegrations, then attempts the alignment when due (enough keyframes
    /// before the first one, a refinement span since it) and records the outcome; returns
    /// the new alignment when one succeeded. The map is not changed here.
    ///
    /// Keyframes count from the map's start, culled ones included (local mapping culls
    /// redundant keyframes, most of them on a slow flight, and would otherwise starve the
    /// alignment): a culled keyframe's pose is the one the map keeps for it,
    /// relative to the keyframe that adopted it.
    pub(crate) fn try_align(&mut self, map: &Map) -> Option<InertialAlignment> {
        self.sync(map);
        if let (AlignmentStatus::Aligned(a), Some(t0)) =
            (&self.per_map.status, self.per_map.first_aligned_s)
        {
            let span = *self.tuning.refinement_spans_s.get(a.refinement)?;
            let newest = self.per_map.history.last()?.timestamp;
            if newest - t0 < span {
                return None;
            }
            let start = self
                .per_map
                .history
                .partition_point(|k| k.timestamp < newest - span);
            let refinement = a.refinement + 1;
            // A failed refinement keeps the current alignment and retries at the next keyframe.
            return self
                .align_window(map, &self.per_map.history[start..])
                .ok()
                .map(|a| InertialAlignment { refinement, ..a });
        }
        let needed = self.config.num_poses_threshold;
        let n = self.per_map.history.len();
        if n < needed {
            self.per_map.status = AlignmentStatus::Waiting {
                keyframes: n,
                needed,
            };
            return None;
        }
        let window = &self.per_map.history[n - self.config.window(n)..];
        match self.align_window(map, window) {
            Ok(alignment) => Some(alignment),
            Err(reason) => {
                self.per_map.status = AlignmentStatus::Failed {
                    keyframes: window.len(),
                    reason,
                };
                None
            }
        }
    }

    /// Aligns the keyframes of `window` at the poses the map holds now. A keyframe culled
    /// before the last rescaling is placed at its last live pose, rescaled: the map keeps a
    /// culled keyframe's offset to its anchor unscaled.
    fn align_window(&self, map: &Map, window: &[Seen]) -> Result<InertialAlignment, String> {
        let mut poses = Vec::with_capacity(window.len());
        for seen in window {
            let T_c_w =
                if map.keyframe(seen.id).is_some() || seen.map_scale == self.per_map.map_scale {
                    map.resolve_keyframe_pose(seen.id)
                        .ok_or_else(|| format!("keyframe {} has no pose", seen.id.0))?
                } else {
                    scale_translation(&seen.T_c_w, self.per_map.map_scale / seen.map_scale)
                };
            poses.push(T_c_w.inverse());
        }
        let prior = self.bias();
        let mut pres = Vec::with_capacity(window.len());
        for (k, pair) in window.windows(2).enumerate() {
            let (a, b) = (pair[0], pair[1]);
            match Preintegrated::between(
                &self.samples,
                a.timestamp,
                b.timestamp,
                prior,
                &self.config.params,
            ) {
                Ok(pre) => pres.push(pre),
                // IMU missing in between: the keyframes after it may still be enough.
                Err(e) => {
                    let after = &window[k + 1..];
                    if after.len() >= self.config.window(self.config.num_poses_threshold) {
                        return self.align_window(map, after);
                    }
                    return Err(format!(
                        "IMU between keyframes {} and {}: {e} (call add_imu with the samples \
                         up to each frame before tracking it; the alignment waits for {} \
                         keyframes with IMU throughout)",
                        a.id.0,
                        b.id.0,
                        self.config.window(self.config.num_poses_threshold)
                    ));
                }
            }
        }
        let config = AlignmentConfig {
            gravity_magnitude: self.config.gravity_magnitude,
            min_keyframes: MIN_ALIGNED_KEYFRAMES,
            // `align` estimates it only once the window rotates enough to tell it from
            // gravity (on EuRoC, at the refinements rather than the first alignment).
            estimate_accel_bias: true,
            known_scale: self.known_scale,
            ..AlignmentConfig::default()
        };
        let out = align(&poses, &self.config.T_b_c, &pres, &config).map_err(|e| e.to_string())?;
        check_plausible(&out, &self.tuning)?;
        Ok(InertialAlignment {
            scale: out.scale,
            refinement: 0,
            map_rescaled: false,
            gravity_w: out.gravity_w,
            R_w_g: out.R_w_gravity,
            gyro_bias: out.gyro_bias,
            accel_bias: out.accel_bias,
            keyframes: window.iter().map(|k| (k.id, k.timestamp)).collect(),
            velocities: out.velocities,
            timestamp: window.last().map_or(f64::NAN, |k| k.timestamp),
            acceleration_excitation: out.acceleration_excitation,
        })
    }

    /// Records a successful alignment (after the system applied it), keeps the history
    /// the refinements still need and reintegrates the keyframes' IMU at the new biases.
    pub(crate) fn accept(&mut self, alignment: InertialAlignment, map: &Map) {
        if alignment.map_rescaled {
            self.per_map.map_scale *= alignment.scale;
        }
        let t0 = *self
            .per_map
            .first_aligned_s
            .get_or_insert(alignment.timestamp);
        let bias = Bias::new(alignment.gyro_bias, alignment.accel_bias);
        self.per_map.states = alignment
            .keyframes
            .iter()
            .zip(&alignment.velocities)
            .map(|(&(id, _), &velocity)| (id, KeyFrameState { velocity, bias }))
            .collect();
        self.per_map.status = AlignmentStatus::Aligned(alignment);
        self.per_map.keyframes.clear();
        if self.next_refinement().is_some() {
            self.per_map.history.retain(|k| k.timestamp >= t0);
        } else {
            self.per_map.history.clear();
        }
        self.sync(map);
    }
}

/// Refuses an alignment whose biases or velocities (m/s) no real IMU and camera produce
/// (the `max_*` bounds of `tuning`), naming the sensor to check.
fn check_plausible(
    out: &ferroslam_imu::alignment::Alignment,
    tuning: &InertialTuning,
) -> Result<(), String> {
    let gyro = out.gyro_bias.norm();
    let max_gyro = tuning.max_gyro_bias_rad_s;
    if gyro > max_gyro {
        return Err(format!(
            "gyroscope: matching the rotation vision sees needs a gyro bias of {gyro:.2} rad/s, \
             beyond any MEMS gyro's ({max_gyro} rad/s): check the gyroscope's unit \
             (deg/s instead of rad/s?), its axes (T_b_c) and imu_time_offset_s"
        ));
    }
    let accel = out.accel_bias.norm();
    let max_accel = tuning.max_accel_bias_m_s2;
    if accel > max_accel {
        return Err(format!(
            "accelerometer: the alignment needs an accelerometer bias of {accel:.2} m/s^2, \
             beyond any MEMS accelerometer's ({max_accel} m/s^2): check its unit \
             (m/s^2) and axes (T_b_c)"
        ));
    }
    let speed = out.velocities.iter().map(|v| v.norm()).fold(0.0, f64::max);
    let max_speed = tuning.max_speed_m_s;
    if speed > max_speed {
        return Err(format!(
            "accelerometer: the alignment puts the camera at {speed:.0} m/s, beyond \
             {max_speed} m/s: check the accelerometer's unit (m/s^2), the IMU timestamps \
             and imu_time_offset_s"
        ));
    }
    Ok(())
}

/// Live keyframes `(id, timestamp)` in time order.
fn live_keyframes(map: &Map) -> Vec<(KeyFrameId, f64)> {
    let mut live: Vec<_> = map.keyframes().map(|k| (k.id(), k.timestamp())).collect();
    live.sort_by(|a, b| a.1.total_cmp(&b.1));
    live
}

/// `T` with its translation multiplied by `s`: the same pose in a world scaled by `s`
/// (for `T_c_w` and `T_w_c` alike, the rotation being unchanged).
pub(crate) fn scale_translation(T: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
    let mut scaled = *T;
    scaled.translation.vector *= s;
    scaled
}

/// Multiplies every keyframe position and point of `map` by `s` about the world origin and
/// refreshes the points' normals and scale-invariance distances.
///
/// # Errors
/// A [`MapError`] only on an internal inconsistency (ids listed by the map itself).
pub(crate) fn rescale_map(map: &mut Map, s: f64) -> Result<(), MapError> {
    for id in map.keyframe_ids() {
        if let Some(T_c_w) = map.keyframe(id).map(|k| scale_translation(k.T_c_w(), s)) {
            map.set_keyframe_pose(id, T_c_w)?;
        }
    }
    for id in map.map_point_ids() {
        if let Some(p) = map.map_point(id).map(|p| p.position() * s) {
            map.set_map_point_position(id, p)?;
            map.update_normal_and_depth(id)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
