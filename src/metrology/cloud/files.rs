//! Cloud files on disk: [`read_ply_file`] (binary PLY streamed through a buffer, never held
//! whole), [`write_ply_file`], and [`read_cloud_file`] / [`write_cloud_file`], which choose
//! the format by extension. A cloud is validated before its file is created.

use super::error::CloudError;
use super::ply_binary::{
    check_finite, decode_into, skip_binary, trailing_data, truncated_vertices,
};
use super::ply_body::{Body, ReadError, too_large};
use super::ply_header::{Element, Format, VertexLayout, find_end_header, parse_header};
use super::ply_read::{assemble, malformed_ply, read_error, read_ply};
use super::ply_write::write_ply;
use super::point_cloud::PointCloud;
use super::text::{XyzSeparator, read_pts, read_xyz, write_xyz};
use std::path::Path;

/// Writes `cloud` to the file at `path` as binary PLY (see [`write_ply`]).
///
/// The cloud is validated before the file is created ([`CloudError::Invalid`]).
pub fn write_ply_file(cloud: &PointCloud, path: &Path) -> Result<(), CloudError> {
    write_file(cloud, path, write_ply)
}

/// Validates `cloud`, then creates the file at `path` and writes it with `write`.
fn write_file(
    cloud: &PointCloud,
    path: &Path,
    write: impl FnOnce(&PointCloud, &mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> Result<(), CloudError> {
    cloud.validate().map_err(|source| CloudError::Invalid {
        path: path.to_path_buf(),
        source,
    })?;
    let io_err = |source| CloudError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::create(path).map_err(io_err)?;
    let mut w = std::io::BufWriter::with_capacity(1 << 16, file);
    write(cloud, &mut w).map_err(io_err)
}

/// Reads the PLY file at `path`; the result is the same as [`read_ply`] on the file's
/// bytes.
///
/// Binary files whose header fits in the first 64 KiB and has no list element before the
/// vertex element (every common file) are streamed: sizes are checked against the file
/// length, then vertex data are read through a 4 MiB buffer and decoded in parallel, so the
/// file is never held whole in memory. Other files are read whole.
pub fn read_ply_file(path: &Path) -> Result<PointCloud, CloudError> {
    match stream_binary_ply(path)? {
        Some(cloud) => Ok(cloud),
        None => read_ply(&read_bytes(path)?, path),
    }
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, CloudError> {
    std::fs::read(path).map_err(|source| CloudError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Extensions [`read_cloud_file`] understands.
const READ_EXTENSIONS: &str = ".ply, .xyz, .xyzn, .txt, .asc, .csv, .pts";

/// Extensions [`write_cloud_file`] understands.
const WRITE_EXTENSIONS: &str = ".ply, .xyz, .xyzn, .txt, .asc, .csv";

fn extension(path: &Path) -> Option<String> {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
}

/// Reads the cloud file at `path`, choosing the format by extension (any case): `.ply`
/// ([`read_ply`]); `.xyz`, `.xyzn`, `.txt`, `.asc`, `.csv` ([`read_xyz`]); `.pts`
/// ([`read_pts`]). Any other extension is [`CloudError::UnsupportedExtension`], decided
/// before the file is opened.
pub fn read_cloud_file(path: &Path) -> Result<PointCloud, CloudError> {
    let ext = extension(path);
    let text_reader: fn(&str, &Path) -> Result<PointCloud, CloudError> = match ext.as_deref() {
        Some("ply") => return read_ply_file(path),
        Some("xyz" | "xyzn" | "txt" | "asc" | "csv") => read_xyz,
        Some("pts") => read_pts,
        _ => {
            return Err(CloudError::UnsupportedExtension {
                path: path.to_path_buf(),
                supported: READ_EXTENSIONS,
            });
        }
    };
    let bytes = read_bytes(path)?;
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        let line = 1 + bytes
            .get(..e.valid_up_to())
            .unwrap_or_default()
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        CloudError::Malformed {
            path: path.to_path_buf(),
            message: format!("malformed text: line {line}: not UTF-8"),
        }
    })?;
    text_reader(text, path)
}

/// Writes `cloud` to the file at `path`, choosing the format by extension (any case):
/// `.ply` (binary little-endian, [`write_ply`]); `.xyz`, `.xyzn`, `.txt`, `.asc` (space
/// separated) and `.csv` (comma separated) ([`write_xyz`]). Any other extension (`.pts`
/// included) is [`CloudError::UnsupportedExtension`]. The cloud is validated before the
/// file is created.
pub fn write_cloud_file(cloud: &PointCloud, path: &Path) -> Result<(), CloudError> {
    let sep = match extension(path).as_deref() {
        Some("ply") => return write_ply_file(cloud, path),
        Some("xyz" | "xyzn" | "txt" | "asc") => XyzSeparator::Space,
        Some("csv") => XyzSeparator::Comma,
        _ => {
            return Err(CloudError::UnsupportedExtension {
                path: path.to_path_buf(),
                supported: WRITE_EXTENSIONS,
            });
        }
    };
    write_file(cloud, path, |c, w| write_xyz(c, w, sep))
}

/// Bytes of a file [`read_ply_file`] reads first, hoping to find the whole header.
const HEAD_BYTES: u64 = 1 << 16;

/// Size of the buffer [`read_ply_file`] streams binary vertex data through (64 KiB in unit
/// tests, so that they cover several blocks).
const STREAM_BYTES: usize = if cfg!(test) { 1 << 16 } else { 1 << 22 };

/// Reads binary vertex data straight from the file through a 4 MiB buffer (the file is
/// never held whole in memory); a file shorter than [`HEAD_BYTES`] is parsed from memory.
/// `Ok(None)` for files this path does not handle (ASCII, a header longer than
/// [`HEAD_BYTES`], list elements before the vertex element): the caller then reads the
/// whole file with [`read_ply`], which gives the same result.
fn stream_binary_ply(path: &Path) -> Result<Option<PointCloud>, CloudError> {
    use std::io::{Read, Seek};
    let io_err = |source| CloudError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io_err)?;
    let file_len = file.metadata().map_err(io_err)?.len();
    let mut head = Vec::new();
    Read::by_ref(&mut file)
        .take(HEAD_BYTES)
        .read_to_end(&mut head)
        .map_err(io_err)?;
    // The end_header line must be complete (newline included) inside what was read.
    let complete = find_end_header(&head)
        .is_some_and(|(_, start)| head.get(..start).is_some_and(|h| h.ends_with(b"\n")));
    if head.len() < HEAD_BYTES as usize {
        // The whole file is in `head`.
        return read_ply(&head, path).map(Some);
    }
    if !complete {
        return Ok(None);
    }
    let header = parse_header(&head).map_err(|m| malformed_ply(path, m))?;
    let be = match header.format {
        Format::Ascii => return Ok(None),
        Format::BinaryLe => false,
        Format::BinaryBe => true,
    };
    let layout = VertexLayout::new(&header).map_err(|m| malformed_ply(path, m))?;
    let fail = |e| read_error(path, e);
    // Sizes, checked against the file length before anything is allocated.
    let data_len = file_len.saturating_sub(header.data_start as u64);
    let fixed_bytes = |e: &Element| {
        e.stride()
            .and_then(|s| e.count.checked_mul(s as u64))
            .ok_or_else(|| too_large(&e.name))
    };
    let mut start = 0u64;
    for e in header.elements.get(..layout.element).unwrap_or_default() {
        if e.stride().is_none() && e.count > 0 {
            return Ok(None);
        }
        start = start
            .checked_add(fixed_bytes(e).map_err(fail)?)
            .ok_or_else(|| fail(too_large(&e.name)))?;
    }
    let vbytes = (layout.count as u64)
        .checked_mul(layout.stride as u64)
        .ok_or_else(|| fail(too_large("vertex")))?;
    let end = start
        .checked_add(vbytes)
        .filter(|&end| end <= data_len)
        .ok_or_else(|| fail(truncated_vertices(&layout, start, data_len)))?;
    let after = header
        .elements
        .get(layout.element + 1..)
        .unwrap_or_default();
    let walk_tail = after.iter().any(|e| e.stride().is_none());
    if !walk_tail {
        let mut total = end;
        for e in after {
            total = total
                .checked_add(fixed_bytes(e).map_err(fail)?)
                .ok_or_else(|| fail(too_large(&e.name)))?;
        }
        if total != data_len {
            return Err(fail(if total > data_len {
                ReadError::Malformed(format!(
                    "truncated data after the vertices: the header declares {total} bytes \
                     but only {data_len} follow the header"
                ))
            } else {
                trailing_data(total, data_len)
            }));
        }
    }
    let mut body = Body::with_capacity(&layout)
        .ok_or_else(|| io_err(std::io::Error::from(std::io::ErrorKind::OutOfMemory)))?;
    file.seek(std::io::SeekFrom::Start(header.data_start as u64 + start))
        .map_err(io_err)?;
    let stride = layout.stride.max(1);
    let block = (STREAM_BYTES / stride).max(1);
    let mut buf = vec![0u8; block.min(layout.count) * stride];
    let mut left = layout.count;
    let short_read = |e: std::io::Error| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            fail(truncated_vertices(&layout, start, data_len))
        } else {
            io_err(e)
        }
    };
    while left > 0 {
        let n = block.min(left);
        let chunk = buf.get_mut(..n * stride).unwrap_or_default();
        file.read_exact(chunk).map_err(short_read)?;
        decode_into(chunk, &layout, be, &mut body);
        left -= n;
    }
    if walk_tail {
        // Elements with lists after the vertices: read them and walk them (bounded by the
        // file length: `end` ≤ `data_len`).
        let mut tail = Vec::new();
        file.read_to_end(&mut tail).map_err(io_err)?;
        let mut pos = 0usize;
        for e in after {
            pos = skip_binary(&tail, pos, e, be).map_err(fail)?;
        }
        if pos != tail.len() {
            return Err(fail(trailing_data(
                end + pos as u64,
                end + tail.len() as u64,
            )));
        }
    }
    check_finite(&body).map_err(fail)?;
    Ok(Some(assemble(&header, layout, body)))
}

