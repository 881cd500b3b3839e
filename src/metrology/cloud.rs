//! Point clouds (mm) with optional unit normals and named scalar fields, and their exchange
//! in the PLY, XYZ/CSV and PTS formats.
//!
//! # PLY
//!
//! [`write_ply`] writes `binary_little_endian` PLY ([`write_ply_as`] also writes
//! `binary_big_endian` or `ascii`): `double` x, y, z, then `double` nx, ny, nz when the
//! cloud has normals, then one `property double <name>` per scalar field, in order. These
//! are the property names Open3D, CloudCompare and MeshLab use; CloudCompare shows the
//! extra properties as scalar fields. The cloud's [`Frame`] travels in a
//! `comment frame workpiece` / `comment frame scanner` header line. ASCII values are
//! printed in Rust's shortest round-trip form, so ASCII files read back bit-exact too.
//!
//! [`read_ply`] accepts `ascii`, `binary_little_endian` and `binary_big_endian`. The
//! `vertex` element must have `x`, `y`, `z`; `nx`, `ny`, `nz` (all three or none) become the
//! normals; every other vertex property becomes a [`ScalarField`] of the same name (colours
//! `red`/`green`/`blue` included, as their 0–255 values). Properties of every PLY scalar
//! type (`char` … `double`, `int8` … `float64`) are converted to `f64`. A list property in
//! the vertex element is refused; other elements before or after the vertex element
//! (`face`, camera data, …) are walked over, lists included, so the file length is checked
//! against the header exactly. Sizes are checked against the input length before anything
//! is allocated, and the reader never panics, whatever the bytes. Binary vertex data are
//! decoded in parallel; the result does not depend on the thread count.
//!
//! # XYZ, CSV and PTS text
//!
//! [`read_xyz`] reads lines of 3 (x y z) or 6 (x y z nx ny nz) numbers separated by white
//! space or commas; [`write_xyz`] writes them. [`read_pts`] reads Leica PTS (a point count
//! line before each block). [`read_cloud_file`] and [`write_cloud_file`] choose the format
//! by file extension.

use crate::math::{Aabb, Point3, Real, Vector3};
use rayon::prelude::*;
use std::collections::HashSet;
use std::io::Write;
use std::ops::Range;
use std::path::{Path, PathBuf};

/// The frame a cloud's coordinates are expressed in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Frame {
    /// workpiece frame W
    Workpiece,
    /// scanner frame S
    Scanner,
}

impl Frame {
    /// The lower-case name used in the PLY `comment frame <name>` header line.
    pub fn name(self) -> &'static str {
        match self {
            Frame::Workpiece => "workpiece",
            Frame::Scanner => "scanner",
        }
    }

    /// The frame with the given lower-case name (`"workpiece"` or `"scanner"`).
    pub fn from_name(name: &str) -> Option<Frame> {
        match name {
            "workpiece" => Some(Frame::Workpiece),
            "scanner" => Some(Frame::Scanner),
            _ => None,
        }
    }
}

/// A named per-point value (a deviation, an intensity, a colour channel, …).
#[derive(Clone, Debug, PartialEq)]
pub struct ScalarField {
    /// The name, written as the PLY property name: no white space or control characters,
    /// not one of `x y z nx ny nz`, unique within the cloud.
    pub name: String,
    /// One value per point. Any `f64`, NaN included (CloudCompare's "no value").
    pub values: Vec<Real>,
}

impl ScalarField {
    /// A scalar field named `name` with `values`.
    pub fn new(name: impl Into<String>, values: Vec<Real>) -> Self {
        Self {
            name: name.into(),
            values,
        }
    }
}

/// A point cloud (mm).
#[derive(Clone, Debug, PartialEq)]
pub struct PointCloud {
    /// The frame the coordinates are expressed in.
    pub frame: Frame,
    /// The points (mm), in acquisition order.
    pub points: Vec<Point3>,
    /// Unit normals, one per point, when known. A zero vector is kept as given (some tools
    /// write it for "unknown").
    pub normals: Option<Vec<Vector3>>,
    /// Scalar fields, each with one value per point.
    pub scalars: Vec<ScalarField>,
}

impl PointCloud {
    /// A cloud of `points` in `frame`, without normals or scalar fields.
    pub fn new(frame: Frame, points: Vec<Point3>) -> Self {
        Self {
            frame,
            points,
            normals: None,
            scalars: Vec::new(),
        }
    }

    /// The cloud with `normals` (one per point; checked by [`PointCloud::validate`]).
    pub fn with_normals(mut self, normals: Vec<Vector3>) -> Self {
        self.normals = Some(normals);
        self
    }

    /// The cloud with one more scalar field (checked by [`PointCloud::validate`]).
    pub fn with_scalar(mut self, name: impl Into<String>, values: Vec<Real>) -> Self {
        self.scalars.push(ScalarField::new(name, values));
        self
    }

