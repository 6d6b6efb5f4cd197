//! RGB-D SLAM on a TUM RGB-D sequence, all in Rust: the images decoded here (RGB PNG or JPEG,
//! 16-bit depth PNG), ORB extracted by `ferroslam_features::OrbExtractor`, depth sampled at the
//! keypoints, `ferroslam_slam::SlamSystem` fed frame by frame; then the frames tracked, the
//! timings and the ATE against `groundtruth.txt`.
//!
//! ```text
//! cargo run --release -p ferroslam-slam --example tum_rgbd -- [SEQUENCE] [--max-frames N]
//!     [--trajectory OUT.txt] [--vocabulary FILE | --no-vocabulary]
//! ```
//!
//! `SEQUENCE` is a folder in the TUM layout (`rgb.txt`, `depth.txt`, `groundtruth.txt`, `rgb/`,
//! `depth/`); by default `tum/rgbd_dataset_freiburg1_rpy` in `$FERROSLAM_DATA`, or in
//! `../shared/data` beside the workspace without the variable. The camera is TUM's freiburg 1,
//! 2 or 3, from the folder name. RGB and depth frames are paired as TUM's `associate.py` pairs
//! them (closer than 0.02 s, greedily by time difference). Colour becomes grey as OpenCV's
//! `imread(IMREAD_GRAYSCALE)`, which the Python pipeline uses, makes it: a JPEG's luma, a
//! PNG's RGB weighted as libpng does; the decoders differ in rounding, by one grey level in
//! a few percent of the pixels, and so do the trajectories a little. `--trajectory` writes
//! the frames' poses `T_w_c` in the TUM format. The ORB vocabulary (relocalisation and loop
//! closing) is the one the Python package ships, `python/ferroslam/vocabulary/
//! orb_vocabulary.fsv`, unless another is named or `--no-vocabulary` is given.
//!
//! The ATE is the RMSE of the camera positions after the rigid (SE(3)) alignment to the ground
//! truth that minimises it (Umeyama), each frame paired with the ground-truth pose closest in
//! time within 0.02 s.

#![allow(non_snake_case)]

use std::fs::File;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

use ferroslam_features::{OrbExtractor, OwnedGrayImage};
use ferroslam_geometry::camera::{PinholeCamera, RadTan};
use ferroslam_geometry::umeyama::umeyama;
use ferroslam_slam::{RgbdInput, Sensor, SlamConfig, SlamSystem, TrackingState};
use ferroslam_vocabulary::Vocabulary;
use nalgebra::Vector3;

type Error = Box<dyn std::error::Error>;

const USAGE: &str = "usage: tum_rgbd [SEQUENCE] [--max-frames N] [--trajectory OUT.txt] \
                     [--vocabulary FILE | --no-vocabulary]";

/// TUM's depth images: pixel value per metre.
const DEPTH_FACTOR: f32 = 5000.0;
/// Largest time difference (s) of frames paired, as TUM's `associate.py`.
const MAX_DIFF_S: f64 = 0.02;

/// Intrinsics `fx fy cx cy` and distortion `k1 k2 p1 p2 k3` of TUM's freiburg 1, 2 and 3
/// cameras (TUM RGB-D benchmark page; 640 x 480).
const TUM_CAMERAS: [([f64; 4], [f64; 5]); 3] = [
    (
        [517.3, 516.5, 318.6, 255.3],
        [0.2624, -0.9531, -0.0054, 0.0026, 1.1633],
    ),
    (
        [520.9, 521.0, 325.1, 249.7],
        [0.2312, -0.7849, -0.0033, -0.0001, 0.9172],
    ),
    ([535.4, 539.2, 320.1, 247.6], [0.0; 5]),
];

struct Args {
    sequence: PathBuf,
    max_frames: usize,
    trajectory: Option<PathBuf>,
    vocabulary: Option<PathBuf>,
}

