//! DBoW2's text vocabulary format, as ORB-SLAM2/3 read and write it (`ORBvoc.txt`):
//!
//! ```text
//! k L scoring weighting
//! parent_id is_leaf b0 b1 ... b31 weight      (one line per node 1, 2, ..., root omitted)
//! ```
//!
//! Node ids are implicit (line order, starting at 1); descriptor bytes are decimal;
//! `scoring` must be 0 (L1, the only scoring this crate implements); words are the lines
//! with `is_leaf = 1`, numbered in line order. The writer emits no trailing newline, which
//! ORB-SLAM2's loader would read as an extra node.

use std::io::{BufRead, BufWriter, Write};
use std::path::Path;

use ferroslam_features::Descriptor;

use crate::bow::NodeId;
use crate::error::{Result, VocabularyError};
use crate::vocabulary::Vocabulary;
use crate::weighting::Weighting;

/// DBoW2's code of L1 scoring.
const L1_SCORING: u32 = 0;

impl Vocabulary {
    /// Writes the DBoW2 text format (weights printed exactly, shortest round-trip form).
    ///
    /// # Errors
    /// [`VocabularyError::Io`] when writing fails.
    pub fn write_dbow2_text<W: Write>(&self, writer: W) -> Result<()> {
        let mut w = BufWriter::new(writer);
        write!(
            w,
            "{} {} {} {}",
            self.branching(),
            self.levels(),
            L1_SCORING,
            self.weighting().code()
        )?;
        let (parents, descriptors, weights) = self.raw_parts();
        for node in 1..parents.len() {
            let leaf = u8::from(self.node_word(node as NodeId).is_some());
            write!(w, "\n{} {}", parents[node], leaf)?;
            for b in &descriptors[node] {
                write!(w, " {b}")?;
            }
            write!(w, " {}", weights[node])?;
        }
        w.flush()?;
        Ok(())
    }

    /// Reads the DBoW2 text format. Blank lines are skipped; ORB-SLAM's `ORBvoc.txt`
    /// (`10 6 0 0`, about 1.08 million nodes) loads as is.
    ///
    /// # Errors
    /// [`VocabularyError::Parse`] with the line number for a malformed header or node line
    /// (wrong field count, byte out of 0..=255, unparsable number, scoring other than L1,
    /// a leaf flag that disagrees with the tree), [`VocabularyError::Io`] on read failure,
    /// [`VocabularyError::Malformed`] for an invalid tree (see [`Vocabulary::from_raw_parts`]).
    pub fn read_dbow2_text<R: BufRead>(reader: R) -> Result<Self> {
        let mut lines = reader.lines().enumerate().map(|(i, l)| (i + 1, l));
        let (k, levels, weighting) = loop {
            match lines.next() {
                None => return Err(parse_error(1, "empty file")),
                Some((n, line)) => {
                    let line = line?;
                    if !line.trim().is_empty() {
                        break parse_header(n, &line)?;
                    }
                }
            }
        };
        let mut parents = vec![0];
        let mut descriptors = vec![[0u8; 32]];
        let mut weights = vec![0.0];
        let mut leaf_flags: Vec<(usize, bool)> = vec![(0, false)];
        for (n, line) in lines {
            let line = line?;
            if line.trim().is_empty() {
                continue;
            }
            let (parent, leaf, descriptor, weight) = parse_node(n, &line)?;
            parents.push(parent);
            descriptors.push(descriptor);
            weights.push(weight);
            leaf_flags.push((n, leaf));
        }
        let vocabulary =
            Vocabulary::from_raw_parts(k, levels, weighting, parents, descriptors, weights)?;
        for (node, &(line, leaf)) in leaf_flags.iter().enumerate().skip(1) {
            if vocabulary.node_word(node as NodeId).is_some() != leaf {
                return Err(parse_error(
                    line,
                    if leaf {
                        "node marked as leaf has children"
                    } else {
                        "node marked as inner has no children"
                    },
                ));
            }
        }
        Ok(vocabulary)
    }

    /// [`Vocabulary::write_dbow2_text`] to a file, through
    /// [`ferroslam_files::write_atomically`] (a temporary file renamed over `path`; a folder,
    /// FIFO or device there is refused).
    ///
    /// # Errors
    /// [`VocabularyError::Io`].
    pub fn save_dbow2_text(&self, path: impl AsRef<Path>) -> Result<()> {
        ferroslam_files::write_atomically(path.as_ref(), |w| self.write_dbow2_text(w))
    }

    /// [`Vocabulary::read_dbow2_text`] from a file.
    ///
    /// # Errors
    /// As [`Vocabulary::read_dbow2_text`].
    pub fn load_dbow2_text(path: impl AsRef<Path>) -> Result<Self> {
        Vocabulary::read_dbow2_text(std::io::BufReader::new(crate::open_regular_file(
            path.as_ref(),
        )?))
    }
}