    /// The scalar field called `name`, if any.
    pub fn scalar(&self, name: &str) -> Option<&ScalarField> {
        self.scalars.iter().find(|s| s.name == name)
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the cloud has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The bounding box of the points ([`Aabb::empty`] for an empty cloud).
    pub fn aabb(&self) -> Aabb {
        let mut b = Aabb::empty();
        for p in &self.points {
            b.grow(p);
        }
        b
    }

    /// Checks what every writer requires: as many normals and scalar values as points,
    /// finite coordinates and normals, and scalar field names that are valid, unique PLY
    /// property names other than `x y z nx ny nz`. Scalar values may be any `f64`.
    pub fn validate(&self) -> Result<(), InvalidCloud> {
        let n = self.points.len();
        if let Some(normals) = &self.normals
            && normals.len() != n
        {
            return Err(InvalidCloud::NormalCount {
                points: n,
                normals: normals.len(),
            });
        }
        let mut seen = HashSet::new();
        for s in &self.scalars {
            if s.values.len() != n {
                return Err(InvalidCloud::ScalarCount {
                    name: s.name.clone(),
                    points: n,
                    values: s.values.len(),
                });
            }
            let problem = scalar_name_problem(&s.name)
                .or_else(|| (!seen.insert(s.name.as_str())).then_some("appears twice"));
            if let Some(reason) = problem {
                return Err(InvalidCloud::ScalarName {
                    name: s.name.clone(),
                    reason,
                });
            }
        }
        if let Some(index) = first_non_finite(&self.points, |p| p.coords) {
            return Err(InvalidCloud::NonFinitePoint { index });
        }
        if let Some(index) = self
            .normals
            .as_ref()
            .and_then(|ns| first_non_finite(ns, |v| *v))
        {
            return Err(InvalidCloud::NonFiniteNormal { index });
        }
        Ok(())
    }
}

/// Index of the first item whose vector has a NaN or infinite component, searched in
/// parallel over fixed chunks (rayon's `position_first` is several times slower here).
fn first_non_finite<T: Sync>(items: &[T], vector: impl Fn(&T) -> Vector3 + Sync) -> Option<usize> {
    items
        .par_chunks(CHECK_CHUNK)
        .enumerate()
        .filter_map(|(k, chunk)| {
            chunk
                .iter()
                .position(|t| {
                    let v = vector(t);
                    !(v.x.is_finite() && v.y.is_finite() && v.z.is_finite())
                })
                .map(|i| k * CHECK_CHUNK + i)
        })
        .min()
}

/// Items per task in [`first_non_finite`].
const CHECK_CHUNK: usize = 1 << 15;

/// Why [`PointCloud::validate`] refuses a cloud.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum InvalidCloud {
    /// The normals are not one per point.
    #[error("{normals} normals for {points} points")]
    NormalCount {
        /// Number of points.
        points: usize,
        /// Number of normals.
        normals: usize,
    },
    /// A scalar field does not have one value per point.
    #[error("scalar field {name:?} has {values} values for {points} points")]
    ScalarCount {
        /// The field's name.
        name: String,
        /// Number of points.
        points: usize,
        /// Number of values.
        values: usize,
    },
    /// A scalar field's name cannot be written as a PLY property name.
    #[error("scalar field name {name:?} {reason}")]
    ScalarName {
        /// The name.
        name: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A point has a NaN or infinite coordinate.
    #[error("point {index} has a non-finite coordinate")]
    NonFinitePoint {
        /// Zero-based index of the first such point.
        index: usize,
    },
    /// A normal has a NaN or infinite component.
    #[error("normal {index} has a non-finite component")]
    NonFiniteNormal {
        /// Zero-based index of the first such normal.
        index: usize,
    },
}

/// What is wrong with `name` as a scalar field (PLY property) name, if anything.
fn scalar_name_problem(name: &str) -> Option<&'static str> {
    if name.is_empty() {
        Some("is empty")
    } else if name
        .chars()
        .any(|c| c.is_ascii_whitespace() || c.is_control())
    {
        Some("contains white space or a control character")
    } else if RESERVED.contains(&name) {
        Some("is reserved for coordinates and normals")
    } else {
        None
    }
}

/// Vertex property names that are not scalar fields.
const RESERVED: [&str; 6] = ["x", "y", "z", "nx", "ny", "nz"];

/// Why a cloud file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum CloudError {
    /// The file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// The file is not one this reader understands: header problems, truncated data,
    /// counts that do not match the data, unsupported layout. The message names the
    /// format and, for text, the 1-based line.
    #[error("{}: {message}", path.display())]
    Malformed {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A point has a NaN or infinite coordinate or normal.
    #[error("{}: {}point {index} has a non-finite {what}", path.display(), at_line(*line))]
    NonFinite {
        /// The file concerned.
        path: PathBuf,
        /// Zero-based index of the first offending point (vertex).
        index: usize,
        /// `"coordinate"` or `"normal"`.
        what: &'static str,
        /// Its 1-based line in a text file.
        line: Option<usize>,
    },
    /// The cloud cannot be written (see [`PointCloud::validate`]); nothing was written.
    #[error("{}: cloud not written: {source}", path.display())]
    Invalid {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong with the cloud.
        source: InvalidCloud,
    },
    /// The file extension does not name a supported format.
    #[error("{}: unsupported file extension (supported: {supported})", path.display())]
    UnsupportedExtension {
        /// The file concerned.
        path: PathBuf,
        /// The extensions that are supported for this operation.
        supported: &'static str,
    },
}

fn at_line(line: Option<usize>) -> String {
    line.map(|l| format!("line {l}: ")).unwrap_or_default()
}

/// The data encoding of a written PLY file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PlyFormat {
    /// `binary_little_endian` (the default: compact, fast, what Open3D writes).
    #[default]
    BinaryLittleEndian,
    /// `binary_big_endian`.
    BinaryBigEndian,
    /// `ascii`, values in shortest round-trip form.
    Ascii,
}

impl PlyFormat {
    fn header_name(self) -> &'static str {
        match self {
            PlyFormat::BinaryLittleEndian => "binary_little_endian",
            PlyFormat::BinaryBigEndian => "binary_big_endian",
            PlyFormat::Ascii => "ascii",
        }
    }
}

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

/// Slices shorter than this are not split further between threads.
const PAR_MIN: usize = 4096;
/// Target size of one encoded block in the writers (one parallel task).
const BLOCK_BYTES: usize = 1 << 19;
/// Most bytes the binary writer encodes before passing them on (1 MiB in unit tests, so
/// that they cover several rounds).
const ROUND_BYTES: usize = if cfg!(test) { 1 << 20 } else { 1 << 22 };
/// Blocks the text writers encode in parallel before writing them out in order.
const BLOCKS_PER_ROUND: usize = 16;

