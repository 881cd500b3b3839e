//! The stock as a tri-dexel: three orthogonal grids of rays (along x, y and z, in the
//! workpiece frame), each ray storing the exact intervals where material is (docs/cutting.md).
//!
//! Every interval end (a *crossing*) keeps the exact surface point along its ray, the
//! outward normal of the material there, and the NC line whose cut made it (0 for the
//! stock's own faces). A plane cut at any angle is therefore represented without grid
//! bias: each crossing lies on the true surface to rounding.
//!
//! Storage is flat per block of 16 × 16 rays: one `Vec<Segment>` and an offset table per
//! block, not a `Vec` per ray. A block whose rays all still hold the untouched box stock
//! has no storage at all until a cut changes it. A cut visits only the blocks in its
//! bounds, in parallel, each block independently, so the result does not depend on the
//! thread count; within a block it evaluates the cutter only on rays with material inside
//! the cutter's bounds along the ray, and rewrites the block only where a ray changed.
//!
//! **Invariant:** the stock knows nothing about G-code, machines or tools: it only asks a
//! [`Cutter`] for the interval it removes along a ray.
//! **Invariant:** within a ray, segments are sorted, disjoint and at least
//! [`tol::SLIVER`] long.

use crate::math::{Aabb, Point3, Real, Vector3, tol};
use rayon::prelude::*;

/// Rays per block side.
const BLOCK: usize = 16;

mod batch;
pub use batch::{Group, GroupCull, Removed};

/// Errors in creating a stock.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StockError {
    /// The box is empty, inverted or not finite.
    #[error("stock box must be finite with min < max on every axis")]
    BadBox,
    /// The pitch is not positive and finite.
    #[error("stock pitch must be positive and finite, got {0} mm")]
    BadPitch(Real),
    /// The tri-dexel would not fit in the memory budget.
    #[error(
        "the tri-dexel stock at pitch {pitch} mm would need {} MiB, more than the {} MiB budget; use a pitch of at least {} mm",
        sig3(*needed_mib),
        sig3(*budget_mib),
        sig3(*suggested_pitch)
    )]
    TooMuchMemory {
        /// Requested pitch (mm).
        pitch: Real,
        /// Estimated need (MiB).
        needed_mib: Real,
        /// Budget (MiB).
        budget_mib: Real,
        /// The finest pitch that fits (mm), rounded up to three significant digits: it fits,
        /// and one unit less in its third digit does not.
        suggested_pitch: Real,
    },
    /// Not even one ray per grid fits in the budget: no pitch helps.
    #[error(
        "the tri-dexel stock needs at least {} MiB at any pitch (one ray per grid), more than the {} MiB budget",
        sig3(*least_mib),
        sig3(*budget_mib)
    )]
    NoPitchFits {
        /// What the coarsest grid needs (MiB).
        least_mib: Real,
        /// Budget (MiB).
        budget_mib: Real,
    },
}

/// `x` with three significant digits (at least as many as an integer part has), as
/// printed in messages.
pub fn sig3(x: Real) -> String {
    if !(x.is_finite() && x > 0.0) {
        return format!("{x}");
    }
    let digits = (2 - x.log10().floor() as i64).max(0) as usize;
    format!("{x:.digits$}")
}

/// One end of a material interval.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    /// Coordinate along the ray (mm, workpiece frame).
    pub t: Real,
    /// Outward unit normal of the material at this point. Stored in f32: it only orients
    /// surface patches; 6e-8 rad of rounding moves a point 0.2 mm away by 1e-8 mm.
    pub normal: [f32; 3],
    /// NC line of the cut that made this surface; 0 for an untouched stock face.
    pub line: u32,
}

impl Crossing {
    /// The normal as a vector.
    pub fn normal(&self) -> Vector3 {
        Vector3::new(
            self.normal[0] as Real,
            self.normal[1] as Real,
            self.normal[2] as Real,
        )
    }

    fn new(t: Real, normal: &Vector3, line: u32) -> Self {
        Self {
            t,
            normal: [normal.x as f32, normal.y as f32, normal.z as f32],
            line,
        }
    }
}

/// A material interval along a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    /// Lower end (smaller coordinate).
    pub lo: Crossing,
    /// Upper end.
    pub hi: Crossing,
}

/// What a cutter removes along one ray: the interval and the outward normals of the
/// *remaining material* at both ends (pointing into the removed region).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayCut {
    /// Entry coordinate along the ray.
    pub t_in: Real,
    /// Exit coordinate along the ray (> `t_in`).
    pub t_out: Real,
    /// Material normal at `t_in` (points along +ray into the cut).
    pub n_in: Vector3,
    /// Material normal at `t_out` (points along −ray into the cut).
    pub n_out: Vector3,
}

impl RayCut {
    /// The hull of a ray's sorted, disjoint intervals: from the first one's entry to the
    /// last one's exit, with their normals; `None` when there is no interval.
    pub fn hull(cuts: &[RayCut]) -> Option<RayCut> {
        let (first, last) = (cuts.first()?, cuts.last()?);
        Some(RayCut {
            t_in: first.t_in,
            t_out: last.t_out,
            n_in: first.n_in,
            n_out: last.n_out,
        })
    }
}

