//! A line-based text form of [`BaProblem`], so that other solvers can be run on exactly the
//! problems ours solves (local BA problems recorded during a run, synthetic ones).
//!
//! ```text
//! ferroslam-ba 1
//! intrinsics <fx> <fy> <cx> <cy> <bf> [kannala_brandt <k1> <k2> <k3> <k4> <w> <h>]
//!                                                          pixels; bf in pixels * metres
//! poses <n>
//! <fixed 0|1> <qw> <qx> <qy> <qz> <tx> <ty> <tz>           x n: T_c_w, unit quaternion, metres
//! points <m>
//! <x> <y> <z>                                              x m: p_w, metres
//! observations <k>
//! <pose> <point> <u> <v> <u_right | -> <inv_sigma2> [<camera>]
//!                                                          x k: pixels, 1/pixels^2
//! ```
//!
//! A multi-camera rig replaces the `intrinsics` line by a `cameras` section, each camera an
//! `intrinsics` line as above followed by its pose relative to the first camera (`-` for
//! [`RigCamera::first`]):
//!
//! ```text
//! cameras <c>
//! intrinsics <fx> <fy> <cx> <cy> <bf> [kannala_brandt ...]  x c, each followed by
//! T_c_c0 <qw> <qx> <qy> <qz> <tx> <ty> <tz> | T_c_c0 -      unit quaternion, metres
//! ```
//!
//! and an observation's last field `<camera>` indexes the cameras (written only when not 0,
//! its default). A problem of one [`RigCamera::first`] is written with the single
//! `intrinsics` line, so single-camera text stays that of readers that know nothing of rigs.
//! The `kannala_brandt` tail marks a fisheye camera (coefficients and image size).
//! `-` marks a monocular observation (no right coordinate). Numbers are written in Rust's
//! shortest round-trip form, so reading a written problem gives it back bit for bit.

use super::problem::{BaProblem, Observation};
use crate::error::OptimError;
use crate::intrinsics::Intrinsics;
use crate::rig_camera::RigCamera;
use ferroslam_geometry::camera::KannalaBrandtCamera;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector2, Vector3};
use std::fmt::Write;

/// First line of the format, with its version.
const HEADER: &str = "ferroslam-ba 1";
/// Opens the cameras section of a rig.
const CAMERAS: &str = "cameras";
/// Opens a camera's pose relative to the first camera.
const EXTRINSICS: &str = "T_c_c0";
/// Marks the fisheye tail of the intrinsics line.
const FISHEYE: &str = "kannala_brandt";
/// How far from 1 a quaternion's norm may be (the text keeps 17 significant digits).
const UNIT_TOLERANCE: f64 = 1e-9;

