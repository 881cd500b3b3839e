//! Neighbourhoods and normals: the k-d tree over a cloud ([`KdIndex`]: k nearest and
//! radius queries, sorted by distance then index) and the PCA normal of each point's k
//! nearest neighbours ([`estimate_normals`]).

use super::input::{MAX_COORD_MM, PLANE_FIT_MIN, SegmentError, check_and_bound, is_valid};
use super::linalg::{add_outer, canonical, eigen_sym3};
use crate::math::{Point3, Real, UnitVector3, Vector3};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use std::num::NonZeroUsize;

#[cfg(doc)]
use super::input::MAX_POINTS;
#[cfg(doc)]
use crate::metrology::fit::PlaneFit;

/// One neighbour found by a [`KdIndex`] query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Neighbour {
    /// Index of the point in the indexed slice.
    pub index: u32,
    /// Euclidean distance from the query point (mm).
    pub distance_mm: Real,
}

/// A k-d tree over a cloud's points (kiddo's immutable tree), built once, queried many
/// times, from any number of threads.
///
/// The tree is always built serially, so its layout — and the choice among neighbours at
/// equal distance — is the same for any thread count. Results come sorted by distance,
/// then index.
pub struct KdIndex {
    tree: ImmutableKdTree<Real, 3>,
    len: usize,
}

impl KdIndex {
    /// Builds the index. Errors: [`SegmentError::NoPoints`], [`SegmentError::NonFinite`],
    /// more than [`MAX_POINTS`] points ([`SegmentError::BadOptions`]).
    pub fn new(points: &[Point3]) -> Result<Self, SegmentError> {
        check_and_bound(points)?;
        let coords: Vec<[Real; 3]> = points.par_iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = ImmutableKdTree::<Real, 3>::builder()
            .with_serial_construction()
            .build_from_slice(&coords)
            .map_err(|e| SegmentError::BadOptions(format!("k-d tree: {e}")))?;
        Ok(Self {
            tree,
            len: points.len(),
        })
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the index is empty (never, as built by [`KdIndex::new`]).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The `k` nearest indexed points to `query` (all of them if fewer), nearest first,
    /// the query point itself included when it is indexed. Empty for `k = 0` or a
    /// non-finite query.
    pub fn nearest(&self, query: &Point3, k: usize) -> Vec<Neighbour> {
        let Some(k) = NonZeroUsize::new(k.min(self.len)) else {
            return Vec::new();
        };
        if !is_valid(query) {
            return Vec::new();
        }
        let q = [query.x, query.y, query.z];
        let found = self
            .tree
            .query(&q)
            .nearest_n::<SquaredEuclidean<Real>>(k)
            .execute();
        Self::sorted(found.iter().map(|r| (r.item, r.distance)))
    }

    /// All indexed points within `radius_mm` of `query` (inclusive), nearest first. Empty
    /// for a negative or non-finite radius or query.
    pub fn within(&self, query: &Point3, radius_mm: Real) -> Vec<Neighbour> {
        if !(is_valid(query) && (0.0..=MAX_COORD_MM).contains(&radius_mm)) {
            return Vec::new();
        }
        let q = [query.x, query.y, query.z];
        let found = self
            .tree
            .query(&q)
            .within::<SquaredEuclidean<Real>>(radius_mm * radius_mm)
            .execute();
        Self::sorted(found.iter().map(|r| (r.item, r.distance)))
    }

    fn sorted(items: impl Iterator<Item = (u32, Real)>) -> Vec<Neighbour> {
        let mut v: Vec<Neighbour> = items
            .map(|(index, d2)| Neighbour {
                index,
                distance_mm: d2.sqrt(),
            })
            .collect();
        v.sort_unstable_by(|a, b| {
            a.distance_mm
                .total_cmp(&b.distance_mm)
                .then(a.index.cmp(&b.index))
        });
        v
    }
}

/// Unit normal of each point: the smallest-eigenvalue direction (PCA) of its `k` nearest
/// neighbours (itself included), from the centred second moments.
///
/// With a `viewpoint` each normal points towards it (n · (viewpoint − p) ≥ 0); without,
/// its largest-magnitude component is positive (the rule of [`PlaneFit`]). `k` above the
/// number of points uses all points. A neighbourhood that is collinear or coincident gets
/// an arbitrary but deterministic normal.
///
/// Errors: [`SegmentError::NoPoints`], [`SegmentError::NonFinite`], `k < 3` or a
/// non-finite viewpoint ([`SegmentError::BadOptions`]), fewer than 3 points
/// ([`SegmentError::NothingFound`]).
pub fn estimate_normals(
    points: &[Point3],
    k: usize,
    viewpoint: Option<Point3>,
) -> Result<Vec<UnitVector3>, SegmentError> {
    check_and_bound(points)?;
    if k < PLANE_FIT_MIN {
        return Err(SegmentError::BadOptions(format!(
            "k = {k}: a normal needs at least {PLANE_FIT_MIN} neighbours"
        )));
    }
    if viewpoint.is_some_and(|v| !is_valid(&v)) {
        return Err(SegmentError::BadOptions(
            "the viewpoint is not finite".to_string(),
        ));
    }
    if points.len() < PLANE_FIT_MIN {
        return Err(SegmentError::NothingFound);
    }
    let index = KdIndex::new(points)?;
    Ok(points
        .par_iter()
        .map(|p| {
            let nb = index.nearest(p, k);
            let n = neighbourhood_normal(points, p, &nb);
            let flip = match viewpoint {
                Some(v) => n.dot(&(v - p)) < 0.0,
                None => canonical(n) != n,
            };
            UnitVector3::new_unchecked(if flip { -n } else { n })
        })
        .collect())
}

/// PCA normal of the neighbours `nb` of `p` (unit; z for an empty or non-finite set).
fn neighbourhood_normal(points: &[Point3], p: &Point3, nb: &[Neighbour]) -> Vector3 {
    let pts = nb.iter().filter_map(|q| points.get(q.index as usize));
    let (count, sum) = pts
        .clone()
        .fold((0usize, Vector3::zeros()), |(c, s), q| (c + 1, s + (q - p)));
    if count == 0 {
        return Vector3::z();
    }
    let c = p.coords + sum / count as Real;
    let mut m = [0.0; 6];
    for q in pts {
        add_outer(&mut m, &(q.coords - c));
    }
    eigen_sym3(&m).map_or(Vector3::z(), |(_, v)| v)
}

#[cfg(test)]
mod tests {
    use super::super::tests::{SIGMA, line_angle, sphere_points};
    use super::*;
    use crate::math::CounterRng;