/// A solid that removes material: anything that can say what it occupies along an
/// axis-parallel ray.
pub trait Cutter: Sync {
    /// A box containing the whole solid.
    fn bounds(&self) -> Aabb;
    /// The interval of the ray `origin + t·e_axis` inside the solid, if any.
    fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut>;
    /// Every interval of the ray inside the solid, sorted and disjoint, appended to `out`.
    /// A non-convex solid may have several; the default is [`Cutter::ray_cut`]'s one.
    fn ray_cuts(&self, origin: &Point3, axis: usize, out: &mut Vec<RayCut>) {
        out.extend(self.ray_cut(origin, axis));
    }
    /// Like [`Cutter::ray_cuts`], and appends to `lines` the NC lines `[at t_in, at t_out]`
    /// of each interval's ends, one entry per interval. A cutter standing for several moves
    /// at once names the move each end comes from; the default names `line` for both.
    fn ray_cuts_lined(
        &self,
        origin: &Point3,
        axis: usize,
        line: u32,
        out: &mut Vec<RayCut>,
        lines: &mut Vec<[u32; 2]>,
    ) {
        let before = out.len();
        self.ray_cuts(origin, axis, out);
        lines.resize(lines.len() + out.len() - before, [line, line]);
    }
    /// Whether each ray costs much more than the bookkeeping around it (the stock then
    /// shares the work out ray row by ray row rather than block by block). Default: no.
    fn costly_rays(&self) -> bool {
        false
    }
    /// Whether the cutter may change the ray `origin + t·e_axis` whose material is `segs`:
    /// `false` only when every interval [`Cutter::ray_cuts_in_span`] would give misses
    /// every segment without touching an end (cut latest first,
    /// [`TriDexel::remove_each`], an end a cut meets exactly may take its crossing), so the
    /// ray would come out unchanged. The default: yes.
    fn may_cut(&self, origin: &Point3, axis: usize, segs: &[Segment]) -> bool {
        let _ = (origin, axis, segs);
        true
    }
    /// Like [`Cutter::ray_cuts_lined`] for a caller that only keeps what lies in `span`
    /// along the ray (the material's extent): an interval end outside `span` may be anywhere
    /// outside it, and an interval wholly outside, not even touching an end of it, may be
    /// left out (cut latest first, [`TriDexel::remove_each`], a cut that only touches the
    /// material's end may take that end's crossing). The default is exact.
    fn ray_cuts_in_span(
        &self,
        origin: &Point3,
        axis: usize,
        span: (Real, Real),
        line: u32,
        out: &mut Vec<RayCut>,
        lines: &mut Vec<[u32; 2]>,
    ) {
        let _ = span;
        self.ray_cuts_lined(origin, axis, line, out, lines);
    }
}

#[derive(Clone, Debug, Default)]
struct Block {
    /// `offsets[i]..offsets[i+1]` are ray i's segments in `segs`. Empty while every ray of
    /// the block still holds the grid's `fill` segment (untouched box stock, no storage).
    offsets: Vec<u32>,
    segs: Vec<Segment>,
}

impl Block {
    fn is_fill(&self) -> bool {
        self.offsets.is_empty()
    }

    /// Ray `local`'s segments; `fill` for an untouched block.
    fn ray<'a>(&'a self, local: usize, fill: &'a [Segment; 1]) -> &'a [Segment] {
        if self.is_fill() {
            fill
        } else {
            &self.segs[self.offsets[local] as usize..self.offsets[local + 1] as usize]
        }
    }
}

/// A ray of a block whose segments a cut replaced: `new[start..end]` of the block's scratch.
#[derive(Clone, Copy)]
struct RayChange {
    local: usize,
    start: usize,
    end: usize,
}

/// One grid of parallel rays.
#[derive(Clone, Debug)]
pub struct DexelGrid {
    axis: usize,
    u: usize,
    v: usize,
    u0: Real,
    v0: Real,
    du: Real,
    dv: Real,
    nu: usize,
    nv: usize,
    nbu: usize,
    /// The untouched stock's segment, held by every ray of a block without storage.
    fill: [Segment; 1],
    blocks: Vec<Block>,
}

impl DexelGrid {
    fn new(bounds: &Aabb, axis: usize, pitch: Real) -> Self {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let count = |k: usize| {
            let size = bounds.max[k] - bounds.min[k];
            ((size / pitch).round() as usize).max(1)
        };
        let (nu, nv) = (count(u), count(v));
        let du = (bounds.max[u] - bounds.min[u]) / nu as Real;
        let dv = (bounds.max[v] - bounds.min[v]) / nv as Real;
        let (nbu, nbv) = (nu.div_ceil(BLOCK), nv.div_ceil(BLOCK));
        let mut lo_n = Vector3::zeros();
        lo_n[axis] = -1.0;
        let fill = [Segment {
            lo: Crossing::new(bounds.min[axis], &lo_n, 0),
            hi: Crossing::new(bounds.max[axis], &-lo_n, 0),
        }];
        let blocks = vec![Block::default(); nbu * nbv];
        Self {
            axis,
            u,
            v,
            u0: bounds.min[u] + du / 2.0,
            v0: bounds.min[v] + dv / 2.0,
            du,
            dv,
            nu,
            nv,
            nbu,
            fill,
            blocks,
        }
    }

    /// Number of the grid's rays in block `b`.
    fn rays_in_block(&self, b: usize) -> usize {
        let (bu, bv) = (b % self.nbu, b / self.nbu);
        let w = (self.nu - bu * BLOCK).min(BLOCK);
        let h = (self.nv - bv * BLOCK).min(BLOCK);
        w * h
    }

    /// The ray direction (0 = x, 1 = y, 2 = z).
    pub fn axis(&self) -> usize {
        self.axis
    }

    /// Number of rays along the grid's two in-plane axes.
    pub fn dims(&self) -> (usize, usize) {
        (self.nu, self.nv)
    }

    /// Ray spacings along the two in-plane axes (mm).
    pub fn pitches(&self) -> (Real, Real) {
        (self.du, self.dv)
    }

    /// The point of ray `(iu, iv)` at coordinate 0 along the ray.
    pub fn ray_origin(&self, iu: usize, iv: usize) -> Point3 {
        let mut p = Point3::origin();
        p[self.u] = self.u0 + iu as Real * self.du;
        p[self.v] = self.v0 + iv as Real * self.dv;
        p
    }

    /// The segments of ray `(iu, iv)`.
    pub fn ray(&self, iu: usize, iv: usize) -> &[Segment] {
        let b = &self.blocks[(iv / BLOCK) * self.nbu + iu / BLOCK];
        b.ray((iv % BLOCK) * BLOCK + iu % BLOCK, &self.fill)
    }

    /// Calls `f(point, crossing)` for every crossing of the grid, in a fixed order.
    pub fn for_each_crossing(&self, mut f: impl FnMut(Point3, &Crossing)) {
        for iv in 0..self.nv {
            for iu in 0..self.nu {
                let o = self.ray_origin(iu, iv);
                for s in self.ray(iu, iv) {
                    for c in [&s.lo, &s.hi] {
                        let mut p = o;
                        p[self.axis] = c.t;
                        f(p, c);
                    }
                }
            }
        }
    }

    /// The ray window `(iu, iv)` around `p`'s projection: the rays within `w` indices of the
    /// nearest one, clamped to the grid.
    fn window(
        &self,
        p: &Point3,
        w: usize,
    ) -> (
        std::ops::RangeInclusive<usize>,
        std::ops::RangeInclusive<usize>,
    ) {
        let near = |x: Real, x0: Real, dx: Real, n: usize| {
            let i = ((x - x0) / dx).round().clamp(0.0, (n - 1) as Real) as usize;
            i.saturating_sub(w)..=(i + w).min(n - 1)
        };
        (
            near(p[self.u], self.u0, self.du, self.nu),
            near(p[self.v], self.v0, self.dv, self.nv),
        )
    }

