//! Step 5 of [`segment_planes`](super::segment_planes): each region's robust fit, the
//! σ-trimming rounds of [`fit_plane_robust`] replayed on moments — the core points summed
//! once, only the fringe re-tested, re-split when the core bound fails — then
//! [`fit_plane`] on the set they settle on; and the segments that result.

use super::assign::RegionShare;
use super::grow::{CORE_FRACTION, LivePlane, RegionPlane};
use super::input::{PLANE_FIT_MIN, chunked_fold, gather};
use super::linalg::{Moments, eigen_sym3};
use super::options::{PlaneSegment, PlaneSegmentOptions};
use crate::math::{Aabb, Point3, Real, tol};
use crate::metrology::fit::{PlaneFit, RobustRule, fit_plane, fit_plane_robust};
use rayon::prelude::*;

/// Re-splits of a region's points into core and fringe before [`fit_region`] gives up
/// on its shortcut and runs [`fit_plane_robust`] itself: one is needed when the first
/// fit is pulled off the region plane (by a neighbouring face's edge points), a second
/// only for faces whose form departs from a plane by more than the noise.
const MAX_RESPLITS: usize = 2;

/// Second-smallest over largest eigenvalue below which points count as collinear: the
/// bound of [`fit_plane`] (an aspect ratio of 1e-6), so both refuse the same sets.
const DEGENERATE_RATIO: Real = 1e-12;

/// A plane fitted from moments, as [`fit_plane`] would fit it (up to rounding).
#[derive(Clone, Copy, Debug)]
struct MomentFit {
    plane: RegionPlane,
    rms: Real,
}

/// The orthogonal fit of the points whose moments about `reference` are `mo`; `None` when
/// [`fit_plane`] would refuse them (fewer than 3, collinear).
fn moment_fit(mo: &Moments, reference: &Point3) -> Option<MomentFit> {
    if mo.n < PLANE_FIT_MIN {
        return None;
    }
    let (mean, cov) = mo.centred()?;
    let (l, normal) = eigen_sym3(&cov)?;
    if !(l[2] > 0.0 && l[1] > DEGENERATE_RATIO * l[2]) {
        return None;
    }
    Some(MomentFit {
        plane: RegionPlane {
            centroid: reference + mean,
            normal,
        },
        rms: (l[0].max(0.0) / mo.n as Real).sqrt(),
    })
}

/// Largest difference between the distances of a point of `bbox` to planes `a` and `b`
/// (affine in the point, so largest at a corner).
fn plane_gap_bound(a: &RegionPlane, b: &RegionPlane, bbox: &Aabb) -> Real {
    let nb = if a.normal.dot(&b.normal) < 0.0 {
        -b.normal
    } else {
        b.normal
    };
    let mut worst: Real = 0.0;
    for corner in 0..8 {
        let x = Point3::new(
            if corner & 1 == 0 {
                bbox.min.x
            } else {
                bbox.max.x
            },
            if corner & 2 == 0 {
                bbox.min.y
            } else {
                bbox.max.y
            },
            if corner & 4 == 0 {
                bbox.min.z
            } else {
                bbox.max.z
            },
        );
        let gap = a.normal.dot(&(x - a.centroid)) - nb.dot(&(x - b.centroid));
        worst = worst.max(gap.abs());
    }
    worst
}

/// A region's points split for the σ-trimming rounds of [`fit_region`]: the *core*
/// (points within `core_mm` of `base`, inside every threshold while the check of
/// [`fit_region`] holds), summed once, and the *fringe*, re-tested each round.
struct Split {
    base: RegionPlane,
    core_mm: Real,
    /// Moments of the core about the region plane's centroid.
    core_moments: Moments,
    /// Fringe points, in index order.
    fringe: Vec<Point3>,
    /// After a re-split: all points in index order, and which are core (the fringe is the
    /// rest, in order). Before: the core is the assignment's.
    all: Option<(Vec<Point3>, Vec<bool>)>,
}

/// Membership of the points in the current subset of the rounds.
enum Members {
    /// The core and the fringe points kept.
    Split(Vec<bool>),
    /// Per point, in index order (from a re-split).
    Full(Vec<bool>),
}

/// Moments about `reference` of the points `pts[i]` with `keep(i)`, over fixed chunks.
fn moments_where(
    pts: &[Point3],
    reference: &Point3,
    keep: impl Fn(usize) -> bool + Sync,
) -> Moments {
    chunked_fold(
        pts.len(),
        Moments::ZERO,
        |r| {
            let mut m = Moments::ZERO;
            for i in r {
                if keep(i) {
                    m.push(&(pts[i] - reference));
                }
            }
            m
        },
        |mut a, b| {
            a.merge(&b);
            a
        },
    )
}