#[cfg(test)]
mod tests {
    use super::super::tests::{
        assert_bit_identical, binary_with_extras, full_cloud, read, sample_cloud, temp_dir,
        to_bytes, to_bytes_as, valid_files,
    };
    use super::super::{Frame, PlyFormat};
    use super::*;
    use crate::math::{Point3, Real, Vector3};
    use std::path::PathBuf;

    // Open3D test data (tests/data/README.md).
    const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data");

    #[test]
    fn reads_open3d_binary_file() {
        let path = PathBuf::from(format!("{DATA}/open3d-small.ply"));
        let c = read_ply_file(&path).expect("Open3D binary PLY");
        // Expected values as printed by Open3D 0.20.0 (tests/data/README.md).
        assert_eq!(c.len(), 120);
        assert_eq!(c.frame, Frame::Workpiece);
        assert_eq!(
            c.points[0],
            Point3::new(-36.62241751713165, -9.06983586796617, -2.0866386621192348)
        );
        assert_eq!(
            c.points[119],
            Point3::new(-41.81178686320026, 41.436158966205696, -35.20868528608628)
        );
        let normals = c.normals.as_ref().expect("normals");
        assert_eq!(
            normals[0],
            Vector3::new(0.6979126105142669, 0.7071873590522735, 0.11315488182942861)
        );
        assert_eq!(
            normals[119],
            Vector3::new(0.07636671898592348, 0.994312603322931, -0.07423322103007796)
        );
        let rgb =
            |i: usize| ["red", "green", "blue"].map(|n| c.scalar(n).expect("colour").values[i]);
        assert_eq!(rgb(0), [216.0, 160.0, 89.0]);
        assert_eq!(rgb(119), [82.0, 117.0, 113.0]);
        assert_eq!(c.scalars.len(), 3);
        // Our own binary writer round-trips it bit-exact.
        assert_bit_identical(&c, &read(&to_bytes(&c)).expect("round trip"));
    }

