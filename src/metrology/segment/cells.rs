//! Steps 1 and 2 of [`segment_planes`](super::segment_planes): the uniform grid, the binning of the points into
//! its cells with their moments (per fixed chunk, in a small hash table, then merged in
//! chunk order), each occupied cell's plane and whether it is planar ([`MIN_CELL_POINTS`],
//! [`MAX_CELL_FLATNESS`], [`CELL_RMS_FRACTION`], [`MIN_CELL_SPREAD_FRACTION`]), and the
//! cells' occupied neighbours.

use super::input::{MAX_POINTS, SegmentError};
use super::linalg::{Moments, eigen_sym3};
use super::options::{PlaneSegmentOptions, check_plane_options};
use crate::math::{Aabb, Point3, Real, Vector3};
use crate::metrology::fit::CHUNK;
use rayon::prelude::*;

/// Most grid cells [`segment_planes`](super::segment_planes) lays over a cloud's bounding box: 2²⁶. Its dense
/// per-cell tables take 4 bytes a cell each (256 MiB at this size); a grid this fine means
/// cells far below the point spacing of any scan that fits in memory.
pub const MAX_GRID_CELLS: usize = 1 << 26;

/// Fewest points for a planar cell: twice the three parameters of a plane, so a cell plane
/// is over-determined and its smallest eigenvalue measures noise, not chance. A 1 mm cell
/// on a face scanned at 0.185 mm spacing holds about 29 points.
pub const MIN_CELL_POINTS: usize = 6;

/// Largest flatness λ₀/(λ₀+λ₁+λ₂) of a planar cell. A face cell of edge h with noise σ
/// along its normal scores about 6σ²/h² (0.004 at h = 1 mm, σ = 0.025 mm; 0.015 at
/// h = 0.5 mm); a cell split evenly by a 90° edge between two faces scores 0.077.
pub const MAX_CELL_FLATNESS: Real = 0.05;

/// A planar cell's rms residual is at most this fraction of `max_distance_mm`: with the
/// membership distance set to about 4σ, a face cell's residual is σ, while a cell across
/// a 90° edge or a 1 mm step has 0.1–0.5 mm.
pub const CELL_RMS_FRACTION: Real = 0.5;

/// A planar cell's points spread, in the in-plane direction of least spread, with rms at
/// least this fraction of the cell edge (a strip at least 0.52 mm wide in a 1 mm cell):
/// a narrower sliver of a face clipped by the cell leaves its tilt about the sliver's
/// axis set by noise. Such cells' points are still assigned by distance.
pub const MIN_CELL_SPREAD_FRACTION: Real = 0.15;

/// Cells per parallel work item in per-cell passes: small enough to balance, large enough
/// to amortise the scheduling.
const CELL_BLOCK: usize = 64;

/// "No cell / no region" in the `u32` tables.
pub(super) const NONE: u32 = u32::MAX;

/// The cell suggested when a grid is too fine is enlarged by this factor (1 %), so that it
/// still fits after the message rounds it.
const SUGGEST_MARGIN: Real = 1.01;

/// Adding this to a double below 2⁵¹ in magnitude leaves its nearest integer in the low
/// mantissa bits (1.5·2⁵²: the exponent stays fixed for the whole range), a floor for
/// x − ½ with no float-to-integer conversion.
const ROUND_MAGIC: Real = 6_755_399_441_055_744.0;

/// Largest distance from the anchor, in cells, binned exactly: 2⁵⁰, far inside the range
/// of [`ROUND_MAGIC`]. A point further out means a grid beyond [`MAX_GRID_CELLS`].
const MAX_CELL_SPAN: Real = 1_125_899_906_842_624.0;

/// Integer cell coordinates of `p` on the grid of edge `1 / inv_cell` through `anchor`
/// (each ⌊(p − anchor)·inv_cell⌋, except that a point exactly on a cell face may go to
/// either side); `None` beyond [`MAX_CELL_SPAN`] cells.
fn cell_triple(p: &Point3, anchor: &Point3, inv_cell: Real) -> Option<[i64; 3]> {
    let magic = ROUND_MAGIC.to_bits() as i64;
    let mut t = [0i64; 3];
    for (k, tk) in t.iter_mut().enumerate() {
        let x = (p[k] - anchor[k]) * inv_cell;
        let near = x.abs() < MAX_CELL_SPAN;
        if !near {
            return None;
        }
        *tk = (x - 0.5 + ROUND_MAGIC).to_bits() as i64 - magic;
    }
    Some(t)
}

