//! Little-endian byte encoding of the map's values: one [`Codec`] impl per type, each an
//! `encode` / `decode` pair written field by field in the same order.
//!
//! Decoding never trusts a length: a collection of `n` items is refused unless the bytes left
//! can hold `n` items of the type's smallest encoding ([`Codec::MIN_SIZE`]), so a corrupt
//! length fails cleanly instead of allocating.
//!
//! Decoders read the layout of the file's format version ([`Decoder::version`]): a field a
//! later version added is absent from older files and decodes as its "none" value.

use std::collections::{BTreeMap, BTreeSet};

use ferroslam_features::{ImageBounds, Keypoint};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3, Vector6};

use super::super::CulledKeyFrame;
use super::{
    CAMERA_MODEL_SINCE, COLORS_SINCE, FORMAT_VERSION, PAIR_CAMERA_SINCE, RIG_CAMERAS_SINCE,
    RIG_CAMERA_PAIRS_SINCE, ROLLING_SHUTTER_SINCE,
};
use crate::frame_features::cameras::camera_grids;
use crate::{
    FrameFeatures, KeyFrame, KeyFrameId, MapError, MapPoint, MapPointId, PairCamera, Rig, RigMember,
};

/// Appends encoded values to a byte buffer.
#[derive(Default)]
pub(super) struct Encoder {
    pub(super) bytes: Vec<u8>,
}

impl Encoder {
    pub(super) fn put<T: Codec>(&mut self, value: &T) {
        value.encode(self);
    }

    /// Item count (u64) then the items: the encoding of a `Vec`.
    pub(super) fn put_all<'v, T: Codec + 'v>(
        &mut self,
        items: impl ExactSizeIterator<Item = &'v T>,
    ) {
        self.put(&items.len());
        items.for_each(|v| self.put(v));
    }

    fn raw(&mut self, bytes: &[u8]) {
        self.bytes.extend_from_slice(bytes);
    }
}

/// Reads encoded values from a byte slice, reporting what it was reading when bytes run out.
pub(super) struct Decoder<'a> {
    bytes: &'a [u8],
    pos: usize,
    /// What is being decoded, for error messages.
    pub(super) context: &'static str,
    /// Format version of the file the bytes come from.
    pub(super) version: u32,
}

impl<'a> Decoder<'a> {
    /// A decoder of `bytes` in the current format version ([`FORMAT_VERSION`]).
    pub(super) fn new(bytes: &'a [u8], context: &'static str) -> Self {
        Self {
            bytes,
            pos: 0,
            context,
            version: FORMAT_VERSION,
        }
    }

    /// The same decoder, reading the layout of format `version`.
    pub(super) fn of_version(self, version: u32) -> Self {
        Self { version, ..self }
    }

    /// Whether the file's format version has the fields added in `version`.
    fn has(&self, version: u32) -> bool {
        self.version >= version
    }

    pub(super) fn get<T: Codec>(&mut self) -> Result<T, MapError> {
        T::decode(self)
    }

    pub(super) fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }

    /// The next `n` bytes.
    ///
    /// # Errors
    /// [`MapError::TruncatedMapFile`] if fewer remain.
    pub(super) fn take(&mut self, n: usize) -> Result<&'a [u8], MapError> {
        if n > self.remaining() {
            return Err(MapError::TruncatedMapFile {
                what: self.context,
                needed: n as u64,
                available: self.remaining() as u64,
            });
        }
        let out = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], MapError> {
        let mut out = [0; N];
        out.copy_from_slice(self.take(N)?);
        Ok(out)
    }

    /// A collection length, refused if the remaining bytes cannot hold that many items.
    fn len_of<T: Codec>(&mut self) -> Result<usize, MapError> {
        let n = self.get::<u64>()?;
        let fits = self.remaining() as u64 / T::MIN_SIZE as u64;
        if n > fits {
            return Err(corrupt(format!(
                "{}: {n} items declared but only {} bytes remain",
                self.context,
                self.remaining()
            )));
        }
        // n <= remaining bytes, so it fits in usize.
        Ok(n as usize)
    }
}

/// A [`MapError::CorruptMapFile`] with `what` as the reason.
pub(super) fn corrupt(what: String) -> MapError {
    MapError::CorruptMapFile { what }
}

