//! Step 4 of [`segment_planes`](super::segment_planes): every point goes to the nearest
//! live plane within reach among the regions of its cell and the 26 neighbours, in one
//! streaming pass over fixed chunks; each region's share of the points is split into core
//! and fringe for the fit.

use super::cells::{Cells, NONE, flat_lists};
use super::grow::LivePlane;
use super::linalg::Moments;
use crate::math::{Point3, Real};
use crate::metrology::fit::CHUNK;
use rayon::prelude::*;

impl Cells {
    /// Step 4: every point goes to the nearest live plane within `max_d` among the live
    /// regions of its cell and the 26 neighbours (ties: the lower region). One streaming
    /// pass over fixed chunks of points; each chunk's share of a region (point indices,
    /// split into core and fringe, and the core's moments) is appended in chunk order.
    pub(super) fn assign(
        &self,
        points: &[Point3],
        region: &[u32],
        live: &[Option<LivePlane>],
        max_d: Real,
    ) -> Vec<RegionShare> {
        let is_live = |r: u32| r != NONE && live.get(r as usize).is_some_and(Option::is_some);
        let (cand_start, cand) = flat_lists(self.len(), |c, out| {
            let first = out.len();
            for r in std::iter::once(region[c])
                .chain(self.neighbours(c).iter().map(|&b| region[b as usize]))
            {
                if is_live(r) && !out[first..].contains(&r) {
                    out.push(r);
                }
            }
            out[first..].sort_unstable();
        });
        let parts: Vec<Vec<RegionShare>> = points
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(ci, chunk)| {
                let mut shares: Vec<RegionShare> = Vec::new();
                let map = self.rec_cell.get(ci).map_or(&[][..], Vec::as_slice);
                let recs = self.rec.get(ci * CHUNK..).unwrap_or_default();
                let mut last_rec = u16::MAX;
                let mut cands: &[u32] = &[];
                // The share being filled and its core moments, summed in registers.
                let mut cur = (NONE, 0usize);
                let mut run = Moments::ZERO;
                for (j, (p, &rec)) in chunk.iter().zip(recs).enumerate() {
                    if rec != last_rec {
                        last_rec = rec;
                        cands = match map.get(rec as usize) {
                            Some(&c) => {
                                let (a, b) = (cand_start[c as usize], cand_start[c as usize + 1]);
                                cand.get(a as usize..b as usize).unwrap_or_default()
                            }
                            None => &[],
                        };
                    }
                    let mut best: Option<(u32, &LivePlane, Real)> = None;
                    for &r in cands {
                        let Some(Some(lp)) = live.get(r as usize) else {
                            continue;
                        };
                        let d = lp.plane.distance(p);
                        if d <= max_d && best.is_none_or(|(_, _, bd)| d < bd) {
                            best = Some((r, lp, d));
                        }
                    }
                    let Some((r, lp, d)) = best else {
                        continue;
                    };
                    if r != cur.0 {
                        if let Some(s) = shares.get_mut(cur.1) {
                            s.core_moments.merge(&run);
                        }
                        run = Moments::ZERO;
                        let k = match shares.iter().position(|s| s.region == r) {
                            Some(k) => k,
                            None => {
                                let mut share = RegionShare::new(r);
                                share.all.reserve(chunk.len());
                                share.core.reserve(chunk.len());
                                shares.push(share);
                                shares.len() - 1
                            }
                        };
                        cur = (r, k);
                    }
                    let i = (ci * CHUNK + j) as u32;
                    if let Some(s) = shares.get_mut(cur.1) {
                        s.all.push(i);
                        if d <= lp.core_mm {
                            s.core.push(i);
                            run.push(&(p - lp.plane.centroid));
                        } else {
                            s.fringe.push(i);
                        }
                    }
                }
                if let Some(s) = shares.get_mut(cur.1) {
                    s.core_moments.merge(&run);
                }
                shares
            })
            .collect();
        let mut out: Vec<RegionShare> = (0..live.len() as u32).map(RegionShare::new).collect();
        out.par_iter_mut().for_each(|whole| {
            let mine = || parts.iter().flatten().filter(|s| s.region == whole.region);
            whole.all.reserve_exact(mine().map(|s| s.all.len()).sum());
            whole.core.reserve_exact(mine().map(|s| s.core.len()).sum());
            whole
                .fringe
                .reserve_exact(mine().map(|s| s.fringe.len()).sum());
            for s in mine() {
                whole.all.extend_from_slice(&s.all);
                whole.core.extend_from_slice(&s.core);
                whole.fringe.extend_from_slice(&s.fringe);
                whole.core_moments.merge(&s.core_moments);
            }
        });
        out
    }
}

/// The points assigned to a region (or a chunk's share of them): indices of the core
/// and the fringe points (see [`fit_region`](super::region_fit::fit_region)), ascending, and the core's moments about
/// the region plane's centroid.
#[derive(Debug)]
pub(super) struct RegionShare {
    region: u32,
    /// All indices, ascending.
    pub(super) all: Vec<u32>,
    pub(super) core: Vec<u32>,
    pub(super) fringe: Vec<u32>,
    pub(super) core_moments: Moments,
}

impl RegionShare {
    fn new(region: u32) -> Self {
        Self {
            region,
            all: Vec::new(),
            core: Vec::new(),
            fringe: Vec::new(),
            core_moments: Moments::ZERO,
        }
    }

    pub(super) fn len(&self) -> usize {
        self.all.len()
    }
}
