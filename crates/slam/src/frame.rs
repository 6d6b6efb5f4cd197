//! A tracked image: its features (undistorted, with depth) and their map associations.

use ferroslam_features::{
    match_stereo, search_by_projection, search_by_projection_with, Descriptor, ImageBounds,
    Keypoint, MatchOptions, ProjectionQuery, ScalePyramid, StereoView,
};
use ferroslam_geometry::camera::CameraModel;
use ferroslam_geometry::rolling_shutter::motion_over;
use ferroslam_map::{FrameFeatures, MapPointId, Rgb};
use nalgebra::{Isometry3, Point3, Vector2, Vector3};

use crate::context::{CameraView, Context, InputShape};
use crate::error::SlamError;

/// One input frame during tracking.
///
/// `map_points[i]` is the map point matched to keypoint `i`; `vo_points[i]` is a temporary
/// "visual odometry" point (ORB-SLAM `UpdateLastFrame`): a depth-backed world position that
/// helps the motion model but is never inserted into the map.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Index of the frame in the input stream (0-based).
    pub index: usize,
    /// Capture time, seconds.
    pub timestamp: f64,
    /// Undistorted keypoints, descriptors, depth and virtual right coordinates.
    pub features: FrameFeatures,
    /// Map point matched to each keypoint.
    pub map_points: Vec<Option<MapPointId>>,
    /// Temporary depth points of the previous frame used by the motion model, world frame.
    pub vo_points: Vec<Option<Vector3<f64>>>,
    /// Whether the association of keypoint `i` was rejected by pose optimisation.
    pub outlier: Vec<bool>,
    /// Camera pose, world to camera.
    pub T_c_w: Isometry3<f64>,
    /// Unrectified pairs matched at keyframes only: what matching needs, until the frame is
    /// matched ([`Frame::match_pair`]) or dropped.
    pub unmatched_pairs: Vec<UnmatchedPair>,
}

/// A camera's raw keypoints and its pair partner's features, kept on a frame whose pairs are
/// matched only if it starts the map or becomes a keyframe.
#[derive(Clone, Debug)]
pub struct UnmatchedPair {
    /// The rig camera whose keypoints the pair gives depth (0, the first, or a further
    /// camera with a partner).
    pub camera: usize,
    /// The camera's keypoints in raw pixels.
    pub left_raw: Vec<Keypoint>,
    /// The partner's keypoints, raw pixels.
    pub right_keypoints: Vec<Keypoint>,
    /// The partner's descriptors.
    pub right_descriptors: Vec<Descriptor>,
}

/// Raw per-frame input of an RGB-D camera: distorted keypoints with their sensor depth.
pub struct RgbdInput<'a> {
    /// Capture time, seconds.
    pub timestamp: f64,
    /// Keypoints in raw (distorted) pixel coordinates.
    pub keypoints: &'a [Keypoint],
    /// 256-bit ORB descriptors, one per keypoint.
    pub descriptors: &'a [Descriptor],
    /// Depth at each keypoint in metres; 0, negative or NaN means no measurement.
    pub depth_m: &'a [f32],
    /// Colour of each keypoint, if known: the map points it creates keep it.
    pub colors: Option<&'a [Rgb]>,
}

impl RgbdInput<'_> {
    /// Rejects inconsistent lengths, non-finite coordinates and octaves beyond the pyramid.
    pub fn validate(&self, shape: &InputShape) -> Result<(), SlamError> {
        let (keypoints, descriptors) = (self.keypoints, self.descriptors);
        validate_features(self.timestamp, keypoints, descriptors, self.colors, shape)?;
        if self.depth_m.len() != self.keypoints.len() {
            return Err(SlamError::InvalidInput(format!(
                "got {} keypoints and {} depths: lengths must match",
                self.keypoints.len(),
                self.depth_m.len()
            )));
        }
        Ok(())
    }
}

/// Raw per-frame input of a monocular camera: distorted keypoints and their descriptors.
pub struct MonoInput<'a> {
    /// Capture time, seconds.
    pub timestamp: f64,
    /// Keypoints in raw (distorted) pixel coordinates.
    pub keypoints: &'a [Keypoint],
    /// 256-bit ORB descriptors, one per keypoint.
    pub descriptors: &'a [Descriptor],
    /// Colour of each keypoint, if known: the map points it creates keep it.
    pub colors: Option<&'a [Rgb]>,
}