impl BaProblem {
    /// The problem in the text form described in the module documentation.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        // Writing to a String cannot fail.
        let _ = writeln!(s, "{HEADER}");
        match self.cameras.as_slice() {
            [RigCamera {
                intrinsics,
                T_c_c0: None,
            }] => write_intrinsics(&mut s, intrinsics),
            cameras => {
                let _ = writeln!(s, "{CAMERAS} {}", cameras.len());
                for c in cameras {
                    write_intrinsics(&mut s, &c.intrinsics);
                    let _ = write!(s, "{EXTRINSICS}");
                    match &c.T_c_c0 {
                        None => {
                            let _ = writeln!(s, " -");
                        }
                        Some(t) => {
                            write_isometry(&mut s, t);
                            let _ = writeln!(s);
                        }
                    }
                }
            }
        }
        let _ = writeln!(s, "poses {}", self.poses.len());
        for (pose, &fixed) in self.poses.iter().zip(&self.pose_fixed) {
            let _ = write!(s, "{}", u8::from(fixed));
            write_isometry(&mut s, pose);
            let _ = writeln!(s);
        }
        let _ = writeln!(s, "points {}", self.points.len());
        for p in &self.points {
            let _ = writeln!(s, "{} {} {}", p.x, p.y, p.z);
        }
        let _ = writeln!(s, "observations {}", self.observations.len());
        for o in &self.observations {
            let right = o.u_right.map_or_else(|| "-".to_owned(), |u| u.to_string());
            let _ = write!(
                s,
                "{} {} {} {} {right} {}",
                o.pose, o.point, o.uv.x, o.uv.y, o.inv_sigma2
            );
            if o.camera != 0 {
                let _ = write!(s, " {}", o.camera);
            }
            let _ = writeln!(s);
        }
        s
    }

    /// Reads the text form; `name` labels error messages (a file name, say).
    ///
    /// # Errors
    /// [`OptimError::InvalidInput`] naming the line for a wrong header, a missing or
    /// unparsable section, count or value, a quaternion that is not of unit norm, or text left
    /// over; then as [`BaProblem::validate`] (indices, finiteness, information weights).
    pub fn from_text(text: &str, name: &str) -> Result<Self, OptimError> {
        let mut lines = Lines::new(text, name);
        let header = lines.next("the header")?;
        if header.text != HEADER {
            return Err(header.error(&format!("expected the header '{HEADER}'")));
        }
        let cameras = parse_cameras(&mut lines)?;
        let n_poses = lines.count("poses")?;
        let mut poses = Vec::with_capacity(n_poses);
        let mut pose_fixed = Vec::with_capacity(n_poses);
        for _ in 0..n_poses {
            let line = lines.next("a pose")?;
            let [fixed, qw, qx, qy, qz, tx, ty, tz] = line.values("")?;
            pose_fixed.push(match fixed {
                0.0 => false,
                1.0 => true,
                _ => return Err(line.error("the fixed flag must be 0 or 1")),
            });
            poses.push(line.isometry([qw, qx, qy, qz, tx, ty, tz])?);
        }
        let n_points = lines.count("points")?;
        let mut points = Vec::with_capacity(n_points);
        for _ in 0..n_points {
            let [x, y, z] = lines.next("a point")?.values("")?;
            points.push(Vector3::new(x, y, z));
        }
        let n_observations = lines.count("observations")?;
        let mut observations = Vec::with_capacity(n_observations);
        for _ in 0..n_observations {
            let line = lines.next("an observation")?;
            // An observation of the first camera may leave out its camera index.
            let tokens: Vec<&str> = line.text.split_whitespace().collect();
            let (fields, camera) = match *tokens.as_slice() {
                [a, b, c, d, e, f] => ([a, b, c, d, e, f], None),
                [a, b, c, d, e, f, camera] => ([a, b, c, d, e, f], Some(camera)),
                _ => {
                    let found = tokens.len();
                    return Err(line.error(&format!("expected 6 or 7 fields, found {found}")));
                }
            };
            let [pose, point, u, v, u_right, inv_sigma2] = fields;
            let index = |token: &str| {
                token
                    .parse::<usize>()
                    .map_err(|_| line.error(&format!("'{token}' is not an index")))
            };
            let u_right = match u_right {
                "-" => None,
                token => Some(line.number(token)?),
            };
            observations.push(Observation {
                pose: index(pose)?,
                point: index(point)?,
                camera: camera.map_or(Ok(0), index)?,
                uv: Vector2::new(line.number(u)?, line.number(v)?),
                u_right,
                inv_sigma2: line.number(inv_sigma2)?,
                // The text format records global-shutter problems only.
                readout_motion: None,
            });
        }
        if let Some(extra) = lines.next_nonempty() {
            return Err(extra.error("text after the last observation"));
        }
        let problem = Self {
            cameras,
            poses,
            pose_fixed,
            points,
            observations,
        };
        problem.validate()?;
        Ok(problem)
    }
}

/// The non-empty lines of a text, numbered for error messages.
struct Lines<'a> {
    lines: std::iter::Enumerate<std::str::Lines<'a>>,
    name: &'a str,
    /// Line number of the end of the text, for "ends before" errors.
    end: usize,
}

/// Writes ` <qw> <qx> <qy> <qz> <tx> <ty> <tz>` of `t`.
fn write_isometry(s: &mut String, t: &Isometry3<f64>) {
    let q = t.rotation.quaternion();
    let v = &t.translation.vector;
    let _ = write!(
        s,
        " {} {} {} {} {} {} {}",
        q.w, q.i, q.j, q.k, v.x, v.y, v.z
    );
}

/// Writes the intrinsics line of `k`.
fn write_intrinsics(s: &mut String, k: &Intrinsics) {
    let _ = write!(s, "intrinsics {} {} {} {} {}", k.fx, k.fy, k.cx, k.cy, k.bf);
    if let Some(c) = &k.fisheye {
        let [k1, k2, k3, k4] = c.k;
        let (w, h) = (c.width, c.height);
        let _ = write!(s, " {FISHEYE} {k1} {k2} {k3} {k4} {w} {h}");
    }
    let _ = writeln!(s);
}

