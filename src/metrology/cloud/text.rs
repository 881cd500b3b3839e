//! XYZ/CSV and PTS text clouds: [`read_xyz`] and [`write_xyz`] (3 or 6 columns, white
//! space or commas, an optional header or count line, a `frame` comment), [`read_pts`]
//! (Leica PTS blocks with intensity and colours), all with errors naming the line.

use super::encode::{encode_text_columns, invalid_input, write_blocks};
use super::error::CloudError;
use super::point_cloud::{Frame, PointCloud, RESERVED, ScalarField};
use crate::math::{Point3, Real, Vector3};
use std::io::Write;
use std::path::Path;

#[cfg(doc)]
use super::point_cloud::InvalidCloud;

/// The column separator [`write_xyz`] uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum XyzSeparator {
    /// One space (`.xyz`, `.txt`).
    #[default]
    Space,
    /// One tab.
    Tab,
    /// One comma, no space (`.csv`).
    Comma,
}

impl XyzSeparator {
    fn as_str(self) -> &'static str {
        match self {
            XyzSeparator::Space => " ",
            XyzSeparator::Tab => "\t",
            XyzSeparator::Comma => ",",
        }
    }

    fn byte(self) -> u8 {
        match self {
            XyzSeparator::Space => b' ',
            XyzSeparator::Tab => b'\t',
            XyzSeparator::Comma => b',',
        }
    }
}

/// Writes `cloud` as XYZ/CSV text: a `// frame <name>` comment line, a column-name header
/// line (`x y z` or `x y z nx ny nz`), then one line per point with x y z and, when the
/// cloud has normals, nx ny nz, separated by `separator`, in shortest round-trip form (so
/// [`read_xyz`] gives back the same numbers bit for bit, and the frame). Open3D 0.20 skips
/// the two first lines (checked); CloudCompare's ASCII reader skips `//` lines. Scalar
/// fields are not written: the format has no names for them (use PLY).
///
/// The cloud is validated first; nothing is written if that fails (an
/// [`InvalidInput`](std::io::ErrorKind::InvalidInput) error wrapping the [`InvalidCloud`]).
pub fn write_xyz(
    cloud: &PointCloud,
    w: &mut impl Write,
    separator: XyzSeparator,
) -> std::io::Result<()> {
    cloud.validate().map_err(invalid_input)?;
    let columns = if cloud.normals.is_some() { 6 } else { 3 };
    let names = ["x", "y", "z", "nx", "ny", "nz"]
        .get(..columns)
        .unwrap_or_default()
        .join(separator.as_str());
    w.write_all(format!("// frame {}\n{names}\n", cloud.frame.name()).as_bytes())?;
    write_blocks(w, cloud.len(), columns * 24, |r, buf| {
        encode_text_columns(cloud, r, separator.byte(), false, buf)
    })?;
    w.flush()
}

/// Most numbers on one text line that are kept (more are counted for the error message).
const MAX_FIELDS: usize = 8;

/// A non-blank, non-comment text line split into numbers.
enum Fields<'a> {
    /// `count` numbers, the first `MAX_FIELDS` of them in the buffer.
    Numbers(usize),
    /// Field `index` (0-based) is not a number.
    NotNumber { index: usize, token: &'a str },
    /// Two commas with nothing between them.
    Empty,
}

/// What one text line holds once comments are removed.
enum TextLine<'a> {
    /// Nothing (blank or comment); `Some(frame)` for a `frame <name>` comment.
    Blank(Option<Frame>),
    /// Data fields.
    Data(Fields<'a>),
}