/// A value with a fixed byte encoding.
pub(super) trait Codec: Sized {
    /// Smallest number of bytes an encoded value occupies (>= 1).
    const MIN_SIZE: usize;
    fn encode(&self, e: &mut Encoder);
    fn decode(d: &mut Decoder) -> Result<Self, MapError>;
}

macro_rules! le_number {
    ($($t:ty),*) => {$(
        impl Codec for $t {
            const MIN_SIZE: usize = std::mem::size_of::<$t>();
            fn encode(&self, e: &mut Encoder) {
                e.raw(&self.to_le_bytes());
            }
            fn decode(d: &mut Decoder) -> Result<Self, MapError> {
                Ok(<$t>::from_le_bytes(d.array()?))
            }
        }
    )*};
}
le_number!(u8, u32, u64, f32, f64);

/// Platform-independent: stored as u64.
impl Codec for usize {
    const MIN_SIZE: usize = 8;
    fn encode(&self, e: &mut Encoder) {
        e.put(&(*self as u64));
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let v = d.get::<u64>()?;
        usize::try_from(v).map_err(|_| corrupt(format!("{}: {v} overflows usize", d.context)))
    }
}

impl<const N: usize> Codec for [u8; N] {
    const MIN_SIZE: usize = N;
    fn encode(&self, e: &mut Encoder) {
        e.raw(self);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        d.array()
    }
}

/// One tag byte (0 = `None`, 1 = `Some`) then the value.
impl<T: Codec> Codec for Option<T> {
    const MIN_SIZE: usize = 1;
    fn encode(&self, e: &mut Encoder) {
        match self {
            None => e.put(&0u8),
            Some(v) => {
                e.put(&1u8);
                e.put(v);
            }
        }
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        match d.get::<u8>()? {
            0 => Ok(None),
            1 => Ok(Some(d.get()?)),
            tag => Err(corrupt(format!(
                "{}: option tag {tag} (not 0/1)",
                d.context
            ))),
        }
    }
}

/// One byte, 0 or 1.
impl Codec for bool {
    const MIN_SIZE: usize = 1;
    fn encode(&self, e: &mut Encoder) {
        e.put(&u8::from(*self));
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        match d.get::<u8>()? {
            0 => Ok(false),
            1 => Ok(true),
            b => Err(corrupt(format!("{}: boolean {b} (not 0/1)", d.context))),
        }
    }
}

/// Item count (u64) then the items.
impl<T: Codec> Codec for Vec<T> {
    const MIN_SIZE: usize = 8;
    fn encode(&self, e: &mut Encoder) {
        e.put_all(self.iter());
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let n = d.len_of::<T>()?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            out.push(d.get()?);
        }
        Ok(out)
    }
}

/// As a `Vec` of keys, which must be strictly increasing (so equal sets encode equally).
impl<T: Codec + Ord + Copy> Codec for BTreeSet<T> {
    const MIN_SIZE: usize = 8;
    fn encode(&self, e: &mut Encoder) {
        e.put_all(self.iter());
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let keys = d.get::<Vec<T>>()?;
        check_increasing(keys.iter(), d.context)?;
        Ok(keys.into_iter().collect())
    }
}

/// As a `Vec` of `(key, value)` pairs with strictly increasing keys.
impl<K: Codec + Ord + Copy, V: Codec> Codec for BTreeMap<K, V> {
    const MIN_SIZE: usize = 8;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.len());
        for (k, v) in self {
            e.put(k);
            e.put(v);
        }
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let pairs = d.get::<Vec<(K, V)>>()?;
        check_increasing(pairs.iter().map(|(k, _)| k), d.context)?;
        Ok(pairs.into_iter().collect())
    }
}

/// Keys of sets and maps are stored sorted and unique; anything else is corruption (and
/// would silently merge entries).
pub(super) fn check_increasing<'k, K: Ord + 'k>(
    mut keys: impl Iterator<Item = &'k K>,
    context: &str,
) -> Result<(), MapError> {
    let Some(mut previous) = keys.next() else {
        return Ok(());
    };
    for key in keys {
        if key <= previous {
            return Err(corrupt(format!("{context}: keys not strictly increasing")));
        }
        previous = key;
    }
    Ok(())
}

