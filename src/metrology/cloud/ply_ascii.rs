//! ASCII PLY data: one non-blank line per item, values checked against their type
//! (integers whole and in range), elements around the vertices checked and walked over,
//! errors naming the file's line.

use super::ply_body::{Body, ReadError, non_finite, too_large};
use super::ply_header::{Element, Header, Kind, Role, Scalar, VertexLayout};
use crate::math::{Point3, Real, Vector3};

/// Parses one ASCII value of type `ty`: integers must be whole and in range.
fn parse_ascii(tok: &str, ty: Scalar) -> Option<Real> {
    let v: Real = tok.parse().ok()?;
    match ty.int_range() {
        None => Some(v),
        Some((lo, hi)) => (v.fract() == 0.0 && lo <= v && v <= hi).then_some(v),
    }
}

/// Non-blank data lines of an ASCII body with their 1-based file line numbers.
struct AsciiLines<'a> {
    lines: std::iter::Enumerate<std::str::Lines<'a>>,
    first_line: usize,
}

impl<'a> AsciiLines<'a> {
    fn next_item(&mut self) -> Option<(usize, &'a str)> {
        self.lines
            .by_ref()
            .find(|(_, s)| !s.trim_ascii().is_empty())
            .map(|(k, s)| (self.first_line + k, s))
    }
}

/// Checks one ASCII item (one line) of a skipped element.
fn check_ascii_item(lineno: usize, line: &str, e: &Element) -> Result<(), ReadError> {
    let bad =
        |what: String| ReadError::Malformed(format!("line {lineno}: element '{}': {what}", e.name));
    let mut toks = line.split_ascii_whitespace();
    let mut value = |ty: Scalar| -> Result<Real, ReadError> {
        let t = toks.next().ok_or_else(|| bad("too few values".into()))?;
        parse_ascii(t, ty).ok_or_else(|| bad(format!("'{t}' is not a valid {}", ty.name())))
    };
    for p in &e.props {
        match p.kind {
            Kind::Scalar(s) => {
                value(s)?;
            }
            Kind::List { count, item } => {
                // A whole, non-negative count (integer type, range-checked).
                let n = value(count)?;
                if n < 0.0 {
                    return Err(bad(format!("negative list length {n}")));
                }
                // Each item consumes a token or fails, so this ends with the line.
                for _ in 0..n as u64 {
                    value(item)?;
                }
            }
        }
    }
    if toks.next().is_some() {
        return Err(bad("too many values".into()));
    }
    Ok(())
}

fn skip_ascii(lines: &mut AsciiLines<'_>, e: &Element) -> Result<(), ReadError> {
    for k in 0..e.count {
        let (lineno, line) = lines.next_item().ok_or_else(|| {
            ReadError::Malformed(format!(
                "data end in element '{}' after {k} of {} items",
                e.name, e.count
            ))
        })?;
        check_ascii_item(lineno, line, e)?;
    }
    Ok(())
}

