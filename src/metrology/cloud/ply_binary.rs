//! Binary PLY data, little- and big-endian: values of every PLY type decoded by readers
//! monomorphic in type and byte order, elements around the vertices walked over (lists
//! included), sizes checked against the data before anything is allocated, vertex records
//! decoded in parallel, and the first non-finite vertex found.

use super::ply_body::{Body, ReadError, non_finite, too_large};
use super::ply_header::{Column, Element, Header, Kind, Scalar, VertexLayout};
use super::point_cloud::first_non_finite;
use crate::math::{Point3, Real, Vector3};
use rayon::prelude::*;

/// Slices shorter than this are not split further between threads.
const PAR_MIN: usize = 4096;

/// `N` bytes at `off` in `rec`.
#[inline(always)]
fn bytes_at<const N: usize>(rec: &[u8], off: usize) -> Option<[u8; N]> {
    rec.get(off..off.checked_add(N)?)?.try_into().ok()
}

/// Decodes one value of type `ty` at `off` in `rec` (`None` if out of range).
#[inline(always)]
fn decode(rec: &[u8], off: usize, ty: Scalar, be: bool) -> Option<Real> {
    macro_rules! num {
        ($t:ty, $n:literal) => {
            bytes_at::<$n>(rec, off).map(|b| {
                Real::from(if be {
                    <$t>::from_be_bytes(b)
                } else {
                    <$t>::from_le_bytes(b)
                })
            })
        };
    }
    match ty {
        Scalar::I8 => num!(i8, 1),
        Scalar::U8 => num!(u8, 1),
        Scalar::I16 => num!(i16, 2),
        Scalar::U16 => num!(u16, 2),
        Scalar::I32 => num!(i32, 4),
        Scalar::U32 => num!(u32, 4),
        Scalar::F32 => num!(f32, 4),
        Scalar::F64 => num!(f64, 8),
    }
}

/// A closure reading one value of wire type `$t` (`$n` bytes, `$from` byte order) at an
/// offset of a record; NaN marks the impossible out-of-range case (columns lie inside the
/// record by construction).
macro_rules! reader {
    ($t:ty, $n:literal, $from:ident) => {
        |rec: &[u8], off: usize| -> Real {
            bytes_at::<$n>(rec, off)
                .map(|b| Real::from(<$t>::$from(b)))
                .unwrap_or(Real::NAN)
        }
    };
}

/// Evaluates `$body` with `$get` bound to a [`reader!`] for scalar type `$ty` and byte
/// order `$be`, so loops in `$body` are monomorphic.
macro_rules! with_reader {
    ($ty:expr, $be:expr, |$get:ident| $body:expr) => {
        match ($ty, $be) {
            (Scalar::I8, _) => {
                let $get = reader!(i8, 1, from_le_bytes);
                $body
            }
            (Scalar::U8, _) => {
                let $get = reader!(u8, 1, from_le_bytes);
                $body
            }
            (Scalar::I16, false) => {
                let $get = reader!(i16, 2, from_le_bytes);
                $body
            }
            (Scalar::I16, true) => {
                let $get = reader!(i16, 2, from_be_bytes);
                $body
            }
            (Scalar::U16, false) => {
                let $get = reader!(u16, 2, from_le_bytes);
                $body
            }
            (Scalar::U16, true) => {
                let $get = reader!(u16, 2, from_be_bytes);
                $body
            }
            (Scalar::I32, false) => {
                let $get = reader!(i32, 4, from_le_bytes);
                $body
            }
            (Scalar::I32, true) => {
                let $get = reader!(i32, 4, from_be_bytes);
                $body
            }
            (Scalar::U32, false) => {
                let $get = reader!(u32, 4, from_le_bytes);
                $body
            }
            (Scalar::U32, true) => {
                let $get = reader!(u32, 4, from_be_bytes);
                $body
            }
            (Scalar::F32, false) => {
                let $get = reader!(f32, 4, from_le_bytes);
                $body
            }
            (Scalar::F32, true) => {
                let $get = reader!(f32, 4, from_be_bytes);
                $body
            }
            (Scalar::F64, false) => {
                let $get = reader!(f64, 8, from_le_bytes);
                $body
            }
            (Scalar::F64, true) => {
                let $get = reader!(f64, 8, from_be_bytes);
                $body
            }
        }
    };
}