impl Split {
    /// Moments of the core and the fringe points kept (all fringe points for `None`).
    fn moments(&self, keep: Option<&[bool]>, reference: &Point3) -> Moments {
        let mut mo = self.core_moments;
        mo.merge(&moments_where(&self.fringe, reference, |i| {
            keep.is_none_or(|k| k[i])
        }));
        mo
    }

    /// All points in index order.
    fn all_points(&self, points: &[Point3], share: &RegionShare) -> Vec<Point3> {
        match &self.all {
            Some((all, _)) => all.clone(),
            None => gather(points, &share.all),
        }
    }

    /// Per point in index order: core, or the next fringe point's flag in `keep`.
    fn full(&self, share: &RegionShare, keep: &[bool]) -> Vec<bool> {
        let mut fringe = keep.iter();
        let mut next_fringe = || fringe.next().copied().unwrap_or(false);
        let mut out = Vec::with_capacity(keep.len() + share.core.len());
        match &self.all {
            Some((_, is_core)) => {
                for &c in is_core {
                    out.push(c || next_fringe());
                }
            }
            None => {
                let (core, fr) = (&share.core, &share.fringe);
                let (mut i, mut j) = (0, 0);
                while i < core.len() || j < fr.len() {
                    let from_core = match (core.get(i), fr.get(j)) {
                        (Some(a), Some(b)) => a < b,
                        (a, _) => a.is_some(),
                    };
                    if from_core {
                        out.push(true);
                        i += 1;
                    } else {
                        out.push(next_fringe());
                        j += 1;
                    }
                }
            }
        }
        out
    }

    /// The fringe part of a per-point membership.
    fn fringe_part(&self, full: &[bool]) -> Vec<bool> {
        match &self.all {
            Some((_, is_core)) => full
                .iter()
                .zip(is_core)
                .filter_map(|(&k, &c)| (!c).then_some(k))
                .collect(),
            None => Vec::new(),
        }
    }

    /// The current members as one buffer: core then kept fringe (both in index order)
    /// before a re-split, index order after.
    fn members(&self, points: &[Point3], share: &RegionShare, members: &Members) -> Vec<Point3> {
        let full = match (members, &self.all) {
            (Members::Split(keep), None) => {
                let mut pts = Vec::with_capacity(share.len());
                share
                    .core
                    .par_iter()
                    .map(|&i| points[i as usize])
                    .collect_into_vec(&mut pts);
                pts.extend(
                    self.fringe
                        .iter()
                        .zip(keep)
                        .filter_map(|(p, &k)| k.then_some(*p)),
                );
                return pts;
            }
            (Members::Split(keep), Some(_)) => self.full(share, keep),
            (Members::Full(full), _) => full.clone(),
        };
        let all = self.all_points(points, share);
        all.par_iter()
            .zip(&full)
            .filter_map(|(p, &k)| k.then_some(*p))
            .collect()
    }

    /// Re-splits all points around `plane` with core distance `CORE_FRACTION · t`.
    /// Returns the new split, the current membership (from `keep`) and the next (the
    /// points within `t` of `plane`), both per point in index order.
    fn resplit(
        &self,
        points: &[Point3],
        share: &RegionShare,
        keep: &[bool],
        plane: &RegionPlane,
        t: Real,
        reference: &Point3,
    ) -> (Split, Vec<bool>, Vec<bool>) {
        let current = self.full(share, keep);
        let all = self.all_points(points, share);
        let core_mm = CORE_FRACTION * t;
        let dist: Vec<Real> = all.par_iter().map(|p| plane.distance(p)).collect();
        let next: Vec<bool> = dist.par_iter().map(|&d| d <= t).collect();
        let is_core: Vec<bool> = dist.par_iter().map(|&d| d <= core_mm).collect();
        let core_moments = moments_where(&all, reference, |i| is_core[i]);
        let fringe: Vec<Point3> = all
            .iter()
            .zip(&is_core)
            .filter_map(|(p, &c)| (!c).then_some(*p))
            .collect();
        let split = Split {
            base: *plane,
            core_mm,
            core_moments,
            fringe,
            all: Some((all, is_core)),
        };
        (split, current, next)
    }
}