fn parse_args() -> Result<Args, Error> {
    let data = std::env::var_os("FERROSLAM_DATA").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
        PathBuf::from,
    );
    let mut args = Args {
        sequence: data.join("tum/rgbd_dataset_freiburg1_rpy"),
        max_frames: usize::MAX,
        trajectory: None,
        vocabulary: Some(
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../python/ferroslam/vocabulary/orb_vocabulary.fsv"),
        ),
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = || it.next().ok_or(format!("{arg} needs a value"));
        match arg.as_str() {
            "--max-frames" => args.max_frames = value()?.parse()?,
            "--trajectory" => args.trajectory = Some(value()?.into()),
            "--vocabulary" => args.vocabulary = Some(value()?.into()),
            "--no-vocabulary" => args.vocabulary = None,
            "-h" | "--help" => {
                return Err(USAGE.into());
            }
            _ if !arg.starts_with('-') => args.sequence = arg.into(),
            _ => return Err(format!("unknown option {arg}; {USAGE}").into()),
        }
    }
    Ok(args)
}

/// The camera of a sequence folder named `..._freiburgN_...`.
fn tum_camera(sequence: &Path) -> Result<PinholeCamera, Error> {
    let name = sequence
        .canonicalize()
        .map_err(|e| format!("{}: {e}", sequence.display()))?
        .to_string_lossy()
        .into_owned();
    let n = (1..=3)
        .find(|n| name.contains(&format!("freiburg{n}")))
        .ok_or_else(|| format!("{name}: not a TUM freiburg 1/2/3 sequence folder"))?;
    let ([fx, fy, cx, cy], [k1, k2, p1, p2, k3]) = TUM_CAMERAS[n - 1];
    let distortion = RadTan { k1, k2, p1, p2, k3 };
    Ok(PinholeCamera::new(fx, fy, cx, cy, distortion, 640, 480)?)
}

/// The `(timestamp, rest of line)` rows of a TUM list (`#` lines are comments).
fn read_list(path: &Path) -> Result<Vec<(f64, String)>, Error> {
    let file = File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut rows = Vec::new();
    for line in BufReader::new(file).lines() {
        let line = line?;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (t, rest) = line.split_once(' ').ok_or(format!("bad line {line:?}"))?;
        rows.push((t.parse()?, rest.trim().to_owned()));
    }
    Ok(rows)
}

/// Index pairs `(i, j)` with `|a[i] - b[j]| < MAX_DIFF_S`, taken greedily by increasing
/// difference, each index at most once; sorted by `i` (TUM's `associate.py`).
fn associate(a: &[f64], b: &[f64]) -> Vec<(usize, usize)> {
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (i, &ta) in a.iter().enumerate() {
        let first = b.partition_point(|&tb| tb <= ta - MAX_DIFF_S);
        for (j, &tb) in b.iter().enumerate().skip(first) {
            if tb >= ta + MAX_DIFF_S {
                break;
            }
            candidates.push(((ta - tb).abs(), i, j));
        }
    }
    candidates.sort_by(|x, y| x.0.total_cmp(&y.0).then((x.1, x.2).cmp(&(y.1, y.2))));
    let (mut used_a, mut used_b) = (vec![false; a.len()], vec![false; b.len()]);
    let mut pairs = Vec::new();
    for (_, i, j) in candidates {
        if !used_a[i] && !used_b[j] {
            (used_a[i], used_b[j]) = (true, true);
            pairs.push((i, j));
        }
    }
    pairs.sort_unstable();
    pairs
}

/// Grey from 8-bit RGB as libpng's `png_set_rgb_to_gray(0.299, 0.587)` makes it:
/// `(9798 R + 19235 G + 3735 B) >> 15`.
fn rgb_to_gray(rgb: &[u8]) -> Vec<u8> {
    rgb.chunks_exact(3)
        .map(|p| {
            let [r, g, b] = [p[0], p[1], p[2]].map(u32::from);
            ((9798 * r + 19235 * g + 3735 * b) >> 15) as u8
        })
        .collect()
}

