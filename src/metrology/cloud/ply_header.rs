//! The PLY header: its format line, elements and properties of every PLY scalar and list
//! type, the frame comment ([`parse_header`]), and the vertex element's layout it declares
//! ([`VertexLayout`]: which column is a coordinate, a normal component or a scalar field).

use super::point_cloud::{Frame, RESERVED, scalar_name_problem};
use crate::math::Real;

/// Data encoding declared by the `format` line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    pub(super) fn name(self) -> &'static str {
        match self {
            Scalar::I8 => "char",
            Scalar::U8 => "uchar",
            Scalar::I16 => "short",
            Scalar::U16 => "ushort",
            Scalar::I32 => "int",
            Scalar::U32 => "uint",
            Scalar::F32 => "float",
            Scalar::F64 => "double",
        }
    }

    pub(super) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Inclusive range of an integer type (`None` for floating point).
    pub(super) fn int_range(self) -> Option<(Real, Real)> {
        Some(match self {
            Scalar::I8 => (-128.0, 127.0),
            Scalar::U8 => (0.0, 255.0),
            Scalar::I16 => (-32768.0, 32767.0),
            Scalar::U16 => (0.0, 65535.0),
            Scalar::I32 => (-2147483648.0, 2147483647.0),
            Scalar::U32 => (0.0, 4294967295.0),
            Scalar::F32 | Scalar::F64 => return None,
        })
    }
}

/// A property's type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    Scalar(Scalar),
    /// A list: an integer count then that many items.
    List {
        count: Scalar,
        item: Scalar,
    },
}

/// One `property` line.
#[derive(Clone, Debug)]
pub(super) struct Property {
    name: String,
    pub(super) kind: Kind,
}

/// One `element` line with its properties.
#[derive(Clone, Debug)]
pub(super) struct Element {
    pub(super) name: String,
    pub(super) count: u64,
    pub(super) props: Vec<Property>,
}

impl Element {
    /// Bytes per item in binary encodings when no property is a list.
    pub(super) fn stride(&self) -> Option<usize> {
        self.props.iter().try_fold(0usize, |acc, p| match p.kind {
            Kind::Scalar(s) => acc.checked_add(s.size()),
            Kind::List { .. } => None,
        })
    }

    /// Fewest bytes one binary item can take (lists empty).
    pub(super) fn min_item_bytes(&self) -> usize {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) | Kind::List { count: s, .. } => s.size(),
            })
            .fold(0usize, usize::saturating_add)
    }
}

/// The parsed header.
#[derive(Debug)]
pub(super) struct Header {
    pub(super) format: Format,
    pub(super) elements: Vec<Element>,
    pub(super) frame: Option<Frame>,
    /// Offset of the first data byte.
    pub(super) data_start: usize,
    /// 1-based line number of the first data line (ASCII).
    pub(super) data_line: usize,
}

/// Finds the `end_header` line; returns the header lines' byte range end and the data
/// start offset.
pub(super) fn find_end_header(bytes: &[u8]) -> Option<(usize, usize)> {
    let mut pos = 0usize;
    while pos < bytes.len() {
        let rest = bytes.get(pos..)?;
        let (line, next) = match rest.iter().position(|&b| b == b'\n') {
            Some(k) => (rest.get(..k)?, pos + k + 1),
            None => (rest, bytes.len()),
        };
        if line.trim_ascii() == b"end_header" {
            return Some((pos, next));
        }
        pos = next;
    }
    None
}

