//! Versioned binary map files: [`Map::save`] / [`Map::load`] and their path helpers.
//!
//! # Format (version 9, all numbers little-endian)
//! ```text
//! offset  size  field
//! 0       8     magic b"FSLAMMAP"
//! 8       4     format version, u32 (= FORMAT_VERSION)
//! 12      8     payload length N, u64
//! 20      N     payload: six sections, in this order, each
//!                 tag [u8; 4] | body length u64 | body
//!                 "RIG_" Option<sensor name Vec<u8>, camera model name Vec<u8> (version
//!                        5 on), fx fy cx cy f64, 5 distortion coefficients f64, width u32,
//!                        height u32, Option<pair camera> (version 7 on), Vec<rig camera>
//!                        (version 8 on)> (version 3 on; see `Rig`; a pair camera = model
//!                        name Vec<u8>, fx fy cx cy f64, 5 distortion coefficients f64, pose
//!                        T_left_right; a rig camera = model name Vec<u8>, fx fy cx cy f64,
//!                        5 distortion coefficients f64, width u32, height u32, pose T_c0_c,
//!                        has depth u8 0/1, Option<pair camera> (version 9 on))
//!                 "PYRM" scale factor f64, number of levels u64
//!                 "IDS_" next keyframe id u32, next map point id u32, origin Option<u32>
//!                 "KEYF" keyframes by increasing id (Vec<KeyFrame>)
//!                 "MPTS" map points by increasing id (Vec<MapPoint>)
//!                 "TOMB" culled keyframes Vec<(id, anchor id, T_c_a)>,
//!                        fused points Vec<(id, replacement id)>, both by increasing id
//! 20+N    8     checksum: 64-bit FNV-1a of bytes [0, 20+N)
//! ```
//! Encodings (`codec.rs`): `Vec<T>` = count u64 + items; `Option<T>` = tag u8 (0/1) + value;
//! `usize` = u64; a pose = translation xyz + quaternion ijkw (f64, bit-exact); a keypoint =
//! x, y f32, octave u8, angle f32, response f32; a colour = r, g, b u8; a velocity = v xyz,
//! w xyz f64; sets/maps = sorted unique `Vec`s.
//!
//! # Versions
//! - 9: each further camera of the rig ends with its stereo partner (`Option<pair camera>`):
//!   a rig of several stereo pairs. Files of version 8 load with none.
//! - 8: the record ends with the rig's further cameras (`Vec`, camera 1 on), and keyframe
//!   features hold their cameras: in place of the one grid bounds, `Vec<(first keypoint
//!   u64, grid bounds)>`, one per camera, so that the keyframes of a multi-camera rig load
//!   with each camera's keypoints and grid. Files of versions 3 to 7 load as one camera.
//! - 7: the sensor and camera record ends with the second camera of an unrectified stereo
//!   pair (`Option`), so that a map made with one pair loads only into a system with the
//!   same pair. Files of versions 3 to 6 load with none.
//! - 6: keyframe features end with their rolling-shutter row times (`Vec<f64>`, seconds,
//!   empty for a global shutter) and the velocity of their pose over the readout, so that a
//!   loaded map is adjusted and exported (`Map::sparse_model`) as the running system did.
//!   Files of versions 3 to 5 load as global-shutter keyframes (no row times, velocity 0).
//! - 5: the camera record names the camera model (`"pinhole"`, `"kannala_brandt"`). Files of
//!   versions 3 and 4 load as pinhole cameras.
//! - 4: keyframe features end with their keypoint colours (`Option<Vec<colour>>`), map
//!   points with their colour (`Option<colour>`).
//! - 3: the sensor and camera record ("RIG_"). Version 3 files still load: as version 4
//!   without colours (every point's [`crate::MapPoint::color`] is `None`); saving writes
//!   the current version.
//! - 2 and older are refused: their sensor is unknown.
//!
//! Everything the map holds is stored verbatim: keyframe features (without the keypoint
//! grids, which are rebuilt from the keypoints, the camera starts and the stored grid
//! bounds), poses, map-point slots, covisibility edges with weights and each keyframe's
//! selected neighbours, spanning-tree parent and children, every map-point field including counters, and the tombstones of
//! culled keyframes and fused points. The pyramid is rebuilt from its scale factor and number
//! of levels. Bad keyframes / points are not stored (they are not in the map); their
//! tombstones are. A loaded map is therefore indistinguishable from the saved one, and
//! saving it again gives the same bytes (for a file of the current version).
//!
//! # Failure modes
//! Loading checks, in order: magic ([`MapError::NotAMapFile`]), version
//! ([`MapError::UnsupportedMapVersion`]), length ([`MapError::TruncatedMapFile`]), checksum
//! ([`MapError::MapFileChecksum`]), then the content: section tags and lengths, collection
//! lengths (capped by the bytes left, so a corrupt length never allocates), sorted unique ids
//! below the next-id counters, and finally [`Map::check_consistency`]
//! ([`MapError::CorruptMapFile`]). Nothing panics.
//!
//! # Example
//! ```
//! use ferroslam_features::ScalePyramid;
//! use ferroslam_map::Map;
//!
//! let map = Map::new(ScalePyramid::default());
//! let mut bytes = Vec::new();
//! map.save(&mut bytes).unwrap();
//! assert_eq!(&bytes[..8], b"FSLAMMAP");
//! let loaded = Map::load(&mut bytes.as_slice()).unwrap();
//! assert_eq!(loaded.pyramid(), map.pyramid());
//! assert!(Map::load(&mut &bytes[..bytes.len() - 1]).is_err()); // truncated
//! ```