fn invalid_input(e: InvalidCloud) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidInput, e)
}

/// Writes `cloud` as `binary_little_endian` PLY (see [`write_ply_as`]).
///
/// A cloud that fails [`PointCloud::validate`] is refused with an
/// [`InvalidInput`](std::io::ErrorKind::InvalidInput) error wrapping the [`InvalidCloud`]
/// before anything is written.
pub fn write_ply(cloud: &PointCloud, w: &mut impl Write) -> std::io::Result<()> {
    write_ply_as(cloud, PlyFormat::BinaryLittleEndian, w)
}

/// Writes `cloud` as PLY in `format`: `double` x y z, `double` nx ny nz when the cloud has
/// normals, then one `double` property per scalar field.
///
/// The header carries `comment generated by twinmill` and `comment frame <name>`. The
/// cloud is validated first ([`PointCloud::validate`]; failure is an
/// [`InvalidInput`](std::io::ErrorKind::InvalidInput) error wrapping the [`InvalidCloud`]),
/// so nothing is written for a cloud that cannot be written whole. Data are encoded in
/// parallel, in blocks of about 512 KiB, into a buffer of 4 MiB (binary) or 16 blocks
/// (ASCII) that is passed to `w` whole, round after round, in order; `w` is flushed at the
/// end. The output does not depend on the thread count.
pub fn write_ply_as(
    cloud: &PointCloud,
    format: PlyFormat,
    w: &mut impl Write,
) -> std::io::Result<()> {
    cloud.validate().map_err(invalid_input)?;
    let mut header = format!(
        "ply\nformat {} 1.0\ncomment generated by twinmill\ncomment frame {}\n\
         element vertex {}\nproperty double x\nproperty double y\nproperty double z\n",
        format.header_name(),
        cloud.frame.name(),
        cloud.points.len()
    );
    if cloud.normals.is_some() {
        header.push_str("property double nx\nproperty double ny\nproperty double nz\n");
    }
    for s in &cloud.scalars {
        header.push_str("property double ");
        header.push_str(&s.name);
        header.push('\n');
    }
    header.push_str("end_header\n");
    w.write_all(header.as_bytes())?;
    let columns = 3 + if cloud.normals.is_some() { 3 } else { 0 } + cloud.scalars.len();
    match format {
        PlyFormat::Ascii => write_blocks(w, cloud.len(), columns * 24, |r, buf| {
            encode_text(cloud, r, b' ', buf)
        })?,
        PlyFormat::BinaryLittleEndian | PlyFormat::BinaryBigEndian => {
            write_binary(w, cloud, columns * 8, format == PlyFormat::BinaryBigEndian)?
        }
    }
    w.flush()
}

/// Writes the binary vertex records of a validated cloud: encoded in parallel, blocks of
/// about 512 KiB at a time, into one reused 4 MiB buffer that is passed to `w` whole. (A
/// small buffer touches few fresh pages: on a VM, first-touch page faults cost more than
/// the encoding, and a buffer the size of the file doubled the time of a write to `Vec`.
/// Encoding the next buffer while writing the current one was tried: no measurable gain.)
fn write_binary<W: Write + ?Sized>(
    w: &mut W,
    cloud: &PointCloud,
    stride: usize,
    be: bool,
) -> std::io::Result<()> {
    let n = cloud.len();
    let stride = stride.max(1);
    let block = (BLOCK_BYTES / stride).max(1);
    let round = (ROUND_BYTES / stride / block).max(1) * block;
    // Zeroed by the allocator (fresh pages), so the encoding threads fault them in.
    let mut buf = vec![0u8; round.min(n) * stride];
    let mut start = 0usize;
    while start < n {
        let end = (start + round).min(n);
        let bytes = buf.get_mut(..(end - start) * stride).unwrap_or_default();
        bytes
            .par_chunks_mut(block * stride)
            .enumerate()
            .for_each(|(k, chunk)| {
                let first = start + k * block;
                encode_binary(
                    cloud,
                    first..first + chunk.len() / stride,
                    stride,
                    be,
                    chunk,
                );
            });
        w.write_all(bytes)?;
        start = end;
    }
    Ok(())
}

/// Encodes points `0..n` block by block (`encode(range, buffer)`), `BLOCKS_PER_ROUND`
/// blocks in parallel, and writes the blocks to `w` in order.
fn write_blocks<W, F>(w: &mut W, n: usize, bytes_per_point: usize, encode: F) -> std::io::Result<()>
where
    W: Write + ?Sized,
    F: Fn(Range<usize>, &mut Vec<u8>) -> std::io::Result<()> + Sync,
{
    let block = (BLOCK_BYTES / bytes_per_point.max(1)).max(1);
    let blocks = n.div_ceil(block);
    let mut bufs: Vec<Vec<u8>> = vec![Vec::new(); BLOCKS_PER_ROUND.min(blocks)];
    let mut first = 0usize;
    while first < blocks {
        let round = BLOCKS_PER_ROUND.min(blocks - first);
        bufs.par_iter_mut()
            .take(round)
            .enumerate()
            .try_for_each(|(k, buf)| {
                let start = (first + k) * block;
                buf.clear();
                encode(start..(start + block).min(n), buf)
            })?;
        for buf in bufs.iter().take(round) {
            w.write_all(buf)?;
        }
        first += round;
    }
    Ok(())
}