impl<A: Codec, B: Codec> Codec for (A, B) {
    const MIN_SIZE: usize = A::MIN_SIZE + B::MIN_SIZE;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.0);
        e.put(&self.1);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        Ok((d.get()?, d.get()?))
    }
}

impl Codec for KeyFrameId {
    const MIN_SIZE: usize = 4;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.0);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        Ok(Self(d.get()?))
    }
}

impl Codec for MapPointId {
    const MIN_SIZE: usize = 4;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.0);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        Ok(Self(d.get()?))
    }
}

/// x, y, z (f64).
impl Codec for Vector3<f64> {
    const MIN_SIZE: usize = 24;
    fn encode(&self, e: &mut Encoder) {
        self.iter().for_each(|v| e.put(v));
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        Ok(Vector3::new(d.get()?, d.get()?, d.get()?))
    }
}

/// A velocity `[v; w]`: six f64.
impl Codec for Vector6<f64> {
    const MIN_SIZE: usize = 48;
    fn encode(&self, e: &mut Encoder) {
        self.iter().for_each(|v| e.put(v));
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let mut out = Vector6::zeros();
        for v in out.iter_mut() {
            *v = d.get()?;
        }
        Ok(out)
    }
}

/// Translation (x, y, z) then the unit quaternion (i, j, k, w), all f64, stored bit-exact.
impl Codec for Isometry3<f64> {
    const MIN_SIZE: usize = 56;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.translation.vector);
        self.rotation.coords.iter().for_each(|v| e.put(v));
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let t: Vector3<f64> = d.get()?;
        let (i, j, k, w) = (d.get()?, d.get()?, d.get()?, d.get()?);
        // Not renormalised: the stored pose is restored bit for bit.
        let rotation = UnitQuaternion::new_unchecked(Quaternion::new(w, i, j, k));
        Ok(Isometry3::from_parts(Translation3::from(t), rotation))
    }
}

/// x, y (f32), octave (u8), angle (f32), response (f32).
impl Codec for Keypoint {
    const MIN_SIZE: usize = 17;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.x);
        e.put(&self.y);
        e.put(&self.octave);
        e.put(&self.angle_deg);
        e.put(&self.response);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        Ok(Keypoint {
            x: d.get()?,
            y: d.get()?,
            octave: d.get()?,
            angle_deg: d.get()?,
            response: d.get()?,
        })
    }
}

/// min_x, max_x, min_y, max_y (f64).
impl Codec for ImageBounds {
    const MIN_SIZE: usize = 32;
    fn encode(&self, e: &mut Encoder) {
        [self.min_x, self.max_x, self.min_y, self.max_y]
            .iter()
            .for_each(|v| e.put(v));
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        Ok(ImageBounds {
            min_x: d.get()?,
            max_x: d.get()?,
            min_y: d.get()?,
            max_y: d.get()?,
        })
    }
}

/// keypoints, descriptors, depth, u_right, the cameras (version 8 on: `(first keypoint,
/// grid bounds)` of each; before: the one camera's grid bounds), colours (version 4 on), row
/// time offsets and readout velocity (version 6 on). The grids themselves are rebuilt from
/// the keypoints and bounds (deterministic). Lengths and camera starts are kept as saved,
/// even if inconsistent (the plausibility checks refuse them).
impl Codec for FrameFeatures {
    /// Version 3's: the smallest of every version read.
    const MIN_SIZE: usize = 4 * 8 + ImageBounds::MIN_SIZE;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.keypoints);
        e.put(&self.descriptors);
        e.put(&self.depth);
        e.put(&self.u_right);
        let cameras = self.camera_starts.iter().zip(&self.grids);
        e.put(&cameras.map(|(&s, g)| (s, g.bounds())).collect::<Vec<_>>());
        e.put(&self.colors);
        e.put(&self.time_offsets_s);
        e.put(&self.xi_dot);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let keypoints: Vec<Keypoint> = d.get()?;
        let (descriptors, depth, u_right) = (d.get()?, d.get()?, d.get()?);
        let cameras: Vec<(usize, ImageBounds)> = if d.has(RIG_CAMERAS_SINCE) {
            d.get()?
        } else {
            vec![(0, d.get()?)]
        };
        let camera_starts: Vec<usize> = cameras.iter().map(|&(s, _)| s).collect();
        let grids = camera_grids(&keypoints, &camera_starts, cameras.iter().map(|&(_, b)| b));
        let colors = if d.has(COLORS_SINCE) { d.get()? } else { None };
        // Older files kept no row times: their keyframes read as a global shutter's.
        let (time_offsets_s, xi_dot) = if d.has(ROLLING_SHUTTER_SINCE) {
            (d.get()?, d.get()?)
        } else {
            (Vec::new(), Vector6::zeros())
        };
        Ok(FrameFeatures {
            keypoints,
            descriptors,
            depth,
            u_right,
            colors,
            camera_starts,
            grids,
            time_offsets_s,
            xi_dot,
        })
    }
}