    #[test]
    fn reads_open3d_ascii_file() {
        let path = PathBuf::from(format!("{DATA}/open3d-small-ascii.ply"));
        let c = read_cloud_file(&path).expect("Open3D ASCII PLY");
        assert_eq!(c.len(), 120);
        // Open3D writes ASCII with 6 significant digits.
        assert_eq!(c.points[0], Point3::new(-36.6224, -9.06984, -2.08664));
        assert_eq!(c.points[119], Point3::new(-41.8118, 41.4362, -35.2087));
        let normals = c.normals.as_ref().expect("normals");
        assert_eq!(normals[0], Vector3::new(0.697913, 0.707187, 0.113155));
        assert_eq!(normals[119], Vector3::new(0.0763667, 0.994313, -0.0742332));
        assert_eq!(c.scalar("red").expect("red").values[0], 216.0);
        assert_eq!(c.scalar("blue").expect("blue").values[119], 113.0);
        // Same cloud as the binary file to within the 6 printed digits.
        let b = read_ply_file(Path::new(&format!("{DATA}/open3d-small.ply"))).expect("binary");
        for (p, q) in c.points.iter().zip(&b.points) {
            assert!((p - q).norm() < 1e-3);
        }
        assert_eq!(c.scalars, b.scalars);
    }

