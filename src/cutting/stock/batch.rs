//! Cutting the stock by several cutters at once ([`TriDexel::remove_each`]): each ray taken
//! through every cutter, each block rewritten once.
//!
//! **Latest first.** A ray is taken through the cutters from the last to the first. The
//! material a set of cuts leaves does not depend on their order, and on consecutive moves
//! of one path the later ones usually reach deepest: cut first, they leave the earlier
//! moves less material to meet, so more of those are cleared by their cheap test
//! ([`Cutter::may_cut`]) and fewer solved. Where two cuts end at exactly the same point the
//! earlier cutter's crossing (its normal and NC line) is kept, as program order keeps it
//! (the later cut meets that end and changes nothing): an end a cut meets exactly, made in
//! this batch by a later cutter, takes the cut's own crossing.
//!
//! **Groups.** Consecutive cutters may come with a [`GroupCull`]: one conservative test that
//! none of them can change a ray's material. A ray it clears skips the whole group (each of
//! its cutters would have left the ray as it was), so the stock is the same either way.
//!
//! **Invariant:** the stock is that of [`TriDexel::remove`] of each cutter in turn (program
//! order), [`cut_ray`] being the one per-ray step of both: bit for bit for a cutter whose
//! intervals do not depend on the material they meet. The per-ray envelope refines only
//! the interval ends inside the material, so where an end lies on a face that stays put
//! through the move (the same point for many poses) the pose it is taken from, and the
//! normal's last bits, may differ; every end stays within the envelope's bound. The 20
//! recorded digests (`dexel_digest`) are those of program order, and the tests find the
//! same points and NC lines. What depends on the order is whether a cutter "removed
//! material": here, whether it changed a ray after the later cutters of the batch had cut
//! it.

use super::*;

/// A conservative test over a group of consecutive cutters of [`TriDexel::remove_each`].
pub trait GroupCull: Sync {
    /// Whether any cutter of the group may change the ray `origin + t·e_axis` whose material
    /// is `segs`: `false` only when each of them would leave it as it is (its
    /// [`Cutter::may_cut`] could answer `false`), whatever the group's other cutters
    /// removed (they only remove material).
    fn may_cut(&self, origin: &Point3, axis: usize, segs: &[Segment]) -> bool;
}

/// Consecutive cutters `cutters` of [`TriDexel::remove_each`] and their [`GroupCull`].
#[derive(Clone)]
pub struct Group<'a> {
    /// The cutters' indices (consecutive, ascending; groups in order and disjoint).
    pub cutters: std::ops::Range<usize>,
    /// The test that none of them can change a ray.
    pub cull: &'a dyn GroupCull,
}

/// What [`TriDexel::remove_each`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Removed {
    /// For each cutter, whether it removed material.
    pub by_cutter: Vec<bool>,
    /// Rays the groups' tests were asked about.
    pub group_tests: u64,
    /// Of those, the rays a group's test cleared (its cutters skipped).
    pub group_skips: u64,
}