/// id, timestamp, frame index, T_c_w, features, map-point slots, covisibility (neighbour ->
/// weight), selected neighbours, spanning-tree parent and children, loop edges.
impl Codec for KeyFrame {
    const MIN_SIZE: usize = 4 + 8 + 8 + 56 + FrameFeatures::MIN_SIZE + 8 + 8 + 8 + 1 + 8 + 8;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.id);
        e.put(&self.timestamp);
        e.put(&self.frame_index);
        e.put(&self.T_c_w);
        e.put(self.features.as_ref());
        e.put(&self.map_points);
        e.put(&self.covisibility);
        e.put(&self.chosen);
        e.put(&self.parent);
        e.put(&self.children);
        e.put(&self.loop_edges);
    }
    #[allow(non_snake_case)]
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let (id, timestamp, frame_index, T_c_w) = (d.get()?, d.get()?, d.get()?, d.get()?);
        let features: FrameFeatures = d.get()?;
        let map_points: Vec<Option<MapPointId>> = d.get()?;
        if map_points.len() != features.len() {
            return Err(corrupt(format!(
                "{id}: {} map-point slots for {} keypoints",
                map_points.len(),
                features.len()
            )));
        }
        Ok(KeyFrame {
            id,
            timestamp,
            frame_index,
            T_c_w,
            features: features.into(),
            map_points,
            covisibility: d.get()?,
            chosen: d.get()?,
            parent: d.get()?,
            children: d.get()?,
            loop_edges: d.get()?,
        })
    }
}

/// id, position, normal, min/max distance, descriptor, observations (keyframe -> keypoint),
/// nObs, reference and first keyframe, visible and found counters, colour (version 4 on).
impl Codec for MapPoint {
    /// Version 3's: the smallest of every version read.
    const MIN_SIZE: usize = 4 + 24 + 24 + 8 + 8 + 32 + 8 + 8 + 4 + 4 + 4 + 4;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.id);
        e.put(&self.position);
        e.put(&self.normal);
        e.put(&self.min_distance);
        e.put(&self.max_distance);
        e.put(&self.descriptor);
        e.put(&self.observations);
        e.put(&self.n_obs);
        e.put(&self.reference);
        e.put(&self.first_keyframe);
        e.put(&self.visible);
        e.put(&self.found);
        e.put(&self.color);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        Ok(MapPoint {
            id: d.get()?,
            position: d.get()?,
            normal: d.get()?,
            min_distance: d.get()?,
            max_distance: d.get()?,
            descriptor: d.get()?,
            observations: d.get()?,
            n_obs: d.get()?,
            reference: d.get()?,
            first_keyframe: d.get()?,
            visible: d.get()?,
            found: d.get()?,
            color: if d.has(COLORS_SINCE) { d.get()? } else { None },
        })
    }
}

/// anchor id, then T_c_a.
#[allow(non_snake_case)]
impl Codec for CulledKeyFrame {
    const MIN_SIZE: usize = 4 + 56;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.anchor);
        e.put(&self.T_c_a);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        Ok(CulledKeyFrame {
            anchor: d.get()?,
            T_c_a: d.get()?,
        })
    }
}

