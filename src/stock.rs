//! The stock as a tri-dexel: three orthogonal grids of rays (along x, y and z, in the
//! workpiece frame), each ray storing the exact intervals where material is (BRIEF §5).
//!
//! Every interval end (a *crossing*) keeps the exact surface point along its ray, the
//! outward normal of the material there, and the NC line whose cut made it (0 for the
//! stock's own faces). A plane cut at any angle is therefore represented without grid
//! bias: each crossing lies on the true surface to rounding.
//!
//! Storage is flat per block of 16 × 16 rays: one `Vec<Segment>` and an offset table per
//! block, not a `Vec` per ray. A cut rebuilds only the blocks it touches, in parallel,
//! each block independently, so the result does not depend on the thread count.
//!
//! **Invariant:** the stock knows nothing about G-code, machines or tools: it only asks a
//! [`Cutter`] for the interval it removes along a ray.
//! **Invariant:** within a ray, segments are sorted, disjoint and at least
//! [`tol::SLIVER`] long.

use crate::math::{Aabb, Point3, Real, Vector3, tol};
use rayon::prelude::*;

/// Rays per block side.
const BLOCK: usize = 16;

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
        "the tri-dexel stock at pitch {pitch} mm would need {needed_mib:.0} MiB, more than the {budget_mib:.0} MiB available; use a pitch of at least {suggested_pitch:.3} mm"
    )]
    TooMuchMemory {
        /// Requested pitch (mm).
        pitch: Real,
        /// Estimated need (MiB).
        needed_mib: Real,
        /// Budget (MiB).
        budget_mib: Real,
        /// The finest pitch that fits (mm).
        suggested_pitch: Real,
    },
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
}

#[derive(Clone, Debug, Default)]
struct Block {
    /// `offsets[i]..offsets[i+1]` are ray i's segments in `segs`.
    offsets: Vec<u32>,
    segs: Vec<Segment>,
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
        let seg = Segment {
            lo: Crossing::new(bounds.min[axis], &lo_n, 0),
            hi: Crossing::new(bounds.max[axis], &-lo_n, 0),
        };
        let blocks = (0..nbu * nbv)
            .map(|b| {
                let (bu, bv) = (b % nbu, b / nbu);
                let mut offsets = Vec::with_capacity(BLOCK * BLOCK + 1);
                let mut segs = Vec::new();
                offsets.push(0);
                for local in 0..BLOCK * BLOCK {
                    let (iu, iv) = (bu * BLOCK + local % BLOCK, bv * BLOCK + local / BLOCK);
                    if iu < nu && iv < nv {
                        segs.push(seg);
                    }
                    offsets.push(segs.len() as u32);
                }
                Block { offsets, segs }
            })
            .collect();
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
            blocks,
        }
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
        let local = (iv % BLOCK) * BLOCK + iu % BLOCK;
        &b.segs[b.offsets[local] as usize..b.offsets[local + 1] as usize]
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

    /// Material volume measured by this grid (mm³): summed lengths times the ray cell area.
    pub fn volume(&self) -> Real {
        let len: Real = self
            .blocks
            .iter()
            .flat_map(|b| b.segs.iter())
            .map(|s| s.hi.t - s.lo.t)
            .sum();
        len * self.du * self.dv
    }

    /// Number of stored segments.
    pub fn segment_count(&self) -> usize {
        self.blocks.iter().map(|b| b.segs.len()).sum()
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

    fn remove(&mut self, cutter: &dyn Cutter, bounds: &Aabb, line: u32) -> bool {
        let Some((iu0, iu1)) = Self::index_range(
            bounds.min[self.u],
            bounds.max[self.u],
            self.u0,
            self.du,
            self.nu,
        ) else {
            return false;
        };
        let Some((iv0, iv1)) = Self::index_range(
            bounds.min[self.v],
            bounds.max[self.v],
            self.v0,
            self.dv,
            self.nv,
        ) else {
            return false;
        };
        let nbu = self.nbu;
        let (axis, u, v, u0, v0, du, dv) = (
            self.axis, self.u, self.v, self.u0, self.v0, self.du, self.dv,
        );
        self.blocks
            .par_iter_mut()
            .enumerate()
            .map(|(b, block)| {
                let (bu, bv) = (b % nbu, b / nbu);
                let (ru0, ru1) = (bu * BLOCK, bu * BLOCK + BLOCK - 1);
                let (rv0, rv1) = (bv * BLOCK, bv * BLOCK + BLOCK - 1);
                if ru1 < iu0 || ru0 > iu1 || rv1 < iv0 || rv0 > iv1 {
                    return false;
                }
                let mut out = Vec::with_capacity(block.segs.len() + 8);
                let mut offsets = Vec::with_capacity(BLOCK * BLOCK + 1);
                offsets.push(0u32);
                let mut changed = false;
                let mut cuts = Vec::new();
                let (mut scratch, mut next) = (Vec::new(), Vec::new());
                for local in 0..BLOCK * BLOCK {
                    let (iu, iv) = (ru0 + local % BLOCK, rv0 + local / BLOCK);
                    let segs = &block.segs
                        [block.offsets[local] as usize..block.offsets[local + 1] as usize];
                    cuts.clear();
                    if (iu0..=iu1).contains(&iu) && (iv0..=iv1).contains(&iv) && !segs.is_empty() {
                        let mut o = Point3::origin();
                        o[u] = u0 + iu as Real * du;
                        o[v] = v0 + iv as Real * dv;
                        cutter.ray_cuts(&o, axis, &mut cuts);
                    }
                    match cuts.as_slice() {
                        [] => out.extend_from_slice(segs),
                        [c] => changed |= subtract(segs, c, line, &mut out),
                        many => {
                            // Subtract the cuts one after another through a scratch buffer.
                            scratch.clear();
                            scratch.extend_from_slice(segs);
                            for c in many {
                                next.clear();
                                changed |= subtract(&scratch, c, line, &mut next);
                                std::mem::swap(&mut scratch, &mut next);
                            }
                            out.extend_from_slice(&scratch);
                        }
                    }
                    offsets.push(out.len() as u32);
                }
                if changed {
                    block.segs = out;
                    block.offsets = offsets;
                }
                changed
            })
            .reduce(|| false, |a, b| a || b)
    }
}