/// The uniform grid: cells of edge `cell` aligned on `anchor` (half a cell below the
/// cloud's first point on each axis),
/// spanning the occupied cells `lo..lo + dims`; x-major keys `(ix·ny + iy)·nz + iz` of
/// coordinates relative to `lo`.
struct Grid {
    anchor: Point3,
    cell: Real,
    inv_cell: Real,
    lo: [i64; 3],
    dims: [usize; 3],
}

impl Grid {
    /// The grid spanning the cells `lo..=hi`, refused beyond [`MAX_GRID_CELLS`].
    fn new(anchor: Point3, cell: Real, lo: [i64; 3], hi: [i64; 3]) -> Result<Self, SegmentError> {
        let span = [0, 1, 2].map(|k| (hi[k] as Real - lo[k] as Real) + 1.0);
        let total: Real = span.iter().product();
        let fits = total <= MAX_GRID_CELLS as Real;
        if !fits {
            let ext = span.map(|s| s * cell);
            let suggest = cell * (total / MAX_GRID_CELLS as Real).cbrt() * SUGGEST_MARGIN;
            return Err(SegmentError::BadOptions(format!(
                "cell_mm = {cell} lays {total:.3e} cells over the cloud's {:.1} × {:.1} × \
                 {:.1} mm bounding box (limit 2^26 = {MAX_GRID_CELLS}): use a cell of at \
                 least {suggest:.3} mm",
                ext[0], ext[1], ext[2]
            )));
        }
        Ok(Self {
            anchor,
            cell,
            inv_cell: 1.0 / cell,
            lo,
            dims: span.map(|s| s as usize),
        })
    }

    fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Grid coordinates of `p` (clamped into the grid).
    fn coords(&self, p: &Point3) -> [usize; 3] {
        let t = cell_triple(p, &self.anchor, self.inv_cell).unwrap_or(self.lo);
        let mut c = [0usize; 3];
        for (k, ck) in c.iter_mut().enumerate() {
            *ck = (t[k].saturating_sub(self.lo[k]).max(0) as usize).min(self.dims[k] - 1);
        }
        c
    }

    fn key(&self, c: [usize; 3]) -> usize {
        (c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]
    }

    /// Centre of the cell with integer coordinates `t` (relative to the anchor).
    fn centre_of_triple(anchor: &Point3, cell: Real, t: [i64; 3]) -> Point3 {
        anchor + Vector3::new(t[0] as Real + 0.5, t[1] as Real + 0.5, t[2] as Real + 0.5) * cell
    }

    /// Centre of the cell with grid coordinates `c`.
    fn centre(&self, c: [usize; 3]) -> Point3 {
        let t = [0, 1, 2].map(|k| c[k] as i64 + self.lo[k]);
        Self::centre_of_triple(&self.anchor, self.cell, t)
    }
}

/// Moments and plane of one occupied cell.
#[derive(Clone, Copy, Debug)]
pub(super) struct CellStat {
    pub(super) n: u32,
    pub(super) centroid: Point3,
    /// Σ (p − c)(p − c)ᵀ about the centroid: xx, xy, xz, yy, yz, zz.
    pub(super) scatter: [Real; 6],
    /// Unit normal of the cell plane (either sign).
    pub(super) normal: Vector3,
    /// Residual sum of squares about the cell plane (λ₀ ≥ 0).
    pub(super) rss: Real,
    /// λ₀ / (λ₀ + λ₁ + λ₂).
    flatness: Real,
    pub(super) planar: bool,
}

impl CellStat {
    /// From the moments `mo` of the cell's points about the cell centre `centre`.
    fn of(mo: &Moments, centre: &Point3, cell_mm: Real, max_distance: Real) -> Self {
        let mut stat = CellStat {
            n: mo.n as u32,
            centroid: *centre,
            scatter: [0.0; 6],
            normal: Vector3::z(),
            rss: 0.0,
            flatness: 1.0,
            planar: false,
        };
        let Some((mean, scatter)) = mo.centred() else {
            return stat;
        };
        stat.centroid = centre + mean;
        stat.scatter = scatter;
        if mo.n < MIN_CELL_POINTS {
            // Never planar; its plane is never used.
            return stat;
        }
        if let Some((l, v)) = eigen_sym3(&scatter) {
            let n = mo.n as Real;
            let l0 = l[0].max(0.0);
            let sum = l0 + l[1] + l[2];
            stat.normal = v;
            stat.rss = l0;
            if sum > 0.0 {
                stat.flatness = l0 / sum;
            }
            let rms_max = CELL_RMS_FRACTION * max_distance;
            let spread_min = MIN_CELL_SPREAD_FRACTION * cell_mm;
            stat.planar = sum > 0.0
                && stat.flatness <= MAX_CELL_FLATNESS
                && l0 / n <= rms_max * rms_max
                && l[1] / n >= spread_min * spread_min;
        }
        stat
    }
}