use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;

use ferroslam_features::ScalePyramid;

use super::Map;
use crate::{KeyFrame, MapError, MapPoint, Rig};

mod codec;
mod plausibility;
#[cfg(test)]
mod tests;

use codec::{check_increasing, corrupt, Decoder, Encoder};
pub use plausibility::{KEYPOINT_BOUNDS_MARGIN, MAX_COORDINATE_M, UNIT_QUATERNION_TOLERANCE};

/// The magic bytes starting every map file, as text.
pub const MAGIC_TEXT: &str = "FSLAMMAP";
/// The magic bytes starting every map file.
pub const MAGIC: &[u8] = MAGIC_TEXT.as_bytes();
/// The map-file format version this build writes (and the newest it reads); see the module
/// docs for what each version added.
pub const FORMAT_VERSION: u32 = 9;
/// The oldest map-file format version this build reads.
pub const OLDEST_READABLE_VERSION: u32 = 3;
/// The version that added keypoint and map-point colours.
const COLORS_SINCE: u32 = 4;
/// The version that added the camera model to the sensor and camera record.
const CAMERA_MODEL_SINCE: u32 = 5;
/// The version that added the keyframes' rolling-shutter row times and velocity.
const ROLLING_SHUTTER_SINCE: u32 = 6;
/// The version that added the unrectified stereo pair's second camera to the record.
const PAIR_CAMERA_SINCE: u32 = 7;
/// The version that added the rig's further cameras and each keyframe's camera starts.
const RIG_CAMERAS_SINCE: u32 = 8;
/// The version that added the further cameras' stereo partners.
const RIG_CAMERA_PAIRS_SINCE: u32 = 9;
/// Magic, version, payload length.
const HEADER_LEN: usize = 8 + 4 + 8;
const CHECKSUM_LEN: usize = 8;
/// Levels beyond this are refused as corrupt (ORB-SLAM uses 8).
const MAX_PYRAMID_LEVELS: usize = 64;

/// A payload section: its tag in the file and its name in error messages.
struct Section {
    tag: [u8; 4],
    name: &'static str,
}

const RIG: Section = Section {
    tag: *b"RIG_",
    name: "the sensor and camera section",
};
const PYRAMID: Section = Section {
    tag: *b"PYRM",
    name: "the scale pyramid section",
};
const IDS: Section = Section {
    tag: *b"IDS_",
    name: "the id section",
};
const KEYFRAMES: Section = Section {
    tag: *b"KEYF",
    name: "the keyframe section",
};
const MAP_POINTS: Section = Section {
    tag: *b"MPTS",
    name: "the map point section",
};
const TOMBSTONES: Section = Section {
    tag: *b"TOMB",
    name: "the tombstone section",
};

