//! Cutting the stock by several cutters at once ([`TriDexel::remove_each`]): each ray taken
//! through every cutter in turn, each block rewritten once.
//!
//! **Invariant:** the stock comes out bit for bit as from [`TriDexel::remove`] of each cutter
//! in turn: a ray's cut by one cutter depends only on the ray's material before it and the
//! cutter, and [`cut_ray`] is the one per-ray step of both.

use super::*;

impl TriDexel {
    /// Removes what each of `cutters` occupies, one after another, cutter `k` tagging its
    /// new surfaces with the NC line `cutters[k].1`: the same stock, bit for bit, as
    /// [`TriDexel::remove`] of each in turn (a ray's cut by one cutter depends only on the
    /// ray's material before it and the cutter, so each ray is taken through all the
    /// cutters in order, and the blocks are rewritten once). Returns for each cutter whether
    /// it removed material.
    pub fn remove_each(&mut self, cutters: &[(&dyn Cutter, u32)]) -> Vec<bool> {
        let boxes: Vec<Option<Aabb>> = cutters
            .iter()
            .map(|(c, _)| Some(c.bounds()).filter(|b| b.intersects(&self.bounds)))
            .collect();
        // Per grid, the cutters' contexts (none: the cutter misses the grid) and the blocks
        // of the union of their ranges, as one pool of tasks.
        let (mut grids, mut tasks) = (Vec::new(), Vec::new());
        for g in &mut self.grids {
            let Some((ctx, blocks)) = g.batch_tasks(cutters, &boxes) else {
                continue;
            };
            let nbu = ctx.ctx.nbu_blocks;
            tasks.extend(
                blocks
                    .into_iter()
                    .map(|(k, block)| (grids.len(), k, nbu, block)),
            );
            grids.push(ctx);
        }
        let jobs: Vec<(usize, usize)> = tasks
            .iter()
            .enumerate()
            .flat_map(|(t, (g, k, nbu, _))| {
                let b: &BatchContext = &grids[*g];
                b.rows_of(k / nbu).map(move |iv| (t, iv))
            })
            .collect();
        let rows: Vec<(RowsCut, Vec<bool>)> = jobs
            .par_iter()
            .map(|&(t, iv)| {
                let (g, k, nbu, block) = &tasks[t];
                grids[*g].cut_row(k % nbu, block, iv)
            })
            .collect();
        let mut removed = vec![false; cutters.len()];
        let mut rows = jobs.iter().map(|&(t, _)| t).zip(rows).peekable();
        for (t, (g, k, nbu, block)) in tasks.into_iter().enumerate() {
            let mut cut = RowsCut::default();
            while let Some((_, (r, flags))) = rows.next_if(|(owner, _)| *owner == t) {
                cut.append(r);
                for (any, f) in removed.iter_mut().zip(flags) {
                    *any |= f;
                }
            }
            grids[g].ctx.apply(k % nbu, k / nbu, block, cut);
        }
        removed
    }
}

impl DexelGrid {
    /// The work of [`TriDexel::remove_each`] on this grid: its context and the blocks of
    /// the union of the cutters' index ranges, in a fixed order (none if every range is
    /// empty). `boxes[k]`: cutter `k`'s bounds, `None` when they miss the stock.
    #[allow(clippy::type_complexity)]
    fn batch_tasks<'a>(
        &'a mut self,
        cutters: &'a [(&'a dyn Cutter, u32)],
        boxes: &[Option<Aabb>],
    ) -> Option<(BatchContext<'a>, Vec<(usize, &'a mut Block)>)> {
        let range = |b: &Aabb| {
            let iu = Self::index_range(b.min[self.u], b.max[self.u], self.u0, self.du, self.nu)?;
            let iv = Self::index_range(b.min[self.v], b.max[self.v], self.v0, self.dv, self.nv)?;
            Some((iu, iv, (b.min[self.axis], b.max[self.axis])))
        };
        let each: Vec<_> = boxes.iter().map(|b| b.as_ref().and_then(range)).collect();
        let (mut iu, mut iv) = ((usize::MAX, 0), (usize::MAX, 0));
        for (u, v, _) in each.iter().flatten() {
            iu = (iu.0.min(u.0), iu.1.max(u.1));
            iv = (iv.0.min(v.0), iv.1.max(v.1));
        }
        if iu.0 == usize::MAX {
            return None;
        }
        let ctx = CutContext {
            cutter: cutters[0].0,
            line: cutters[0].1,
            axis: self.axis,
            u: self.u,
            v: self.v,
            u0: self.u0,
            v0: self.v0,
            du: self.du,
            dv: self.dv,
            iu,
            iv,
            along: (Real::NEG_INFINITY, Real::INFINITY),
            fill: self.fill,
            nu: self.nu,
            nv: self.nv,
            nbu_blocks: self.nbu,
        };
        let touched = Self::blocks_in(&mut self.blocks, self.nbu, iu, iv);
        Some((BatchContext { ctx, cutters, each }, touched))
    }
}

/// What [`TriDexel::remove_each`] needs to know of one grid: the union's context (its
/// cutter unused) and each cutter's index ranges and bounds along the rays.
struct BatchContext<'a> {
    ctx: CutContext<'a>,
    cutters: &'a [(&'a dyn Cutter, u32)],
    #[allow(clippy::type_complexity)]
    each: Vec<Option<((usize, usize), (usize, usize), (Real, Real))>>,
}

impl BatchContext<'_> {
    fn rows_of(&self, bv: usize) -> std::ops::RangeInclusive<usize> {
        self.ctx.rows_of(bv)
    }

    /// Cuts the rays of row `iv` of block column `bu` by every cutter in turn, reading the
    /// block only; also which cutters changed a ray.
    fn cut_row(&self, bu: usize, block: &Block, iv: usize) -> (RowsCut, Vec<bool>) {
        let c = &self.ctx;
        let mut flags = vec![false; self.cutters.len()];
        let mut used = Vec::new();
        let mut bufs = RayBuffers::default();
        let (mut new, mut changes) = (Vec::new(), Vec::new());
        let (mut own, mut next): (Vec<Segment>, Vec<Segment>) = (Vec::new(), Vec::new());
        for iu in c.iu.0.max(bu * BLOCK)..=c.iu.1.min(bu * BLOCK + BLOCK - 1) {
            let local = (iv % BLOCK) * BLOCK + iu % BLOCK;
            let o = c.origin(iu, iv);
            let mut changed = false;
            for (k, ((cutter, line), each)) in self.cutters.iter().zip(&self.each).enumerate() {
                let Some((ru, rv, along)) = each else {
                    continue;
                };
                if iu < ru.0 || iu > ru.1 || iv < rv.0 || iv > rv.1 {
                    continue;
                }
                let segs: &[Segment] = if changed {
                    &own
                } else {
                    block.ray(local, &c.fill)
                };
                next.clear();
                let cutter = (*cutter, *line, *along);
                if cut_ray(cutter, &o, c.axis, segs, &mut bufs, &mut next, &mut used) {
                    flags[k] = true;
                    changed = true;
                    std::mem::swap(&mut own, &mut next);
                }
            }
            if changed {
                let start = new.len();
                new.extend_from_slice(&own);
                changes.push(RayChange {
                    local,
                    start,
                    end: new.len(),
                });
            }
        }
        (RowsCut { new, changes, used }, flags)
    }
}