impl Column {
    /// The column's value in `rec`. Records are `stride` bytes and every column lies inside
    /// them by construction; NaN marks the impossible out-of-range case.
    #[inline(always)]
    fn get(self, rec: &[u8], be: bool) -> Real {
        decode(rec, self.offset, self.ty, be).unwrap_or(Real::NAN)
    }
}

/// Returns the offset just past the binary items of `e` starting at `pos`, walking list
/// properties item by item; errors if the data end first.
pub(super) fn skip_binary(
    data: &[u8],
    pos: usize,
    e: &Element,
    be: bool,
) -> Result<usize, ReadError> {
    let truncated = || {
        ReadError::Malformed(format!(
            "truncated data in element '{}' ({} items declared)",
            e.name, e.count
        ))
    };
    if e.count == 0 || e.props.is_empty() {
        return Ok(pos);
    }
    let remaining = data.len().checked_sub(pos).ok_or_else(truncated)?;
    if let Some(stride) = e.stride() {
        let bytes = usize::try_from(e.count)
            .ok()
            .and_then(|n| n.checked_mul(stride))
            .ok_or_else(truncated)?;
        return if bytes > remaining {
            Err(truncated())
        } else {
            Ok(pos + bytes)
        };
    }
    // Every item takes at least `min` bytes: refuse counts the data cannot hold before
    // walking (so the walk is bounded by the data length).
    let min = e.min_item_bytes().max(1) as u64;
    if e.count > remaining as u64 / min {
        return Err(truncated());
    }
    let mut pos = pos;
    for _ in 0..e.count {
        for p in &e.props {
            pos = match p.kind {
                Kind::Scalar(s) => pos.checked_add(s.size()),
                Kind::List { count, item } => {
                    let n = decode(data, pos, count, be).ok_or_else(truncated)?;
                    if n < 0.0 {
                        return Err(ReadError::Malformed(format!(
                            "negative list length {n} in element '{}'",
                            e.name
                        )));
                    }
                    (n as usize)
                        .checked_mul(item.size())
                        .and_then(|b| b.checked_add(count.size()))
                        .and_then(|b| b.checked_add(pos))
                }
            }
            .filter(|&end| end <= data.len())
            .ok_or_else(truncated)?;
        }
    }
    Ok(pos)
}

/// The error for vertex data that end before the declared vertices.
pub(super) fn truncated_vertices(l: &VertexLayout, start: u64, data_len: u64) -> ReadError {
    ReadError::Malformed(format!(
        "truncated data: the header declares {} vertices of {} bytes from data offset \
         {start} but only {data_len} bytes follow the header",
        l.count, l.stride
    ))
}

/// The error for data beyond the declared elements.
pub(super) fn trailing_data(declared: u64, data_len: u64) -> ReadError {
    ReadError::Malformed(format!(
        "{} bytes of data after the {declared} bytes the header declares",
        data_len.saturating_sub(declared)
    ))
}

pub(super) fn read_binary(
    data: &[u8],
    h: &Header,
    l: &VertexLayout,
    be: bool,
) -> Result<Body, ReadError> {
    let mut start = 0usize;
    for e in h.elements.get(..l.element).unwrap_or_default() {
        start = skip_binary(data, start, e, be)?;
    }
    let vbytes = l
        .count
        .checked_mul(l.stride)
        .ok_or_else(|| too_large("vertex"))?;
    let end = start
        .checked_add(vbytes)
        .filter(|&end| end <= data.len())
        .ok_or_else(|| truncated_vertices(l, start as u64, data.len() as u64))?;
    let mut total = end;
    for e in h.elements.get(l.element + 1..).unwrap_or_default() {
        total = skip_binary(data, total, e, be)?;
    }
    if total != data.len() {
        return Err(trailing_data(total as u64, data.len() as u64));
    }
    // The sizes are checked against the data: allocating `count` items is safe.
    let mut body = Body::with_capacity(l).ok_or_else(|| too_large("vertex"))?;
    decode_into(data.get(start..end).unwrap_or_default(), l, be, &mut body);
    check_finite(&body)?;
    Ok(body)
}

