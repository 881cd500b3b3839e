//! Vertex records encoded in parallel blocks and written in order, for every writer: binary
//! records (little- or big-endian `double`s) through one reused buffer, text lines (x y z,
//! normals, scalars) in Rust's shortest round-trip form. The output never depends on the
//! thread count.

use super::point_cloud::{InvalidCloud, PointCloud};
use crate::math::Real;
use rayon::prelude::*;
use std::io::Write;
use std::ops::Range;

/// Target size of one encoded block in the writers (one parallel task).
const BLOCK_BYTES: usize = 1 << 19;

/// Most bytes the binary writer encodes before passing them on (1 MiB in unit tests, so
/// that they cover several rounds).
const ROUND_BYTES: usize = if cfg!(test) { 1 << 20 } else { 1 << 22 };

/// Blocks the text writers encode in parallel before writing them out in order.
const BLOCKS_PER_ROUND: usize = 16;

pub(super) fn invalid_input(e: InvalidCloud) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidInput, e)
}

/// Writes the binary vertex records of a validated cloud: encoded in parallel, blocks of
/// about 512 KiB at a time, into one reused 4 MiB buffer that is passed to `w` whole. (A
/// small buffer touches few fresh pages: on a VM, first-touch page faults cost more than
/// the encoding, and a buffer the size of the file doubled the time of a write to `Vec`.
/// Encoding the next buffer while writing the current one was tried: no measurable gain.)
pub(super) fn write_binary<W: Write + ?Sized>(
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
pub(super) fn write_blocks<W, F>(
    w: &mut W,
    n: usize,
    bytes_per_point: usize,
    encode: F,
) -> std::io::Result<()>
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
pub(super) fn encode_text(
    cloud: &PointCloud,
    r: Range<usize>,
    sep: u8,
    buf: &mut Vec<u8>,
) -> std::io::Result<()> {
    encode_text_columns(cloud, r, sep, true, buf)
}

pub(super) fn encode_text_columns(
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
