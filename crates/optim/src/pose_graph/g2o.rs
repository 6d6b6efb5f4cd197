//! Reader for 3-D g2o pose-graph files (`VERTEX_SE3:QUAT`, `EDGE_SE3:QUAT`, `FIX`).
//!
//! * `VERTEX_SE3:QUAT id x y z qx qy qz qw`: pose `T_w_id`;
//! * `EDGE_SE3:QUAT i j x y z qx qy qz qw I11 I12 .. I16 I22 .. I66`: measurement
//!   `Z_ij = T_i_j` and the upper triangle (row-major) of its 6x6 information in
//!   `[translation, rotation]` order, which is the se(3) `[rho; phi]` order used here;
//! * `FIX id`: hold pose `id` constant.
//!
//! Quaternions are normalised (files print about 7 digits). Vertex ids may be any
//! non-negative integers; poses are stored in order of first appearance. Without `FIX`
//! lines the first vertex is fixed (the gauge). Blank lines and `#` comments are skipped;
//! any other tag (including the 2-D `VERTEX_SE2` / `EDGE_SE2`) is an error.

use super::problem::{PoseEdge, Se3PoseGraph};
use crate::error::OptimError;
use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};
use std::collections::HashMap;
use std::path::Path;

/// Reads a 3-D g2o file.
///
/// # Errors
/// [`OptimError::InvalidInput`] naming the file (and line, for content errors) if it cannot
/// be read or is malformed: unknown tag, wrong field count, unparsable or non-finite
/// number, zero quaternion, duplicate vertex, edge or `FIX` naming an unknown vertex, no
/// vertices.
pub fn read_g2o(path: impl AsRef<Path>) -> Result<Se3PoseGraph, OptimError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path)
        .map_err(|e| OptimError::InvalidInput(format!("cannot read {}: {e}", path.display())))?;
    parse_g2o(&text, &path.display().to_string())
}

/// Parses g2o text; `name` labels error messages (`name:line: ...`).
///
/// # Errors
/// As [`read_g2o`].
pub fn parse_g2o(text: &str, name: &str) -> Result<Se3PoseGraph, OptimError> {
    let mut index_of: HashMap<u64, usize> = HashMap::new();
    let mut poses = Vec::new();
    // Edges and FIX lines may precede their vertices: resolve ids after the whole file.
    let mut raw_edges = Vec::new();
    let mut fixes = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let lineno = n + 1;
        let err = |msg: String| OptimError::InvalidInput(format!("{name}:{lineno}: {msg}"));
        let mut fields = line.split_whitespace();
        let Some(tag) = fields.next() else { continue };
        if tag.starts_with('#') {
            continue;
        }
        let rest: Vec<&str> = fields.collect();
        let id = |s: &str| {
            s.parse::<u64>()
                .map_err(|_| err(format!("'{s}' is not a vertex id")))
        };
        let numbers = |fields: &[&str]| -> Result<Vec<f64>, OptimError> {
            fields
                .iter()
                .map(|s| {
                    s.parse::<f64>()
                        .ok()
                        .filter(|v| v.is_finite())
                        .ok_or_else(|| err(format!("'{s}' is not a finite number")))
                })
                .collect()
        };
        let expect = |count: usize| {
            if rest.len() == count {
                Ok(())
            } else {
                Err(err(format!(
                    "{tag} needs {count} fields after the tag, found {}",
                    rest.len()
                )))
            }
        };
        match tag {
            "VERTEX_SE3:QUAT" => {
                expect(8)?;
                let v = id(rest[0])?;
                let pose = isometry(&numbers(&rest[1..8])?).map_err(err)?;
                if index_of.insert(v, poses.len()).is_some() {
                    return Err(err(format!("vertex {v} defined twice")));
                }
                poses.push(pose);
            }
            "EDGE_SE3:QUAT" => {
                expect(30)?;
                let (i, j) = (id(rest[0])?, id(rest[1])?);
                let measurement = isometry(&numbers(&rest[2..9])?).map_err(err)?;
                let upper = numbers(&rest[9..30])?;
                let mut information = Matrix6::zeros();
                let mut k = 0;
                for r in 0..6 {
                    for c in r..6 {
                        information[(r, c)] = upper[k];
                        information[(c, r)] = upper[k];
                        k += 1;
                    }
                }
                raw_edges.push((lineno, i, j, measurement, information));
            }
            "FIX" => {
                if rest.is_empty() {
                    return Err(err("FIX needs at least one vertex id".into()));
                }
                for s in &rest {
                    fixes.push((lineno, id(s)?));
                }
            }
            "VERTEX_SE2" | "EDGE_SE2" => {
                return Err(err(format!("{tag}: 2-D pose graphs are not supported")))
            }
            _ => return Err(err(format!("unknown tag {tag}"))),
        }
    }
    if poses.is_empty() {
        return Err(OptimError::InvalidInput(format!(
            "{name}: no VERTEX_SE3:QUAT lines (initial estimates are required)"
        )));
    }
    let resolve = |lineno: usize, v: u64| {
        index_of.get(&v).copied().ok_or_else(|| {
            OptimError::InvalidInput(format!("{name}:{lineno}: vertex {v} is not defined"))
        })
    };
    let edges = raw_edges
        .into_iter()
        .map(|(lineno, i, j, measurement, information)| {
            Ok(PoseEdge {
                from: resolve(lineno, i)?,
                to: resolve(lineno, j)?,
                measurement,
                information,
            })
        })
        .collect::<Result<Vec<_>, OptimError>>()?;
    let mut fixed = vec![false; poses.len()];
    if fixes.is_empty() {
        fixed[0] = true;
    }
    for (lineno, v) in fixes {
        fixed[resolve(lineno, v)?] = true;
    }
    Ok(Se3PoseGraph {
        poses,
        fixed,
        edges,
    })
}