    /// The surface of this grid's material along its rays at `p`, seen from the side the
    /// outward normal `n` faces: the coordinate along the rays of the material ends facing
    /// like `n` (upper ends where `n` points along +ray, lower ends where −ray, their stored
    /// normals within 60° of `n`) nearest `p` within `reach`, on the four rays around `p`,
    /// interpolated bilinearly at `p` (rays without such an end left out, the weights of
    /// the others renormalised); `None` where no ray has one.
    fn surface_along(&self, p: &Point3, n: &Vector3, reach: Real) -> Option<Real> {
        let a = self.axis;
        let up = n[a] > 0.0;
        let fu = ((p[self.u] - self.u0) / self.du).clamp(0.0, (self.nu - 1) as Real);
        let fv = ((p[self.v] - self.v0) / self.dv).clamp(0.0, (self.nv - 1) as Real);
        let (iu, iv) = (fu.floor() as usize, fv.floor() as usize);
        let (wu, wv) = (fu - iu as Real, fv - iv as Real);
        let (mut sum, mut weight) = (0.0, 0.0);
        for (ju, wu) in [(iu, 1.0 - wu), (iu + 1, wu)] {
            for (jv, wv) in [(iv, 1.0 - wv), (iv + 1, wv)] {
                let w = wu * wv;
                if ju >= self.nu || jv >= self.nv || w == 0.0 {
                    continue;
                }
                let best = self
                    .ray(ju, jv)
                    .iter()
                    .map(|s| if up { &s.hi } else { &s.lo })
                    .filter(|c| c.normal().dot(n) >= 0.5 && (c.t - p[a]).abs() <= reach)
                    .map(|c| c.t)
                    .min_by(|x, y| (x - p[a]).abs().total_cmp(&(y - p[a]).abs()));
                if let Some(t) = best {
                    sum += w * t;
                    weight += w;
                }
            }
        }
        (weight > 0.0).then(|| sum / weight)
    }

    /// The crossing nearest `p` among the rays within `w` indices of it whose outward normal
    /// passes `keep`, as (squared distance, crossing point, outward normal).
    fn nearest_crossing(
        &self,
        p: &Point3,
        w: usize,
        keep: &impl Fn(&Vector3) -> bool,
    ) -> Option<(Real, Point3, Vector3)> {
        let mut best: Option<(Real, Point3, Vector3)> = None;
        self.for_each_crossing_near(p, w, |q, c| {
            let d = (q - p).norm_squared();
            if best.is_none_or(|b| d < b.0) {
                let n = c.normal();
                if keep(&n) {
                    best = Some((d, q, n));
                }
            }
        });
        best
    }

    /// Calls `f(point, crossing)` for every crossing on the rays within `w` indices of `p`
    /// (the ray nearest `p` in each direction of the grid's plane, and `w` more on each
    /// side), in a fixed order.
    pub fn for_each_crossing_near(
        &self,
        p: &Point3,
        w: usize,
        mut f: impl FnMut(Point3, &Crossing),
    ) {
        let (us, vs) = self.window(p, w);
        for iv in vs {
            for iu in us.clone() {
                let o = self.ray_origin(iu, iv);
                for c in self.ray(iu, iv).iter().flat_map(|s| [&s.lo, &s.hi]) {
                    let mut q = o;
                    q[self.axis] = c.t;
                    f(q, c);
                }
            }
        }
    }

    /// Material volume measured by this grid (mm³): summed lengths times the ray cell area.
    pub fn volume(&self) -> Real {
        let fill = self.fill[0].hi.t - self.fill[0].lo.t;
        let len: Real = self
            .blocks
            .iter()
            .enumerate()
            .map(|(i, b)| {
                if b.is_fill() {
                    self.rays_in_block(i) as Real * fill
                } else {
                    b.segs.iter().map(|s| s.hi.t - s.lo.t).sum()
                }
            })
            .sum();
        len * self.du * self.dv
    }

    /// Number of segments (held by untouched blocks too).
    pub fn segment_count(&self) -> usize {
        self.blocks
            .iter()
            .enumerate()
            .map(|(i, b)| {
                if b.is_fill() {
                    self.rays_in_block(i)
                } else {
                    b.segs.len()
                }
            })
            .sum()
    }

    /// Bytes held on the heap by this grid's blocks.
    fn heap_bytes(&self) -> usize {
        self.blocks.capacity() * std::mem::size_of::<Block>()
            + self
                .blocks
                .iter()
                .map(|b| {
                    b.segs.capacity() * std::mem::size_of::<Segment>()
                        + b.offsets.capacity() * std::mem::size_of::<u32>()
                })
                .sum::<usize>()
    }

    fn index_range(
        lo: Real,
        hi: Real,
        first: Real,
        step: Real,
        n: usize,
    ) -> Option<(usize, usize)> {
        let a = ((lo - first) / step).ceil().max(0.0);
        let b = ((hi - first) / step).floor();
        if !(a.is_finite() && b.is_finite()) || b < a || a >= n as Real || b < 0.0 {
            return None;
        }
        Some((a as usize, (b as usize).min(n - 1)))
    }