pub(super) fn read_ascii(data: &[u8], h: &Header, l: &VertexLayout) -> Result<Body, ReadError> {
    let text = std::str::from_utf8(data).map_err(|e| {
        let line = h.data_line
            + data
                .get(..e.valid_up_to())
                .unwrap_or_default()
                .iter()
                .filter(|&&b| b == b'\n')
                .count();
        ReadError::Malformed(format!("line {line}: ASCII data is not text"))
    })?;
    let mut lines = AsciiLines {
        lines: text.lines().enumerate(),
        first_line: h.data_line,
    };
    for e in h.elements.get(..l.element).unwrap_or_default() {
        skip_ascii(&mut lines, e)?;
    }
    let nprops = l.columns.len();
    // Each vertex line needs at least `2·nprops − 1` bytes plus a separator: refuse counts
    // the data cannot hold before allocating.
    let min_bytes = l
        .count
        .checked_mul(2 * nprops)
        .ok_or_else(|| too_large("vertex"))?
        .saturating_sub(1);
    if min_bytes > data.len() {
        return Err(ReadError::Malformed(format!(
            "{} vertices declared but only {} data bytes",
            l.count,
            data.len()
        )));
    }
    let mut points = Vec::with_capacity(l.count);
    let mut normals = l.normal.map(|_| Vec::with_capacity(l.count));
    let mut scalars: Vec<Vec<Real>> = l
        .scalar_cols
        .iter()
        .map(|_| Vec::with_capacity(l.count))
        .collect();
    for i in 0..l.count {
        let (lineno, line) = lines.next_item().ok_or_else(|| {
            ReadError::Malformed(format!(
                "data end after {i} of {} declared vertices",
                l.count
            ))
        })?;
        let mut c = [0.0; 3];
        let mut n = [0.0; 3];
        let mut toks = line.split_ascii_whitespace();
        for (k, col) in l.columns.iter().enumerate() {
            let Some(tok) = toks.next() else {
                return Err(ReadError::At {
                    line: lineno,
                    column: line.chars().count() + 1,
                    message: format!(
                        "vertex {i}: got {} values, expected {nprops}",
                        line.split_ascii_whitespace().count()
                    ),
                });
            };
            let v = parse_ascii(tok, col.ty).ok_or_else(|| {
                // the token is a slice of the line: its column is the characters before it
                let at = tok.as_ptr() as usize - line.as_ptr() as usize;
                ReadError::At {
                    line: lineno,
                    column: line[..at].chars().count() + 1,
                    message: format!(
                        "vertex {i}, property {}: got '{tok}', expected a {}",
                        l.names.get(k).map_or("?", String::as_str),
                        col.ty.name()
                    ),
                }
            })?;
            let slot = match col.role {
                Role::Coord(a) => c.get_mut(a),
                Role::Normal(a) => n.get_mut(a),
                Role::Scalar(j) => {
                    if let Some(s) = scalars.get_mut(j) {
                        s.push(v);
                    }
                    None
                }
            };
            if let Some(slot) = slot {
                *slot = v;
            }
        }
        if let Some(extra) = toks.next() {
            let at = extra.as_ptr() as usize - line.as_ptr() as usize;
            return Err(ReadError::At {
                line: lineno,
                column: line[..at].chars().count() + 1,
                message: format!(
                    "vertex {i}: got {} values, expected {nprops}",
                    line.split_ascii_whitespace().count()
                ),
            });
        }
        if !c.iter().all(|v| v.is_finite()) {
            return Err(non_finite(i, "coordinate", Some(lineno)));
        }
        points.push(Point3::new(c[0], c[1], c[2]));
        if let Some(normals) = &mut normals {
            if !n.iter().all(|v| v.is_finite()) {
                return Err(non_finite(i, "normal", Some(lineno)));
            }
            normals.push(Vector3::new(n[0], n[1], n[2]));
        }
    }
    for e in h.elements.get(l.element + 1..).unwrap_or_default() {
        skip_ascii(&mut lines, e)?;
    }
    if let Some((lineno, _)) = lines.next_item() {
        return Err(ReadError::Malformed(format!(
            "line {lineno}: data beyond the items the header declares"
        )));
    }
    Ok(Body {
        points,
        normals,
        scalars,
    })
}

#[cfg(test)]
mod tests {
    use super::super::tests::{is_malformed, malformed_message, read};
    use super::super::{CloudError, Frame};
    use crate::math::{Point3, Vector3};