impl MonoInput<'_> {
    /// Rejects inconsistent lengths, non-finite coordinates and octaves beyond the pyramid.
    pub fn validate(&self, shape: &InputShape) -> Result<(), SlamError> {
        let (keypoints, descriptors) = (self.keypoints, self.descriptors);
        validate_features(self.timestamp, keypoints, descriptors, self.colors, shape)
    }
}

/// Raw per-frame input of a rectified stereo camera: features and image pyramids of both
/// images (keypoints in rectified pixels; the left image is the tracked frame).
pub struct StereoInput<'a> {
    /// Capture time of the pair, seconds.
    pub timestamp: f64,
    /// Left image: keypoints, descriptors, pyramid.
    pub left: StereoView<'a>,
    /// Right image: keypoints, descriptors, pyramid.
    pub right: StereoView<'a>,
    /// Colour of each left keypoint, if known: the map points it creates keep it.
    pub colors: Option<&'a [Rgb]>,
}

impl StereoInput<'_> {
    /// Rejects inconsistent lengths, non-finite coordinates, octaves beyond the pyramid,
    /// missing pyramid levels and left/right images of different sizes.
    pub fn validate(&self, shape: &InputShape) -> Result<(), SlamError> {
        let sides = [
            ("left", &self.left, self.colors),
            ("right", &self.right, None),
        ];
        for (side, view, colors) in sides {
            validate_features(
                self.timestamp,
                view.keypoints,
                view.descriptors,
                colors,
                shape,
            )
            .map_err(|e| SlamError::InvalidInput(format!("{side} image: {e}")))?;
            let top = view.keypoints.iter().map(|k| k.octave as usize + 1).max();
            if view.levels.len() < top.unwrap_or(1) {
                return Err(SlamError::InvalidInput(format!(
                    "{side} image: keypoints reach octave {} but only {} pyramid levels were given",
                    top.unwrap_or(1) - 1,
                    view.levels.len()
                )));
            }
        }
        let size = |v: &StereoView<'_>, l: usize| v.levels.get(l).map(|i| (i.width(), i.height()));
        let camera_size = (shape.width as usize, shape.height as usize);
        if let Some(level0) = size(&self.left, 0).filter(|&s| s != camera_size) {
            return Err(SlamError::InvalidInput(format!(
                "the images are {}x{} but the camera is {}x{} (width x height)",
                level0.0, level0.1, shape.width, shape.height
            )));
        }
        for l in 0..self.left.levels.len().min(self.right.levels.len()) {
            if size(&self.left, l) != size(&self.right, l) {
                return Err(SlamError::InvalidInput(format!(
                    "left and right images differ in size at pyramid level {l}: {:?} vs {:?} \
                     (width, height)",
                    size(&self.left, l).unwrap_or_default(),
                    size(&self.right, l).unwrap_or_default()
                )));
            }
        }
        Ok(())
    }
}

/// Checks what every sensor's features share: finite time and coordinates inside the image,
/// one descriptor (and colour, when given) per keypoint, octaves inside the pyramid.
fn validate_features(
    timestamp: f64,
    keypoints: &[Keypoint],
    descriptors: &[Descriptor],
    colors: Option<&[Rgb]>,
    shape: &InputShape,
) -> Result<(), SlamError> {
    let n_levels = shape.n_levels;
    let n = keypoints.len();
    if !timestamp.is_finite() {
        return Err(SlamError::InvalidInput("timestamp is not finite".into()));
    }
    if descriptors.len() != n {
        return Err(SlamError::InvalidInput(format!(
            "got {n} keypoints and {} descriptors: lengths must match",
            descriptors.len()
        )));
    }
    if let Some(colors) = colors.filter(|c| c.len() != n) {
        return Err(SlamError::InvalidInput(format!(
            "got {n} keypoints and {} colors: lengths must match",
            colors.len()
        )));
    }
    if let Some(i) = keypoints
        .iter()
        .position(|k| !(k.x.is_finite() && k.y.is_finite()))
    {
        return Err(SlamError::InvalidInput(format!(
            "keypoint {i} has non-finite coordinates"
        )));
    }
    let (w, h) = (shape.width as f32, shape.height as f32);
    if let Some(i) = keypoints
        .iter()
        .position(|k| !(0.0..w).contains(&k.x) || !(0.0..h).contains(&k.y))
    {
        return Err(SlamError::InvalidInput(format!(
            "keypoint {i} at ({}, {}) px lies outside the camera's {}x{} image: are the \
             images the size the camera was calibrated for?",
            keypoints[i].x, keypoints[i].y, shape.width, shape.height
        )));
    }
    if let Some(i) = keypoints.iter().position(|k| k.octave as usize >= n_levels) {
        return Err(SlamError::InvalidInput(format!(
            "keypoint {i} has octave {} but the pyramid has {n_levels} levels",
            keypoints[i].octave
        )));
    }
    Ok(())
}