/// Splits a text line: `#` starts a comment anywhere, `//` at the start of a line makes it
/// a comment (CloudCompare's convention); fields are separated by commas (surrounding
/// blanks ignored) if the line has any, else by white space.
fn split_text_line<'a>(raw: &'a str, out: &mut [Real; MAX_FIELDS]) -> TextLine<'a> {
    let (content, mut comment) = match raw.split_once('#') {
        Some((c, rest)) => (c.trim(), Some(rest)),
        None => (raw.trim(), None),
    };
    let content = match content.strip_prefix("//") {
        Some(rest) => {
            comment = Some(rest);
            ""
        }
        None => content,
    };
    if content.is_empty() {
        let frame = comment.and_then(|c| {
            let mut t = c.split_ascii_whitespace();
            match (t.next(), t.next(), t.next()) {
                (Some("frame"), Some(name), None) => Frame::from_name(name),
                _ => None,
            }
        });
        return TextLine::Blank(frame);
    }
    let mut count = 0usize;
    let mut take = |token: &'a str| -> Option<Fields<'a>> {
        match token.parse::<Real>() {
            Ok(v) => {
                if let Some(slot) = out.get_mut(count) {
                    *slot = v;
                }
                count += 1;
                None
            }
            Err(_) => Some(Fields::NotNumber {
                index: count,
                token,
            }),
        }
    };
    if content.contains(',') {
        for token in content.split(',').map(str::trim) {
            if token.is_empty() {
                return TextLine::Data(Fields::Empty);
            }
            if let Some(f) = take(token) {
                return TextLine::Data(f);
            }
        }
    } else {
        for token in content.split_ascii_whitespace() {
            if let Some(f) = take(token) {
                return TextLine::Data(f);
            }
        }
    }
    TextLine::Data(Fields::Numbers(count))
}

/// Whether `v` is a non-negative whole number (a point count).
fn as_count(v: Real) -> Option<u64> {
    (v >= 0.0 && v.fract() == 0.0 && v < 1.8e19).then_some(v as u64)
}

/// Reads an XYZ/CSV text cloud; `path` only labels errors.
///
/// Each data line holds 3 (x y z) or 6 (x y z nx ny nz) numbers separated by white space or
/// by commas; every data line must have as many as the first. Blank lines are ignored; `#`
/// starts a comment anywhere on a line and a line starting with `//` is a comment (a
/// `frame workpiece` / `frame scanner` comment before the data sets the frame, else
/// [`Frame::Workpiece`]). The first data line may be a header (its first field is not a
/// number, e.g. `x,y,z`), and the first numeric line may be a single point count (as
/// CloudCompare can write), which must then match the number of points. Errors name the
/// 1-based line.
pub fn read_xyz(text: &str, path: &Path) -> Result<PointCloud, CloudError> {
    let malformed = |line: usize, message: String| CloudError::Malformed {
        path: path.to_path_buf(),
        message: format!("malformed XYZ: line {line}: {message}"),
    };
    let mut frame = None;
    let mut header_allowed = true;
    let mut declared: Option<(usize, u64)> = None;
    let mut columns: Option<(usize, usize)> = None;
    let mut points = Vec::new();
    let mut normals = Vec::new();
    let mut buf = [0.0; MAX_FIELDS];
    for (k, raw) in text.lines().enumerate() {
        let line = k + 1;
        let count = match split_text_line(raw, &mut buf) {
            TextLine::Blank(f) => {
                if points.is_empty() && frame.is_none() {
                    frame = f;
                }
                continue;
            }
            TextLine::Data(Fields::NotNumber { index: 0, .. }) if header_allowed => {
                header_allowed = false;
                // Column names `x y z` or `x y z nx ny nz` (any case) fix the layout.
                let names: Vec<String> = raw
                    .split(|c: char| c == ',' || c.is_ascii_whitespace())
                    .filter(|t| !t.is_empty())
                    .map(str::to_ascii_lowercase)
                    .collect();
                if let n @ (3 | 6) = names.len()
                    && names.iter().zip(RESERVED).all(|(a, b)| a == b)
                {
                    columns = Some((line, n));
                }
                continue;
            }
            TextLine::Data(Fields::NotNumber { token, .. }) => {
                return Err(malformed(line, format!("'{token}' is not a number")));
            }
            TextLine::Data(Fields::Empty) => {
                return Err(malformed(line, "empty field between commas".into()));
            }
            TextLine::Data(Fields::Numbers(n)) => n,
        };
        header_allowed = false;
        if count == 1 && points.is_empty() && declared.is_none() {
            let n = as_count(buf[0]).ok_or_else(|| {
                malformed(
                    line,
                    "a single value must be a point count (a whole number)".into(),
                )
            })?;
            declared = Some((line, n));
            continue;
        }
        let (first, want) = match columns {
            Some(c) => c,
            None if count == 3 || count == 6 => {
                columns = Some((line, count));
                (line, count)
            }
            None => {
                return Err(malformed(
                    line,
                    format!("expected 3 (x y z) or 6 (x y z nx ny nz) values, found {count}"),
                ));
            }
        };
        if count != want {
            return Err(malformed(
                line,
                format!("expected {want} values (as line {first}), found {count}"),
            ));
        }
        let index = points.len();
        let non_finite = |what| CloudError::NonFinite {
            path: path.to_path_buf(),
            index,
            what,
            line: Some(line),
        };
        let [x, y, z, nx, ny, nz, ..] = buf;
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            return Err(non_finite("coordinate"));
        }
        points.push(Point3::new(x, y, z));
        if want == 6 {
            if !(nx.is_finite() && ny.is_finite() && nz.is_finite()) {
                return Err(non_finite("normal"));
            }
            normals.push(Vector3::new(nx, ny, nz));
        }
    }
    if let Some((line, n)) = declared
        && n != points.len() as u64
    {
        return Err(malformed(
            line,
            format!(
                "the count line declares {n} points but {} follow",
                points.len()
            ),
        ));
    }
    let has_normals = columns.is_some_and(|(_, c)| c == 6);
    Ok(PointCloud {
        frame: frame.unwrap_or(Frame::Workpiece),
        points,
        normals: has_normals.then_some(normals),
        scalars: Vec::new(),
    })
}