    #[test]
    fn ascii_with_extra_properties() {
        let text = "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nelement vertex 3\r\n\
                    property float x\r\nproperty float y\r\nproperty double z\r\n\
                    property float nx\r\nproperty float ny\r\nproperty float nz\r\n\
                    property uchar red\r\nproperty uchar green\r\nproperty uchar blue\r\n\
                    element face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n\
                    1.5 2 3 0 0 1 255 0 0\r\n-4 5.25 6e2 0 1 0 0 255 0\r\n\
                    7 8 -9.125 1 0 0 0 0 255\r\n3 0 1 2\r\n";
        let c = read(text.as_bytes()).expect("ascii");
        assert_eq!(c.frame, Frame::Workpiece);
        assert_eq!(
            c.points,
            vec![
                Point3::new(1.5, 2.0, 3.0),
                Point3::new(-4.0, 5.25, 600.0),
                Point3::new(7.0, 8.0, -9.125)
            ]
        );
        assert_eq!(
            c.normals,
            Some(vec![Vector3::z(), Vector3::y(), Vector3::x()])
        );
        let names: Vec<&str> = c.scalars.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["red", "green", "blue"]);
        assert_eq!(c.scalars[0].values, [255.0, 0.0, 0.0]);
        assert_eq!(c.scalars[2].values, [0.0, 0.0, 255.0]);
    }

    #[test]
    fn ascii_count_mismatches_are_malformed() {
        let head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\n\
                    property double y\nproperty double z\nend_header\n";
        assert!(read(format!("{head}1 2 3\n4 5 6\n").as_bytes()).is_ok());
        assert!(is_malformed(read(format!("{head}1 2 3\n").as_bytes())));
        assert!(is_malformed(read(
            format!("{head}1 2 3\n4 5 6\n7 8 9\n").as_bytes()
        )));
        assert!(is_malformed(read(format!("{head}1 2 3\n4 5\n").as_bytes())));
        assert!(is_malformed(read(
            format!("{head}1 2 3\n4 5 x\n").as_bytes()
        )));
        assert!(matches!(
            read(format!("{head}1 2 3\n4 nan 6\n").as_bytes()),
            Err(CloudError::NonFinite {
                index: 1,
                line: Some(9),
                ..
            })
        ));
    }

    #[test]
    fn ascii_errors_name_file_and_line() {
        let head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\n\
                    property double y\nproperty double z\nproperty uchar red\nend_header\n";
        // file:line:column of the offending value, its property, what was expected
        let m = malformed_message(read(format!("{head}1 2 3 4\n4 5 x 6\n").as_bytes()));
        assert!(
            m.starts_with("test.ply:10:5: ")
                && m.contains("property z: got 'x', expected a double"),
            "{m}"
        );
        let m = malformed_message(read(format!("{head}1 2 3 4\n\n4 5 6 7 8\n").as_bytes()));
        assert!(
            m.starts_with("test.ply:11:9: ") && m.contains("got 5 values, expected 4"),
            "{m}"
        );
        let m = malformed_message(read(format!("{head}1 2 3 4\n44444 55555\n").as_bytes()));
        assert!(
            m.starts_with("test.ply:10:12: ") && m.contains("got 2 values, expected 4"),
            "{m}"
        );
        // Integers must be whole and in range for their type.
        let m = malformed_message(read(format!("{head}1 2 3 256\n4 5 6 7\n").as_bytes()));
        assert!(
            m.starts_with("test.ply:9:7: ")
                && m.contains("property red: got '256', expected a uchar"),
            "{m}"
        );
        assert!(is_malformed(read(
            format!("{head}1 2 3 2.5\n4 5 6 7\n").as_bytes()
        )));
        let e = read(format!("{head}1 2 3 4\n4 inf 6 7\n").as_bytes()).expect_err("inf");
        let m = e.to_string();
        assert!(
            m.contains("test.ply") && m.contains("line 10") && m.contains("point 1"),
            "{m}"
        );
        // Header errors name their line too.
        let m = malformed_message(read(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n",
        ));
        assert!(m.starts_with("test.ply:4:1: ") && m.contains("quad"), "{m}");
    }

    #[test]
    fn ascii_skips_leading_fixed_elements() {
        let text = "ply\nformat ascii 1.0\ncomment frame scanner\nelement camera 2\n\
                    property float a\nproperty int b\nelement vertex 2\nproperty double z\n\
                    property double y\nproperty double x\nend_header\n1.0 2\n3.0 4\n\n\
                    1 2 3\n  4 5 6  \n";
        let c = read(text.as_bytes()).expect("ascii");
        assert_eq!(c.frame, Frame::Scanner);
        assert_eq!(
            c.points,
            vec![Point3::new(3.0, 2.0, 1.0), Point3::new(6.0, 5.0, 4.0)]
        );
        let bad_frame = text.replace("frame scanner", "frame machine");
        assert!(is_malformed(read(bad_frame.as_bytes())));
    }

    #[test]
    fn ascii_elements_with_lists_before_and_after_vertex() {
        let text = "ply\nformat ascii 1.0\nelement range_grid 2\nproperty list uchar int idx\n\
                    element vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
                    element face 2\nproperty list uchar int vertex_indices\n\
                    property uchar flags\nend_header\n0\n2 0 1\n1 2 3\n4 5 6\n\
                    3 0 1 1 7\n0 9\n";
        let c = read(text.as_bytes()).expect("lists skipped");
        assert_eq!(c.points.len(), 2);
        // Wrong list length, too few face lines, too many lines.
        assert!(is_malformed(read(
            text.replace("3 0 1 1 7", "3 0 1 7").as_bytes()
        )));
        assert!(is_malformed(read(text.replace("0 9\n", "").as_bytes())));
        assert!(is_malformed(read(format!("{text}1 2\n").as_bytes())));
        assert!(is_malformed(read(
            text.replace("\n0\n2 0", "\n-1\n2 0").as_bytes()
        )));
    }
}