/// Writes `v` at `off` in `rec` (no-op if out of range, which the callers exclude).
#[inline(always)]
fn put(rec: &mut [u8], off: usize, v: Real, be: bool) {
    if let Some(dst) = rec.get_mut(off..off + 8) {
        dst.copy_from_slice(&if be { v.to_be_bytes() } else { v.to_le_bytes() });
    }
}

/// Encodes the binary records of points `r` (validated cloud) into `buf`
/// (`r.len() · stride` bytes).
fn encode_binary(cloud: &PointCloud, r: Range<usize>, stride: usize, be: bool, buf: &mut [u8]) {
    let points = cloud.points.get(r.clone()).unwrap_or_default();
    for (rec, p) in buf.chunks_exact_mut(stride).zip(points) {
        put(rec, 0, p.x, be);
        put(rec, 8, p.y, be);
        put(rec, 16, p.z, be);
    }
    let mut off = 24;
    if let Some(normals) = &cloud.normals {
        let normals = normals.get(r.clone()).unwrap_or_default();
        for (rec, v) in buf.chunks_exact_mut(stride).zip(normals) {
            put(rec, off, v.x, be);
            put(rec, off + 8, v.y, be);
            put(rec, off + 16, v.z, be);
        }
        off += 24;
    }
    for s in &cloud.scalars {
        let values = s.values.get(r.clone()).unwrap_or_default();
        for (rec, &v) in buf.chunks_exact_mut(stride).zip(values) {
            put(rec, off, v, be);
        }
        off += 8;
    }
}

/// Appends one text line per point of `r` (validated cloud) to `buf`: x y z, normals,
/// scalars, separated by `sep`, in shortest round-trip form.
fn encode_text(
    cloud: &PointCloud,
    r: Range<usize>,
    sep: u8,
    buf: &mut Vec<u8>,
) -> std::io::Result<()> {
    encode_text_columns(cloud, r, sep, true, buf)
}

fn encode_text_columns(
    cloud: &PointCloud,
    r: Range<usize>,
    sep: u8,
    scalars: bool,
    buf: &mut Vec<u8>,
) -> std::io::Result<()> {
    let points = cloud.points.get(r.clone()).unwrap_or_default();
    let normals = cloud.normals.as_ref().and_then(|ns| ns.get(r.clone()));
    let value = |buf: &mut Vec<u8>, v: Real, first: bool| {
        if !first {
            buf.push(sep);
        }
        write!(buf, "{v:?}")
    };
    for (k, p) in points.iter().enumerate() {
        value(buf, p.x, true)?;
        value(buf, p.y, false)?;
        value(buf, p.z, false)?;
        if let Some(n) = normals.and_then(|ns| ns.get(k)) {
            value(buf, n.x, false)?;
            value(buf, n.y, false)?;
            value(buf, n.z, false)?;
        }
        if scalars {
            for s in &cloud.scalars {
                if let Some(&v) = s.values.get(r.start + k) {
                    value(buf, v, false)?;
                }
            }
        }
        buf.push(b'\n');
    }
    Ok(())
}

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

// ---------------------------------------------------------------------------------------
// Text clouds (XYZ, CSV, PTS)
// ---------------------------------------------------------------------------------------

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

// ---------------------------------------------------------------------------------------
// PLY reading
// ---------------------------------------------------------------------------------------

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

fn malformed_ply(path: &Path, message: String) -> CloudError {
    CloudError::Malformed {
        path: path.to_path_buf(),
        message: format!("malformed PLY: {message}"),
    }
}

fn read_error(path: &Path, e: ReadError) -> CloudError {
    match e {
        ReadError::Malformed(message) => malformed_ply(path, message),
        ReadError::NonFinite { index, what, line } => CloudError::NonFinite {
            path: path.to_path_buf(),
            index,
            what,
            line,
        },
    }
}