    /// The work of removing what `cutter` occupies within `bounds`: the shared context and
    /// the blocks in the index range, in a fixed order (none if the range is empty).
    #[allow(clippy::type_complexity)]
    fn cut_tasks<'a>(
        &'a mut self,
        cutter: &'a dyn Cutter,
        bounds: &Aabb,
        line: u32,
    ) -> Option<(CutContext<'a>, Vec<(usize, &'a mut Block)>)> {
        let (iu0, iu1) = Self::index_range(
            bounds.min[self.u],
            bounds.max[self.u],
            self.u0,
            self.du,
            self.nu,
        )?;
        let (iv0, iv1) = Self::index_range(
            bounds.min[self.v],
            bounds.max[self.v],
            self.v0,
            self.dv,
            self.nv,
        )?;
        let ctx = CutContext {
            cutter,
            line,
            axis: self.axis,
            u: self.u,
            v: self.v,
            u0: self.u0,
            v0: self.v0,
            du: self.du,
            dv: self.dv,
            iu: (iu0, iu1),
            iv: (iv0, iv1),
            along: (bounds.min[self.axis], bounds.max[self.axis]),
            fill: self.fill,
            nu: self.nu,
            nv: self.nv,
            nbu_blocks: self.nbu,
        };
        let touched = Self::blocks_in(&mut self.blocks, self.nbu, (iu0, iu1), (iv0, iv1));
        Some((ctx, touched))
    }

    /// The blocks of `blocks` (rows of `nbu`) that hold the cell index ranges `iu`, `iv`,
    /// with their indices, in a fixed order (row by row).
    fn blocks_in(
        blocks: &mut [Block],
        nbu: usize,
        iu: (usize, usize),
        iv: (usize, usize),
    ) -> Vec<(usize, &mut Block)> {
        let (bu0, bu1) = (iu.0 / BLOCK, iu.1 / BLOCK);
        let (bv0, bv1) = (iv.0 / BLOCK, iv.1 / BLOCK);
        blocks
            .chunks_mut(nbu)
            .enumerate()
            .skip(bv0)
            .take(bv1 - bv0 + 1)
            .flat_map(|(bv, row)| {
                row[bu0..=bu1]
                    .iter_mut()
                    .enumerate()
                    .map(move |(k, b)| (bv * nbu + bu0 + k, b))
            })
            .collect()
    }
}

/// What a cut of one grid needs to know, shared by its blocks.
struct CutContext<'a> {
    cutter: &'a dyn Cutter,
    line: u32,
    axis: usize,
    u: usize,
    v: usize,
    u0: Real,
    v0: Real,
    du: Real,
    dv: Real,
    /// Ray index ranges (inclusive) in the cutter's bounds.
    iu: (usize, usize),
    iv: (usize, usize),
    /// The cutter's bounds along the rays.
    along: (Real, Real),
    fill: [Segment; 1],
    nu: usize,
    nv: usize,
    /// Blocks per row of the grid.
    nbu_blocks: usize,
}

impl CutContext<'_> {
    /// The rows of block row `bv` in the cut's range.
    fn rows_of(&self, bv: usize) -> std::ops::RangeInclusive<usize> {
        self.iv.0.max(bv * BLOCK)..=self.iv.1.min(bv * BLOCK + BLOCK - 1)
    }

    /// Cuts the rays of block `(bu, bv)` in range; returns the NC lines of the cuts that
    /// changed a ray (consecutive repeats dropped).
    fn cut_block(&self, bu: usize, bv: usize, block: &mut Block) -> Vec<u32> {
        let cut = self.cut_rows(bu, block, self.rows_of(bv));
        self.apply(bu, bv, block, vec![cut])
    }

    /// Writes what cutting the block's rays produced (`rows`, in ray order) into it, each
    /// changed ray's segments read where its row left them; returns the NC lines used (the
    /// rows' in turn).
    fn apply(&self, bu: usize, bv: usize, block: &mut Block, rows: Vec<RowsCut>) -> Vec<u32> {
        let rays: Vec<(usize, &[Segment])> = rows
            .iter()
            .flat_map(|r| {
                r.changes
                    .iter()
                    .map(move |c| (c.local, &r.new[c.start..c.end]))
            })
            .collect();
        if !rays.is_empty() {
            let in_grid = |local: usize| {
                bu * BLOCK + local % BLOCK < self.nu && bv * BLOCK + local / BLOCK < self.nv
            };
            apply_changes(block, &rays, &self.fill, in_grid);
        }
        drop(rays);
        let mut rows = rows.into_iter();
        let mut used = rows.next().map(|r| r.used).unwrap_or_default();
        for r in rows {
            used.extend(r.used);
        }
        used
    }

    /// Cuts the rays of rows `rows` of block `(bu, bv)` in range, reading the block only.
    fn cut_rows(&self, bu: usize, block: &Block, rows: std::ops::RangeInclusive<usize>) -> RowsCut {
        with_ray_buffers(|bufs| self.cut_rows_with(bu, block, rows, bufs))
    }

    /// [`Self::cut_rows`] with the scratch buffers `bufs`.
    fn cut_rows_with(
        &self,
        bu: usize,
        block: &Block,
        rows: std::ops::RangeInclusive<usize>,
        bufs: &mut RayBuffers,
    ) -> RowsCut {
        let mut used = Vec::new();
        let mut new: Vec<Segment> = Vec::new();
        let mut changes: Vec<RayChange> = Vec::new();
        let iu_range = self.iu.0.max(bu * BLOCK)..=self.iu.1.min(bu * BLOCK + BLOCK - 1);
        for iv in rows {
            for iu in iu_range.clone() {
                let local = (iv % BLOCK) * BLOCK + iu % BLOCK;
                let segs = block.ray(local, &self.fill);
                let o = self.origin(iu, iv);
                let start = new.len();
                let cutter = (self.cutter, self.line, self.along);
                if cut_ray(
                    cutter,
                    &o,
                    self.axis,
                    (segs, None),
                    bufs,
                    &mut new,
                    &mut used,
                ) {
                    changes.push(RayChange {
                        local,
                        start,
                        end: new.len(),
                    });
                } else {
                    new.truncate(start);
                }
            }
        }
        RowsCut { new, changes, used }
    }

    /// The origin of ray `(iu, iv)`.
    fn origin(&self, iu: usize, iv: usize) -> Point3 {
        let mut o = Point3::origin();
        o[self.u] = self.u0 + iu as Real * self.du;
        o[self.v] = self.v0 + iv as Real * self.dv;
        o
    }
}

/// Scratch buffers of [`cut_ray`], reused from ray to ray (and, per thread, from row to
/// row: [`RAY_BUFFERS`]).
#[derive(Default)]
struct RayBuffers {
    cuts: Vec<RayCut>,
    lines: Vec<[u32; 2]>,
    scratch: Vec<Segment>,
    next: Vec<Segment>,
    /// A ray's material between the cutters of a batch ([`TriDexel::remove_each`]).
    own: Vec<Segment>,
    after: Vec<Segment>,
    /// A batch's row as it is cut: its new segments, changed rays and NC lines, copied out
    /// at their exact size when the row is done (no buffer grown from empty a row).
    row: RowsCut,
}

thread_local! {
    /// Each thread's [`RayBuffers`], taken by a row's cut and put back after it, so the rows
    /// of a sweep reuse their capacity instead of growing new buffers from empty.
    static RAY_BUFFERS: std::cell::Cell<Option<Box<RayBuffers>>> =
        const { std::cell::Cell::new(None) };
}