impl Body {
    /// Empty outputs with room for `l.count` vertices (`None` if that cannot be allocated).
    pub(super) fn with_capacity(l: &VertexLayout) -> Option<Body> {
        fn vec<T>(n: usize) -> Option<Vec<T>> {
            let mut v = Vec::new();
            v.try_reserve_exact(n).ok()?;
            Some(v)
        }
        Some(Body {
            points: vec(l.count)?,
            normals: match l.normal {
                Some(_) => Some(vec(l.count)?),
                None => None,
            },
            scalars: l
                .scalar_cols
                .iter()
                .map(|_| vec(l.count))
                .collect::<Option<_>>()?,
        })
    }
}

/// Decodes the whole vertex records in `vdata` and appends them to `body`, in parallel over
/// fixed runs of records (the result does not depend on the thread count). Columns of one
/// type (the usual case) are read by a reader monomorphic in type and byte order; mixed
/// types fall back to per-value dispatch.
pub(super) fn decode_into(vdata: &[u8], l: &VertexLayout, be: bool, body: &mut Body) {
    let stride = l.stride.max(1);
    let records = || vdata.par_chunks_exact(stride).with_min_len(PAR_MIN);
    let [a, b, c] = l.xyz;
    if a.ty == b.ty && b.ty == c.ty {
        with_reader!(a.ty, be, |get| body.points.par_extend(records().map(|r| {
            Point3::new(get(r, a.offset), get(r, b.offset), get(r, c.offset))
        })))
    } else {
        body.points
            .par_extend(records().map(|r| Point3::new(a.get(r, be), b.get(r, be), c.get(r, be))))
    }
    if let (Some([a, b, c]), Some(normals)) = (l.normal, body.normals.as_mut()) {
        if a.ty == b.ty && b.ty == c.ty {
            with_reader!(a.ty, be, |get| normals.par_extend(records().map(|r| {
                Vector3::new(get(r, a.offset), get(r, b.offset), get(r, c.offset))
            })))
        } else {
            normals.par_extend(
                records().map(|r| Vector3::new(a.get(r, be), b.get(r, be), c.get(r, be))),
            )
        }
    }
    for (c, values) in l.scalar_cols.iter().zip(&mut body.scalars) {
        with_reader!(c.ty, be, |get| values
            .par_extend(records().map(|r| get(r, c.offset))))
    }
}