/// The cloud from a header, its vertex layout and the decoded data.
fn assemble(header: &Header, layout: VertexLayout, body: Body) -> PointCloud {
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

/// Data encoding declared by the `format` line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
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

    fn name(self) -> &'static str {
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

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Inclusive range of an integer type (`None` for floating point).
    fn int_range(self) -> Option<(Real, Real)> {
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
enum Kind {
    Scalar(Scalar),
    /// A list: an integer count then that many items.
    List {
        count: Scalar,
        item: Scalar,
    },
}

/// One `property` line.
#[derive(Clone, Debug)]
struct Property {
    name: String,
    kind: Kind,
}

/// One `element` line with its properties.
#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
}

impl Element {
    /// Bytes per item in binary encodings when no property is a list.
    fn stride(&self) -> Option<usize> {
        self.props.iter().try_fold(0usize, |acc, p| match p.kind {
            Kind::Scalar(s) => acc.checked_add(s.size()),
            Kind::List { .. } => None,
        })
    }

    /// Fewest bytes one binary item can take (lists empty).
    fn min_item_bytes(&self) -> usize {
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
struct Header {
    format: Format,
    elements: Vec<Element>,
    frame: Option<Frame>,
    /// Offset of the first data byte.
    data_start: usize,
    /// 1-based line number of the first data line (ASCII).
    data_line: usize,
}

/// Finds the `end_header` line; returns the header lines' byte range end and the data
/// start offset.
fn find_end_header(bytes: &[u8]) -> Option<(usize, usize)> {
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

fn parse_header(bytes: &[u8]) -> Result<Header, String> {
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
enum Role {
    /// Coordinate 0, 1, 2.
    Coord(usize),
    /// Normal component 0, 1, 2.
    Normal(usize),
    /// Scalar field j.
    Scalar(usize),
}

/// One vertex property: its type, role and offset in a binary record.
#[derive(Clone, Copy, Debug)]
struct Column {
    ty: Scalar,
    role: Role,
    offset: usize,
}

/// The vertex element's layout.
#[derive(Debug)]
struct VertexLayout {
    /// Index of the vertex element in the header.
    element: usize,
    /// Vertex count.
    count: usize,
    /// Every vertex property, in file order.
    columns: Vec<Column>,
    /// Columns of x, y, z.
    xyz: [Column; 3],
    /// Columns of nx, ny, nz.
    normal: Option<[Column; 3]>,
    /// Scalar field names, in file order.
    scalar_names: Vec<String>,
    /// Column of each scalar field.
    scalar_cols: Vec<Column>,
    /// Bytes per binary vertex record.
    stride: usize,
}

impl VertexLayout {
    fn new(h: &Header) -> Result<Self, String> {
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
            xyz: [x, y, z],
            normal,
            scalar_names,
            scalar_cols,
            stride: offset,
        })
    }
}

/// Reader-internal error, given a path by [`read_ply`].
enum ReadError {
    Malformed(String),
    NonFinite {
        index: usize,
        what: &'static str,
        line: Option<usize>,
    },
}

/// What the data section yields.
struct Body {
    points: Vec<Point3>,
    normals: Option<Vec<Vector3>>,
    scalars: Vec<Vec<Real>>,
}

fn too_large(what: &str) -> ReadError {
    ReadError::Malformed(format!("{what}: element counts too large for the file"))
}

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
fn skip_binary(data: &[u8], pos: usize, e: &Element, be: bool) -> Result<usize, ReadError> {
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
fn truncated_vertices(l: &VertexLayout, start: u64, data_len: u64) -> ReadError {
    ReadError::Malformed(format!(
        "truncated data: the header declares {} vertices of {} bytes from data offset \
         {start} but only {data_len} bytes follow the header",
        l.count, l.stride
    ))
}

/// The error for data beyond the declared elements.
fn trailing_data(declared: u64, data_len: u64) -> ReadError {
    ReadError::Malformed(format!(
        "{} bytes of data after the {declared} bytes the header declares",
        data_len.saturating_sub(declared)
    ))
}

fn read_binary(data: &[u8], h: &Header, l: &VertexLayout, be: bool) -> Result<Body, ReadError> {
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
    fn with_capacity(l: &VertexLayout) -> Option<Body> {
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
fn decode_into(vdata: &[u8], l: &VertexLayout, be: bool, body: &mut Body) {
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
fn check_finite(body: &Body) -> Result<(), ReadError> {
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

fn non_finite(index: usize, what: &'static str, line: Option<usize>) -> ReadError {
    ReadError::NonFinite { index, what, line }
}

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

fn read_ascii(data: &[u8], h: &Header, l: &VertexLayout) -> Result<Body, ReadError> {
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
        for col in &l.columns {
            let Some(tok) = toks.next() else {
                return Err(ReadError::Malformed(format!(
                    "line {lineno}: vertex {i}: expected {nprops} values, found {}",
                    line.split_ascii_whitespace().count()
                )));
            };
            let v = parse_ascii(tok, col.ty).ok_or_else(|| {
                ReadError::Malformed(format!(
                    "line {lineno}: vertex {i}: '{tok}' is not a valid {}",
                    col.ty.name()
                ))
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
        if toks.next().is_some() {
            return Err(ReadError::Malformed(format!(
                "line {lineno}: vertex {i}: expected {nprops} values, found {}",
                line.split_ascii_whitespace().count()
            )));
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
    use super::*;
    use crate::math::CounterRng;
    use proptest::prelude::*;

    fn sample_cloud(n: usize, frame: Frame) -> PointCloud {
        let rng = CounterRng::new(42);
        let points = (0..n as u64)
            .map(|i| {
                Point3::new(
                    100.0 * rng.normal(3 * i),
                    250.0 + rng.normal(3 * i + 1) / 3.0,
                    -1e-7 * rng.normal(3 * i + 2),
                )
            })
            .collect();
        PointCloud::new(frame, points)
    }

    /// A cloud with normals and two scalar fields, including awkward values (−0, a
    /// subnormal, huge and tiny magnitudes) in its first points.
    fn full_cloud(n: usize, frame: Frame) -> PointCloud {
        let mut c = sample_cloud(n, frame);
        let rng = CounterRng::new(7);
        let normals: Vec<Vector3> = (0..n as u64)
            .map(|i| {
                Vector3::new(
                    rng.normal(3 * i),
                    rng.normal(3 * i + 1),
                    rng.normal(3 * i + 2),
                )
                .normalize()
            })
            .collect();
        let dist: Vec<Real> = (0..n as u64).map(|i| 1e-3 * rng.normal(i + 999)).collect();
        let index: Vec<Real> = (0..n).map(|i| i as Real).collect();
        let awkward = [
            -0.0,
            5e-324,
            1.7976931348623157e308,
            -1e-300,
            0.1,
            1.0 / 3.0,
        ];
        for (k, v) in awkward.iter().enumerate().take(n) {
            c.points[k].x = *v;
        }
        c = c
            .with_normals(normals)
            .with_scalar("scalar_distance", dist)
            .with_scalar("index", index);
        if n > 0 {
            c.normals.as_mut().expect("normals")[0] = Vector3::zeros();
            c.scalars[0].values[0] = -0.0;
        }
        c
    }

    fn to_bytes(c: &PointCloud) -> Vec<u8> {
        let mut out = Vec::new();
        write_ply(c, &mut out).expect("write to Vec");
        out
    }

    fn to_bytes_as(c: &PointCloud, f: PlyFormat) -> Vec<u8> {
        let mut out = Vec::new();
        write_ply_as(c, f, &mut out).expect("write to Vec");
        out
    }

    fn read(bytes: &[u8]) -> Result<PointCloud, CloudError> {
        read_ply(bytes, Path::new("test.ply"))
    }

    fn is_malformed(r: Result<PointCloud, CloudError>) -> bool {
        matches!(r, Err(CloudError::Malformed { .. }))
    }

    /// The Malformed message, or a description of what came instead.
    fn malformed_message(r: Result<PointCloud, CloudError>) -> String {
        match r {
            Err(e @ CloudError::Malformed { .. }) => e.to_string(),
            other => panic!("expected Malformed, got {other:?}"),
        }
    }

    /// Bitwise equality of two clouds (NaN-safe, distinguishes −0).
    fn assert_bit_identical(a: &PointCloud, b: &PointCloud) {
        assert_eq!(a.frame, b.frame);
        assert_eq!(a.points.len(), b.points.len());
        for (p, q) in a.points.iter().zip(&b.points) {
            for k in 0..3 {
                assert_eq!(p[k].to_bits(), q[k].to_bits(), "{p} vs {q}");
            }
        }
        assert_eq!(a.normals.is_some(), b.normals.is_some());
        if let (Some(na), Some(nb)) = (&a.normals, &b.normals) {
            assert_eq!(na.len(), nb.len());
            for (p, q) in na.iter().zip(nb) {
                for k in 0..3 {
                    assert_eq!(p[k].to_bits(), q[k].to_bits());
                }
            }
        }
        assert_eq!(a.scalars.len(), b.scalars.len());
        for (s, t) in a.scalars.iter().zip(&b.scalars) {
            assert_eq!(s.name, t.name);
            let bits = |v: &[Real]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&s.values), bits(&t.values), "field {}", s.name);
        }
    }

    // ----- binary PLY, existing behaviour -----

    #[test]
    fn round_trip_is_bit_exact() {
        for frame in [Frame::Workpiece, Frame::Scanner] {
            let c = sample_cloud(1000, frame);
            let back = read(&to_bytes(&c)).expect("read back");
            assert_bit_identical(&c, &back);
            assert_eq!(back, c);
        }
    }

    #[test]
    fn header_is_standard() {
        let bytes = to_bytes(&sample_cloud(2, Frame::Scanner));
        let text = String::from_utf8_lossy(&bytes);
        assert!(text.starts_with(
            "ply\nformat binary_little_endian 1.0\ncomment generated by twinmill\n\
             comment frame scanner\nelement vertex 2\nproperty double x\nproperty double y\n\
             property double z\nend_header\n"
        ));
        assert_eq!(
            bytes.len(),
            text.find("end_header\n").unwrap_or(0) + 11 + 48
        );
    }

    #[test]
    fn header_with_normals_and_scalars() {
        let c = full_cloud(3, Frame::Workpiece);
        let bytes = to_bytes(&c);
        let head = "ply\nformat binary_little_endian 1.0\ncomment generated by twinmill\n\
                    comment frame workpiece\nelement vertex 3\nproperty double x\n\
                    property double y\nproperty double z\nproperty double nx\n\
                    property double ny\nproperty double nz\n\
                    property double scalar_distance\nproperty double index\nend_header\n";
        assert!(bytes.starts_with(head.as_bytes()));
        assert_eq!(bytes.len(), head.len() + 3 * 8 * 8);
        let ascii = to_bytes_as(&c, PlyFormat::Ascii);
        assert!(ascii.starts_with(head.replace("binary_little_endian", "ascii").as_bytes()));
    }

    #[test]
    fn empty_cloud_round_trips() {
        let c = PointCloud::new(Frame::Workpiece, Vec::new());
        for f in [
            PlyFormat::BinaryLittleEndian,
            PlyFormat::BinaryBigEndian,
            PlyFormat::Ascii,
        ] {
            assert_eq!(read(&to_bytes_as(&c, f)).expect("read"), c);
        }
        let e = full_cloud(0, Frame::Scanner);
        assert_eq!(read(&to_bytes(&e)).expect("read"), e);
    }

    #[test]
    fn write_refuses_non_finite() {
        let mut c = sample_cloud(3, Frame::Workpiece);
        c.points[1].y = Real::NAN;
        let mut out = Vec::new();
        assert!(write_ply(&c, &mut out).is_err());
        assert!(out.is_empty());
    }

    // ----- normals and scalar fields -----

    #[test]
    fn normals_and_scalars_round_trip_in_every_format() {
        for frame in [Frame::Workpiece, Frame::Scanner] {
            let c = full_cloud(500, frame);
            c.validate().expect("valid");
            for f in [
                PlyFormat::BinaryLittleEndian,
                PlyFormat::BinaryBigEndian,
                PlyFormat::Ascii,
            ] {
                let back = read(&to_bytes_as(&c, f)).expect("read back");
                assert_bit_identical(&c, &back);
                assert_eq!(back, c, "{f:?}");
            }
        }
    }

    #[test]
    fn non_finite_scalars_round_trip() {
        let c = sample_cloud(4, Frame::Workpiece).with_scalar(
            "sf",
            vec![Real::NAN, Real::INFINITY, Real::NEG_INFINITY, -0.0],
        );
        for f in [
            PlyFormat::BinaryLittleEndian,
            PlyFormat::BinaryBigEndian,
            PlyFormat::Ascii,
        ] {
            let back = read(&to_bytes_as(&c, f)).expect("read back");
            assert_bit_identical(&c, &back);
        }
    }

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
    fn validate_catches_every_problem() {
        let c = full_cloud(5, Frame::Workpiece);
        assert_eq!(c.validate(), Ok(()));
        let mut bad = c.clone();
        bad.normals.as_mut().expect("normals").pop();
        assert_eq!(
            bad.validate(),
            Err(InvalidCloud::NormalCount {
                points: 5,
                normals: 4
            })
        );
        let bad = c.clone().with_scalar("short", vec![1.0; 4]);
        assert!(matches!(
            bad.validate(),
            Err(InvalidCloud::ScalarCount { values: 4, .. })
        ));
        for name in ["", "a b", "tab\there", "nx", "x", "index", "ctl\u{1}"] {
            let bad = c.clone().with_scalar(name, vec![0.0; 5]);
            assert!(
                matches!(bad.validate(), Err(InvalidCloud::ScalarName { .. })),
                "{name:?}"
            );
        }
        let mut bad = c.clone();
        bad.points[3].z = Real::INFINITY;
        assert_eq!(
            bad.validate(),
            Err(InvalidCloud::NonFinitePoint { index: 3 })
        );
        let mut bad = c.clone();
        bad.normals.as_mut().expect("normals")[2].x = Real::NAN;
        assert_eq!(
            bad.validate(),
            Err(InvalidCloud::NonFiniteNormal { index: 2 })
        );
    }

    #[test]
    fn invalid_clouds_write_nothing() {
        let c = full_cloud(5, Frame::Workpiece);
        let mut short = c.clone();
        short.scalars[1].values.pop();
        let mut long_normals = c.clone();
        long_normals
            .normals
            .as_mut()
            .expect("normals")
            .push(Vector3::x());
        let dup = c.clone().with_scalar("index", vec![0.0; 5]);
        for bad in [&short, &long_normals, &dup] {
            for f in [
                PlyFormat::BinaryLittleEndian,
                PlyFormat::BinaryBigEndian,
                PlyFormat::Ascii,
            ] {
                let mut out = Vec::new();
                let e = write_ply_as(bad, f, &mut out).expect_err("refused");
                assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput);
                assert!(
                    e.get_ref()
                        .is_some_and(|inner| inner.downcast_ref::<InvalidCloud>().is_some())
                );
                assert!(out.is_empty());
            }
            let mut out = Vec::new();
            assert!(write_xyz(bad, &mut out, XyzSeparator::Space).is_err());
            assert!(out.is_empty());
        }
        let dir = temp_dir("invalid");
        let path = dir.join("bad.ply");
        assert!(matches!(
            write_ply_file(&short, &path),
            Err(CloudError::Invalid { .. })
        ));
        assert!(!path.exists(), "no file is created for an invalid cloud");
        assert!(matches!(
            write_cloud_file(&short, &dir.join("bad.csv")),
            Err(CloudError::Invalid { .. })
        ));
        assert!(!dir.join("bad.csv").exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    // ----- reading other writers' PLY -----

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
        let m = malformed_message(read(format!("{head}1 2 3 4\n4 5 x 6\n").as_bytes()));
        assert!(
            m.contains("test.ply") && m.contains("line 10") && m.contains("'x'"),
            "{m}"
        );
        let m = malformed_message(read(format!("{head}1 2 3 4\n\n4 5 6 7 8\n").as_bytes()));
        assert!(m.contains("line 11") && m.contains("found 5"), "{m}");
        // Integers must be whole and in range for their type.
        let m = malformed_message(read(format!("{head}1 2 3 256\n4 5 6 7\n").as_bytes()));
        assert!(m.contains("line 9") && m.contains("uchar"), "{m}");
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
        assert!(m.contains("line 4") && m.contains("quad"), "{m}");
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

    /// A binary file with x y z float, nx ny nz float, red green blue uchar, plus a
    /// leading fixed-size element and a trailing face element.
    fn binary_with_extras(big_endian: bool, pts: &[[f32; 3]]) -> Vec<u8> {
        let fmt = if big_endian {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        };
        let mut out = format!(
            "ply\nformat {fmt} 1.0\ncomment frame scanner\nobj_info whatever\n\
             element camera 1\nproperty short id\nproperty double scale\n\
             element vertex {}\nproperty float32 x\nproperty float32 y\nproperty float32 z\n\
             property float nx\nproperty float ny\nproperty float nz\n\
             property uchar red\nproperty uchar green\nproperty uchar blue\n\
             element face 1\nproperty list uchar int vertex_indices\nend_header\n",
            pts.len()
        )
        .into_bytes();
        let f32b = |v: f32| {
            if big_endian {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        if big_endian {
            out.extend_from_slice(&7i16.to_be_bytes());
            out.extend_from_slice(&2.5f64.to_be_bytes());
        } else {
            out.extend_from_slice(&7i16.to_le_bytes());
            out.extend_from_slice(&2.5f64.to_le_bytes());
        }
        for p in pts {
            for v in p {
                out.extend_from_slice(&f32b(*v));
            }
            for v in [0.0f32, 0.6, 0.8] {
                out.extend_from_slice(&f32b(v));
            }
            out.extend_from_slice(&[200, 100, 50]);
        }
        out.push(3);
        for i in 0..3i32 {
            out.extend_from_slice(&if big_endian {
                i.to_be_bytes()
            } else {
                i.to_le_bytes()
            });
        }
        out
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

    // ----- Open3D test data (tests/data/README.md) -----

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

    // ----- XYZ / CSV / PTS -----

    fn xyz(text: &str) -> Result<PointCloud, CloudError> {
        read_xyz(text, Path::new("test.xyz"))
    }

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

    fn xyz_round_trip(c: &PointCloud, sep: XyzSeparator) -> PointCloud {
        let mut out = Vec::new();
        write_xyz(c, &mut out, sep).expect("write xyz");
        let text = String::from_utf8(out).expect("utf-8");
        xyz(&text).expect("read back")
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

    fn pts(text: &str) -> Result<PointCloud, CloudError> {
        read_pts(text, Path::new("test.pts"))
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

    fn temp_dir(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("twinmill_cloud_{tag}_{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        dir
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

    // ----- robustness -----

    fn ascii_sample() -> Vec<u8> {
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
          property float z\nproperty uchar red\nelement face 1\n\
          property list uchar int vertex_indices\nend_header\n1 2 3 4\n5 6 7 8\n9 10 11 12\n\
          3 0 1 2\n"
            .to_vec()
    }

    fn xyz_sample() -> Vec<u8> {
        b"// frame scanner\nx,y,z,nx,ny,nz\n1,2,3,0,0,1\n4,5,6,0,1,0 # c\n\n7,8,9,1,0,0\n".to_vec()
    }

    /// Valid files of every kind to mutate.
    fn valid_files() -> Vec<Vec<u8>> {
        let c = full_cloud(4, Frame::Scanner);
        vec![
            to_bytes(&sample_cloud(4, Frame::Scanner)),
            to_bytes(&c),
            to_bytes_as(&c, PlyFormat::BinaryBigEndian),
            to_bytes_as(&c, PlyFormat::Ascii),
            binary_with_extras(true, &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]),
            binary_with_extras(false, &[[1.0, 2.0, 3.0]]),
            ascii_sample(),
            xyz_sample(),
            b"2\n1 2 3 4 5 6 7\n8 9 10 11 12 13 14\n".to_vec(),
        ]
    }

    /// Reads `bytes` with every reader (results ignored: they must only not panic).
    fn read_all_ways(bytes: &[u8]) {
        let _ = read(bytes);
        let text = String::from_utf8_lossy(bytes);
        let _ = xyz(&text);
        let _ = pts(&text);
    }

    #[test]
    fn valid_files_are_valid() {
        let files = valid_files();
        for f in &files[..7] {
            read(f).expect("valid PLY");
        }
        let c = xyz(&String::from_utf8_lossy(&files[7])).expect("valid XYZ");
        assert_eq!((c.len(), c.frame), (3, Frame::Scanner));
        assert_eq!(
            pts(&String::from_utf8_lossy(&files[8])).expect("PTS").len(),
            2
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
            read_all_ways(&bytes);
            for prefix in [
                &b"ply\nformat ascii 1.0\n"[..],
                b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n\
                  property float y\nproperty float z\nproperty list uchar int f\n",
                b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty uchar x\n\
                  property char y\nproperty int z\nelement face 3\n\
                  property list uint int vertex_indices\nend_header\n",
            ] {
                let mut with_magic = prefix.to_vec();
                with_magic.extend_from_slice(&bytes);
                let _ = read(&with_magic);
            }
        }

        #[test]
        fn random_text_never_panics(
            lines in proptest::collection::vec("[0-9eE.,+\\- \t#/naif]{0,30}", 0..20),
        ) {
            let text = lines.join("\n");
            let _ = xyz(&text);
            let _ = pts(&text);
        }

        #[test]
        fn truncations_never_panic(cut in 0usize..4000, which in 0usize..9) {
            let files = valid_files();
            let bytes = &files[which % files.len()];
            let cut = cut.min(bytes.len());
            read_all_ways(&bytes[..cut]);
            if cut < bytes.len() && bytes.starts_with(b"ply\nformat binary") {
                // Every truncated binary PLY is an error, never a shorter cloud.
                prop_assert!(read(&bytes[..cut]).is_err());
            }
        }

        #[test]
        fn mutations_never_panic(
            edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8),
            which in 0usize..9,
        ) {
            let files = valid_files();
            let mut bytes = files[which % files.len()].clone();
            let n = bytes.len();
            for (pos, val) in edits {
                if let Some(b) = bytes.get_mut(pos % n) {
                    *b = val;
                }
            }
            read_all_ways(&bytes);
        }

        #[test]
        fn header_digit_mutations_never_panic(
            count in any::<u64>(),
            tail in proptest::collection::vec(any::<u8>(), 0..100),
        ) {
            for fmt in ["ascii", "binary_little_endian", "binary_big_endian"] {
                let mut bytes = format!(
                    "ply\nformat {fmt} 1.0\nelement other {count}\nproperty uchar a\n\
                     element vertex {count}\nproperty float x\nproperty float y\n\
                     property float z\nelement face {count}\nproperty list uchar int v\n\
                     end_header\n"
                )
                .into_bytes();
                bytes.extend_from_slice(&tail);
                let _ = read(&bytes);
            }
        }

        #[test]
        fn random_clouds_round_trip(
            raw in proptest::collection::vec(any::<[u64; 7]>(), 0..40),
            normals in any::<bool>(),
            frame in any::<bool>(),
        ) {
            // Any finite coordinates/normals and any scalar bits survive every format.
            let finite = |b: u64| {
                let v = f64::from_bits(b);
                if v.is_finite() { v } else { 0.5 }
            };
            let frame = if frame { Frame::Scanner } else { Frame::Workpiece };
            let mut c = PointCloud::new(
                frame,
                raw.iter().map(|r| Point3::new(finite(r[0]), finite(r[1]), finite(r[2]))).collect(),
            )
            .with_scalar("s", raw.iter().map(|r| finite(r[6])).collect());
            if normals {
                c = c.with_normals(
                    raw.iter().map(|r| Vector3::new(finite(r[3]), finite(r[4]), finite(r[5]))).collect(),
                );
            }
            for f in [PlyFormat::BinaryLittleEndian, PlyFormat::BinaryBigEndian, PlyFormat::Ascii] {
                let back = read(&to_bytes_as(&c, f)).expect("round trip");
                prop_assert_eq!(&back, &c);
            }
            let mut want = c.clone();
            want.scalars.clear();
            for sep in [XyzSeparator::Space, XyzSeparator::Comma] {
                prop_assert_eq!(&xyz_round_trip(&c, sep), &want);
            }
        }
    }
}
