//! The sums every fit is built on: fixed chunks of [`CHUNK`] points summed in parallel
//! and combined in chunk order (every result bit independent of the thread count); the
//! centroid and centred second moments of a point set by the corrected two-pass
//! algorithm; the canonical sign of a direction; and the eigen-solver bounds the fits
//! share.

use super::error::FitError;
use crate::math::{Matrix3, Point3, Real, Vector3};
use rayon::prelude::*;

/// Points per parallel work item. Fixed (never derived from the thread count) so that the
/// floating-point summation order, and hence every result bit, is independent of threads.
pub const CHUNK: usize = 4096;

/// Smallest over largest eigenvalue ratio below which the points count as degenerate: an
/// aspect ratio of 1e-6 (40 nm across a 40 mm line). Applied to the second-smallest
/// eigenvalue it detects collinear points (plane, circle, cylinder), to the smallest
/// coplanar points (sphere).
pub(super) const DEGENERATE_RATIO: Real = 1e-12;

/// Iteration cap of the symmetric eigensolver on the 3×3 to 6×6 matrices here: it
/// converges in tens of sweeps on any finite input; the cap only bounds pathological input.
pub(super) const EIGEN_ITERATIONS: usize = 10_000;

/// Symmetric second moments and first moments of a chunk about a centre.
#[derive(Clone, Copy, Default)]
struct Moments {
    s: [Real; 3],
    /// xx, xy, xz, yy, yz, zz.
    m: [Real; 6],
}

impl Moments {
    fn of(points: &[Point3], c: &Vector3) -> Self {
        let mut acc = Moments::default();
        for p in points {
            let d = p.coords - c;
            acc.s[0] += d.x;
            acc.s[1] += d.y;
            acc.s[2] += d.z;
            acc.m[0] += d.x * d.x;
            acc.m[1] += d.x * d.y;
            acc.m[2] += d.x * d.z;
            acc.m[3] += d.y * d.y;
            acc.m[4] += d.y * d.z;
            acc.m[5] += d.z * d.z;
        }
        acc
    }

    fn add(mut self, o: &Moments) -> Self {
        for k in 0..3 {
            self.s[k] += o.s[k];
        }
        for k in 0..6 {
            self.m[k] += o.m[k];
        }
        self
    }
}

/// Sum of `f` over fixed chunks, combined in chunk order (thread-count independent).
pub(super) fn chunked_sum<T, F, G>(points: &[Point3], f: F, zero: T, add: G) -> T
where
    T: Send + Copy,
    F: Fn(&[Point3]) -> T + Sync + Send,
    G: Fn(T, &T) -> T,
{
    let partial: Vec<T> = points.par_chunks(CHUNK).map(f).collect();
    partial.iter().fold(zero, add)
}

/// Centroid and centred second-moment sum (corrected two-pass); `points` is non-empty.
pub(super) fn centred_moments(points: &[Point3]) -> Result<(Point3, Matrix3), FitError> {
    let nr = points.len() as Real;
    let p0 = points
        .first()
        .ok_or(FitError::TooFewPoints { needed: 3, got: 0 })?;
    let p0 = p0.coords;

    // Pass 1: mean relative to the first point.
    let sum_d = chunked_sum(
        points,
        |c| c.iter().fold(Vector3::zeros(), |s, p| s + (p.coords - p0)),
        Vector3::zeros(),
        |a, b| a + b,
    );
    let c1 = p0 + sum_d / nr;

    // Pass 2: moments about c1, corrected for the residual mean.
    let mo = chunked_sum(
        points,
        |c| Moments::of(c, &c1),
        Moments::default(),
        |a, b| a.add(b),
    );
    let s = Vector3::new(mo.s[0], mo.s[1], mo.s[2]);
    let centroid = Point3::from(c1 + s / nr);
    let m = &mo.m;
    let cov = Matrix3::new(
        m[0], m[1], m[2], //
        m[1], m[3], m[4], //
        m[2], m[4], m[5],
    ) - s * s.transpose() / nr;
    Ok((centroid, cov))
}

/// `v` flipped if needed so that its largest-magnitude component is positive (the first of
/// x, y, z on a tie).
pub(super) fn canonical_sign(v: Vector3) -> Vector3 {
    let mut k_big = 0;
    for k in 1..3 {
        if v[k].abs() > v[k_big].abs() {
            k_big = k;
        }
    }
    if v[k_big] < 0.0 { -v } else { v }
}
