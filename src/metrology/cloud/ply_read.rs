//! Reading PLY: [`read_ply`], which parses the header (`ply_header`), reads the data in
//! its encoding (`ply_binary`, `ply_ascii`, into a `ply_body::Body`) and assembles the
//! cloud, with the reader's errors worded for the user.

use super::error::CloudError;
use super::ply_ascii::read_ascii;
use super::ply_binary::read_binary;
use super::ply_body::{Body, ReadError};
use super::ply_header::{Format, Header, VertexLayout, parse_header};
use super::point_cloud::{Frame, PointCloud, ScalarField};
use std::path::Path;

/// Parses a PLY file held in `bytes`; `path` only labels errors.
///
/// Accepts `ascii`, `binary_little_endian` and `binary_big_endian`. The `vertex` element
/// must carry `x`, `y`, `z`; `nx`, `ny`, `nz` (all or none) become the normals; every other
/// vertex property becomes a scalar field of the same name. Properties of any PLY scalar
/// type are converted to `f64` (ASCII integers must be whole and in range for their type).
/// A list property in the vertex element, a duplicate vertex property or a second vertex
/// element is [`CloudError::Malformed`]. Other elements, before or after `vertex`, are
/// walked over (lists included) and not kept; the data must then end exactly where the
/// header says (binary) or have exactly one non-blank line per declared item (ASCII).
/// Non-finite coordinates or normals are [`CloudError::NonFinite`] with the first vertex
/// index (and line, for ASCII). The frame comes from a `comment frame <name>` line, else
/// [`Frame::Workpiece`]. Errors from ASCII data and from the header name the 1-based line.
pub fn read_ply(bytes: &[u8], path: &Path) -> Result<PointCloud, CloudError> {
    let header = parse_header(bytes).map_err(|m| malformed_ply(path, m))?;
    let layout = VertexLayout::new(&header).map_err(|m| malformed_ply(path, m))?;
    let data = bytes.get(header.data_start..).unwrap_or_default();
    let body = match header.format {
        Format::Ascii => read_ascii(data, &header, &layout),
        Format::BinaryLe => read_binary(data, &header, &layout, false),
        Format::BinaryBe => read_binary(data, &header, &layout, true),
    }
    .map_err(|e| read_error(path, e))?;
    Ok(assemble(&header, layout, body))
}

/// A PLY reader's message as the user's error: one that starts `line N: ` (the header's
/// and the ASCII data's) is located at that line, column 1 (the line's keyword or first
/// value); others name the file only.
pub(super) fn malformed_ply(path: &Path, message: String) -> CloudError {
    let located = message.strip_prefix("line ").and_then(|rest| {
        let (n, what) = rest.split_once(": ")?;
        Some((n.parse::<usize>().ok()?, what))
    });
    match located {
        Some((line, what)) => CloudError::At {
            path: path.to_path_buf(),
            line,
            column: 1,
            message: format!("malformed PLY: {what}"),
        },
        None => CloudError::Malformed {
            path: path.to_path_buf(),
            message: format!("malformed PLY: {message}"),
        },
    }
}

pub(super) fn read_error(path: &Path, e: ReadError) -> CloudError {
    match e {
        ReadError::Malformed(message) => malformed_ply(path, message),
        ReadError::At {
            line,
            column,
            message,
        } => CloudError::At {
            path: path.to_path_buf(),
            line,
            column,
            message: format!("malformed PLY: {message}"),
        },
        ReadError::NonFinite { index, what, line } => CloudError::NonFinite {
            path: path.to_path_buf(),
            index,
            what,
            line,
        },
    }
}

/// The cloud from a header, its vertex layout and the decoded data.
pub(super) fn assemble(header: &Header, layout: VertexLayout, body: Body) -> PointCloud {
    let scalars = layout
        .scalar_names
        .into_iter()
        .zip(body.scalars)
        .map(|(name, values)| ScalarField { name, values })
        .collect();
    PointCloud {
        frame: header.frame.unwrap_or(Frame::Workpiece),
        points: body.points,
        normals: body.normals,
        scalars,
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::read;
    use crate::math::{Point3, Real};

    /// Vertex properties of every scalar type, under both sets of type names.
    #[test]
    fn every_scalar_type_in_every_encoding() {
        let types = [
            ("char", "int8", -5.0),
            ("uchar", "uint8", 250.0),
            ("short", "int16", -300.0),
            ("ushort", "uint16", 60000.0),
            ("int", "int32", -70000.0),
            ("uint", "uint32", 4e9),
            ("float", "float32", 0.375),
            ("double", "float64", -1.0 / 3.0),
        ];
        let enc = |ty: &str, v: Real, be: bool| -> Vec<u8> {
            macro_rules! e {
                ($t:ty) => {
                    if be {
                        (v as $t).to_be_bytes().to_vec()
                    } else {
                        (v as $t).to_le_bytes().to_vec()
                    }
                };
            }
            match ty {
                "char" => e!(i8),
                "uchar" => e!(u8),
                "short" => e!(i16),
                "ushort" => e!(u16),
                "int" => e!(i32),
                "uint" => e!(u32),
                "float" => e!(f32),
                _ => e!(f64),
            }
        };
        for long_names in [false, true] {
            // x is int, y ushort, z float: coordinates of any type are accepted too.
            let name = |k: usize| if long_names { types[k].1 } else { types[k].0 };
            let mut head = format!(
                "element vertex 2\nproperty {} x\nproperty {} y\nproperty {} z\n",
                name(4),
                name(3),
                name(6)
            );
            for (k, t) in types.iter().enumerate() {
                head.push_str(&format!("property {} s_{}\n", name(k), t.0));
            }
            head.push_str("end_header\n");
            let coords = [[4.0, 3.0, 6.0], [-2.0, 65535.0, -0.5]];
            for fmt in ["ascii", "binary_little_endian", "binary_big_endian"] {
                let mut bytes = format!("ply\nformat {fmt} 1.0\n{head}").into_bytes();
                for c in coords {
                    if fmt == "ascii" {
                        let mut line = format!("{} {} {}", c[0], c[1], c[2]);
                        for t in &types {
                            line.push_str(&format!(" {:?}", t.2));
                        }
                        bytes.extend_from_slice(format!("{line}\n").as_bytes());
                    } else {
                        let be = fmt == "binary_big_endian";
                        bytes.extend(enc("int", c[0], be));
                        bytes.extend(enc("ushort", c[1], be));
                        bytes.extend(enc("float", c[2], be));
                        for t in &types {
                            bytes.extend(enc(t.0, t.2, be));
                        }
                    }
                }
                let cloud = read(&bytes).unwrap_or_else(|e| panic!("{fmt}: {e}"));
                assert_eq!(
                    cloud.points,
                    vec![Point3::new(4.0, 3.0, 6.0), Point3::new(-2.0, 65535.0, -0.5)]
                );
                assert_eq!(cloud.scalars.len(), types.len());
                for (s, t) in cloud.scalars.iter().zip(&types) {
                    assert_eq!(s.name, format!("s_{}", t.0));
                    let want = if t.0 == "double" {
                        t.2
                    } else {
                        t.2 as f32 as Real
                    };
                    let want = if fmt == "ascii" { t.2 } else { want };
                    assert_eq!(s.values, [want, want], "{fmt} {}", t.0);
                }
            }
        }
    }
}