impl TriDexel {
    /// Removes what each of `cutters` occupies, cutter `k` tagging its new surfaces with the
    /// NC line `cutters[k].1`: the crossings of [`TriDexel::remove`] of each in turn (see
    /// the module docs), each ray taken through all the cutters, the last first, and the
    /// blocks rewritten once. A ray that a group's test clears ([`GroupCull`]) skips the
    /// group's cutters, which would have left it as it was. Returns for each cutter whether
    /// it changed a ray after the later cutters had cut it (or made an end a later one
    /// meets exactly), and how often the groups' tests cleared a ray.
    pub fn remove_each(&mut self, cutters: &[(&dyn Cutter, u32)], groups: &[Group]) -> Removed {
        debug_assert!(
            groups
                .windows(2)
                .all(|w| w[0].cutters.end <= w[1].cutters.start)
                && groups.iter().all(|g| g.cutters.end <= cutters.len())
        );
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
        // Each block in one task: its rows cut in turn (reading the block), then the block
        // rewritten from them. Blocks are disjoint, so the stock is the same in any
        // order; what the cutters did is combined by `or` and sums, the same in any order.
        let flags = tasks
            .into_par_iter()
            .map(|(g, k, nbu, block)| {
                let b: &BatchContext = &grids[g];
                let (bu, bv) = (k % nbu, k / nbu);
                let (rows, flags) = b.cut_rows(bu, block, b.rows_of(bv), groups);
                b.ctx.apply(bu, bv, block, vec![rows]);
                flags
            })
            .reduce(|| RowFlags::none(cutters.len()), RowFlags::and);
        Removed {
            by_cutter: flags.cut,
            group_tests: flags.group_tests,
            group_skips: flags.group_skips,
        }
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

    /// Cuts the rays of rows `rows` of block column `bu` by every cutter, the last first, a
    /// group's cutters skipped where its test clears the ray, reading the block only; also
    /// which cutters changed a ray.
    fn cut_rows(
        &self,
        bu: usize,
        block: &Block,
        rows: std::ops::RangeInclusive<usize>,
        groups: &[Group],
    ) -> (RowsCut, RowFlags) {
        with_ray_buffers(|bufs| self.cut_rows_with(bu, block, rows, groups, bufs))
    }

    /// [`Self::cut_rows`] with the scratch buffers `bufs`.
    fn cut_rows_with(
        &self,
        bu: usize,
        block: &Block,
        rows: std::ops::RangeInclusive<usize>,
        groups: &[Group],
        bufs: &mut RayBuffers,
    ) -> (RowsCut, RowFlags) {
        let c = &self.ctx;
        let mut flags = RowFlags {
            cut: vec![false; self.cutters.len()],
            ..RowFlags::default()
        };
        // The row's output and the ray's material between cutters: taken out of `bufs`,
        // which `cut_ray` borrows.
        let RowsCut {
            mut new,
            mut changes,
            mut used,
        } = std::mem::take(&mut bufs.row);
        new.clear();
        changes.clear();
        used.clear();
        let (mut own, mut next) = (
            std::mem::take(&mut bufs.own),
            std::mem::take(&mut bufs.after),
        );
        for iv in rows {
            for iu in c.iu.0.max(bu * BLOCK)..=c.iu.1.min(bu * BLOCK + BLOCK - 1) {
                let local = (iv % BLOCK) * BLOCK + iu % BLOCK;
                let o = c.origin(iu, iv);
                // The ray's material before the batch.
                let before = block.ray(local, &c.fill);
                let mut changed = false;
                // Whether the ray lies in cutter k's index ranges, and those ranges' extent
                // along it.
                let reach = |k: usize| {
                    self.each[k]
                        .filter(|(u, v, _)| (u.0..=u.1).contains(&iu) && (v.0..=v.1).contains(&iv))
                        .map(|(_, _, along)| along)
                };
                let mut group = groups.iter().rev().peekable();
                let mut k = self.cutters.len();
                while k > 0 {
                    // The ray's material as the cutters after k left it.
                    let segs = |own| {
                        if changed { own } else { before }
                    };
                    if let Some(g) = group.next_if(|g| g.cutters.end == k) {
                        let asked = g.cutters.clone().any(|j| reach(j).is_some());
                        flags.group_tests += u64::from(asked);
                        if !asked || !g.cull.may_cut(&o, c.axis, segs(&own)) {
                            flags.group_skips += u64::from(asked);
                            k = g.cutters.start;
                            continue;
                        }
                    }
                    k -= 1;
                    let (cutter, line) = self.cutters[k];
                    let Some(along) = reach(k) else {
                        continue;
                    };
                    next.clear();
                    let cutter = (cutter, line, along);
                    if cut_ray(
                        cutter,
                        &o,
                        c.axis,
                        (segs(&own), Some(before)),
                        bufs,
                        &mut next,
                        &mut used,
                    ) {
                        flags.cut[k] = true;
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
        }
        (bufs.own, bufs.after) = (own, next);
        let cut = RowsCut {
            new: new.to_vec(),
            changes: changes.to_vec(),
            used: used.to_vec(),
        };
        bufs.row = RowsCut { new, changes, used };
        (cut, flags)
    }
}

/// What cutting some rows says of the cutters: which changed a ray, and how often the groups'
/// tests were asked and cleared a ray.
#[derive(Default)]
struct RowFlags {
    cut: Vec<bool>,
    group_tests: u64,
    group_skips: u64,
}

impl RowFlags {
    /// No cutter changed a ray, no test asked: for `n` cutters.
    fn none(n: usize) -> Self {
        Self {
            cut: vec![false; n],
            ..Self::default()
        }
    }

    /// What `self` and `other` say together (the cutters that changed a ray in either, the
    /// tests of both): the same in any order.
    fn and(mut self, other: Self) -> Self {
        for (a, b) in self.cut.iter_mut().zip(other.cut) {
            *a |= b;
        }
        self.group_tests += other.group_tests;
        self.group_skips += other.group_skips;
        self
    }
}