/// Model name (bytes, UTF-8), intrinsics, distortion, pose in the first camera.
impl Codec for PairCamera {
    const MIN_SIZE: usize = 8 + 9 * 8 + 7 * 8;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.model.as_bytes().to_vec());
        self.intrinsics
            .iter()
            .chain(&self.distortion)
            .for_each(|v| e.put(v));
        e.put(&self.T_left_right);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let model = String::from_utf8(d.get::<Vec<u8>>()?)
            .map_err(|_| corrupt(format!("{}: pair camera model is not UTF-8", d.context)))?;
        let values = camera_values(d)?;
        Ok(PairCamera {
            model,
            intrinsics: [values[0], values[1], values[2], values[3]],
            distortion: [values[4], values[5], values[6], values[7], values[8]],
            T_left_right: d.get()?,
        })
    }
}

/// Model name (bytes, UTF-8), intrinsics, distortion, image size, pose in the first camera,
/// whether it has depth, its stereo partner (version 9 on).
impl Codec for RigMember {
    const MIN_SIZE: usize = 8 + 9 * 8 + 2 * 4 + 7 * 8 + 1;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.model.as_bytes().to_vec());
        self.intrinsics
            .iter()
            .chain(&self.distortion)
            .for_each(|v| e.put(v));
        e.put(&self.width);
        e.put(&self.height);
        e.put(&self.T_c0_c);
        e.put(&self.has_depth);
        e.put(&self.pair);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let model = String::from_utf8(d.get::<Vec<u8>>()?)
            .map_err(|_| corrupt(format!("{}: rig camera model is not UTF-8", d.context)))?;
        let values = camera_values(d)?;
        Ok(RigMember {
            model,
            intrinsics: [values[0], values[1], values[2], values[3]],
            distortion: [values[4], values[5], values[6], values[7], values[8]],
            width: d.get()?,
            height: d.get()?,
            T_c0_c: d.get()?,
            has_depth: d.get()?,
            pair: if d.has(RIG_CAMERA_PAIRS_SINCE) {
                d.get()?
            } else {
                None
            },
        })
    }
}

/// The 9 camera numbers of a record: `fx fy cx cy` and 5 distortion coefficients.
fn camera_values(d: &mut Decoder) -> Result<[f64; 9], MapError> {
    let mut values = [0.0; 9];
    for v in &mut values {
        *v = d.get()?;
    }
    Ok(values)
}

/// Sensor name (bytes, UTF-8), camera model name (version 5 on), intrinsics, distortion,
/// image size, the unrectified pair's second camera (version 7 on), the rig's further
/// cameras (version 8 on).
impl Codec for Rig {
    /// Version 3's: the smallest of every version read.
    const MIN_SIZE: usize = 8 + 9 * 8 + 2 * 4;
    fn encode(&self, e: &mut Encoder) {
        e.put(&self.sensor.as_bytes().to_vec());
        e.put(&self.model.as_bytes().to_vec());
        self.intrinsics
            .iter()
            .chain(&self.distortion)
            .for_each(|v| e.put(v));
        e.put(&self.width);
        e.put(&self.height);
        e.put(&self.pair);
        e.put(&self.cameras);
    }
    fn decode(d: &mut Decoder) -> Result<Self, MapError> {
        let sensor = String::from_utf8(d.get::<Vec<u8>>()?)
            .map_err(|_| corrupt(format!("{}: sensor name is not UTF-8", d.context)))?;
        let model = if d.has(CAMERA_MODEL_SINCE) {
            String::from_utf8(d.get::<Vec<u8>>()?)
                .map_err(|_| corrupt(format!("{}: camera model is not UTF-8", d.context)))?
        } else {
            Rig::PINHOLE.to_owned()
        };
        let values = camera_values(d)?;
        Ok(Rig {
            sensor,
            model,
            intrinsics: [values[0], values[1], values[2], values[3]],
            distortion: [values[4], values[5], values[6], values[7], values[8]],
            width: d.get()?,
            height: d.get()?,
            pair: if d.has(PAIR_CAMERA_SINCE) {
                d.get()?
            } else {
                None
            },
            cameras: if d.has(RIG_CAMERAS_SINCE) {
                d.get()?
            } else {
                Vec::new()
            },
        })
    }
}
