//! Step 3 of [`segment_planes`](super::segment_planes): regions grown breadth-first over
//! neighbouring planar cells from the flattest seeds, a cell joining when its plane agrees
//! with its neighbour's and with the region's (refreshed whenever the region doubles);
//! each region's summed moments and the plane it takes into the assignment.

use super::cells::{CellStat, Cells, NONE};
use super::linalg::{Moments, add_outer, eigen_sym3};
use super::options::PlaneSegmentOptions;
use crate::math::{Aabb, Point3, Real, Vector3};

/// Core distance of a region, as a fraction of `k_sigma` times the pooled rms residual
/// of its cells (≈ 0.93σ with ~22 points a cell): for the default rule (k = 3) points
/// within 2.1σ of the cell-level plane are core — 96 % of them, each safely inside every
/// threshold σ-trimming reaches (≈ 2.9σ), so only 4 % are re-tested per round.
pub(super) const CORE_FRACTION: Real = 0.75;

impl Cells {
    /// Step 3: regions grown from `seeds` in order; returns each cell's region (or
    /// [`NONE`]) and each region's accumulated moments.
    pub(super) fn grow(
        &self,
        seeds: &[u32],
        opts: &PlaneSegmentOptions,
    ) -> (Vec<u32>, Vec<RegionAcc>) {
        let cos_max = opts.max_angle_rad.cos();
        let max_d = opts.max_distance_mm;
        let mut region = vec![NONE; self.len()];
        let mut accs: Vec<RegionAcc> = Vec::new();
        let mut queue: Vec<u32> = Vec::new();
        for &s in seeds {
            let s = s as usize;
            if region[s] != NONE || !self.stats[s].planar {
                continue;
            }
            let rid = accs.len() as u32;
            let mut acc = RegionAcc::new(&self.stats[s], self.coords[s]);
            let mut plane = RegionPlane {
                centroid: self.stats[s].centroid,
                normal: self.stats[s].normal,
            };
            let mut refresh_at = 2;
            region[s] = rid;
            queue.clear();
            queue.push(s as u32);
            let mut head = 0;
            while let Some(&a) = queue.get(head) {
                head += 1;
                let sa = &self.stats[a as usize];
                for &b in self.neighbours(a as usize) {
                    let b = b as usize;
                    if region[b] != NONE {
                        continue;
                    }
                    let sb = &self.stats[b];
                    if !sb.planar || !joins(sa, sb, &plane, cos_max, max_d) {
                        continue;
                    }
                    region[b] = rid;
                    queue.push(b as u32);
                    acc.add(sb, self.coords[b]);
                    if acc.cells >= refresh_at {
                        if let Some(p) = acc.plane() {
                            plane = p;
                        }
                        refresh_at *= 2;
                    }
                }
            }
            accs.push(acc);
        }
        (region, accs)
    }
}

/// Whether planar cell `b`, neighbour of region cell `a`, joins the region.
fn joins(a: &CellStat, b: &CellStat, region: &RegionPlane, cos_max: Real, max_d: Real) -> bool {
    if a.normal.dot(&b.normal).abs() < cos_max || region.normal.dot(&b.normal).abs() < cos_max {
        return false;
    }
    let mid = (a.centroid.coords + b.centroid.coords) * 0.5;
    let gap = a.normal.dot(&(mid - a.centroid.coords)).abs()
        + b.normal.dot(&(mid - b.centroid.coords)).abs();
    gap <= max_d && region.distance(&b.centroid) <= max_d
}

/// A plane through `centroid` with unit `normal` (either sign).
#[derive(Clone, Copy, Debug)]
pub(super) struct RegionPlane {
    pub(super) centroid: Point3,
    pub(super) normal: Vector3,
}

impl RegionPlane {
    pub(super) fn distance(&self, p: &Point3) -> Real {
        self.normal.dot(&(p - self.centroid)).abs()
    }
}

/// Summed moments of a region's cells, about the seed cell's centroid.
#[derive(Clone, Debug)]
pub(super) struct RegionAcc {
    reference: Vector3,
    cells: usize,
    pub(super) mo: Moments,
    /// Σ of the cells' residual sums of squares about their own planes.
    rss: Real,
    /// Range of the cells' grid coordinates.
    lo: [u32; 3],
    hi: [u32; 3],
}

impl RegionAcc {
    fn new(seed: &CellStat, at: [u32; 3]) -> Self {
        let mut acc = Self {
            reference: seed.centroid.coords,
            cells: 0,
            mo: Moments::ZERO,
            rss: 0.0,
            lo: at,
            hi: at,
        };
        acc.add(seed, at);
        acc
    }

    fn add(&mut self, c: &CellStat, at: [u32; 3]) {
        let w = c.n as Real;
        let d = c.centroid.coords - self.reference;
        self.mo.n += c.n as usize;
        self.cells += 1;
        self.rss += c.rss;
        self.mo.s += d * w;
        let mut dd = [0.0; 6];
        add_outer(&mut dd, &d);
        for ((m, sc), o) in self.mo.m.iter_mut().zip(&c.scatter).zip(dd) {
            *m += sc + w * o;
        }
        for ((lo, hi), a) in self.lo.iter_mut().zip(&mut self.hi).zip(at) {
            *lo = (*lo).min(a);
            *hi = (*hi).max(a);
        }
    }

    fn plane(&self) -> Option<RegionPlane> {
        let (mean, cov) = self.mo.centred()?;
        let (_, normal) = eigen_sym3(&cov)?;
        Some(RegionPlane {
            centroid: Point3::from(self.reference + mean),
            normal,
        })
    }

    /// The region's plane for assignment, its core distance (`CORE_FRACTION · k_sigma`
    /// times the pooled within-cell rms residual) and a box holding all its points.
    pub(super) fn live(&self, k_sigma: Real, cells: &Cells) -> Option<LivePlane> {
        let plane = self.plane()?;
        let sigma = (self.rss / self.mo.n as Real).sqrt();
        Some(LivePlane {
            plane,
            core_mm: CORE_FRACTION * k_sigma * sigma,
            bbox: cells.cell_box(self.lo, self.hi),
        })
    }
}

/// A region taking part in the assignment.
#[derive(Clone, Copy, Debug)]
pub(super) struct LivePlane {
    pub(super) plane: RegionPlane,
    /// Points nearer the plane than this are *core*: expected inside every threshold of
    /// the robust rule (checked, see [`fit_region`](super::region_fit::fit_region)).
    pub(super) core_mm: Real,
    /// Holds every point that can be assigned to the region.
    pub(super) bbox: Aabb,
}