/// Runs `f` with this thread's [`RayBuffers`] (fresh ones when a caller up the stack holds
/// them): their contents on entry are whatever the last user left, so `f` clears what it
/// reads.
fn with_ray_buffers<T>(f: impl FnOnce(&mut RayBuffers) -> T) -> T {
    let mut bufs = RAY_BUFFERS.take().unwrap_or_default();
    let out = f(&mut bufs);
    RAY_BUFFERS.set(Some(bufs));
    out
}

/// Cuts the ray `o + t·e_axis` whose material is `segs` by `cutter` (with its NC line and
/// its bounds `along` the ray): appends the ray's new segments to `new` when it changed
/// (returning true; nothing appended, or something to truncate, otherwise) and the lines
/// used to `used`. `before`: see [`subtract`].
fn cut_ray(
    (cutter, line, along): (&dyn Cutter, u32, (Real, Real)),
    o: &Point3,
    axis: usize,
    (segs, before): (&[Segment], Option<&[Segment]>),
    bufs: &mut RayBuffers,
    new: &mut Vec<Segment>,
    used: &mut Vec<u32>,
) -> bool {
    let (lo_a, hi_a) = along;
    // A ray with no material inside the cutter's extent along it cannot change (nor, cut
    // latest first, with none touching it: no end of the cut can meet an end of it).
    let touching = before.is_some();
    let mut inside = segs.iter().filter(|s| {
        (s.hi.t > lo_a || (touching && s.hi.t == lo_a))
            && (s.lo.t < hi_a || (touching && s.lo.t == hi_a))
    });
    let Some(first) = inside.next() else {
        return false;
    };
    let span = (first.lo.t, inside.next_back().unwrap_or(first).hi.t);
    if !cutter.may_cut(o, axis, segs) {
        return false;
    }
    let RayBuffers {
        cuts,
        lines,
        scratch,
        next,
        ..
    } = bufs;
    cuts.clear();
    lines.clear();
    cutter.ray_cuts_in_span(o, axis, span, line, cuts, lines);
    match cuts.as_slice() {
        [] => false,
        [c] => subtract((segs, before), c, lines[0], new, used),
        many => {
            // Subtract the cuts one after another through a scratch buffer.
            scratch.clear();
            scratch.extend_from_slice(segs);
            let mut changed = false;
            for (c, l) in many.iter().zip(lines.iter()) {
                next.clear();
                changed |= subtract((scratch, before), c, *l, next, used);
                std::mem::swap(scratch, next);
            }
            new.extend_from_slice(scratch);
            changed
        }
    }
}

/// What cutting some rays of a block produced: their new segments, which rays changed (in
/// ray order, ranges into `new`) and the NC lines used.
#[derive(Default)]
struct RowsCut {
    new: Vec<Segment>,
    changes: Vec<RayChange>,
    used: Vec<u32>,
}

/// Replaces the changed rays of `block` (`rays`: each ray's index in the block and its new
/// segments, sorted by ray): in place when every changed ray keeps its segment count, else
/// by one rebuild of the block at its exact size. An untouched block is materialised, its
/// rays in the grid (`in_grid`) holding `fill`.
fn apply_changes(
    block: &mut Block,
    rays: &[(usize, &[Segment])],
    fill: &[Segment; 1],
    in_grid: impl Fn(usize) -> bool,
) {
    let old_len = |local: usize| block.ray(local, fill).len();
    if !block.is_fill() && rays.iter().all(|(l, new)| new.len() == old_len(*l)) {
        for (l, new) in rays {
            let at = block.offsets[*l] as usize;
            block.segs[at..at + new.len()].copy_from_slice(new);
        }
        return;
    }
    let before = if block.is_fill() {
        (0..BLOCK * BLOCK).filter(|&l| in_grid(l)).count()
    } else {
        block.segs.len()
    };
    let total = rays
        .iter()
        .fold(before, |n, (l, new)| n + new.len() - old_len(*l));
    let mut segs = Vec::with_capacity(total);
    let mut offsets = Vec::with_capacity(BLOCK * BLOCK + 1);
    offsets.push(0u32);
    let mut pending = rays.iter().peekable();
    for local in 0..BLOCK * BLOCK {
        match pending.peek() {
            Some((l, new)) if *l == local => {
                segs.extend_from_slice(new);
                pending.next();
            }
            _ if block.is_fill() => {
                if in_grid(local) {
                    segs.push(fill[0]);
                }
            }
            _ => segs.extend_from_slice(block.ray(local, fill)),
        }
        offsets.push(segs.len() as u32);
    }
    *block = Block { offsets, segs };
}
/// Appends `segs` minus the cut to `out`; returns whether anything changed. The new
/// crossings carry `lines` (`[at t_in, at t_out]`); the lines of the cut's ends that left a
/// crossing, or of both ends when a segment vanished whole, are appended to `used`.
/// `before`: the ray's material before a batch cut latest first
/// ([`TriDexel::remove_each`]), where an end the cut meets exactly that is not in it takes
/// the cut's crossing (a change); `None` in program order.
fn subtract(
    (segs, before): (&[Segment], Option<&[Segment]>),
    c: &RayCut,
    lines: [u32; 2],
    out: &mut Vec<Segment>,
    used: &mut Vec<u32>,
) -> bool {
    let mut changed = false;
    let mut note = |l: u32| {
        if used.last() != Some(&l) {
            used.push(l);
        }
    };
    for s in segs {
        if c.t_out <= s.lo.t || c.t_in >= s.hi.t {
            let mut s = *s;
            // Cutting a batch latest first: an end this cut meets exactly, made by a later
            // cutter of the batch (not in `before`), is the one this cut would have made
            // first in program order, where the later cut then changes nothing.
            if let Some(before) = before {
                if c.t_out == s.lo.t && !before.iter().any(|b| b.lo == s.lo) {
                    s.lo = Crossing::new(c.t_out, &c.n_out, lines[1]);
                    note(lines[1]);
                    changed = true;
                }
                if c.t_in == s.hi.t && !before.iter().any(|b| b.hi == s.hi) {
                    s.hi = Crossing::new(c.t_in, &c.n_in, lines[0]);
                    note(lines[0]);
                    changed = true;
                }
            }
            out.push(s);
            continue;
        }
        changed = true;
        let keep_lo = c.t_in - s.lo.t >= tol::SLIVER;
        let keep_hi = s.hi.t - c.t_out >= tol::SLIVER;
        if keep_lo {
            out.push(Segment {
                lo: s.lo,
                hi: Crossing::new(c.t_in, &c.n_in, lines[0]),
            });
            note(lines[0]);
        }
        if keep_hi {
            out.push(Segment {
                lo: Crossing::new(c.t_out, &c.n_out, lines[1]),
                hi: s.hi,
            });
            note(lines[1]);
        }
        if !(keep_lo || keep_hi) {
            note(lines[0]);
            note(lines[1]);
        }
    }
    changed
}