    #[test]
    fn normals_on_a_sphere_are_radial() {
        let centre = Point3::new(12.0, -7.0, 30.0);
        let pts = sphere_points(centre, 10.0, -1.0, SIGMA);
        let normals = estimate_normals(&pts, 100, None).expect("normals");
        let two_deg = 2f64.to_radians();
        for (p, n) in pts.iter().zip(&normals) {
            let a = line_angle(n, &(p - centre));
            assert!(a <= two_deg.sin(), "{} deg", a.asin().to_degrees());
            let k = n.iamax();
            assert!(n[k] > 0.0, "canonical sign");
        }
        // Towards a viewpoint far above: outward on the upper cap.
        let cap = sphere_points(centre, 10.0, 0.3, SIGMA);
        let eye = centre + Vector3::z() * 1000.0;
        let normals = estimate_normals(&cap, 30, Some(eye)).expect("normals");
        for (p, n) in cap.iter().zip(&normals) {
            assert!(n.dot(&(p - centre)) > 0.0);
        }
    }

    #[test]
    fn kd_index_matches_brute_force() {
        let rng = CounterRng::new(3);
        let pts: Vec<Point3> = (0..3000u64)
            .map(|i| {
                // Coarse coordinates: many equal distances.
                let c = |k| (rng.uniform(i, k) * 20.0).round() * 0.5;
                Point3::new(c(0), c(1), c(2))
            })
            .collect();
        let index = KdIndex::new(&pts).expect("index");
        assert_eq!(index.len(), pts.len());
        let brute = |q: &Point3| {
            let mut v: Vec<(Real, u32)> = pts
                .iter()
                .enumerate()
                .map(|(i, p)| ((p - q).norm(), i as u32))
                .collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            v
        };
        for i in 0..40u64 {
            let q = Point3::new(rng.uniform(i, 7) * 10.0, rng.uniform(i, 8) * 10.0, 5.0);
            let want = brute(&q);
            let got = index.nearest(&q, 10);
            assert_eq!(got.len(), 10);
            for (g, w) in got.iter().zip(&want) {
                assert!((g.distance_mm - w.0).abs() < 1e-12);
            }
            // The k-th distance is right; ties at it may pick any of the tied points.
            let r = 1.7;
            let within: Vec<u32> = index.within(&q, r).iter().map(|n| n.index).collect();
            let want_within: Vec<u32> = want.iter().filter(|w| w.0 <= r).map(|w| w.1).collect();
            assert_eq!(within, want_within);
        }
        assert!(
            index
                .nearest(&Point3::new(Real::NAN, 0.0, 0.0), 3)
                .is_empty()
        );
        assert!(index.nearest(&Point3::origin(), 0).is_empty());
        assert_eq!(index.nearest(&Point3::origin(), 5000).len(), pts.len());
        assert!(index.within(&Point3::origin(), -1.0).is_empty());
    }
}