/// Step 5: the robust fit of a region's points — [`fit_plane_robust`]'s result, cheaply.
///
/// [`fit_plane_robust`] re-tests every point against each new plane, five passes over
/// the points per round, for the five or six rounds σ-trimming takes to settle. Here the
/// same rounds (threshold max(k·rms, [`tol::LENGTH_EPS`]), all points re-tested, until
/// the set repeats, a refit would fail, or `max_iterations`) run on moments: the *core*
/// points (nearer a base plane P₀ than `core_mm` — at first the region plane, summed
/// during assignment) provably stay inside every threshold t — checked each round as
/// `core_mm + max |dist(P) − dist(P₀)|` over the region's bounding box ≤ t — so only the
/// few *fringe* points are re-tested. When the check fails, all points are re-split
/// around the current plane (at most [`MAX_RESPLITS`] times; then [`fit_plane_robust`]
/// itself runs). The set the rounds end with is fitted by [`fit_plane`]: the fit
/// [`fit_plane_robust`] ends with, as it would find nothing more to reject (its planes
/// differ from the moment planes only by rounding, 1e-15 relative). `n_rejected` counts
/// against all assigned points.
pub(super) fn fit_region(
    points: &[Point3],
    share: &RegionShare,
    lp: &LivePlane,
    rule: &RobustRule,
) -> Option<PlaneFit> {
    let total = share.len();
    let reference = lp.plane.centroid;
    let mut split = Split {
        base: lp.plane,
        core_mm: lp.core_mm,
        core_moments: share.core_moments,
        fringe: gather(points, &share.fringe),
        all: None,
    };
    let slow = |split: &Split| fit_plane_robust(&split.all_points(points, share), rule);
    let Some(mut fit) = moment_fit(&split.moments(None, &reference), &reference) else {
        return finish(slow(&split), total);
    };
    let mut members = Members::Split(vec![true; split.fringe.len()]);
    let mut resplits = 0;
    for _ in 0..rule.max_iterations {
        let t = (rule.k_sigma * fit.rms).max(tol::LENGTH_EPS);
        let bound = split.core_mm + plane_gap_bound(&split.base, &fit.plane, &lp.bbox);
        let keep = match &members {
            Members::Split(keep) => keep.clone(),
            Members::Full(full) => split.fringe_part(full),
        };
        let next = if bound + tol::LENGTH_EPS <= t {
            let next: Vec<bool> = split
                .fringe
                .par_iter()
                .map(|p| fit.plane.distance(p) <= t)
                .collect();
            if next == keep {
                break;
            }
            next
        } else {
            if resplits == MAX_RESPLITS {
                return finish(slow(&split), total);
            }
            resplits += 1;
            let (new_split, current, next) =
                split.resplit(points, share, &keep, &fit.plane, t, &reference);
            split = new_split;
            let settled = next == current;
            members = Members::Full(current);
            if settled {
                break;
            }
            split.fringe_part(&next)
        };
        // A refit that would fail ends the rounds with the previous fit.
        let Some(f) = moment_fit(&split.moments(Some(&next), &reference), &reference) else {
            break;
        };
        fit = f;
        members = Members::Split(next);
    }
    finish(fit_plane(&split.members(points, share, &members)), total)
}

/// The fit, with `n_rejected` counted against all `total` assigned points.
fn finish(
    fit: Result<PlaneFit, crate::metrology::fit::FitError>,
    total: usize,
) -> Option<PlaneFit> {
    let mut fit = fit.ok()?;
    fit.n_rejected = total - fit.n_used;
    Some(fit)
}

/// Step 5 for every live region; segments of at least `min_points` points, largest first
/// (ties: smallest first index).
pub(super) fn fit_regions(
    points: &[Point3],
    shares: Vec<RegionShare>,
    live: &[Option<LivePlane>],
    opts: &PlaneSegmentOptions,
) -> Vec<PlaneSegment> {
    let min_points = opts.min_points.max(PLANE_FIT_MIN);
    let mut segments: Vec<PlaneSegment> = shares
        .into_par_iter()
        .zip(live)
        .filter_map(|(share, lp)| {
            let lp = lp.as_ref()?;
            if share.len() < min_points {
                return None;
            }
            let fit = fit_region(points, &share, lp, &opts.robust)?;
            Some(PlaneSegment {
                fit,
                indices: share.all,
            })
        })
        .collect();
    segments.sort_by(|a, b| {
        b.indices
            .len()
            .cmp(&a.indices.len())
            .then(a.indices.first().cmp(&b.indices.first()))
    });
    segments
}

#[cfg(test)]
mod tests {
    use super::super::tests::{
        SIGMA, check_indices, line_angle, step_cloud, step_opts, tilted_pose,
    };
    use super::super::{linalg::basis_perpendicular, segment_planes};
    use super::*;
    use crate::math::{CounterRng, UnitVector3, Vector3};
    use proptest::prelude::*;