/// 64-bit FNV-1a of the concatenated `parts`: detects any single changed byte (each step
/// is a bijection of the state).
fn fnv1a64(parts: &[&[u8]]) -> u64 {
    parts
        .iter()
        .flat_map(|p| p.iter())
        .fold(0xcbf2_9ce4_8422_2325, |h, &b| {
            (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
        })
}

impl Map {
    /// Writes the map in the versioned binary format described in the [module
    /// docs](self). The map is encoded in memory first, then written with one `write_all`.
    ///
    /// # Errors
    /// [`MapError::MapFileIo`] if writing fails.
    pub fn save(&self, w: &mut impl Write) -> Result<(), MapError> {
        w.write_all(&self.to_bytes())?;
        Ok(())
    }

    /// Reads a map written by [`Map::save`], consuming exactly its bytes from `r`.
    ///
    /// # Errors
    /// [`MapError::NotAMapFile`], [`MapError::UnsupportedMapVersion`],
    /// [`MapError::TruncatedMapFile`], [`MapError::MapFileChecksum`],
    /// [`MapError::CorruptMapFile`], [`MapError::MapFileIo`]: see the module docs.
    pub fn load(r: &mut impl Read) -> Result<Map, MapError> {
        let header = read_up_to(r, HEADER_LEN as u64)?;
        let magic_len = header.len().min(MAGIC.len());
        if header[..magic_len] != MAGIC[..magic_len] {
            return Err(MapError::NotAMapFile {
                found: header[..magic_len].to_vec(),
                expected: MAGIC_TEXT,
            });
        }
        let mut d = Decoder::new(&header, "the header");
        d.take(MAGIC.len())?;
        let version: u32 = d.get()?;
        if !(OLDEST_READABLE_VERSION..=FORMAT_VERSION).contains(&version) {
            return Err(MapError::UnsupportedMapVersion {
                found: version,
                oldest: OLDEST_READABLE_VERSION,
                newest: FORMAT_VERSION,
            });
        }
        let payload_len: u64 = d.get()?;
        let rest_len = payload_len.saturating_add(CHECKSUM_LEN as u64);
        // Grows with the bytes actually read, never with the declared length.
        let rest = read_up_to(r, rest_len)?;
        if (rest.len() as u64) < rest_len {
            return Err(MapError::TruncatedMapFile {
                what: "the payload and checksum",
                needed: rest_len,
                available: rest.len() as u64,
            });
        }
        let (payload, stored) = rest.split_at(rest.len() - CHECKSUM_LEN);
        let stored = Decoder::new(stored, "the checksum").get::<u64>()?;
        let computed = fnv1a64(&[&header, payload]);
        if stored != computed {
            return Err(MapError::MapFileChecksum { stored, computed });
        }
        Self::decode_payload(payload, version)
    }

    /// [`Map::save`] to a file, created or replaced through [`ferroslam_files::write_atomically`]:
    /// a temporary file beside `path` renamed over it, so an interrupted save leaves any
    /// previous file intact; a folder, FIFO or device at `path` is refused, a symlink there
    /// replaced (never written through); missing parent folders are created.
    ///
    /// # Errors
    /// [`MapError::MapFileIo`] naming the path.
    pub fn save_to_path(&self, path: impl AsRef<Path>) -> Result<(), MapError> {
        ferroslam_files::write_atomically(path.as_ref(), |w| self.save(w))
    }

    /// [`Map::load`] from a file; bytes after the map's checksum are refused.
    ///
    /// # Errors
    /// As [`Map::load`]; [`MapError::MapFileIo`] naming the path if the file cannot be read
    /// or is not a regular file (a FIFO or a device is refused before reading: it could
    /// block or never end), [`MapError::CorruptMapFile`] for trailing bytes.
    pub fn load_from_path(path: impl AsRef<Path>) -> Result<Map, MapError> {
        let file = ferroslam_files::open_regular(path.as_ref(), u64::MAX, "map file")?;
        let mut r = BufReader::new(file);
        let map = Self::load(&mut r)?;
        if !read_up_to(&mut r, 1)?.is_empty() {
            return Err(corrupt("bytes after the checksum".into()));
        }
        Ok(map)
    }

    /// Writes an atlas file: the records of `maps` back to back, in order, through
    /// [`ferroslam_files::write_atomically`] as [`Map::save_to_path`] (a one-map atlas file
    /// is a map file).
    ///
    /// # Errors
    /// [`MapError::MapFileIo`] naming the path.
    pub fn save_all_to_path(maps: &[&Map], path: impl AsRef<Path>) -> Result<(), MapError> {
        ferroslam_files::write_atomically(path.as_ref(), |w| {
            maps.iter().try_for_each(|m| m.save(w))
        })
    }

    /// Every map of an atlas file ([`Map::save_all_to_path`]), in file order; a map file
    /// gives one.
    ///
    /// # Errors
    /// As [`Map::load_from_path`]: bytes after a record that do not start another record
    /// are [`MapError::CorruptMapFile`].
    pub fn load_all_from_path(path: impl AsRef<Path>) -> Result<Vec<Map>, MapError> {
        let file = ferroslam_files::open_regular(path.as_ref(), u64::MAX, "map file")?;
        let mut r = BufReader::new(file);
        let mut maps = vec![Self::load(&mut r)?];
        while !r.fill_buf()?.is_empty() {
            match Self::load(&mut r) {
                Ok(map) => maps.push(map),
                Err(MapError::NotAMapFile { .. }) => {
                    return Err(corrupt("bytes after the checksum".into()))
                }
                Err(e) => return Err(e),
            }
        }
        Ok(maps)
    }

    /// The whole file: header, sections, checksum.
    fn to_bytes(&self) -> Vec<u8> {
        let mut payload = Encoder::default();
        section(&mut payload, RIG, |e| e.put(&self.rig));
        section(&mut payload, PYRAMID, |e| {
            e.put(&self.pyramid.scale_factor);
            e.put(&self.pyramid.n_levels);
        });
        section(&mut payload, IDS, |e| {
            e.put(&self.next_keyframe);
            e.put(&self.next_map_point);
            e.put(&self.origin);
        });
        section(&mut payload, KEYFRAMES, |e| {
            e.put_all(self.keyframes.values())
        });
        section(&mut payload, MAP_POINTS, |e| {
            e.put_all(self.map_points.values())
        });
        section(&mut payload, TOMBSTONES, |e| {
            e.put(&sorted(&self.culled_keyframes));
            e.put(&sorted(&self.replaced_points));
        });

        let mut file = Encoder::default();
        file.bytes.extend_from_slice(MAGIC);
        file.put(&FORMAT_VERSION);
        file.put(&payload.bytes.len());
        file.bytes.extend_from_slice(&payload.bytes);
        let checksum = fnv1a64(&[&file.bytes]);
        file.put(&checksum);
        file.bytes
    }

    /// Decodes the sections of a file of format `version` and validates ids and invariants.
    fn decode_payload(payload: &[u8], version: u32) -> Result<Map, MapError> {
        let mut d = Decoder::new(payload, "the section table").of_version(version);
        let rig: Option<Rig> = read_section(&mut d, RIG, Decoder::get)?;
        let (scale_factor, n_levels): (f64, usize) =
            read_section(&mut d, PYRAMID, |d| Ok((d.get()?, d.get()?)))?;
        if n_levels > MAX_PYRAMID_LEVELS {
            return Err(corrupt(format!("{n_levels} pyramid levels")));
        }
        let pyramid = ScalePyramid::new(scale_factor, n_levels)
            .map_err(|e| corrupt(format!("scale pyramid: {e}")))?;
        let (next_keyframe, next_map_point, origin) =
            read_section(&mut d, IDS, |d| Ok((d.get()?, d.get()?, d.get()?)))?;
        let keyframes: Vec<KeyFrame> = read_section(&mut d, KEYFRAMES, Decoder::get)?;
        let map_points: Vec<MapPoint> = read_section(&mut d, MAP_POINTS, Decoder::get)?;
        let (culled, replaced): (Vec<_>, Vec<_>) =
            read_section(&mut d, TOMBSTONES, |d| Ok((d.get()?, d.get()?)))?;
        if d.remaining() > 0 {
            return Err(corrupt(format!(
                "{} bytes after the last section",
                d.remaining()
            )));
        }

        let kf_ids = keyframes.iter().map(|k| k.id);
        let kf_ids: Vec<_> = kf_ids.chain(culled.iter().map(|(id, _)| *id)).collect();
        let mp_ids = map_points.iter().map(|p| p.id);
        let mp_ids: Vec<_> = mp_ids.chain(replaced.iter().map(|(id, _)| *id)).collect();
        check_increasing(keyframes.iter().map(|k| &k.id), "keyframe ids")?;
        check_increasing(map_points.iter().map(|p| &p.id), "map point ids")?;
        check_increasing(culled.iter().map(|(id, _)| id), "culled keyframe ids")?;
        check_increasing(replaced.iter().map(|(id, _)| id), "fused point ids")?;
        if let Some(id) = kf_ids.iter().find(|id| id.0 >= next_keyframe) {
            return Err(corrupt(format!(
                "{id} not below the next id {next_keyframe}"
            )));
        }
        if let Some(id) = mp_ids.iter().find(|id| id.0 >= next_map_point) {
            return Err(corrupt(format!(
                "{id} not below the next id {next_map_point}"
            )));
        }

        let map = Map {
            pyramid,
            keyframes: keyframes.into_iter().map(|k| (k.id, k)).collect(),
            map_points: map_points.into_iter().map(|p| (p.id, p)).collect(),
            next_keyframe,
            next_map_point,
            origin,
            culled_keyframes: culled.into_iter().collect(),
            replaced_points: replaced.into_iter().collect(),
            recorder: None,
            rig,
        };
        if let Some(o) = origin.filter(|o| !map.keyframes.contains_key(o)) {
            return Err(corrupt(format!("the origin {o} is not a keyframe")));
        }
        plausibility::check_plausible(&map)?;
        map.check_consistency().map_err(corrupt)?;
        Ok(map)
    }
}

/// A tombstone table's entries by increasing id (a deterministic file).
fn sorted<K: Ord + Copy, V: Clone>(table: &super::Arena<K, V>) -> Vec<(K, V)> {
    table.iter().map(|(&k, v)| (k, v.clone())).collect()
}

/// Writes the section's tag, body length and the body `write` produces.
fn section(e: &mut Encoder, section: Section, write: impl FnOnce(&mut Encoder)) {
    let mut body = Encoder::default();
    write(&mut body);
    e.put(&section.tag);
    e.put(&body.bytes.len());
    e.bytes.extend_from_slice(&body.bytes);
}

/// Reads `section` with `read`, which must consume exactly its body.
fn read_section<'a, T>(
    d: &mut Decoder<'a>,
    section: Section,
    read: impl FnOnce(&mut Decoder<'a>) -> Result<T, MapError>,
) -> Result<T, MapError> {
    let found: [u8; 4] = d.get()?;
    if found != section.tag {
        return Err(corrupt(format!(
            "expected {} (tag {:?}), found tag {found:02x?}",
            section.name,
            String::from_utf8_lossy(&section.tag)
        )));
    }
    let len = usize::try_from(d.get::<u64>()?).unwrap_or(usize::MAX);
    let version = d.version;
    let mut body = Decoder::new(d.take(len)?, section.name).of_version(version);
    let value = read(&mut body)?;
    if body.remaining() > 0 {
        return Err(corrupt(format!(
            "{}: {} unread bytes at its end",
            section.name,
            body.remaining()
        )));
    }
    Ok(value)
}

/// Up to `n` bytes from `r` (fewer at end of input), allocating only what is read.
fn read_up_to(r: &mut impl Read, n: u64) -> Result<Vec<u8>, MapError> {
    let mut out = Vec::new();
    r.take(n).read_to_end(&mut out)?;
    Ok(out)
}