/// Margin (in cells) of a region's bounding box beyond its cells and their neighbours: a
/// point exactly on a cell face may be binned on either side ([`cell_triple`]), and the
/// box corners are rounded; a thousandth of a cell covers both by far.
const CELL_BOX_SLACK: Real = 1e-3;

/// Slots of the per-chunk hash table of cells: a power of two at least twice [`CHUNK`],
/// so the table is at most half full.
const CHUNK_TABLE: usize = 2 * CHUNK;

/// log₂ of [`CHUNK_TABLE`].
const TABLE_BITS: u32 = CHUNK_TABLE.trailing_zeros();

/// The spatial-hash primes of Teschner et al. (2003), one per axis.
const HASH_PRIMES: [i64; 3] = [73_856_093, 19_349_663, 83_492_791];

/// 2⁶⁴/φ: Fibonacci hashing spreads the hash's high bits over the table.
const FIBONACCI: u64 = 0x9e37_79b9_7f4a_7c15;

/// One chunk's cells: integer coordinates and moments of its points about each cell's
/// centre, in order of first appearance in the chunk; and the first non-finite point.
struct ChunkCells {
    cells: Vec<([i64; 3], Moments)>,
    invalid: Option<usize>,
    /// A point lies beyond [`MAX_CELL_SPAN`] cells from the anchor.
    too_far: bool,
}

/// Bins one chunk: writes each point's record number (its cell among the chunk's) to
/// `rec` and sums the moments. Consecutive points of a scan mostly share a cell, so a run
/// of them is summed in registers and added to its cell's record when the cell changes.
/// `table` is a hash table of [`CHUNK_TABLE`] slots, all [`NONE`], left so.
fn chunk_cells(
    chunk: &[Point3],
    anchor: &Point3,
    cell: Real,
    rec: &mut [u16],
    table: &mut [u32],
) -> ChunkCells {
    let inv = 1.0 / cell;
    let mut out = ChunkCells {
        cells: Vec::with_capacity(CHUNK / MIN_CELL_POINTS),
        invalid: None,
        too_far: false,
    };
    let mut cur = ([i64::MIN; 3], usize::MAX, Point3::origin());
    let mut run = Moments::ZERO;
    let mut used: Vec<usize> = Vec::with_capacity(CHUNK / MIN_CELL_POINTS);
    let mut unbinnable = false;
    for (p, r) in chunk.iter().zip(rec.iter_mut()) {
        let Some(t) = cell_triple(p, anchor, inv) else {
            unbinnable = true;
            break;
        };
        if t != cur.0 {
            if let Some(c) = out.cells.get_mut(cur.1) {
                c.1.merge(&run);
            }
            run = Moments::ZERO;
            // Spatial hash of the coordinates, Fibonacci-mixed; linear probing.
            let h = (t[0].wrapping_mul(HASH_PRIMES[0]) ^ t[1].wrapping_mul(HASH_PRIMES[1]))
                ^ t[2].wrapping_mul(HASH_PRIMES[2]);
            let mut slot = ((h as u64).wrapping_mul(FIBONACCI) >> (u64::BITS - TABLE_BITS))
                as usize
                % CHUNK_TABLE;
            let r = loop {
                let r = table[slot];
                if r == NONE {
                    table[slot] = out.cells.len() as u32;
                    used.push(slot);
                    out.cells.push((t, Moments::ZERO));
                    break out.cells.len() - 1;
                }
                if out.cells[r as usize].0 == t {
                    break r as usize;
                }
                slot = (slot + 1) % CHUNK_TABLE;
            };
            cur = (t, r, Grid::centre_of_triple(anchor, cell, t));
        }
        *r = cur.1 as u16;
        run.push(&(p - cur.2));
    }
    if unbinnable {
        // A non-finite point, or one too far to bin (the grid would be refused).
        out.invalid = chunk
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()));
        out.too_far = out.invalid.is_none();
    }
    if let Some(c) = out.cells.get_mut(cur.1) {
        c.1.merge(&run);
    }
    for s in used {
        table[s] = NONE;
    }
    out
}