/// Estimated bytes of a tri-dexel over `bounds` at `pitch`, assuming two segments per
/// ray on average (a cut part) plus the offset tables, on the grids [`TriDexel::new_box`]
/// lays out: `round(size/pitch)` rays per side, at least one.
pub fn estimate_bytes(bounds: &Aabb, pitch: Real) -> Real {
    let count = |k: usize| ((bounds.max[k] - bounds.min[k]) / pitch).round().max(1.0);
    let (nx, ny, nz) = (count(0), count(1), count(2));
    let rays = ny * nz + nx * nz + nx * ny;
    rays * BYTES_PER_RAY
}

/// Estimated bytes per ray: two segments and an offset.
const BYTES_PER_RAY: Real = 2.0 * std::mem::size_of::<Segment>() as Real + 4.0;

/// Checks that a tri-dexel over `bounds` at `pitch` fits in `budget_bytes`. Over the budget,
/// the error gives the finest pitch that fits, rounded up to three significant digits
/// (always finite), or says that no pitch does (not even one ray per grid fits).
pub fn check_memory(bounds: &Aabb, pitch: Real, budget_bytes: Real) -> Result<(), StockError> {
    let needed = estimate_bytes(bounds, pitch);
    if needed <= budget_bytes {
        return Ok(());
    }
    const MIB: Real = 1048576.0;
    let fits = |p: Real| estimate_bytes(bounds, p) <= budget_bytes;
    // One ray per grid from a pitch of twice the largest extent on (round(size/p) ≤ 1).
    let e = bounds.max - bounds.min;
    let coarsest = 2.0 * e.x.max(e.y).max(e.z);
    if !fits(coarsest) {
        return Err(StockError::NoPitchFits {
            least_mib: estimate_bytes(bounds, coarsest) / MIB,
            budget_mib: budget_bytes / MIB,
        });
    }
    // The need never grows with the pitch: bisect for the boundary between `pitch`
    // (too fine) and `coarsest` (fits), then round up to three significant digits.
    let (mut lo, mut hi) = (pitch, coarsest);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if fits(mid) { hi = mid } else { lo = mid }
    }
    let unit = 10f64.powi(hi.log10().floor() as i32 - 2);
    let mut suggested = (hi / unit).ceil() * unit;
    while !fits(suggested) {
        suggested += unit;
    }
    Err(StockError::TooMuchMemory {
        pitch,
        needed_mib: needed / MIB,
        budget_mib: budget_bytes / MIB,
        suggested_pitch: suggested,
    })
}

/// The tri-dexel stock.
#[derive(Clone, Debug)]
pub struct TriDexel {
    bounds: Aabb,
    pitch: Real,
    grids: [DexelGrid; 3],
}

impl TriDexel {
    /// A box stock at `pitch` (mm), refusing if the estimate exceeds `budget_bytes`.
    pub fn new_box(bounds: Aabb, pitch: Real, budget_bytes: Real) -> Result<Self, StockError> {
        if !bounds.is_proper_box() {
            return Err(StockError::BadBox);
        }
        if !(pitch.is_finite() && pitch > 0.0) {
            return Err(StockError::BadPitch(pitch));
        }
        check_memory(&bounds, pitch, budget_bytes)?;
        Ok(Self {
            bounds,
            pitch,
            grids: [
                DexelGrid::new(&bounds, 0, pitch),
                DexelGrid::new(&bounds, 1, pitch),
                DexelGrid::new(&bounds, 2, pitch),
            ],
        })
    }

    /// A stock of any [`crate::cutting::shape::Solid`] (cylinder, closed mesh, …) on the grids of `bounds` at
    /// `pitch` (mm): each ray keeps the solid's exact intervals, clipped to `bounds`, with the
    /// solid's outward normals (line 0). Spans shorter than [`tol::SLIVER`] are dropped and
    /// gaps shorter than it closed. Refuses like [`TriDexel::new_box`] before allocating.
    pub fn from_solid(
        bounds: Aabb,
        pitch: Real,
        budget_bytes: Real,
        solid: &dyn crate::cutting::shape::Solid,
    ) -> Result<Self, StockError> {
        let mut stock = Self::new_box(bounds, pitch, budget_bytes)?;
        for g in &mut stock.grids {
            let (axis, u, v, u0, v0, du, dv) = (g.axis, g.u, g.v, g.u0, g.v0, g.du, g.dv);
            let (nu, nv, nbu) = (g.nu, g.nv, g.nbu);
            let (lo_k, hi_k) = (bounds.min[axis], bounds.max[axis]);
            g.blocks.par_iter_mut().enumerate().for_each(|(b, block)| {
                let (bu, bv) = (b % nbu, b / nbu);
                let mut spans = Vec::new();
                let mut segs: Vec<Segment> = Vec::new();
                let mut offsets = Vec::with_capacity(BLOCK * BLOCK + 1);
                offsets.push(0u32);
                for local in 0..BLOCK * BLOCK {
                    let (iu, iv) = (bu * BLOCK + local % BLOCK, bv * BLOCK + local / BLOCK);
                    if iu < nu && iv < nv {
                        let mut o = Point3::origin();
                        o[u] = u0 + iu as Real * du;
                        o[v] = v0 + iv as Real * dv;
                        spans.clear();
                        solid.ray_spans(&o, axis, &mut spans);
                        for sp in &spans {
                            let (mut t0, mut n0) = (sp.t_in, sp.n_in);
                            let (mut t1, mut n1) = (sp.t_out, sp.n_out);
                            let mut e = Vector3::zeros();
                            e[axis] = 1.0;
                            if t0 < lo_k {
                                (t0, n0) = (lo_k, -e);
                            }
                            if t1 > hi_k {
                                (t1, n1) = (hi_k, e);
                            }
                            let start = offsets[offsets.len() - 1] as usize;
                            // A gap thinner than a sliver joins this span to the last one.
                            let join = segs[start..]
                                .last()
                                .is_some_and(|last| t0 - last.hi.t < tol::SLIVER);
                            if join {
                                if let Some(last) = segs.last_mut()
                                    && t1 > last.hi.t
                                {
                                    last.hi = Crossing::new(t1, &n1, 0);
                                }
                            } else if t1 - t0 >= tol::SLIVER {
                                segs.push(Segment {
                                    lo: Crossing::new(t0, &n0, 0),
                                    hi: Crossing::new(t1, &n1, 0),
                                });
                            }
                        }
                    }
                    offsets.push(segs.len() as u32);
                }
                *block = Block { offsets, segs };
            });
        }
        Ok(stock)
    }