/// The single camera's `intrinsics` line, or the `cameras` section of a rig.
#[allow(non_snake_case)]
fn parse_cameras(lines: &mut Lines<'_>) -> Result<Vec<RigCamera>, OptimError> {
    let line = lines.next("the intrinsics")?;
    if line.text.split_whitespace().next() != Some(CAMERAS) {
        return Ok(vec![RigCamera::first(parse_intrinsics(&line)?)]);
    }
    let [count] = line.fields(CAMERAS)?;
    let n: usize = count
        .parse()
        .map_err(|_| line.error(&format!("'{count}' is not a count")))?;
    let mut cameras = Vec::with_capacity(n);
    for _ in 0..n {
        let intrinsics = parse_intrinsics(&lines.next("a camera's intrinsics")?)?;
        let line = lines.next("a camera's T_c_c0")?;
        let T_c_c0 = match line.text.split_whitespace().collect::<Vec<_>>().as_slice() {
            [EXTRINSICS, "-"] => None,
            _ => Some(line.isometry(line.values(EXTRINSICS)?)?),
        };
        cameras.push(RigCamera { intrinsics, T_c_c0 });
    }
    Ok(cameras)
}

/// The intrinsics line, pinhole or with the fisheye tail.
fn parse_intrinsics(line: &Line<'_>) -> Result<Intrinsics, OptimError> {
    let (pinhole, fisheye) = match line.text.split_once(FISHEYE) {
        Some((pinhole, fisheye)) => (pinhole, Some(fisheye)),
        None => (line.text, None),
    };
    let head = Line {
        text: pinhole.trim(),
        ..*line
    };
    let [fx, fy, cx, cy, bf] = head.values("intrinsics")?;
    let fisheye = match fisheye {
        None => None,
        Some(tail) => {
            let tail = Line {
                text: tail.trim(),
                ..*line
            };
            let [k1, k2, k3, k4, w, h] = tail.values("")?;
            let size = |v: f64| {
                (v >= 1.0 && v.fract() == 0.0 && v <= f64::from(u32::MAX))
                    .then_some(v as u32)
                    .ok_or_else(|| line.error(&format!("'{v}' is not an image size")))
            };
            let camera =
                KannalaBrandtCamera::new(fx, fy, cx, cy, [k1, k2, k3, k4], size(w)?, size(h)?)
                    .map_err(|e| line.error(&e.to_string()))?;
            Some(camera)
        }
    };
    Ok(Intrinsics {
        fx,
        fy,
        cx,
        cy,
        bf,
        fisheye,
    })
}

/// One line and where it is.
struct Line<'a> {
    text: &'a str,
    number: usize,
    name: &'a str,
}

impl<'a> Lines<'a> {
    fn new(text: &'a str, name: &'a str) -> Self {
        Self {
            lines: text.lines().enumerate(),
            name,
            end: text.lines().count() + 1,
        }
    }

    fn next_nonempty(&mut self) -> Option<Line<'a>> {
        self.lines
            .by_ref()
            .map(|(i, text)| Line {
                text: text.trim(),
                number: i + 1,
                name: self.name,
            })
            .find(|l| !l.text.is_empty())
    }

    fn next(&mut self, what: &str) -> Result<Line<'a>, OptimError> {
        let end = self.end;
        let name = self.name;
        self.next_nonempty().ok_or_else(|| {
            Line {
                text: "",
                number: end,
                name,
            }
            .error(&format!("the text ends before {what}"))
        })
    }

    /// The count of a section line `<keyword> <count>`.
    fn count(&mut self, keyword: &str) -> Result<usize, OptimError> {
        let line = self.next(&format!("the '{keyword}' line"))?;
        let [key, count] = line.fields("")?;
        if key != keyword {
            return Err(line.error(&format!("expected '{keyword} <count>'")));
        }
        count
            .parse()
            .map_err(|_| line.error(&format!("'{count}' is not a count")))
    }
}