/// The first vertex with a non-finite coordinate or normal, as an error.
pub(super) fn check_finite(body: &Body) -> Result<(), ReadError> {
    let bad_point = first_non_finite(&body.points, |p| p.coords);
    let bad_normal = body
        .normals
        .as_ref()
        .and_then(|ns| first_non_finite(ns, |v| *v));
    match (bad_point, bad_normal) {
        (Some(i), Some(j)) if j < i => Err(non_finite(j, "normal", None)),
        (Some(i), _) => Err(non_finite(i, "coordinate", None)),
        (None, Some(j)) => Err(non_finite(j, "normal", None)),
        (None, None) => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{
        assert_bit_identical, binary_with_extras, full_cloud, is_malformed, malformed_message,
        read, sample_cloud, to_bytes,
    };
    use super::super::{CloudError, Frame};
    use crate::math::{Point3, Real, Vector3};

    #[test]
    fn large_cloud_read_in_parallel_matches() {
        let c = full_cloud(100_003, Frame::Scanner);
        let bytes = to_bytes(&c);
        let back = read(&bytes).expect("read back");
        assert_bit_identical(&c, &back);
        // A non-finite coordinate far into the data: the first one is reported.
        let mut bad = c.clone();
        bad.points[70_001].y = 0.0;
        bad.points[90_000].z = 0.0;
        let mut bytes = to_bytes(&bad);
        let data = bytes.len() - 100_003 * 64;
        let nan = Real::NAN.to_le_bytes();
        bytes[data + 90_000 * 64 + 16..][..8].copy_from_slice(&nan);
        bytes[data + 70_001 * 64 + 8..][..8].copy_from_slice(&nan);
        assert!(matches!(
            read(&bytes),
            Err(CloudError::NonFinite {
                index: 70_001,
                what: "coordinate",
                line: None,
                ..
            })
        ));
        // A non-finite normal before it wins.
        bytes[data + 5 * 64 + 32..][..8].copy_from_slice(&Real::INFINITY.to_le_bytes());
        assert!(matches!(
            read(&bytes),
            Err(CloudError::NonFinite {
                index: 5,
                what: "normal",
                ..
            })
        ));
    }

    #[test]
    fn binary_extra_properties_both_endians() {
        let pts = [[1.0f32, -2.5, 3.25], [10.0, 20.0, 30.5], [0.1, 0.2, 0.3]];
        for be in [false, true] {
            let bytes = binary_with_extras(be, &pts);
            let c = read(&bytes).expect("binary with extras");
            assert_eq!(c.frame, Frame::Scanner);
            let want: Vec<Point3> = pts
                .iter()
                .map(|p| Point3::new(p[0].into(), p[1].into(), p[2].into()))
                .collect();
            assert_eq!(c.points, want, "big endian {be}");
            let n = Vector3::new(0.0, 0.6f32.into(), 0.8f32.into());
            assert_eq!(c.normals, Some(vec![n; 3]));
            assert_eq!(c.scalar("red").expect("red").values, [200.0; 3]);
            assert_eq!(c.scalar("green").expect("green").values, [100.0; 3]);
            assert_eq!(c.scalar("blue").expect("blue").values, [50.0; 3]);
            // The face list is walked: a missing byte or an extra one is an error.
            assert!(is_malformed(read(&bytes[..bytes.len() - 1])));
            let mut long = bytes.clone();
            long.push(0);
            assert!(is_malformed(read(&long)));
            // A list length running past the end of the data.
            let mut bad = bytes.clone();
            let k = bad.len() - 13;
            bad[k] = 4;
            assert!(is_malformed(read(&bad)));
        }
    }

    #[test]
    fn big_endian_doubles() {
        let mut out = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\n\
                        property double x\nproperty double y\nproperty double z\nend_header\n"
            .to_vec();
        for v in [1.0f64, 2.0, 3.0, -0.1, 1e3, 123.456] {
            out.extend_from_slice(&v.to_be_bytes());
        }
        let c = read(&out).expect("big endian");
        assert_eq!(
            c.points,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-0.1, 1e3, 123.456)]
        );
    }

    #[test]
    fn mixed_type_normals_both_endians() {
        for be in [false, true] {
            let fmt = if be { "big" } else { "little" };
            let mut bytes = format!(
                "ply\nformat binary_{fmt}_endian 1.0\nelement vertex 2\nproperty float nx\n\
                 property double x\nproperty double y\nproperty double z\n\
                 property double ny\nproperty short nz\nproperty ushort quality\nend_header\n"
            )
            .into_bytes();
            for i in 0..2i16 {
                let f = f32::from(i) + 0.5;
                let d = [f64::from(i), 10.0, -20.0, -0.25];
                let sh = -7 - i;
                let q = 300u16 + i as u16;
                if be {
                    bytes.extend(f.to_be_bytes());
                    d.iter().for_each(|v| bytes.extend(v.to_be_bytes()));
                    bytes.extend(sh.to_be_bytes());
                    bytes.extend(q.to_be_bytes());
                } else {
                    bytes.extend(f.to_le_bytes());
                    d.iter().for_each(|v| bytes.extend(v.to_le_bytes()));
                    bytes.extend(sh.to_le_bytes());
                    bytes.extend(q.to_le_bytes());
                }
            }
            let c = read(&bytes).expect("mixed types");
            assert_eq!(
                c.points,
                vec![Point3::new(0.0, 10.0, -20.0), Point3::new(1.0, 10.0, -20.0)]
            );
            assert_eq!(
                c.normals,
                Some(vec![
                    Vector3::new(0.5, -0.25, -7.0),
                    Vector3::new(1.5, -0.25, -8.0)
                ])
            );
            assert_eq!(c.scalar("quality").expect("q").values, [300.0, 301.0]);
        }
    }

    #[test]
    fn binary_errors() {
        let good = to_bytes(&sample_cloud(10, Frame::Workpiece));
        // Truncated.
        let m = malformed_message(read(&good[..good.len() - 1]));
        assert!(m.contains("test.ply") && m.contains("truncated"), "{m}");
        // Trailing garbage.
        let mut long = good.clone();
        long.push(0);
        assert!(is_malformed(read(&long)));
        // No end_header.
        let text = "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty double x\n";
        assert!(is_malformed(read(text.as_bytes())));
        // Huge counts must be refused before allocating.
        for count in [
            "18446744073709551615",
            "1000000000000000",
            "1000000000000",
            "99999999999999999999",
        ] {
            let s = String::from_utf8_lossy(&good).replacen(
                "element vertex 10",
                &format!("element vertex {count}"),
                1,
            );
            let header_only = s.split("end_header\n").next().unwrap_or("").to_string();
            let bytes = format!("{header_only}end_header\n");
            assert!(is_malformed(read(bytes.as_bytes())), "count {count}");
            let ascii = bytes.replace("binary_little_endian", "ascii");
            assert!(is_malformed(read(ascii.as_bytes())), "ascii count {count}");
            let with_data = format!("{bytes}{}", "1 2 3\n".repeat(4));
            assert!(is_malformed(read(with_data.as_bytes())), "count {count}");
        }
        // Huge counts in elements around the vertex element, with and without lists.
        for (elem, fmt) in [
            (
                "element face 1000000000000000\nproperty list uchar int v\n",
                "binary_little_endian",
            ),
            (
                "element face 1000000000000000\nproperty list uchar int v\n",
                "ascii",
            ),
            (
                "element face 1000000000000000\nproperty int v\n",
                "binary_big_endian",
            ),
        ] {
            for before in [false, true] {
                let vertex = "element vertex 1\nproperty float x\nproperty float y\n\
                              property float z\n";
                let (a, b) = if before {
                    (elem, vertex)
                } else {
                    (vertex, elem)
                };
                let bytes = format!("ply\nformat {fmt} 1.0\n{a}{b}end_header\n1 2 3\n");
                assert!(is_malformed(read(bytes.as_bytes())), "{fmt} {before}");
            }
        }
        // A list element before the vertex element is walked over.
        let mut s = b"ply\nformat binary_little_endian 1.0\nelement face 2\n\
                      property list uchar int vertex_indices\nelement vertex 1\n\
                      property double x\nproperty double y\nproperty double z\nend_header\n"
            .to_vec();
        s.push(0);
        s.push(2);
        s.extend_from_slice(&5i32.to_le_bytes());
        s.extend_from_slice(&6i32.to_le_bytes());
        for v in [1.0f64, 2.0, 3.0] {
            s.extend_from_slice(&v.to_le_bytes());
        }
        let c = read(&s).expect("leading list element");
        assert_eq!(c.points, vec![Point3::new(1.0, 2.0, 3.0)]);
        // Non-finite vertex index is reported.
        let mut c = sample_cloud(5, Frame::Workpiece);
        c.points[3].z = 0.0;
        let mut bytes = to_bytes(&c);
        let n = bytes.len();
        bytes[n - 2 * 24 + 16..n - 24].copy_from_slice(&Real::INFINITY.to_le_bytes());
        assert!(matches!(
            read(&bytes),
            Err(CloudError::NonFinite { index: 3, .. })
        ));
    }
}