fn parse_error(line: usize, message: impl Into<String>) -> VocabularyError {
    VocabularyError::Parse {
        line,
        message: message.into(),
    }
}

fn parse_field<T: std::str::FromStr>(line: usize, token: Option<&str>, what: &str) -> Result<T> {
    let token = token.ok_or_else(|| parse_error(line, format!("missing {what}")))?;
    token
        .parse()
        .map_err(|_| parse_error(line, format!("bad {what} {token:?}")))
}

fn parse_header(line: usize, text: &str) -> Result<(u32, u32, Weighting)> {
    let mut t = text.split_whitespace();
    let k: u32 = parse_field(line, t.next(), "branching factor")?;
    let levels: u32 = parse_field(line, t.next(), "levels")?;
    let scoring: u32 = parse_field(line, t.next(), "scoring type")?;
    let weighting: u32 = parse_field(line, t.next(), "weighting type")?;
    if t.next().is_some() {
        return Err(parse_error(line, "header has more than 4 fields"));
    }
    if scoring != L1_SCORING {
        return Err(parse_error(
            line,
            format!("scoring type {scoring} unsupported (only L1 = 0)"),
        ));
    }
    let weighting =
        Weighting::from_code(weighting).map_err(|e| parse_error(line, e.to_string()))?;
    Ok((k, levels, weighting))
}

fn parse_node(line: usize, text: &str) -> Result<(NodeId, bool, Descriptor, f64)> {
    let mut t = text.split_whitespace();
    let parent: NodeId = parse_field(line, t.next(), "parent id")?;
    let leaf = match parse_field::<u32>(line, t.next(), "leaf flag")? {
        0 => false,
        1 => true,
        other => {
            return Err(parse_error(
                line,
                format!("leaf flag {other} is not 0 or 1"),
            ))
        }
    };
    let mut descriptor = [0u8; 32];
    for b in &mut descriptor {
        *b = parse_field(line, t.next(), "descriptor byte")?;
    }
    let weight: f64 = parse_field(line, t.next(), "weight")?;
    if t.next().is_some() {
        return Err(parse_error(line, "node line has more than 35 fields"));
    }
    Ok((parent, leaf, descriptor, weight))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> Vocabulary {
        Vocabulary::from_raw_parts(
            2,
            2,
            Weighting::TfIdf,
            vec![0, 0, 0, 1, 1],
            vec![[0; 32], [1; 32], [255; 32], [3; 32], [4; 32]],
            vec![0.0, 0.0, 0.1 + 0.2, 1.5, 1e-300],
        )
        .unwrap()
    }

    fn to_text(v: &Vocabulary) -> String {
        let mut out = Vec::new();
        v.write_dbow2_text(&mut out).unwrap();
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn text_layout_and_exact_round_trip() {
        let v = tiny();
        let text = to_text(&v);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 5);
        assert_eq!(lines[0], "2 2 0 0");
        assert!(lines[1].starts_with("0 0 1 1 1 "));
        assert!(lines[2].starts_with("0 1 255 255 "));
        assert_eq!(lines[2].split_whitespace().count(), 35);
        assert!(!text.ends_with('\n'));
        assert_eq!(Vocabulary::read_dbow2_text(text.as_bytes()).unwrap(), v);
        // Blank lines and a trailing newline are tolerated.
        let padded = format!("\n{text}\n\n");
        assert_eq!(Vocabulary::read_dbow2_text(padded.as_bytes()).unwrap(), v);
    }

    #[test]
    fn malformed_text_reports_the_line() {
        let text = to_text(&tiny());
        let cases = [
            (text.replacen("2 2 0 0", "2 2 1 0", 1), 1),
            (text.replacen("2 2 0 0", "2 2 0", 1), 1),
            (text.replacen("2 2 0 0", "2 2 0 9", 1), 1),
            (text.replacen("0 1 255", "0 1 256", 1), 3),
            (text.replacen("0 1 255", "0 1 x", 1), 3),
            (text.replacen("0 1 255", "0 2 255", 1), 3),
            (text.replacen("0 1 255", "0 0 255", 1), 3),
            (text.replacen("0 0 1 1", "0 1 1 1", 1), 2),
            (format!("{text}\n1 1 5"), 6),
        ];
        for (bad, line) in cases {
            match Vocabulary::read_dbow2_text(bad.as_bytes()) {
                Err(VocabularyError::Parse { line: got, .. }) => assert_eq!(got, line, "{bad}"),
                other => panic!("expected a parse error on line {line}, got {other:?}"),
            }
        }
        assert!(Vocabulary::read_dbow2_text("".as_bytes()).is_err());
        // Parent after child: structural error.
        let forward = text.replacen("\n0 0 1 1", "\n3 0 1 1", 1);
        assert!(matches!(
            Vocabulary::read_dbow2_text(forward.as_bytes()),
            Err(VocabularyError::Malformed(_))
        ));
    }
}