pub(super) fn parse_header(bytes: &[u8]) -> Result<Header, String> {
    if !bytes.starts_with(b"ply") {
        return Err("missing the 'ply' magic line".into());
    }
    let (header_end, data_start) =
        find_end_header(bytes).ok_or_else(|| "header without end_header".to_string())?;
    let text = bytes
        .get(..header_end)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| "header is not ASCII text".to_string())?;
    let mut lines = text.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err("line 1: first line is not 'ply'".into());
    }
    let mut format = None;
    let mut frame = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut last_line = 1;
    for (k, line) in lines.enumerate() {
        let lineno = k + 2;
        last_line = lineno;
        let mut tok = line.split_ascii_whitespace();
        let keyword = tok.next();
        if keyword == Some("comment") && tok.next() == Some("frame") {
            let name = tok.next().unwrap_or("");
            frame = Some(
                Frame::from_name(name)
                    .ok_or_else(|| format!("line {lineno}: unknown frame '{name}' in comment"))?,
            );
            continue;
        }
        match keyword {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                if format.is_some() {
                    return Err(format!("line {lineno}: second format line"));
                }
                let f = match tok.next() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::BinaryLe,
                    Some("binary_big_endian") => Format::BinaryBe,
                    other => {
                        return Err(format!(
                            "line {lineno}: unsupported format '{}'",
                            other.unwrap_or("")
                        ));
                    }
                };
                match tok.next() {
                    Some("1.0") | Some("1") => {}
                    other => {
                        return Err(format!(
                            "line {lineno}: unsupported PLY version '{}'",
                            other.unwrap_or("")
                        ));
                    }
                }
                format = Some(f);
            }
            Some("element") => {
                let (Some(name), Some(count), None) = (tok.next(), tok.next(), tok.next()) else {
                    return Err(format!("line {lineno}: expected 'element <name> <count>'"));
                };
                let count = count
                    .parse::<u64>()
                    .map_err(|_| format!("line {lineno}: bad element count '{count}'"))?;
                if name == "vertex" && elements.iter().any(|e| e.name == "vertex") {
                    return Err(format!("line {lineno}: second vertex element"));
                }
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let Some(element) = elements.last_mut() else {
                    return Err(format!("line {lineno}: property before any element"));
                };
                let words: Vec<&str> = tok.collect();
                let kind = match words.as_slice() {
                    ["list", count_ty, item_ty, _] => {
                        let count = Scalar::parse(count_ty).filter(|s| s.int_range().is_some());
                        match (count, Scalar::parse(item_ty)) {
                            (Some(count), Some(item)) => Kind::List { count, item },
                            _ => {
                                return Err(format!(
                                    "line {lineno}: bad list property types '{count_ty} {item_ty}'"
                                ));
                            }
                        }
                    }
                    [ty, _] => {
                        Kind::Scalar(Scalar::parse(ty).ok_or_else(|| {
                            format!("line {lineno}: unknown property type '{ty}'")
                        })?)
                    }
                    _ => return Err(format!("line {lineno}: expected 'property <type> <name>'")),
                };
                let name = words.last().copied().unwrap_or_default();
                if element.name == "vertex" {
                    if let Kind::List { .. } = kind {
                        return Err(format!(
                            "line {lineno}: list property '{name}' in the vertex element \
                             is not supported"
                        ));
                    }
                    if element.props.iter().any(|p| p.name == name) {
                        return Err(format!("line {lineno}: duplicate vertex property '{name}'"));
                    }
                    if !RESERVED.contains(&name)
                        && let Some(problem) = scalar_name_problem(name)
                    {
                        return Err(format!(
                            "line {lineno}: vertex property name {name:?} {problem}"
                        ));
                    }
                }
                element.props.push(Property {
                    name: name.to_string(),
                    kind,
                });
            }
            Some(other) => return Err(format!("line {lineno}: unknown header keyword '{other}'")),
        }
    }
    let format = format.ok_or_else(|| "header has no format line".to_string())?;
    Ok(Header {
        format,
        elements,
        frame,
        data_start,
        // The end_header line follows the last header line read.
        data_line: last_line + 2,
    })
}

/// What a vertex property becomes.
#[derive(Clone, Copy, Debug)]
pub(super) enum Role {
    /// Coordinate 0, 1, 2.
    Coord(usize),
    /// Normal component 0, 1, 2.
    Normal(usize),
    /// Scalar field j.
    Scalar(usize),
}

/// One vertex property: its type, role and offset in a binary record.
#[derive(Clone, Copy, Debug)]
pub(super) struct Column {
    pub(super) ty: Scalar,
    pub(super) role: Role,
    pub(super) offset: usize,
}

/// The vertex element's layout.
#[derive(Debug)]
pub(super) struct VertexLayout {
    /// Index of the vertex element in the header.
    pub(super) element: usize,
    /// Vertex count.
    pub(super) count: usize,
    /// Every vertex property, in file order.
    pub(super) columns: Vec<Column>,
    /// Their names.
    pub(super) names: Vec<String>,
    /// Columns of x, y, z.
    pub(super) xyz: [Column; 3],
    /// Columns of nx, ny, nz.
    pub(super) normal: Option<[Column; 3]>,
    /// Scalar field names, in file order.
    pub(super) scalar_names: Vec<String>,
    /// Column of each scalar field.
    pub(super) scalar_cols: Vec<Column>,
    /// Bytes per binary vertex record.
    pub(super) stride: usize,
}