    #[test]
    fn segment_fits_equal_fit_plane_robust_of_their_points() {
        let c = step_cloud(SIGMA, &tilted_pose());
        let rules = [
            RobustRule::default(),
            RobustRule {
                k_sigma: 3.0,
                max_iterations: 0,
            },
            RobustRule {
                k_sigma: 2.0,
                max_iterations: 2,
            },
            RobustRule {
                k_sigma: 1.0,
                max_iterations: 10,
            },
        ];
        for robust in rules {
            let opts = PlaneSegmentOptions {
                robust,
                ..step_opts()
            };
            for s in segment_planes(&c.points, &opts).expect("segments") {
                let pts: Vec<Point3> = s.indices.iter().map(|&i| c.points[i as usize]).collect();
                let want = fit_plane_robust(&pts, &robust).expect("fit");
                let got = &s.fit;
                assert_eq!((got.n_used, got.n_rejected), (want.n_used, want.n_rejected));
                let pl = got.plane.oriented_towards(&want.plane.normal);
                assert!(line_angle(&pl.normal, &want.plane.normal) < 1e-12);
                assert!((pl.offset - want.plane.offset).abs() < 1e-10);
                assert!((got.rms_mm - want.rms_mm).abs() < 1e-12);
                assert!((got.offset_sigma_mm / want.offset_sigma_mm - 1.0).abs() < 1e-9);
            }
        }
    }

    /// Up to three random rectangular patches of random planes, with noise and outliers.
    fn random_planes(seed: u64, n_planes: usize, per_plane: usize, noise: Real) -> Vec<Point3> {
        let rng = CounterRng::new(seed);
        let mut pts = Vec::new();
        for k in 0..n_planes as u64 {
            let n = UnitVector3::new_normalize(Vector3::new(
                rng.normal(100 + 3 * k),
                rng.normal(101 + 3 * k),
                rng.normal(102 + 3 * k),
            ));
            let (a, b) = basis_perpendicular(&n);
            let centre = Point3::new(
                60.0 * rng.uniform(200 + k, 0),
                60.0 * rng.uniform(200 + k, 1),
                60.0 * rng.uniform(200 + k, 2),
            );
            let size = 5.0 + 25.0 * rng.uniform(300 + k, 0);
            for i in 0..per_plane as u64 {
                let j = 1000 * (k + 1) + i;
                let (s, u) = (rng.uniform(j, 0) - 0.5, rng.uniform(j, 1) - 0.5);
                let q = centre + a * (size * s) + b * (size * u) + *n * (noise * rng.normal(j));
                pts.push(q);
                if rng.uniform(j, 2) < 0.02 {
                    pts.push(q + *n * (0.5 + rng.uniform(j, 3)));
                }
            }
        }
        pts
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        #[test]
        fn random_planes_segment_consistently(
            seed in any::<u64>(),
            n_planes in 1usize..4,
            per_plane in 200usize..3000,
            noise in prop_oneof![Just(0.0), 0.001..0.05f64],
            cell in 0.5..3.0f64,
            k_sigma in 1.5..4.0f64,
            max_iterations in 0usize..12,
        ) {
            let pts = random_planes(seed, n_planes, per_plane, noise);
            let robust = RobustRule { k_sigma, max_iterations };
            let opts = PlaneSegmentOptions {
                cell_mm: cell,
                max_angle_rad: 0.2,
                max_distance_mm: (4.0 * noise).max(0.01),
                min_points: 50,
                robust,
            };
            if let Ok(segs) = segment_planes(&pts, &opts) {
                let mut all: Vec<u32> = Vec::new();
                for s in &segs {
                    check_indices(&s.indices, pts.len());
                    all.extend(&s.indices);
                    let own: Vec<Point3> = s.indices.iter().map(|&i| pts[i as usize]).collect();
                    let want = fit_plane_robust(&own, &robust).expect("fit");
                    prop_assert_eq!((s.fit.n_used, s.fit.n_rejected), (want.n_used, want.n_rejected));
                    let pl = s.fit.plane.oriented_towards(&want.plane.normal);
                    prop_assert!(line_angle(&pl.normal, &want.plane.normal) < 1e-10);
                    prop_assert!((pl.offset - want.plane.offset).abs() < 1e-9);
                }
                all.sort_unstable();
                prop_assert!(all.windows(2).all(|w| w[0] < w[1]), "disjoint");
                for w in segs.windows(2) {
                    prop_assert!(w[0].indices.len() >= w[1].indices.len());
                }
            }
        }
    }
}