    /// The initial box.
    pub fn bounds(&self) -> &Aabb {
        &self.bounds
    }

    /// The requested pitch (mm); each grid's actual spacing divides the box evenly.
    pub fn pitch(&self) -> Real {
        self.pitch
    }

    /// The largest actual ray spacing of the three grids (mm).
    pub fn max_spacing(&self) -> Real {
        self.grids
            .iter()
            .map(|g| g.du.max(g.dv))
            .fold(0.0, Real::max)
    }

    /// How far the surface point `p` of another part, with outward unit normal `n`, lies
    /// outside this part's surface (mm; − inside), measured along the rays of the grid most
    /// nearly along `n`: with `t` this part's surface along those rays at `p` (its crossings
    /// facing like `n` within `reach` of `p` on the four rays around it, interpolated
    /// bilinearly), `(p_a − t)·n_a` — the distance between two parallel planes offset by
    /// `p_a − t` along the axis. `None` where no ray near `p` has such a crossing (a face
    /// this part does not have).
    pub fn offset_along(&self, p: &Point3, n: &Vector3, reach: Real) -> Option<Real> {
        let a = (0..3)
            .max_by(|&i, &j| n[i].abs().total_cmp(&n[j].abs()))
            .unwrap_or(2);
        let t = self.grids[a].surface_along(p, n, reach / n[a].abs().max(0.5))?;
        Some((p[a] - t) * n[a])
    }

    /// The signed distance of `p` from this part's surface as its nearest crossing sees it
    /// (mm; + outside, − inside): the distance of `p` from the tangent plane at the
    /// crossing nearest it (by its outward normal) among the three grids' rays within
    /// `reach` of `p` (searched from the two nearest rays outwards); `None` without a
    /// crossing there.
    pub fn nearest_offset(&self, p: &Point3, reach: Real) -> Option<Real> {
        self.nearest_crossing(p, reach, |_| true)
            .map(|(q, n)| (p - q).dot(&n))
    }

    /// The crossing nearest `p` within `reach` (mm) among the three grids' rays whose
    /// outward normal passes `keep`, as (point, outward unit normal); searched from the two
    /// nearest rays outwards. `None` without such a crossing there.
    pub fn nearest_crossing(
        &self,
        p: &Point3,
        reach: Real,
        keep: impl Fn(&Vector3) -> bool,
    ) -> Option<(Point3, Vector3)> {
        // Rays within `w` indices hold every crossing within `w` pitches of `p`.
        let pitch = self
            .grids
            .iter()
            .map(|g| g.du.min(g.dv))
            .fold(Real::INFINITY, Real::min);
        let wide = (reach / pitch).ceil().max(2.0) as usize;
        let mut w = 2usize;
        loop {
            let best = self
                .grids
                .iter()
                .filter_map(|g| g.nearest_crossing(p, w, &keep))
                .min_by(|x, y| x.0.total_cmp(&y.0));
            let covered = |d2: Real| d2.sqrt() <= w as Real * pitch;
            match best {
                Some((d2, q, n)) if covered(d2) || w >= wide => {
                    return (d2.sqrt() <= reach).then_some((q, n));
                }
                Some((d2, _, _)) => w = ((d2.sqrt() / pitch).ceil() as usize).clamp(w + 1, wide),
                None if w >= wide => return None,
                None => w = (2 * w).min(wide),
            }
        }
    }

    /// The three grids (rays along x, y, z).
    pub fn grids(&self) -> &[DexelGrid; 3] {
        &self.grids
    }

    /// Removes what `cutter` occupies; `line` tags the new surfaces. Returns whether any
    /// material was removed.
    pub fn remove(&mut self, cutter: &dyn Cutter, line: u32) -> bool {
        !self.remove_lines(cutter, line).is_empty()
    }

    /// Removes what `cutter` occupies, tagging the new surfaces with the NC lines the
    /// cutter names ([`Cutter::ray_cuts_lined`], `line` by default). Returns the distinct
    /// lines of the cuts that removed material, sorted: empty if nothing was removed.
    pub fn remove_lines(&mut self, cutter: &dyn Cutter, line: u32) -> Vec<u32> {
        let b = cutter.bounds();
        let mut used = Vec::new();
        if !b.intersects(&self.bounds) {
            return used;
        }
        // The blocks of all three grids as one pool of tasks, so the threads share the
        // uneven work; results are gathered in grid and block order.
        let (mut contexts, mut tasks) = (Vec::new(), Vec::new());
        for g in &mut self.grids {
            if let Some((ctx, blocks)) = g.cut_tasks(cutter, &b, line) {
                let nbu = ctx.nbu_blocks;
                tasks.extend(
                    blocks
                        .into_iter()
                        .map(|(k, block)| (contexts.len(), k, nbu, block)),
                );
                contexts.push(ctx);
            }
        }
        let lines: Vec<Vec<u32>> = if cutter.costly_rays() {
            // Each ray costs much: rows of all blocks are the tasks, then each block is
            // written from its rows in order.
            let jobs: Vec<(usize, usize)> = tasks
                .iter()
                .enumerate()
                .flat_map(|(t, (c, k, nbu, _))| {
                    contexts[*c].rows_of(k / nbu).map(move |iv| (t, iv))
                })
                .collect();
            let rows: Vec<RowsCut> = jobs
                .par_iter()
                .map(|&(t, iv)| {
                    let (c, k, nbu, block) = &tasks[t];
                    contexts[*c].cut_rows(k % nbu, block, iv..=iv)
                })
                .collect();
            let mut rows = jobs.iter().map(|&(t, _)| t).zip(rows).peekable();
            tasks
                .into_iter()
                .enumerate()
                .map(|(t, (c, k, nbu, block))| {
                    let mut mine = Vec::new();
                    while let Some((_, r)) = rows.next_if(|(owner, _)| *owner == t) {
                        mine.push(r);
                    }
                    contexts[c].apply(k % nbu, k / nbu, block, mine)
                })
                .collect()
        } else {
            tasks
                .into_par_iter()
                .map(|(c, k, nbu, block)| contexts[c].cut_block(k % nbu, k / nbu, block))
                .collect()
        };
        for l in lines {
            used.extend(l);
        }
        used.sort_unstable();
        used.dedup();
        used
    }

