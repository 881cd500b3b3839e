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
//!
//! # Layout
//!
//! One idea a file: `point_cloud` ([`PointCloud`], [`Frame`], [`ScalarField`] and the
//! validation every writer requires), `error` ([`CloudError`]), `encode` (vertex records
//! encoded in parallel blocks, binary and text), `ply_write` (the PLY writers), the PLY
//! reader in parts: `ply_header` (the header and the vertex layout it declares), `ply_body`
//! (the decoded data and the readers' error), `ply_binary` and `ply_ascii` (the two data
//! encodings) and `ply_read` (the entry point that puts them together); `text` (XYZ/CSV and
//! PTS), and `files` (files on disk, chosen by extension, binary PLY streamed).

mod point_cloud;
mod error;
mod encode;
mod ply_write;
mod ply_header;
mod ply_body;
mod ply_binary;
mod ply_ascii;
mod ply_read;
mod text;
mod files;
#[cfg(test)]
mod tests;

pub use error::CloudError;
pub use files::{read_cloud_file, read_ply_file, write_cloud_file, write_ply_file};
pub use ply_read::read_ply;
pub use ply_write::{PlyFormat, write_ply, write_ply_as};
pub use point_cloud::{Frame, InvalidCloud, PointCloud, ScalarField};
pub use text::{XyzSeparator, read_pts, read_xyz, write_xyz};