/// Reads a Leica PTS text cloud; `path` only labels errors.
///
/// The file is a sequence of blocks (scans), each a line with its point count followed by
/// that many point lines of 3 (x y z), 4 (x y z intensity), 6 (x y z red green blue) or 7
/// (x y z intensity red green blue) numbers, separated by white space or commas, the same
/// number on every line. Intensity and colours become scalar fields `intensity`, `red`,
/// `green`, `blue`. Blank lines and comments are skipped as in [`read_xyz`]; the frame is
/// [`Frame::Workpiece`] unless a `frame` comment says otherwise. Errors name the 1-based
/// line.
pub fn read_pts(text: &str, path: &Path) -> Result<PointCloud, CloudError> {
    let malformed = |line: usize, message: String| CloudError::Malformed {
        path: path.to_path_buf(),
        message: format!("malformed PTS: line {line}: {message}"),
    };
    let mut frame = None;
    let mut columns: Option<(usize, usize)> = None;
    let mut points = Vec::new();
    let mut extra: [Vec<Real>; 4] = Default::default();
    // (line of the count, declared, still expected)
    let mut block: Option<(usize, u64, u64)> = None;
    let mut buf = [0.0; MAX_FIELDS];
    for (k, raw) in text.lines().enumerate() {
        let line = k + 1;
        let count = match split_text_line(raw, &mut buf) {
            TextLine::Blank(f) => {
                if points.is_empty() && frame.is_none() {
                    frame = f;
                }
                continue;
            }
            TextLine::Data(Fields::NotNumber { token, .. }) => {
                return Err(malformed(line, format!("'{token}' is not a number")));
            }
            TextLine::Data(Fields::Empty) => {
                return Err(malformed(line, "empty field between commas".into()));
            }
            TextLine::Data(Fields::Numbers(n)) => n,
        };
        match block {
            Some((_, _, left)) if left > 0 => {}
            _ => {
                if count != 1 {
                    return Err(malformed(
                        line,
                        format!("expected a point count line, found {count} values"),
                    ));
                }
                let n = as_count(buf[0]).ok_or_else(|| {
                    malformed(line, "the point count must be a whole number".into())
                })?;
                block = Some((line, n, n));
                continue;
            }
        }
        let (first, want) = match columns {
            Some(c) => c,
            None if matches!(count, 3 | 4 | 6 | 7) => {
                columns = Some((line, count));
                (line, count)
            }
            None => {
                return Err(malformed(
                    line,
                    format!(
                        "expected 3, 4, 6 or 7 values (x y z [intensity] [r g b]), found {count}"
                    ),
                ));
            }
        };
        if count != want {
            return Err(malformed(
                line,
                format!("expected {want} values (as line {first}), found {count}"),
            ));
        }
        let [x, y, z, a, b, c, d, _] = buf;
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            return Err(CloudError::NonFinite {
                path: path.to_path_buf(),
                index: points.len(),
                what: "coordinate",
                line: Some(line),
            });
        }
        points.push(Point3::new(x, y, z));
        for (col, v) in extra
            .iter_mut()
            .zip([a, b, c, d])
            .take(want.saturating_sub(3))
        {
            col.push(v);
        }
        if let Some((_, _, left)) = &mut block {
            *left = left.saturating_sub(1);
        }
    }
    if let Some((line, n, left)) = block
        && left > 0
    {
        return Err(malformed(
            line,
            format!(
                "the block declares {n} points but the file ends after {}",
                n.saturating_sub(left)
            ),
        ));
    }
    let names: &[&str] = match columns.map(|c| c.1) {
        Some(4) => &["intensity"],
        Some(6) => &["red", "green", "blue"],
        Some(7) => &["intensity", "red", "green", "blue"],
        _ => &[],
    };
    let scalars = names
        .iter()
        .zip(extra)
        .map(|(name, values)| ScalarField::new(*name, values))
        .collect();
    Ok(PointCloud {
        frame: frame.unwrap_or(Frame::Workpiece),
        points,
        normals: None,
        scalars,
    })
}