    /// Material volume (mm³): the mean of the three grids' measures.
    pub fn volume(&self) -> Real {
        self.grids.iter().map(DexelGrid::volume).sum::<Real>() / 3.0
    }

    /// Bytes held on the heap: the blocks, their segments and offset tables (untouched
    /// blocks hold none).
    pub fn memory_bytes(&self) -> usize {
        self.grids.iter().map(DexelGrid::heap_bytes).sum()
    }

    /// The stock as bytes, every crossing bit for bit (little-endian: a magic, the box and
    /// pitch, each grid's blocks with their offset tables and segments, then an FNV-1a 64
    /// checksum of all before it); read back by [`TriDexel::from_bytes`].
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(64 + self.memory_bytes());
        out.extend_from_slice(DEXEL_MAGIC);
        for x in [self.bounds.min, self.bounds.max]
            .iter()
            .flat_map(|p| p.coords.iter().copied())
            .chain([self.pitch])
        {
            out.extend_from_slice(&x.to_le_bytes());
        }
        let crossing = |out: &mut Vec<u8>, c: &Crossing| {
            out.extend_from_slice(&c.t.to_le_bytes());
            for n in c.normal {
                out.extend_from_slice(&n.to_le_bytes());
            }
            out.extend_from_slice(&c.line.to_le_bytes());
        };
        for g in &self.grids {
            out.extend_from_slice(&(g.blocks.len() as u64).to_le_bytes());
            for b in &g.blocks {
                out.extend_from_slice(&(b.offsets.len() as u32).to_le_bytes());
                out.extend_from_slice(&(b.segs.len() as u32).to_le_bytes());
                for o in &b.offsets {
                    out.extend_from_slice(&o.to_le_bytes());
                }
                for s in &b.segs {
                    crossing(&mut out, &s.lo);
                    crossing(&mut out, &s.hi);
                }
            }
        }
        let sum = fnv1a(&out);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// The stock [`TriDexel::to_bytes`] wrote; `None` for anything else (another format, a
    /// checksum that does not match, a truncated or inconsistent layout), so that a
    /// damaged copy is never taken for a stock.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        let body_len = bytes.len().checked_sub(8)?;
        let (body, sum) = bytes.split_at(body_len);
        if !body.starts_with(DEXEL_MAGIC) || fnv1a(body).to_le_bytes() != sum {
            return None;
        }
        let mut r = ByteReader {
            bytes: &body[DEXEL_MAGIC.len()..],
        };
        let mut f = [0.0; 7];
        for x in &mut f {
            *x = Real::from_le_bytes(r.take()?);
        }
        let bounds = Aabb {
            min: Point3::new(f[0], f[1], f[2]),
            max: Point3::new(f[3], f[4], f[5]),
        };
        let pitch = f[6];
        if !(bounds.is_proper_box() && pitch.is_finite() && pitch > 0.0) {
            return None;
        }
        // The grids laid out by the box and pitch (refused if absurdly many rays).
        let rays: Real = (0..3)
            .map(|k| ((bounds.max[k] - bounds.min[k]) / pitch).round().max(1.0))
            .product();
        if rays > 1e12 {
            return None;
        }
        let mut grids = [0, 1, 2].map(|axis| DexelGrid::new(&bounds, axis, pitch));
        for g in &mut grids {
            if u64::from_le_bytes(r.take()?) != g.blocks.len() as u64 {
                return None;
            }
            for (i, b) in g.blocks.iter_mut().enumerate() {
                let n_off = u32::from_le_bytes(r.take()?) as usize;
                let n_seg = u32::from_le_bytes(r.take()?) as usize;
                if n_off == 0 {
                    if n_seg != 0 {
                        return None;
                    }
                    continue;
                }
                if n_off != BLOCK * BLOCK + 1 || r.bytes.len() < 4 * n_off + 48 * n_seg {
                    return None;
                }
                let offsets: Vec<u32> = (0..n_off)
                    .map(|_| r.take().map(u32::from_le_bytes))
                    .collect::<Option<_>>()?;
                let valid = offsets[0] == 0
                    && offsets.windows(2).all(|w| w[0] <= w[1])
                    && offsets[n_off - 1] as usize == n_seg;
                // Rays outside the grid hold nothing.
                let (bu, bv) = (i % g.nbu, i / g.nbu);
                let outside = (0..BLOCK * BLOCK).any(|l| {
                    let out = bu * BLOCK + l % BLOCK >= g.nu || bv * BLOCK + l / BLOCK >= g.nv;
                    out && offsets[l] != offsets[l + 1]
                });
                if !valid || outside {
                    return None;
                }
                let mut crossing = || -> Option<Crossing> {
                    let t = Real::from_le_bytes(r.take()?);
                    let normal = [0; 3].map(|_| r.take().map(f32::from_le_bytes));
                    let line = u32::from_le_bytes(r.take()?);
                    Some(Crossing {
                        t,
                        normal: [normal[0]?, normal[1]?, normal[2]?],
                        line,
                    })
                };
                let mut segs = Vec::with_capacity(n_seg);
                for _ in 0..n_seg {
                    let (lo, hi) = (crossing()?, crossing()?);
                    if !(lo.t.is_finite() && hi.t.is_finite() && lo.t < hi.t) {
                        return None;
                    }
                    segs.push(Segment { lo, hi });
                }
                *b = Block { offsets, segs };
            }
        }
        r.bytes.is_empty().then_some(Self {
            bounds,
            pitch,
            grids,
        })
    }
}

/// The first bytes of [`TriDexel::to_bytes`]: the format and its version.
const DEXEL_MAGIC: &[u8; 8] = b"TMDEXEL1";

/// FNV-1a 64 of `bytes`.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Reads fixed-size little-endian values off the front of a byte slice.
struct ByteReader<'a> {
    bytes: &'a [u8],
}

impl ByteReader<'_> {
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let (head, rest) = self.bytes.split_first_chunk::<N>()?;
        self.bytes = rest;
        Some(*head)
    }
}

#[cfg(test)]
mod tests;