impl VertexLayout {
    pub(super) fn new(h: &Header) -> Result<Self, String> {
        let element = h
            .elements
            .iter()
            .position(|e| e.name == "vertex")
            .ok_or_else(|| "no vertex element".to_string())?;
        let v = h
            .elements
            .get(element)
            .ok_or_else(|| "no vertex element".to_string())?;
        let count =
            usize::try_from(v.count).map_err(|_| format!("vertex count {} too large", v.count))?;
        let mut columns = Vec::with_capacity(v.props.len());
        let mut names = Vec::with_capacity(v.props.len());
        let mut coord: [Option<Column>; 3] = [None; 3];
        let mut normal: [Option<Column>; 3] = [None; 3];
        let mut scalar_names = Vec::new();
        let mut scalar_cols = Vec::new();
        let mut offset = 0usize;
        for p in &v.props {
            let Kind::Scalar(ty) = p.kind else {
                return Err(format!(
                    "list property '{}' in the vertex element is not supported",
                    p.name
                ));
            };
            let mut col = Column {
                ty,
                role: Role::Scalar(scalar_names.len()),
                offset,
            };
            let reserved = match p.name.as_str() {
                "x" => Some((false, 0)),
                "y" => Some((false, 1)),
                "z" => Some((false, 2)),
                "nx" => Some((true, 0)),
                "ny" => Some((true, 1)),
                "nz" => Some((true, 2)),
                _ => None,
            };
            match reserved {
                Some((is_normal, a)) => {
                    let slots = if is_normal { &mut normal } else { &mut coord };
                    col.role = if is_normal {
                        Role::Normal(a)
                    } else {
                        Role::Coord(a)
                    };
                    if let Some(slot) = slots.get_mut(a) {
                        if slot.is_some() {
                            return Err(format!("duplicate vertex property '{}'", p.name));
                        }
                        *slot = Some(col);
                    }
                }
                None => {
                    scalar_names.push(p.name.clone());
                    scalar_cols.push(col);
                }
            }
            columns.push(col);
            names.push(p.name.clone());
            offset = offset
                .checked_add(ty.size())
                .ok_or_else(|| "vertex record too large".to_string())?;
        }
        let [Some(x), Some(y), Some(z)] = coord else {
            return Err("vertex element lacks x, y or z".into());
        };
        let normal = match normal {
            [Some(a), Some(b), Some(c)] => Some([a, b, c]),
            [None, None, None] => None,
            _ => return Err("vertex element has some but not all of nx, ny, nz".into()),
        };
        Ok(Self {
            element,
            count,
            columns,
            names,
            xyz: [x, y, z],
            normal,
            scalar_names,
            scalar_cols,
            stride: offset,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{is_malformed, malformed_message, read};

    #[test]
    fn vertex_layout_errors() {
        let base = "ply\nformat binary_little_endian 1.0\nelement vertex 0\n\
                    property double x\nproperty double y\nproperty double z\n";
        let m = malformed_message(read(
            format!("{base}property list uchar int idx\nend_header\n").as_bytes(),
        ));
        assert!(m.contains("list property") && m.contains("vertex"), "{m}");
        let m = malformed_message(read(
            format!("{base}property float nx\nend_header\n").as_bytes(),
        ));
        assert!(m.contains("nx, ny, nz"), "{m}");
        let m = malformed_message(read(
            format!("{base}property float y\nend_header\n").as_bytes(),
        ));
        assert!(m.contains("duplicate"), "{m}");
        let m = malformed_message(read(
            format!("{base}element vertex 0\nproperty double x\nend_header\n").as_bytes(),
        ));
        assert!(m.contains("second vertex"), "{m}");
        assert!(is_malformed(read(
            b"ply\nformat ascii 1.0\nelement vertex 0\nproperty double x\nend_header\n"
        )));
        assert!(is_malformed(read(
            b"ply\nformat ascii 1.0\nelement face 0\nproperty uchar a\nend_header\n"
        )));
    }
}