impl Frame {
    /// Undistorts the keypoints and derives the virtual right coordinate from depth.
    pub fn from_rgbd(
        index: usize,
        input: &RgbdInput<'_>,
        ctx: &Context,
    ) -> Result<Self, SlamError> {
        let (keypoints, depth, u_right) =
            with_depth(&ctx.view(0), input.keypoints, input.depth_m, ctx);
        Self::new(
            index,
            input.timestamp,
            keypoints,
            input.descriptors,
            depth,
            u_right,
            input.colors,
            time_offsets_s(input.keypoints, &ctx.camera),
            ctx.bounds,
        )
    }

    /// The frame with the keypoints of the rig's further cameras appended, camera by camera
    /// (`observed[k]` is camera `k + 1`'s: raw keypoints, descriptors, colours and, for a
    /// depth camera, depths in metres).
    pub fn with_observers(
        self,
        observed: &[ObserverInput<'_>],
        ctx: &Context,
    ) -> Result<Self, SlamError> {
        let mut f = self.features;
        let mut starts = vec![0];
        let mut bounds = vec![ctx.bounds];
        let mut colors = f.colors.take();
        // Each camera's rows timed by its own shutter; none for a rig of global shutters.
        let mut offsets = std::mem::take(&mut f.time_offsets_s);
        let rolling = ctx.has_rolling_shutter();
        if rolling {
            offsets.resize(f.keypoints.len(), 0.0);
        }
        for (k, input) in observed.iter().enumerate() {
            let view = ctx.view(k + 1);
            starts.push(f.keypoints.len());
            bounds.push(*view.bounds);
            if rolling {
                offsets.extend(row_time_offsets_s(input.keypoints, view.camera));
            }
            let (keypoints, depth, u_right) = match input.depth_m {
                Some(d) => with_depth(&view, input.keypoints, d, ctx),
                None => {
                    let n = input.keypoints.len();
                    let kps = to_core_pixels(input.keypoints, view.camera);
                    (kps, vec![-1.0; n], vec![-1.0; n])
                }
            };
            f.keypoints.extend(keypoints);
            f.descriptors.extend_from_slice(input.descriptors);
            f.depth.extend(depth);
            f.u_right.extend(u_right);
            if let Some(c) = colors.as_mut() {
                c.extend_from_slice(input.colors);
            }
        }
        let mut features =
            FrameFeatures::new(f.keypoints, f.descriptors, f.depth, f.u_right, ctx.bounds)?
                .with_cameras(starts, &bounds)?;
        if let Some(colors) = colors {
            features = features.with_colors(colors)?;
        }
        if rolling {
            features = features.with_time_offsets(offsets)?;
        }
        let n = features.len();
        Ok(Self {
            features,
            map_points: vec![None; n],
            vo_points: vec![None; n],
            outlier: vec![false; n],
            ..self
        })
    }

    /// Undistorts the keypoints; no feature has depth.
    pub fn from_mono(
        index: usize,
        input: &MonoInput<'_>,
        ctx: &Context,
    ) -> Result<Self, SlamError> {
        let keypoints = to_core_pixels(input.keypoints, &ctx.camera);
        let n = keypoints.len();
        Self::new(
            index,
            input.timestamp,
            keypoints,
            input.descriptors,
            vec![-1.0; n],
            vec![-1.0; n],
            input.colors,
            time_offsets_s(input.keypoints, &ctx.camera),
            ctx.bounds,
        )
    }

    /// Matches the left keypoints into the right image (see [`match_stereo`]); depth and
    /// right coordinate come from the disparity. The camera must be the rectified pinhole.
    pub fn from_stereo(
        index: usize,
        input: &StereoInput<'_>,
        pyramid: &ScalePyramid,
        ctx: &Context,
    ) -> Result<Self, SlamError> {
        let matches = match_stereo(
            &input.left,
            &input.right,
            pyramid,
            ctx.config.depth.bf,
            ctx.camera.fx(),
        );
        let (dmin, dmax) = ctx.config.depth.depth_range;
        let (u_right, depth) = matches
            .iter()
            .map(|m| match m {
                Some(m) if (dmin..dmax).contains(&(m.depth_m as f64)) => (m.u_right, m.depth_m),
                _ => (-1.0, -1.0),
            })
            .unzip();
        Self::new(
            index,
            input.timestamp,
            input.left.keypoints.to_vec(),
            input.left.descriptors,
            depth,
            u_right,
            input.colors,
            // Rectified rows stand in for the raw ones: the core never sees the raw pair.
            time_offsets_s(input.left.keypoints, &ctx.camera),
            ctx.bounds,
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn new(
        index: usize,
        timestamp: f64,
        keypoints: Vec<Keypoint>,
        descriptors: &[Descriptor],
        depth: Vec<f32>,
        u_right: Vec<f32>,
        colors: Option<&[Rgb]>,
        time_offsets_s: Vec<f64>,
        bounds: ImageBounds,
    ) -> Result<Self, SlamError> {
        let n = keypoints.len();
        let mut features =
            FrameFeatures::new(keypoints, descriptors.to_vec(), depth, u_right, bounds)?;
        if let Some(colors) = colors {
            features = features.with_colors(colors.to_vec())?;
        }
        if !time_offsets_s.is_empty() {
            features = features.with_time_offsets(time_offsets_s)?;
        }
        Ok(Self {
            index,
            timestamp,
            features,
            map_points: vec![None; n],
            vo_points: vec![None; n],
            outlier: vec![false; n],
            T_c_w: Isometry3::identity(),
            unmatched_pairs: Vec::new(),
        })
    }

    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.map_points.len()
    }

    /// Gives the keypoints of each camera whose pair was kept unmatched their depth from it
    /// (see [`UnmatchedPair`]); nothing for a frame matched already.
    pub fn match_pair(&mut self, pyramid: &ScalePyramid, ctx: &Context) {
        for unmatched in std::mem::take(&mut self.unmatched_pairs) {
            let k = unmatched.camera;
            let pair = match k.checked_sub(1) {
                None => ctx.pair.as_ref(),
                Some(o) => ctx.observers.get(o).and_then(|o| o.pair.as_ref()),
            };
            let Some(pair) = pair else { continue };
            let view = ctx.view(k);
            let range = self.features.camera_range(k);
            let depth_m = pair.depths(
                view.camera,
                (
                    &unmatched.left_raw,
                    &self.features.descriptors[range.clone()],
                ),
                (&unmatched.right_keypoints, &unmatched.right_descriptors),
                &pyramid.sigma2,
            );
            let (_, depth, u_right) = with_depth(&view, &unmatched.left_raw, &depth_m, ctx);
            self.features.depth[range.clone()].copy_from_slice(&depth);
            self.features.u_right[range].copy_from_slice(&u_right);
        }
    }

    /// Camera centre in the world frame, metres.
    pub fn camera_center(&self) -> Vector3<f64> {
        self.T_c_w.inverse().translation.vector
    }

    /// Keypoints with measured depth, closest first, as far as ORB-SLAM back-projects them
    /// (`UpdateLastFrame`, `CreateNewKeyFrame`): every close one (depth below `close_depth_m`)
    /// and at least the 100 closest.
    pub fn closest_depth_features(&self, close_depth_m: f64) -> Vec<usize> {
        let depth = &self.features.depth;
        let mut by_depth: Vec<usize> = (0..self.len()).filter(|&i| depth[i] > 0.0).collect();
        by_depth.sort_by(|&a, &b| depth[a].total_cmp(&depth[b]));
        let beyond = by_depth
            .iter()
            .enumerate()
            .position(|(n, &i)| depth[i] as f64 > close_depth_m && n + 1 > 100);
        by_depth.truncate(beyond.map_or(by_depth.len(), |n| n + 1));
        by_depth
    }

    /// Forgets every association (before a new matching attempt).
    pub fn clear_associations(&mut self) {
        self.map_points.iter_mut().for_each(|m| *m = None);
        self.vo_points.iter_mut().for_each(|m| *m = None);
        self.outlier.iter_mut().for_each(|o| *o = false);
    }

    /// Matches points projected into camera `camera` against that camera's keypoints (see
    /// [`ferroslam_features::search_by_projection`]): per query, `(keypoint, distance)`.
    ///
    /// `predicted_u_right[q]` is the right-image coordinate query `q` should have (`u - bf/z`);
    /// candidates with a measured one further than the search radius away are skipped before
    /// descriptors are compared, as ORB-SLAM does for stereo/RGB-D: a point on the wrong side
    /// of a depth edge looks alike but sits at another depth.
    pub fn search_by_projection(
        &self,
        camera: usize,
        queries: &[ProjectionQuery],
        predicted_u_right: &[f64],
        taken: &[bool],
        opts: &MatchOptions,
    ) -> Vec<Option<(usize, u32)>> {
        let f = &self.features;
        let range = f.camera_range(camera);
        let first = range.start;
        let depth_agrees = |q: usize, t: usize| {
            let measured = f.u_right[first + t];
            measured < 0.0 || (predicted_u_right[q] - measured as f64).abs() <= queries[q].radius
        };
        let found = search_by_projection_with(
            queries,
            &f.keypoints[range.clone()],
            &f.descriptors[range.clone()],
            f.grid(camera),
            &taken[range],
            opts,
            depth_agrees,
        );
        found
            .into_iter()
            .map(|hit| hit.map(|(t, d)| (first + t, d)))
            .collect()
    }
}

/// [`search_by_projection`] over the keypoints of camera `camera` of `f` (a keyframe's, for
/// loop matching); the indices are `f`'s. `taken` is empty or one flag per keypoint of `f`.
pub fn search_camera(
    queries: &[ProjectionQuery],
    f: &FrameFeatures,
    camera: usize,
    taken: &[bool],
    opts: &MatchOptions,
) -> Vec<Option<(usize, u32)>> {
    let r = f.camera_range(camera);
    let first = r.start;
    let taken = taken.get(r.clone()).unwrap_or_default();
    search_by_projection(
        queries,
        &f.keypoints[r.clone()],
        &f.descriptors[r],
        f.grid(camera),
        taken,
        opts,
    )
    .into_iter()
    .map(|hit| hit.map(|(t, d)| (first + t, d)))
    .collect()
}

/// One further camera's measured features at an instant (see [`Frame::with_observers`]).
pub struct ObserverInput<'a> {
    /// Keypoints in the camera's raw pixels.
    pub keypoints: &'a [Keypoint],
    /// One descriptor per keypoint.
    pub descriptors: &'a [Descriptor],
    /// One colour per keypoint.
    pub colors: &'a [Rgb],
    /// Depth at each keypoint (metres, `<= 0` none) for a depth camera.
    pub depth_m: Option<&'a [f32]>,
}

/// Core-pixel keypoints of camera `view` with their depths and virtual right coordinates
/// (`-1` where the depth is missing or outside the configured range).
fn with_depth(
    view: &CameraView<'_>,
    raw: &[Keypoint],
    depth_m: &[f32],
    ctx: &Context,
) -> (Vec<Keypoint>, Vec<f32>, Vec<f32>) {
    let (camera, config) = (view.camera, &ctx.config);
    let (dmin, dmax) = config.depth.depth_range;
    let mut keypoints = Vec::with_capacity(raw.len());
    let mut depth = Vec::with_capacity(raw.len());
    let mut u_right = Vec::with_capacity(raw.len());
    for (kp, &d) in raw.iter().zip(depth_m) {
        let uv = camera.core_pixel(&Vector2::new(kp.x as f64, kp.y as f64));
        keypoints.push(Keypoint {
            x: uv.x as f32,
            y: uv.y as f32,
            ..*kp
        });
        let d = d as f64;
        // A fisheye's measured right coordinate: the virtual right camera's column of
        // the keypoint's ray at its (z-)depth.
        let ur = match camera {
            CameraModel::Pinhole(_) => Some(uv.x - config.depth.bf / d),
            CameraModel::KannalaBrandt(_) => camera
                .unproject(&uv)
                .and_then(|ray| point_at_depth(&ray, d))
                .and_then(|p_c| view.intrinsics.u_right(&p_c, uv.x)),
        };
        if let Some(ur) = ur.filter(|_| d.is_finite() && d > dmin && d < dmax) {
            depth.push(d as f32);
            u_right.push(ur as f32);
        } else {
            depth.push(-1.0);
            u_right.push(-1.0);
        }
    }
    (keypoints, depth, u_right)
}

/// Keypoints moved from raw pixels to the camera's core pixels (see [`CameraModel`]).
fn to_core_pixels(keypoints: &[Keypoint], camera: &CameraModel) -> Vec<Keypoint> {
    keypoints
        .iter()
        .map(|kp| {
            let uv = camera.core_pixel(&Vector2::new(kp.x as f64, kp.y as f64));
            Keypoint {
                x: uv.x as f32,
                y: uv.y as f32,
                ..*kp
            }
        })
        .collect()
}

/// Back-projects keypoint `i` of `features` with its depth (along its camera's optical
/// axis), returning the world point, for a rig whose first camera is at `T_w_c0`; `None`
/// without depth or, for a fisheye, for a ray that does not point forwards.
#[allow(non_snake_case)]
pub fn unproject_depth(
    features: &FrameFeatures,
    i: usize,
    ctx: &Context,
    T_w_c0: &Isometry3<f64>,
) -> Option<Vector3<f64>> {
    let z = features.depth[i] as f64;
    if z <= 0.0 {
        return None;
    }
    let view = ctx.view(features.camera_of(i));
    let camera = view.camera;
    let kp = &features.keypoints[i];
    let uv = Vector2::new(kp.x as f64, kp.y as f64);
    let p_c = match camera {
        CameraModel::Pinhole(c) => c.unproject(&uv) * z,
        CameraModel::KannalaBrandt(_) => point_at_depth(&camera.unproject(&uv)?, z)?,
    };
    // Depth is measured in the camera at its row's time (RGB-D: registered to the colour
    // image, so sampled at the colour row's time): D^-1 of the first camera's motion brings
    // it, in that camera's frame, to the reference line.
    let p_c = Point3::from(p_c);
    let p_c0 = view.T_c_c0.map_or(p_c, |T| T.inverse_transform_point(&p_c));
    let p_c0 = readout_motion(features, i).map_or(p_c0, |D| D.inverse_transform_point(&p_c0));
    Some((T_w_c0 * p_c0).coords)
}

/// The motion `D` of the rig's first camera from its frame's reference line to the row of
/// keypoint `i` in the camera that saw it (camera `k` saw it from `T_ck_c0 * D(dt) * T_c0_w`,
/// see [`ferroslam_geometry::rolling_shutter`]), at the velocity tracking estimated; `None`
/// for a global shutter or the reference line, where the pose is `T_c0_w` itself.
#[allow(non_snake_case)]
pub fn readout_motion(features: &FrameFeatures, i: usize) -> Option<Isometry3<f64>> {
    let dt = features.time_offset_s(i);
    (dt != 0.0).then(|| motion_over(&features.xi_dot, dt))
}

/// Seconds from the frame's timestamp to the readout of each keypoint's row (`keypoints` in
/// the camera's raw pixels); empty for a global shutter, so no per-keypoint work is done.
fn time_offsets_s(keypoints: &[Keypoint], camera: &CameraModel) -> Vec<f64> {
    if camera.rolling_shutter().is_global() {
        return Vec::new();
    }
    row_time_offsets_s(keypoints, camera).collect()
}

/// Each keypoint's row time offset (seconds, 0 for a global shutter) in `camera`.
fn row_time_offsets_s<'a>(
    keypoints: &'a [Keypoint],
    camera: &'a CameraModel,
) -> impl Iterator<Item = f64> + 'a {
    keypoints
        .iter()
        .map(|kp| camera.time_offset_s(&Vector2::new(kp.x as f64, kp.y as f64)))
}

/// The point along unit `ray` at z-depth `z` (depth cameras measure along the optical
/// axis); `None` for a ray that does not point forwards.
pub fn point_at_depth(ray: &Vector3<f64>, z: f64) -> Option<Vector3<f64>> {
    (ray.z > 0.0).then(|| ray * (z / ray.z))
}