/// `(width, height, samples)` of a PNG of colour type and bit depth `kind` (16-bit samples
/// big-endian); `what` names the kind in the error.
fn read_png(
    path: &Path,
    kind: (png::ColorType, png::BitDepth),
    what: &str,
) -> Result<(usize, usize, Vec<u8>), Error> {
    let context = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let reader = BufReader::new(File::open(path).map_err(|e| context(&e))?);
    let mut png = png::Decoder::new(reader)
        .read_info()
        .map_err(|e| context(&e))?;
    let mut buf = vec![0; png.output_buffer_size().ok_or("PNG too large")?];
    let info = png.next_frame(&mut buf).map_err(|e| context(&e))?;
    if (info.color_type, info.bit_depth) != kind {
        return Err(context(&format!("expected {what}")).into());
    }
    buf.truncate(info.buffer_size());
    Ok((info.width as usize, info.height as usize, buf))
}

/// A colour image (RGB PNG or YCbCr JPEG) in grey.
fn read_gray(path: &Path) -> Result<OwnedGrayImage, Error> {
    let is_png = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    let (width, height, gray) = if is_png {
        let kind = (png::ColorType::Rgb, png::BitDepth::Eight);
        let (width, height, rgb) = read_png(path, kind, "an 8-bit RGB PNG")?;
        (width, height, rgb_to_gray(&rgb))
    } else {
        let context = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
        let reader = BufReader::new(File::open(path).map_err(|e| context(&e))?);
        let mut jpeg = jpeg_decoder::Decoder::new(reader);
        // "RGB": no conversion, so the channels stay Y, Cb, Cr
        jpeg.set_color_transform(jpeg_decoder::ColorTransform::RGB);
        let pixels = jpeg.decode().map_err(|e| context(&e))?;
        let info = jpeg.info().ok_or("JPEG without a header")?;
        if info.pixel_format != jpeg_decoder::PixelFormat::RGB24 {
            return Err(context(&"expected a three-channel JPEG").into());
        }
        let luma = pixels.chunks_exact(3).map(|p| p[0]).collect();
        (usize::from(info.width), usize::from(info.height), luma)
    };
    Ok(OwnedGrayImage::new(width, height, gray)?)
}

/// A 16-bit depth PNG in metres, with its width.
fn read_depth_m(path: &Path) -> Result<(usize, Vec<f32>), Error> {
    let kind = (png::ColorType::Grayscale, png::BitDepth::Sixteen);
    let (width, _, samples) = read_png(path, kind, "a 16-bit grey PNG")?;
    let depth = samples
        .chunks_exact(2)
        .map(|be| f32::from(u16::from_be_bytes([be[0], be[1]])) / DEPTH_FACTOR)
        .collect();
    Ok((width, depth))
}

/// Depth (m) at the pixel nearest `(x, y)`, 0 outside the image.
fn depth_at((width, depth_m): &(usize, Vec<f32>), x: f32, y: f32) -> f32 {
    let (u, v) = (x.round_ties_even(), y.round_ties_even());
    let inside = u >= 0.0 && v >= 0.0 && (u as usize) < *width;
    inside
        .then(|| depth_m.get(v as usize * width + u as usize))
        .flatten()
        .copied()
        .unwrap_or(0.0)
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}