/// The cloud binned into grid cells, with each cell's plane and neighbours.
pub(super) struct Cells {
    grid: Grid,
    /// Dense over the grid: key → occupied cell, or [`NONE`].
    lookup: Vec<u32>,
    /// Per occupied cell (numbered in order of first appearance in the cloud): grid
    /// coordinates.
    pub(super) coords: Vec<[u32; 3]>,
    /// Per occupied cell: moments and plane.
    pub(super) stats: Vec<CellStat>,
    /// Occupied 26-neighbours of each cell (in key order): `nbrs[nbr_start[c]..nbr_start[c + 1]]`.
    nbr_start: Vec<u32>,
    nbrs: Vec<u32>,
    /// Per point: its cell's record number in its chunk.
    pub(super) rec: Vec<u16>,
    /// Per chunk: record number → cell.
    pub(super) rec_cell: Vec<Vec<u32>>,
}

/// A flat list of per-item lists built over fixed blocks of items in parallel:
/// `(start, items)` with `items[start[i]..start[i + 1]]` for item i.
pub(super) fn flat_lists(
    n: usize,
    f: impl Fn(usize, &mut Vec<u32>) + Sync,
) -> (Vec<u32>, Vec<u32>) {
    let blocks: Vec<(Vec<u32>, Vec<u32>)> = (0..n.div_ceil(CELL_BLOCK))
        .into_par_iter()
        .map(|b| {
            let mut ends = Vec::with_capacity(CELL_BLOCK);
            let mut list = Vec::new();
            for i in b * CELL_BLOCK..((b + 1) * CELL_BLOCK).min(n) {
                f(i, &mut list);
                ends.push(list.len() as u32);
            }
            (ends, list)
        })
        .collect();
    let mut start = Vec::with_capacity(n + 1);
    let mut flat = Vec::with_capacity(blocks.iter().map(|b| b.1.len()).sum());
    start.push(0u32);
    for (ends, list) in blocks {
        let base = flat.len() as u32;
        start.extend(ends.iter().map(|e| base + e));
        flat.extend(list);
    }
    (start, flat)
}

impl Cells {
    /// Steps 1 and 2: bin and cell planes. Each fixed chunk of points checks its points
    /// and sums their moments per cell (about the cell centre); the partial sums are
    /// added cell by cell in chunk order, so every bit is independent of the threads.
    pub(super) fn build(
        points: &[Point3],
        opts: &PlaneSegmentOptions,
    ) -> Result<Self, SegmentError> {
        check_plane_options(opts)?;
        if points.len() > MAX_POINTS {
            return Err(SegmentError::BadOptions(format!(
                "{} points: at most {MAX_POINTS} are supported",
                points.len()
            )));
        }
        let first = points.first().ok_or(SegmentError::NoPoints)?;
        let cell = opts.cell_mm;
        // Cells centred on the first point, whose surface then lies mid-cell rather than
        // on a cell face (where its points would split between two layers of cells).
        let anchor = first - Vector3::repeat(0.5 * cell);
        let mut rec = vec![0u16; points.len()];
        let parts: Vec<ChunkCells> = points
            .par_chunks(CHUNK)
            .zip(rec.par_chunks_mut(CHUNK))
            .map_init(
                || vec![NONE; CHUNK_TABLE],
                |table, (chunk, rec)| chunk_cells(chunk, &anchor, cell, rec, table),
            )
            .collect();
        let mut lo = [i64::MAX; 3];
        let mut hi = [i64::MIN; 3];
        if let Some((ci, j)) = parts
            .iter()
            .enumerate()
            .find_map(|(ci, part)| part.invalid.map(|j| (ci, j)))
        {
            return Err(SegmentError::NonFinite {
                index: ci * CHUNK + j,
            });
        }
        if parts.iter().any(|part| part.too_far) {
            lo = [0; 3];
            hi = [MAX_CELL_SPAN as i64; 3];
        }
        for part in &parts {
            for (t, _) in &part.cells {
                for k in 0..3 {
                    lo[k] = lo[k].min(t[k]);
                    hi[k] = hi[k].max(t[k]);
                }
            }
        }
        let grid = Grid::new(anchor, cell, lo, hi)?;
        let mut lookup = vec![NONE; grid.len()];
        let mut moments: Vec<Moments> = Vec::new();
        let mut coords: Vec<[u32; 3]> = Vec::new();
        let mut rec_cell: Vec<Vec<u32>> = Vec::with_capacity(parts.len());
        for part in &parts {
            let mut map = Vec::with_capacity(part.cells.len());
            for (t, mo) in &part.cells {
                let c = [0, 1, 2].map(|k| (t[k] - lo[k]) as usize);
                let id = &mut lookup[grid.key(c)];
                if *id == NONE {
                    *id = moments.len() as u32;
                    moments.push(*mo);
                    coords.push(c.map(|v| v as u32));
                } else {
                    moments[*id as usize].merge(mo);
                }
                map.push(*id);
            }
            rec_cell.push(map);
        }
        drop(parts);
        let stats: Vec<CellStat> = moments
            .par_iter()
            .zip(coords.par_iter())
            .with_min_len(CELL_BLOCK)
            .map(|(mo, c)| {
                let centre = grid.centre(c.map(|v| v as usize));
                CellStat::of(mo, &centre, opts.cell_mm, opts.max_distance_mm)
            })
            .collect();
        let mut cells = Self {
            grid,
            lookup,
            coords,
            stats,
            nbr_start: Vec::new(),
            nbrs: Vec::new(),
            rec,
            rec_cell,
        };
        let (nbr_start, nbrs) = flat_lists(cells.len(), |c, out| {
            cells.scan_neighbours(c, |b| out.push(b as u32));
        });
        cells.nbr_start = nbr_start;
        cells.nbrs = nbrs;
        Ok(cells)
    }