#[cfg(test)]
mod tests {
    use super::super::tests::{
        assert_bit_identical, full_cloud, pts, sample_cloud, xyz, xyz_round_trip,
    };
    use super::*;

    #[test]
    fn xyz_variants() {
        let want = vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-4.5, 5e-3, 6e10)];
        for text in [
            "1 2 3\n-4.5 5e-3 6e10\n",
            "1\t2\t3\r\n-4.5\t5e-3 \t6e10\r\n",
            "1,2,3\n-4.5, 5e-3 ,6e10\n",
            "x,y,z\n1,2,3\n-4.5,5e-3,6e10",
            "# scan 1\n\nX Y Z\n  1 2 3   # first\n\n// CloudCompare comment\n-4.5 5e-3 6e10\n",
            "//X,Y,Z\n1,2,3\n-4.5,5e-3,6e10\n",
            "2\n1 2 3\n-4.5 5e-3 6e10\n",
            "x y z\n2\n1 2 3\n-4.5 5e-3 6e10\n",
        ] {
            let c = xyz(text).unwrap_or_else(|e| panic!("{text:?}: {e}"));
            assert_eq!(c.points, want, "{text:?}");
            assert_eq!(c.normals, None);
            assert_eq!(c.frame, Frame::Workpiece);
        }
        let c = xyz("# frame scanner\n1 2 3 0 0 1\n4 5 6 0 1 0\n").expect("normals");
        assert_eq!(c.frame, Frame::Scanner);
        assert_eq!(c.normals, Some(vec![Vector3::z(), Vector3::y()]));
        let c = xyz("// frame scanner\n").expect("empty");
        assert!(c.is_empty() && c.frame == Frame::Scanner);
        assert!(xyz("").expect("empty").is_empty());
    }

    #[test]
    fn xyz_errors_name_the_line() {
        let check = |text: &str, line: usize, what: &str| {
            let e = xyz(text).expect_err(text);
            let m = e.to_string();
            assert!(matches!(e, CloudError::Malformed { .. }), "{m}");
            assert!(
                m.contains("test.xyz") && m.contains(&format!("line {line}:")) && m.contains(what),
                "{text:?}: {m}"
            );
        };
        check(
            "1 2 3\n4 5 6\n7 8 9 0 0 1\n",
            3,
            "expected 3 values (as line 1)",
        );
        check("# c\n\n1 2 3 4\n", 3, "3 (x y z) or 6");
        check("1 2 3\n4 5 six\n", 2, "'six'");
        check("x y z\n1 2 3\nx y z\n", 3, "'x'");
        check("1,,3\n", 1, "empty field");
        check("3\n1 2 3\n", 1, "declares 3 points but 1 follow");
        check("2.5\n1 2 3\n", 1, "point count");
        check("1 2\n", 1, "found 2");
        let e = xyz("1 2 3\n\n4 NaN 6\n").expect_err("nan");
        assert!(matches!(
            e,
            CloudError::NonFinite {
                index: 1,
                what: "coordinate",
                line: Some(3),
                ..
            }
        ));
        assert!(e.to_string().contains("line 3"));
        assert!(matches!(
            xyz("1 2 3 0 0 1\n1 2 3 0 inf 1\n"),
            Err(CloudError::NonFinite {
                index: 1,
                what: "normal",
                ..
            })
        ));
    }

    #[test]
    fn xyz_round_trips_exactly() {
        for sep in [XyzSeparator::Space, XyzSeparator::Tab, XyzSeparator::Comma] {
            for frame in [Frame::Workpiece, Frame::Scanner] {
                let c = full_cloud(300, frame);
                let mut want = c.clone();
                want.scalars.clear();
                assert_bit_identical(&xyz_round_trip(&c, sep), &want);
                let plain = sample_cloud(300, frame);
                assert_bit_identical(&xyz_round_trip(&plain, sep), &plain);
            }
        }
        let mut out = Vec::new();
        write_xyz(
            &full_cloud(2, Frame::Scanner),
            &mut out,
            XyzSeparator::Comma,
        )
        .expect("w");
        let text = String::from_utf8(out).expect("utf-8");
        assert!(
            text.starts_with("// frame scanner\nx,y,z,nx,ny,nz\n-0.0,"),
            "{text}"
        );
        assert_eq!(text.lines().count(), 4);
        assert_eq!(text.lines().nth(2).map(|l| l.split(',').count()), Some(6));
        // The header fixes the columns: an empty cloud keeps its (empty) normals.
        let empty = full_cloud(0, Frame::Workpiece);
        let back = xyz_round_trip(&empty, XyzSeparator::Space);
        assert_eq!(back.normals, Some(Vec::new()));
        let e = xyz("x y z nx ny nz\n1 2 3\n").expect_err("header says 6");
        assert!(e.to_string().contains("line 2"), "{e}");
    }

    #[test]
    fn pts_variants_and_errors() {
        let c = pts("2\n1 2 3\n4 5 6\n").expect("3 columns");
        assert_eq!(c.len(), 2);
        assert!(c.scalars.is_empty());
        let c = pts("1\n1 2 3 -100\n2\n4 5 6 7\n7 8 9 10\n").expect("two blocks");
        assert_eq!(c.len(), 3);
        assert_eq!(
            c.scalar("intensity").expect("i").values,
            [-100.0, 7.0, 10.0]
        );
        let c = pts("1\n1 2 3 10 20 30 40\n").expect("7 columns");
        assert_eq!(c.points, vec![Point3::new(1.0, 2.0, 3.0)]);
        let names: Vec<&str> = c.scalars.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["intensity", "red", "green", "blue"]);
        assert_eq!(c.scalar("green").expect("g").values, [30.0]);
        let c = pts("1\n1 2 3 10 20 30\n").expect("6 columns");
        assert_eq!(c.scalar("red").expect("r").values, [10.0]);
        assert_eq!(c.scalars.len(), 3);
        assert!(pts("").expect("empty").is_empty());
        assert!(pts("0\n").expect("empty block").is_empty());
        for (text, line, what) in [
            (
                "3\n1 2 3\n4 5 6\n",
                1,
                "declares 3 points but the file ends after 2",
            ),
            ("1 2 3\n", 1, "point count line"),
            ("2\n1 2 3\n4 5 6 7\n", 3, "expected 3 values (as line 2)"),
            ("1\n1 2 3 4 5\n", 2, "3, 4, 6 or 7"),
            ("1.5\n1 2 3\n", 1, "whole number"),
            ("1\n1 2 3\n1 2 3\n", 3, "point count line"),
        ] {
            let m = pts(text).expect_err(text).to_string();
            assert!(
                m.contains("test.pts") && m.contains(&format!("line {line}:")) && m.contains(what),
                "{text:?}: {m}"
            );
        }
        assert!(matches!(
            pts("1\n1 nan 3\n"),
            Err(CloudError::NonFinite { line: Some(2), .. })
        ));
    }
}