/// `[x y z qx qy qz qw]` to an isometry, normalising the quaternion.
fn isometry(v: &[f64]) -> Result<Isometry3<f64>, String> {
    let q = Quaternion::new(v[6], v[3], v[4], v[5]);
    // The components are finite (checked by the caller).
    if q.norm() <= 1e-6 {
        return Err(format!("quaternion {:?} has (near) zero norm", &v[3..7]));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(v[0], v[1], v[2]),
        UnitQuaternion::from_quaternion(q),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    const EDGE_INFO: &str = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 2 0 0 2 0 2";

    #[test]
    fn parses_vertices_edges_and_information() {
        let text =
            "# comment\nVERTEX_SE3:QUAT 5 0 0 0 0 0 0 1\n\nVERTEX_SE3:QUAT 7 1 2 3 0 0 0 2\n\
             EDGE_SE3:QUAT 5 7 1 2 3 0 0 0 1 1 0.5 0 0 0 0 1 0 0 0 0 1 0 0 0 2 0 0 2 0 2\n";
        let g = parse_g2o(text, "t.g2o").unwrap();
        assert_eq!(g.poses.len(), 2);
        assert_eq!(g.fixed, vec![true, false]);
        assert_eq!((g.edges[0].from, g.edges[0].to), (0, 1));
        assert_eq!(g.poses[1].rotation.quaternion().w, 1.0);
        let info = g.edges[0].information;
        assert_eq!((info[(0, 1)], info[(1, 0)], info[(5, 5)]), (0.5, 0.5, 2.0));
        assert_eq!(g.cost(), 0.0);
    }

    #[test]
    fn errors_name_file_and_line() {
        let cases = [
            (
                "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 0 0 x 0 0 0 1\n",
                "t.g2o:2:",
            ),
            ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0\n", "t.g2o:1:"),
            ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 0\n", "t.g2o:1:"),
            (
                "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n",
                "t.g2o:2:",
            ),
            ("VERTEX_SE2 0 0 0 0\n", "t.g2o:1:"),
            ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 inf\n", "t.g2o:1:"),
            ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nFIX 3\n", "t.g2o:2:"),
            ("", "t.g2o: no VERTEX"),
        ];
        for (text, prefix) in cases {
            match parse_g2o(text, "t.g2o") {
                Err(OptimError::InvalidInput(msg)) => {
                    assert!(
                        msg.starts_with(prefix),
                        "{msg:?} should start with {prefix:?}"
                    )
                }
                other => panic!("{text:?} gave {other:?}"),
            }
        }
        let dangling = format!(
            "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 9 0 0 0 0 0 0 1 {EDGE_INFO}\n"
        );
        let msg = parse_g2o(&dangling, "t.g2o").unwrap_err().to_string();
        assert!(msg.contains("t.g2o:2: vertex 9"), "{msg}");
        let missing = read_g2o("/nonexistent/x.g2o").unwrap_err().to_string();
        assert!(missing.contains("/nonexistent/x.g2o"), "{missing}");
    }

    #[test]
    fn fix_lines_replace_the_default_gauge() {
        let text = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\nFIX 1\n";
        assert_eq!(parse_g2o(text, "t").unwrap().fixed, vec![false, true]);
    }
}