fn run() -> Result<(), Error> {
    let args = parse_args()?;
    let seq = &args.sequence;
    let camera = tum_camera(seq)?;
    let (rgb, depth) = (
        read_list(&seq.join("rgb.txt"))?,
        read_list(&seq.join("depth.txt"))?,
    );
    let times = |rows: &[(f64, String)]| rows.iter().map(|r| r.0).collect::<Vec<_>>();
    let pairs = associate(&times(&rgb), &times(&depth));

    let config = SlamConfig::for_camera(Sensor::Rgbd, camera.width);
    let extractor = OrbExtractor::new(config.extractor.orb())?;
    let mut slam = SlamSystem::new(camera, config)?;
    if let Some(path) = &args.vocabulary {
        let vocabulary = Vocabulary::load(path).map_err(|e| format!("{}: {e}", path.display()))?;
        slam.set_vocabulary(Arc::new(vocabulary));
    }
    let (mut extract_ms, mut track_ms, mut tracked) = (Vec::new(), Vec::new(), 0);
    let frames = pairs.len().min(args.max_frames);
    println!("{}: {frames} RGB-D frames", seq.display());
    for &(i, j) in &pairs[..frames] {
        let gray = read_gray(&seq.join(&rgb[i].1))?;
        let depth_m = read_depth_m(&seq.join(&depth[j].1))?;
        let start = Instant::now();
        let features = extractor.extract(&gray.view(), None)?;
        extract_ms.push(start.elapsed().as_secs_f64() * 1e3);
        let keypoint_depths: Vec<f32> = features
            .keypoints
            .iter()
            .map(|k| depth_at(&depth_m, k.x, k.y))
            .collect();
        let start = Instant::now();
        let result = slam.track_rgbd(&RgbdInput {
            timestamp: rgb[i].0,
            keypoints: &features.keypoints,
            descriptors: &features.descriptors,
            depth_m: &keypoint_depths,
            colors: None,
        })?;
        track_ms.push(start.elapsed().as_secs_f64() * 1e3);
        tracked += usize::from(result.state == TrackingState::Ok);
    }
    slam.finish_mapping()?;
    let trajectory = slam.frame_trajectory();
    println!(
        "tracked {tracked} of {frames} frames; {} keyframes, {} map points",
        slam.keyframe_trajectory().len(),
        slam.map_points().len()
    );
    println!(
        "median per frame: ORB extraction {:.2} ms, tracking + mapping {:.2} ms",
        median(extract_ms),
        median(track_ms)
    );
    if let Some(path) = &args.trajectory {
        let mut out = std::io::BufWriter::new(File::create(path)?);
        for (t, T_w_c) in &trajectory {
            let (p, q) = (T_w_c.translation.vector, T_w_c.rotation);
            let (x, y, z, w) = (q.i, q.j, q.k, q.w);
            writeln!(out, "{t:.6} {} {} {} {x} {y} {z} {w}", p.x, p.y, p.z)?;
        }
        println!("trajectory (TUM format) written to {}", path.display());
    }
    let truth = read_list(&seq.join("groundtruth.txt"))?;
    let position = |row: &str| -> Result<Vector3<f64>, Error> {
        let v: Vec<f64> = row
            .split_whitespace()
            .take(3)
            .map(str::parse)
            .collect::<Result<_, _>>()?;
        Ok(Vector3::new(v[0], v[1], v[2]))
    };
    let matched = associate(
        &trajectory.iter().map(|f| f.0).collect::<Vec<_>>(),
        &times(&truth),
    );
    let estimated: Vec<Vector3<f64>> = matched
        .iter()
        .map(|&(i, _)| trajectory[i].1.translation.vector)
        .collect();
    let reference = matched
        .iter()
        .map(|&(_, j)| position(&truth[j].1))
        .collect::<Result<Vec<_>, _>>()?;
    let S_ref_est = umeyama(&estimated, &reference, false).ok_or("too few poses to align")?;
    let squared: f64 = estimated
        .iter()
        .zip(&reference)
        .map(|(e, r)| (S_ref_est.transform_point(e) - r).norm_squared())
        .sum();
    let rmse_m = (squared / estimated.len() as f64).sqrt();
    println!(
        "ATE (SE(3)-aligned, {} poses): RMSE {:.2} cm",
        estimated.len(),
        rmse_m * 100.0
    );
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tum_rgbd: {e}");
            ExitCode::FAILURE
        }
    }
}
