//! Reader for BAL problem files, plain text or bzip2-compressed (`.txt.bz2`, as published).
//!
//! Layout (whitespace-separated, BAL's `problem-*-pre.txt`):
//!
//! ```text
//! <num_cameras> <num_points> <num_observations>
//! <camera> <point> <u> <v>          x num_observations
//! <camera parameter>                x 9 * num_cameras   ([w, t, f, k1, k2] per camera)
//! <point coordinate>                x 3 * num_points
//! ```

use super::problem::{BalObservation, BalProblem};
use super::snavely::{CameraParams, CAMERA_PARAMS};
use crate::error::OptimError;
use nalgebra::{Vector2, Vector3};
use std::io::Read;
use std::path::Path;

/// The bzip2 stream magic ("BZh"): such files are decompressed whatever their name.
const BZIP2_MAGIC: &[u8] = b"BZh";

/// Reads a BAL file; bzip2 content (detected by its magic bytes) is decompressed.
///
/// # Errors
/// [`OptimError::InvalidInput`] naming the file if it cannot be read or decompressed, is not
/// UTF-8, or is malformed (see [`parse_bal`]).
pub fn read_bal(path: impl AsRef<Path>) -> Result<BalProblem, OptimError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let io_err = |e: std::io::Error| OptimError::InvalidInput(format!("cannot read {name}: {e}"));
    let bytes = std::fs::read(path).map_err(io_err)?;
    let text = if bytes.starts_with(BZIP2_MAGIC) {
        let mut text = String::new();
        bzip2::read::MultiBzDecoder::new(bytes.as_slice())
            .read_to_string(&mut text)
            .map_err(io_err)?;
        text
    } else {
        String::from_utf8(bytes)
            .map_err(|e| OptimError::InvalidInput(format!("{name} is not UTF-8 text: {e}")))?
    };
    parse_bal(&text, &name)
}

/// Parses BAL text; `name` labels error messages.
///
/// # Errors
/// [`OptimError::InvalidInput`] for a missing or unparsable count or value, a non-finite
/// value, an observation naming a camera or point beyond the header's counts, or text left
/// over after the last point.
pub fn parse_bal(text: &str, name: &str) -> Result<BalProblem, OptimError> {
    let mut tokens = text.split_whitespace();
    let mut next = |what: &dyn Fn() -> String| {
        tokens
            .next()
            .ok_or_else(|| OptimError::InvalidInput(format!("{name}: file ends before {}", what())))
    };
    let bad = |what: String, token: &str| {
        OptimError::InvalidInput(format!("{name}: {what} is '{token}', not a finite number"))
    };
    let mut count = |what: &'static str| -> Result<usize, OptimError> {
        let t = next(&|| format!("the {what} count"))?;
        t.parse().map_err(|_| bad(format!("the {what} count"), t))
    };
    let (num_cameras, num_points, num_observations) =
        (count("camera")?, count("point")?, count("observation")?);
    let mut number = |what: &dyn Fn() -> String| -> Result<f64, OptimError> {
        let t = next(what)?;
        t.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| bad(what(), t))
    };
    let mut observations = Vec::with_capacity(num_observations);
    for i in 0..num_observations {
        let what = |field: &'static str| move || format!("observation {i}'s {field}");
        let index = |v: f64, len: usize, field: &'static str| {
            let ok = v >= 0.0 && v.fract() == 0.0 && v < len as f64;
            ok.then_some(v as usize).ok_or_else(|| {
                OptimError::InvalidInput(format!(
                    "{name}: observation {i}'s {field} index {v} is not in 0..{len}"
                ))
            })
        };
        let camera = index(number(&what("camera"))?, num_cameras, "camera")?;
        let point = index(number(&what("point"))?, num_points, "point")?;
        let uv = Vector2::new(number(&what("u"))?, number(&what("v"))?);
        observations.push(BalObservation { camera, point, uv });
    }
    let mut cameras = Vec::with_capacity(num_cameras);
    for c in 0..num_cameras {
        let mut params = CameraParams::zeros();
        for k in 0..CAMERA_PARAMS {
            params[k] = number(&|| format!("camera {c}'s parameter {k}"))?;
        }
        cameras.push(params);
    }
    let mut points = Vec::with_capacity(num_points);
    for j in 0..num_points {
        let mut p = Vector3::zeros();
        for k in 0..3 {
            p[k] = number(&|| format!("point {j}'s coordinate {k}"))?;
        }
        points.push(p);
    }
    if let Some(t) = tokens.next() {
        return Err(OptimError::InvalidInput(format!(
            "{name}: unexpected '{t}' after the last point"
        )));
    }
    Ok(BalProblem {
        cameras,
        points,
        observations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bal::fixtures;

    /// Loads fixture `name`, checks its counts and its initial cost against REFERENCE.md's
    /// (exact there; reproduced to 1e-12 relative, summation order aside).
    fn check_fixture(name: &str, counts: (usize, usize, usize), initial_cost: f64) {
        let problem = read_bal(fixtures::path(name)).unwrap();
        let c = &problem;
        assert_eq!(
            (c.cameras.len(), c.points.len(), c.observations.len()),
            counts
        );
        problem.validate().unwrap();
        let cost = problem.cost();
        assert!((cost / initial_cost - 1.0).abs() < 1e-12, "{name}: {cost}");
    }

    #[test]
    fn dubrovnik_loads_with_the_reference_initial_cost() {
        check_fixture("dubrovnik-3-7-pre.txt", (3, 7, 19), 2764.2199844221636);
    }

    #[test]
    fn trafalgar_bz2_loads_with_the_reference_initial_cost() {
        check_fixture(
            "problem-21-11315-pre.txt.bz2",
            (21, 11315, 36455),
            4413239.314432217,
        );
    }

    #[test]
    fn malformed_text_is_an_error_naming_the_problem() {
        let ok = "1 1 1\n0 0 1.0 2.0\n0 0 0 0 0 -1 500 0 0\n0 0 1\n";
        let p = parse_bal(ok, "t").unwrap();
        assert_eq!(p.observations[0].uv, Vector2::new(1.0, 2.0));
        for (text, needle) in [
            ("1 1", "observation count"),
            ("1 1 1\n0 3 1 2", "point index 3"),
            ("1 1 1\n0 0 x 2", "observation 0's u is 'x'"),
            (
                "1 1 1\n0 0 1 2\n0 0 0 0 0 -1 500 0",
                "camera 0's parameter 8",
            ),
            (
                "1 1 1\n0 0 1 2\n0 0 0 0 0 -1 500 0 0\n0 0 inf",
                "point 0's coordinate 2",
            ),
            (&format!("{ok} 7"), "unexpected '7'"),
        ] {
            let e = parse_bal(text, "t").unwrap_err().to_string();
            assert!(e.contains(needle), "{e} lacks {needle}");
        }
        assert!(read_bal("/nonexistent.bal").is_err());
    }
}