/// Appends `segs` minus the cut to `out`; returns whether anything changed.
fn subtract(segs: &[Segment], c: &RayCut, line: u32, out: &mut Vec<Segment>) -> bool {
    let mut changed = false;
    for s in segs {
        if c.t_out <= s.lo.t || c.t_in >= s.hi.t {
            out.push(*s);
            continue;
        }
        changed = true;
        if c.t_in - s.lo.t >= tol::SLIVER {
            out.push(Segment {
                lo: s.lo,
                hi: Crossing::new(c.t_in, &c.n_in, line),
            });
        }
        if s.hi.t - c.t_out >= tol::SLIVER {
            out.push(Segment {
                lo: Crossing::new(c.t_out, &c.n_out, line),
                hi: s.hi,
            });
        }
    }
    changed
}

/// Estimated bytes of a tri-dexel over `bounds` at `pitch`, assuming two segments per
/// ray on average (a cut part) plus the offset tables.
pub fn estimate_bytes(bounds: &Aabb, pitch: Real) -> Real {
    let e = bounds.max - bounds.min;
    let rays = (e.y * e.z + e.x * e.z + e.x * e.y) / (pitch * pitch);
    rays * (2.0 * std::mem::size_of::<Segment>() as Real + 4.0)
}

/// Checks that a tri-dexel over `bounds` at `pitch` fits in `budget_bytes`; the error
/// suggests the finest pitch that does (memory scales as 1/pitch²).
pub fn check_memory(bounds: &Aabb, pitch: Real, budget_bytes: Real) -> Result<(), StockError> {
    let needed = estimate_bytes(bounds, pitch);
    if needed > budget_bytes {
        return Err(StockError::TooMuchMemory {
            pitch,
            needed_mib: needed / 1048576.0,
            budget_mib: budget_bytes / 1048576.0,
            suggested_pitch: pitch * (needed / budget_bytes).sqrt() * 1.01,
        });
    }
    Ok(())
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
        let finite = bounds
            .min
            .coords
            .iter()
            .chain(bounds.max.coords.iter())
            .all(|c| c.is_finite());
        if !finite || (0..3).any(|k| bounds.max[k] <= bounds.min[k]) {
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

    /// A stock of any [`crate::shape::Solid`] (cylinder, closed mesh, …) on the grids of `bounds` at
    /// `pitch` (mm): each ray keeps the solid's exact intervals, clipped to `bounds`, with the
    /// solid's outward normals (line 0). Spans shorter than [`tol::SLIVER`] are dropped and
    /// gaps shorter than it closed. Refuses like [`TriDexel::new_box`] before allocating.
    pub fn from_solid(
        bounds: Aabb,
        pitch: Real,
        budget_bytes: Real,
        solid: &dyn crate::shape::Solid,
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

    /// The three grids (rays along x, y, z).
    pub fn grids(&self) -> &[DexelGrid; 3] {
        &self.grids
    }

    /// Removes what `cutter` occupies; `line` tags the new surfaces. Returns whether any
    /// material was removed.
    pub fn remove(&mut self, cutter: &dyn Cutter, line: u32) -> bool {
        let b = cutter.bounds();
        if !b.intersects(&self.bounds) {
            return false;
        }
        let mut changed = false;
        for g in &mut self.grids {
            changed |= g.remove(cutter, &b, line);
        }
        changed
    }

    /// Material volume (mm³): the mean of the three grids' measures.
    pub fn volume(&self) -> Real {
        self.grids.iter().map(DexelGrid::volume).sum::<Real>() / 3.0
    }

    /// Bytes held by the segment and offset storage.
    pub fn memory_bytes(&self) -> usize {
        self.grids
            .iter()
            .flat_map(|g| g.blocks.iter())
            .map(|b| b.segs.capacity() * std::mem::size_of::<Segment>() + b.offsets.capacity() * 4)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An axis-aligned box cutter, exact by construction.
    struct BoxCutter(Aabb);

    impl Cutter for BoxCutter {
        fn bounds(&self) -> Aabb {
            self.0
        }
        fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut> {
            let mut e = Vector3::zeros();
            e[axis] = 1.0;
            let (t0, t1) = self.0.ray_interval(origin, &e)?;
            (t1 > t0).then_some(RayCut {
                t_in: t0,
                t_out: t1,
                n_in: e,
                n_out: -e,
            })
        }
    }

    fn unit_box(size: Real) -> Aabb {
        Aabb {
            min: Point3::origin(),
            max: Point3::new(size, size, size),
        }
    }

    #[test]
    fn box_volume_is_exact() {
        let s = TriDexel::new_box(unit_box(10.0), 0.5, 1e9).expect("fits");
        assert!((s.volume() - 1000.0).abs() < 1e-9);
    }

    #[test]
    fn removing_a_box_pocket_is_exact() {
        let mut s = TriDexel::new_box(unit_box(10.0), 0.25, 1e9).expect("fits");
        let pocket = Aabb {
            min: Point3::new(2.0, 2.0, 5.0),
            max: Point3::new(8.0, 8.0, 11.0),
        };
        assert!(s.remove(&BoxCutter(pocket), 7));
        // Pocket faces fall on ray-cell boundaries here, so every grid measures exactly.
        assert!((s.volume() - (1000.0 - 36.0 * 5.0)).abs() < 1e-9);
        // A z ray in the pocket ends at z = 5 with the floor normal +z and line 7.
        let g = &s.grids()[2];
        let segs = g.ray(20, 20);
        assert_eq!(segs.len(), 1);
        assert_eq!(segs[0].hi.t, 5.0);
        assert_eq!(segs[0].hi.normal, [0.0, 0.0, 1.0]);
        assert_eq!(segs[0].hi.line, 7);
    }

    #[test]
    fn refuses_a_pitch_beyond_the_budget() {
        let err = TriDexel::new_box(unit_box(100.0), 1e-4, 24e9).expect_err("too big");
        match err {
            StockError::TooMuchMemory {
                suggested_pitch, ..
            } => {
                // The suggested pitch must itself fit.
                assert!(estimate_bytes(&unit_box(100.0), suggested_pitch) <= 24e9);
            }
            other => panic!("unexpected {other:?}"),
        }
    }

    #[test]
    fn result_is_independent_of_thread_count() {
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| {
                let mut s = TriDexel::new_box(unit_box(10.0), 0.1, 1e9).expect("fits");
                let pocket = Aabb {
                    min: Point3::new(2.05, 1.33, 5.01),
                    max: Point3::new(8.7, 8.2, 11.0),
                };
                s.remove(&BoxCutter(pocket), 1);
                let mut all = Vec::new();
                for g in s.grids() {
                    g.for_each_crossing(|p, c| all.push((p, *c)));
                }
                all
            })
        };
        assert_eq!(run(1), run(2));
    }
}