impl Line<'_> {
    /// The isometry of `[qw, qx, qy, qz, tx, ty, tz]` read from this line.
    fn isometry(
        &self,
        [qw, qx, qy, qz, tx, ty, tz]: [f64; 7],
    ) -> Result<Isometry3<f64>, OptimError> {
        let q = Quaternion::new(qw, qx, qy, qz);
        if (q.norm() - 1.0).abs() > UNIT_TOLERANCE {
            return Err(self.error("the rotation is not a unit quaternion"));
        }
        Ok(Isometry3::from_parts(
            Translation3::new(tx, ty, tz),
            UnitQuaternion::new_unchecked(q),
        ))
    }

    fn error(&self, what: &str) -> OptimError {
        OptimError::InvalidInput(format!("{}, line {}: {what}", self.name, self.number))
    }

    /// The `N` whitespace-separated fields, after a leading `keyword` if it is not empty.
    fn fields<const N: usize>(&self, keyword: &str) -> Result<[&str; N], OptimError> {
        let mut tokens = self.text.split_whitespace();
        if !keyword.is_empty() && tokens.next() != Some(keyword) {
            return Err(self.error(&format!("expected '{keyword}'")));
        }
        let tokens: Vec<&str> = tokens.collect();
        let wanted = N + usize::from(!keyword.is_empty());
        let found = tokens.len() + usize::from(!keyword.is_empty());
        tokens
            .try_into()
            .map_err(|_| self.error(&format!("expected {wanted} fields, found {found}")))
    }

    fn number(&self, token: &str) -> Result<f64, OptimError> {
        token
            .parse()
            .map_err(|_| self.error(&format!("'{token}' is not a number")))
    }

    /// `N` numbers, after a leading `keyword` if it is not empty.
    fn values<const N: usize>(&self, keyword: &str) -> Result<[f64; N], OptimError> {
        let fields: [&str; N] = self.fields(keyword)?;
        let mut values = [0.0; N];
        for (value, token) in values.iter_mut().zip(fields) {
            *value = self.number(token)?;
        }
        Ok(values)
    }
}

#[cfg(test)]
#[allow(non_snake_case)]
mod tests {
    use super::*;