    #[test]
    fn file_helpers_round_trip() {
        let dir = temp_dir("files");
        let path = dir.join("c.ply");
        let c = sample_cloud(50, Frame::Scanner);
        write_ply_file(&c, &path).expect("write file");
        assert_eq!(read_ply_file(&path).expect("read file"), c);
        assert!(matches!(
            read_ply_file(&dir.join("missing.ply")),
            Err(CloudError::Io { .. })
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// `read_ply_file` streams binary files; it must agree with `read_ply` on the bytes.
    #[test]
    fn streamed_file_reading_matches_in_memory_reading() {
        let dir = temp_dir("stream");
        let big = full_cloud(20_000, Frame::Scanner);
        let mut files = valid_files();
        for f in [
            PlyFormat::BinaryLittleEndian,
            PlyFormat::BinaryBigEndian,
            PlyFormat::Ascii,
        ] {
            files.push(to_bytes_as(&big, f));
        }
        // A header longer than the first block read.
        let plain = to_bytes(&sample_cloud(3, Frame::Scanner));
        let mut long = b"ply\n".to_vec();
        long.extend("comment padding padding padding\n".repeat(3000).as_bytes());
        long.extend_from_slice(&plain[4..]);
        files.push(long);
        let many = vec![[1.5f32, -2.0, 3.25]; 5000];
        files.push(binary_with_extras(false, &many));
        files.push(binary_with_extras(true, &many));
        let mut corrupted = Vec::new();
        for f in files.iter().filter(|f| f.starts_with(b"ply")) {
            let text = String::from_utf8_lossy(f);
            let count: usize = text
                .split("element vertex ")
                .nth(1)
                .and_then(|r| r.split_whitespace().next())
                .and_then(|n| n.parse().ok())
                .expect("vertex count");
            for (from, to) in [(count, count + 1), (count, count - 1), (count, 1 << 60)] {
                let mut g = f.clone();
                let (a, b) = (format!("vertex {from}\n"), format!("vertex {to}\n"));
                let k = text.find(&a).expect("count line");
                g.splice(k..k + a.len(), b.bytes());
                corrupted.push(g);
            }
            for cut in [1, 7, 100, 5000] {
                corrupted.push(f[..f.len().saturating_sub(cut)].to_vec());
            }
            let mut g = f.clone();
            g.extend_from_slice(b"\0\0");
            corrupted.push(g);
        }
        // A non-finite coordinate deep in the streamed data.
        let mut bad = big.clone();
        bad.points[15_000].z = 0.0;
        let mut g = to_bytes(&bad);
        let k = g.len() - (20_000 - 15_000) * 64 + 16;
        g[k..k + 8].copy_from_slice(&Real::NAN.to_le_bytes());
        corrupted.push(g);
        for (k, bytes) in files.iter().chain(&corrupted).enumerate() {
            let path = dir.join(format!("f{k}.ply"));
            std::fs::write(&path, bytes).expect("write");
            match (read_ply_file(&path), read_ply(bytes, &path)) {
                (Ok(a), Ok(b)) => assert_bit_identical(&a, &b),
                (Err(a), Err(b)) => {
                    assert_eq!(
                        std::mem::discriminant(&a),
                        std::mem::discriminant(&b),
                        "file {k}: {a} vs {b}"
                    );
                    if let (
                        CloudError::NonFinite { index: i, .. },
                        CloudError::NonFinite { index: j, .. },
                    ) = (&a, &b)
                    {
                        assert_eq!(i, j);
                    }
                }
                (a, b) => panic!("file {k}: {a:?} vs {b:?}"),
            }
        }
        // Small files are read whole at once, the big binary ones streamed; big ASCII
        // and the long header are left to `read_ply`.
        for k in [0, 3, 9, 10, 13, 14] {
            let path = dir.join(format!("f{k}.ply"));
            assert!(matches!(stream_binary_ply(&path), Ok(Some(_))), "file {k}");
        }
        for k in [11, 12] {
            let path = dir.join(format!("f{k}.ply"));
            assert!(matches!(stream_binary_ply(&path), Ok(None)), "file {k}");
        }
        assert!(matches!(
            read_ply_file(&dir.join(format!("f{}.ply", files.len()))),
            Err(CloudError::Malformed { .. })
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn cloud_files_by_extension() {
        let dir = temp_dir("ext");
        let c = full_cloud(40, Frame::Scanner);
        let mut no_scalars = c.clone();
        no_scalars.scalars.clear();
        for name in [
            "a.ply", "b.PLY", "c.xyz", "d.txt", "e.csv", "f.xyzn", "g.asc",
        ] {
            let path = dir.join(name);
            write_cloud_file(&c, &path).expect("write");
            let back = read_cloud_file(&path).expect("read");
            let want = if name.to_lowercase().ends_with(".ply") {
                &c
            } else {
                &no_scalars
            };
            assert_bit_identical(want, &back);
        }
        let csv = std::fs::read_to_string(dir.join("e.csv")).expect("csv");
        assert!(
            csv.lines()
                .nth(2)
                .is_some_and(|l| l.split(',').count() == 6)
        );
        std::fs::write(dir.join("h.pts"), "1\n1 2 3 4\n").expect("pts");
        let p = read_cloud_file(&dir.join("h.pts")).expect("pts");
        assert_eq!(p.scalar("intensity").expect("i").values, [4.0]);
        for name in ["x.obj", "noext", "x.ply.gz"] {
            let e = read_cloud_file(&dir.join(name)).expect_err(name);
            assert!(matches!(e, CloudError::UnsupportedExtension { .. }), "{e}");
            assert!(e.to_string().contains(".ply, .xyz"), "{e}");
        }
        assert!(matches!(
            write_cloud_file(&c, &dir.join("out.pts")),
            Err(CloudError::UnsupportedExtension { .. })
        ));
        assert!(!dir.join("out.pts").exists());
        std::fs::write(dir.join("bad.xyz"), b"1 2 3\n4 5 \xff\n").expect("bad");
        let m = read_cloud_file(&dir.join("bad.xyz"))
            .expect_err("utf8")
            .to_string();
        assert!(m.contains("line 2") && m.contains("UTF-8"), "{m}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