    pub(super) fn len(&self) -> usize {
        self.coords.len()
    }

    /// The occupied cell holding `p` (`None` for a point that was not binned).
    pub(super) fn cell_of(&self, p: &Point3) -> Option<usize> {
        let id = *self.lookup.get(self.grid.key(self.grid.coords(p)))?;
        (id != NONE).then_some(id as usize)
    }

    /// Calls `f` for each occupied cell among the 26 neighbours of cell `c`, in key order,
    /// from the grid.
    fn scan_neighbours(&self, c: usize, mut f: impl FnMut(usize)) {
        let [x, y, z] = self.coords[c].map(|v| v as usize);
        let [dx, dy, dz] = self.grid.dims;
        let (z0, z1) = (z.saturating_sub(1), (z + 1).min(dz - 1));
        for ix in x.saturating_sub(1)..=(x + 1).min(dx - 1) {
            for iy in y.saturating_sub(1)..=(y + 1).min(dy - 1) {
                let row = (ix * dy + iy) * dz;
                let Some(column) = self.lookup.get(row + z0..=row + z1) else {
                    continue;
                };
                let centre = (ix, iy) == (x, y);
                for (iz, &id) in (z0..).zip(column) {
                    if id != NONE && !(centre && iz == z) {
                        f(id as usize);
                    }
                }
            }
        }
    }

    /// The occupied 26-neighbours of cell `c`, in key order.
    pub(super) fn neighbours(&self, c: usize) -> &[u32] {
        let (a, b) = (self.nbr_start[c] as usize, self.nbr_start[c + 1] as usize);
        self.nbrs.get(a..b).unwrap_or_default()
    }

    /// Planar cells, flattest first (ties: lower cell).
    pub(super) fn seeds(&self) -> Vec<u32> {
        let mut s: Vec<(u64, u32)> = self
            .stats
            .par_iter()
            .enumerate()
            .filter(|(_, s)| s.planar)
            // Flatness is finite and ≥ 0, so its bits order as the values do.
            .map(|(i, s)| (s.flatness.to_bits(), i as u32))
            .collect();
        s.sort_unstable();
        s.into_iter().map(|(_, i)| i).collect()
    }

    /// Bounding box of the cells from `lo` to `hi` (grid coordinates) grown by one cell
    /// and [`CELL_BOX_SLACK`]: it holds every point of those cells and of their neighbours.
    pub(super) fn cell_box(&self, lo: [u32; 3], hi: [u32; 3]) -> Aabb {
        let g = &self.grid;
        let corner = |c: [u32; 3], shift: Real| {
            let t = [0, 1, 2].map(|k| (c[k] as i64 + g.lo[k]) as Real + shift);
            g.anchor + Vector3::new(t[0], t[1], t[2]) * g.cell
        };
        Aabb {
            min: corner(lo, -1.0 - CELL_BOX_SLACK),
            max: corner(hi, 2.0 + CELL_BOX_SLACK),
        }
    }
}