    fn problem() -> BaProblem {
        let rotation = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3);
        BaProblem {
            cameras: vec![RigCamera::first(Intrinsics {
                fx: 517.3,
                fy: 516.5,
                cx: 318.6,
                cy: 255.3,
                bf: 40.0,
                fisheye: None,
            })],
            poses: vec![
                Isometry3::identity(),
                Isometry3::from_parts(Translation3::new(0.1, -1.0 / 3.0, 2e-7), rotation),
            ],
            pose_fixed: vec![true, false],
            points: vec![Vector3::new(0.5, -0.25, 3.0), Vector3::new(1e-3, 2.0, 7.1)],
            observations: vec![
                Observation {
                    pose: 0,
                    point: 0,
                    camera: 0,
                    uv: Vector2::new(404.5, 213.125),
                    u_right: Some(391.2),
                    inv_sigma2: 1.0,
                    readout_motion: None,
                },
                Observation {
                    pose: 1,
                    point: 1,
                    camera: 0,
                    uv: Vector2::new(100.0 / 7.0, 30.0),
                    u_right: None,
                    inv_sigma2: 1.0 / 1.44,
                    readout_motion: None,
                },
            ],
        }
    }

    fn error(text: &str) -> String {
        match BaProblem::from_text(text, "p.txt") {
            Err(OptimError::InvalidInput(e)) => e,
            other => panic!("expected InvalidInput, got {other:?}"),
        }
    }

    #[test]
    fn a_written_problem_reads_back_bit_for_bit() {
        let p = problem();
        let text = p.to_text();
        assert!(text.starts_with("ferroslam-ba 1\nintrinsics 517.3 516.5 318.6 255.3 40\n"));
        assert!(text.contains("\n1 1 0 0 0 0 0 0\n"), "{text}");
        assert!(text.ends_with(&format!("1 1 {} 30 - {}\n", 100.0 / 7.0, 1.0 / 1.44)));
        assert_eq!(BaProblem::from_text(&text, "p.txt").unwrap(), p);
    }

    #[test]
    fn a_fisheye_problem_reads_back_with_its_lens() {
        let mut p = problem();
        let (_, lens) = ferroslam_geometry::camera::test_fisheye_cameras()[0];
        p.cameras = vec![RigCamera::first(Intrinsics::new(&lens.into(), 40.0))];
        let text = p.to_text();
        assert!(
            text.lines().nth(1).unwrap().contains(" kannala_brandt "),
            "{text}"
        );
        assert_eq!(BaProblem::from_text(&text, "p.txt").unwrap(), p);
    }

    #[test]
    fn a_rig_problem_reads_back_with_its_cameras() {
        let mut p = problem();
        let (_, lens) = ferroslam_geometry::camera::test_fisheye_cameras()[0];
        let T_c1_c0 = Isometry3::from_parts(
            Translation3::new(-0.1, 0.02, 1.0 / 3.0),
            UnitQuaternion::from_euler_angles(0.0, 1.5, 0.1),
        );
        p.cameras
            .push(RigCamera::new(Intrinsics::new(&lens.into(), 0.0), T_c1_c0));
        p.observations[1].camera = 1;
        let text = p.to_text();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[1], "cameras 2");
        assert!(lines[2].starts_with("intrinsics 517.3 "), "{text}");
        assert_eq!(lines[3], "T_c_c0 -");
        assert!(lines[4].contains(" kannala_brandt "), "{text}");
        assert!(lines[5].starts_with("T_c_c0 "), "{text}");
        assert!(text.ends_with(&format!("1 1 {} 30 - {} 1\n", 100.0 / 7.0, 1.0 / 1.44)));
        assert_eq!(BaProblem::from_text(&text, "p.txt").unwrap(), p);
        // A first camera given an extrinsic pose is a rig of one camera, kept as such.
        let mut one = problem();
        one.cameras[0].T_c_c0 = Some(T_c1_c0);
        let text = one.to_text();
        assert!(text.starts_with("ferroslam-ba 1\ncameras 1\n"), "{text}");
        assert_eq!(BaProblem::from_text(&text, "p.txt").unwrap(), one);
    }

    #[test]
    fn a_malformed_rig_is_refused_naming_the_line() {
        let mut p = problem();
        p.cameras.push(RigCamera::new(
            p.cameras[0].intrinsics,
            Isometry3::identity(),
        ));
        p.observations[1].camera = 1;
        let text = p.to_text();
        let lines: Vec<&str> = text.lines().collect();
        let with_line = |i: usize, new: &str| {
            let mut l = lines.clone();
            l[i] = new;
            l.join("\n")
        };
        assert_eq!(
            error(&with_line(5, "T_c_c0 1 0 0 0 0 0")),
            "p.txt, line 6: expected 8 fields, found 7"
        );
        assert_eq!(
            error(&with_line(5, "T_c_c0 2 0 0 0 0 0 0")),
            "p.txt, line 6: the rotation is not a unit quaternion"
        );
        assert_eq!(
            error(&with_line(1, "cameras two")),
            "p.txt, line 2: 'two' is not a count"
        );
        let last = lines.len() - 1;
        assert_eq!(
            error(&with_line(last, "1 1 1 30 - 1 x")),
            format!("p.txt, line {}: 'x' is not an index", last + 1)
        );
        assert_eq!(
            error(&with_line(last, "1 1 1 30 - 1 1 1")),
            format!("p.txt, line {}: expected 6 or 7 fields, found 8", last + 1)
        );
        assert_eq!(
            BaProblem::from_text(&with_line(last, "1 1 1 30 - 1 2"), "p.txt"),
            Err(OptimError::IndexOutOfRange {
                observation: 1,
                what: "camera",
                index: 2,
                len: 2
            })
        );
    }

    #[test]
    fn malformed_text_is_refused_naming_the_line() {
        let text = problem().to_text();
        let lines: Vec<&str> = text.lines().collect();
        let with_line = |i: usize, new: &str| {
            let mut l = lines.clone();
            l[i] = new;
            l.join("\n")
        };
        assert_eq!(
            error("ferroslam-ba 2\n"),
            "p.txt, line 1: expected the header 'ferroslam-ba 1'"
        );
        assert_eq!(
            error(&lines[..4].join("\n")),
            "p.txt, line 5: the text ends before a pose"
        );
        assert_eq!(
            error(&with_line(1, "intrinsics 517.3 516.5 318.6 255.3")),
            "p.txt, line 2: expected 6 fields, found 5"
        );
        assert_eq!(
            error(&with_line(3, "2 1 0 0 0 0 0 0")),
            "p.txt, line 4: the fixed flag must be 0 or 1"
        );
        assert_eq!(
            error(&with_line(3, "1 1 0.1 0 0 0 0 0")),
            "p.txt, line 4: the rotation is not a unit quaternion"
        );
        assert_eq!(
            error(&with_line(5, "point 2")),
            "p.txt, line 6: expected 'points <count>'"
        );
        assert_eq!(
            error(&with_line(6, "0.5 -0.25 x")),
            "p.txt, line 7: 'x' is not a number"
        );
        assert_eq!(
            error(&with_line(10, "-1 0 404.5 213.125 - 1")),
            "p.txt, line 11: '-1' is not an index"
        );
        assert_eq!(
            error(&format!("{text}0 0 1 1 - 1\n")),
            "p.txt, line 12: text after the last observation"
        );
    }

    #[test]
    fn a_well_formed_but_invalid_problem_fails_validation() {
        let text = problem().to_text();
        let (head, last) = text.trim_end().rsplit_once('\n').unwrap();
        let text = format!("{head}\n{}", last.replacen("1 1 ", "1 5 ", 1));
        assert_eq!(
            BaProblem::from_text(&text, "p.txt"),
            Err(OptimError::IndexOutOfRange {
                observation: 1,
                what: "point",
                index: 5,
                len: 2
            })
        );
    }
}
