//! The numeric vocabulary of twinmill: one real type, points and vectors kept apart,
//! rigid poses as isometries, and every tolerance named here with its physical reason.
//!
//! Lengths are millimetres and angles radians inside the library (degrees only at the
//! interfaces: NC programs, scene files, reports).

/// The one floating-point type. f32 spacing at 1,000 mm is 0.06 µm: too coarse for µm metrology.
pub type Real = f64;
/// A position in some frame (mm).
pub type Point3 = nalgebra::Point3<Real>;
/// A displacement or direction in some frame (mm or unitless).
pub type Vector3 = nalgebra::Vector3<Real>;
/// A direction of unit length: tool axes, normals, viewing rays.
pub type UnitVector3 = nalgebra::Unit<Vector3>;
/// A rigid pose. Named `a_from_b`: maps coordinates in frame b to frame a.
pub type Isometry3 = nalgebra::Isometry3<Real>;
/// A pure rotation.
pub type Rotation3 = nalgebra::UnitQuaternion<Real>;
/// A 3×3 matrix (covariances, rotation matrices).
pub type Matrix3 = nalgebra::Matrix3<Real>;

/// Named tolerances, each with the reason for its value.
pub mod tol {
    use super::Real;

    /// Below this a length is treated as zero when deciding degeneracy (a move with no
    /// displacement, a ray parallel to a plane): 1 pm, a millionth of the µm scale we
    /// resolve, and still 1e4 above f64 rounding at 1,000 mm.
    pub const LENGTH_EPS: Real = 1e-9;

    /// Two dexel intervals closer than this are merged: a sliver thinner than 1 nm is
    /// numerical residue of two cuts meeting at the same surface, not material.
    pub const SLIVER: Real = 1e-6;

    /// Relative size below which a coefficient or determinant is treated as zero against
    /// the magnitude of the terms it is made of: a few tens of f64 ulps (2.2e-16), so only
    /// genuinely degenerate cases (a ray parallel to a face, a move along the tool axis) are.
    pub const RELATIVE_EPS: Real = 1e-14;

    /// Slack (mm, or mm² for squared distances) when deciding whether a candidate point of
    /// the ray/sweep problem satisfies the tool's constraints: 0.1 nm, above rounding of
    /// coordinates up to 1,000 mm and far below anything physical.
    pub const FEASIBILITY: Real = 1e-10;

    /// Slack on the move parameter s ∈ [0, 1] (unitless) in the same test.
    pub const PARAMETER: Real = 1e-12;

    /// A point within this distance (mm) of a tool face lies on it, for choosing the
    /// surface normal at a crossing: 1 nm.
    pub const ON_SURFACE: Real = 1e-9;

    /// Below this cosine a ray meets a surface edge-on (grazing): it sees no surface there.
    pub const GRAZING_COS: Real = 1e-6;

    /// Two rotary positions equal within this (degrees): NC values are printed to far
    /// fewer digits.
    pub const ANGLE_DEG: Real = 1e-9;

    /// Default bound on how far a rotary move's piecewise-straight approximation may
    /// depart from the true tool motion: 0.1 µm, five times below the 0.5 µm accuracy the
    /// face tests demand.
    pub const ROTARY_STEP_BOUND: Real = 1e-4;

    /// Forward kinematics of a hexapod has converged when every strut length of the pose
    /// is within this of the given one (mm): 1 pm, genhexkins' tolerance (1e-9), a
    /// millionth of the µm scale and still far above rounding of lengths up to 10 m.
    pub const STRUT_RESIDUAL: Real = 1e-9;

    /// A strut residual below this (mm) is rounding: another Newton step cannot improve the
    /// pose (f64 spacing at strut lengths up to 4 m is below 1e-12 mm).
    pub const STRUT_ROUNDING: Real = 1e-12;

    /// A 6×6 kinematic Jacobian whose smallest LU pivot is below this fraction of its
    /// largest is singular: a strut change of 1 nm would move the pose by metres there.
    pub const JACOBIAN_CONDITION: Real = 1e-10;
}

/// Degrees to radians.
pub fn deg_to_rad(deg: Real) -> Real {
    deg.to_radians()
}

/// Radians to degrees.
pub fn rad_to_deg(rad: Real) -> Real {
    rad.to_degrees()
}

/// An axis-aligned box (mm), used for stock extents and quick rejection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: Point3,
    /// Upper corner.
    pub max: Point3,
}

impl Aabb {
    /// Whether this is a usable solid box: finite corners and a positive extent on every axis.
    pub fn is_proper_box(&self) -> bool {
        self.min
            .coords
            .iter()
            .chain(self.max.coords.iter())
            .all(|c| c.is_finite())
            && (0..3).all(|k| self.max[k] > self.min[k])
    }

    /// The empty box (contains nothing; any `grow` makes it the grown point).
    pub fn empty() -> Self {
        Self {
            min: Point3::new(Real::INFINITY, Real::INFINITY, Real::INFINITY),
            max: Point3::new(Real::NEG_INFINITY, Real::NEG_INFINITY, Real::NEG_INFINITY),
        }
    }

    /// Enlarges the box to contain `p`.
    pub fn grow(&mut self, p: &Point3) {
        self.min = self.min.inf(p);
        self.max = self.max.sup(p);
    }

    /// The box enlarged by `margin` on every side.
    pub fn inflated(&self, margin: Real) -> Self {
        let m = Vector3::repeat(margin);
        Self {
            min: self.min - m,
            max: self.max + m,
        }
    }

    /// Whether the two boxes overlap (touching counts).
    pub fn intersects(&self, other: &Aabb) -> bool {
        (0..3).all(|k| self.min[k] <= other.max[k] && other.min[k] <= self.max[k])
    }

    /// Whether `p` lies inside or on the box.
    pub fn contains(&self, p: &Point3) -> bool {
        (0..3).all(|k| self.min[k] <= p[k] && p[k] <= self.max[k])
    }

    /// The parameter interval `[t0, t1]` of the ray `origin + t·dir` inside the box, if any
    /// (slab method; `dir` need not be unit).
    pub fn ray_interval(&self, origin: &Point3, dir: &Vector3) -> Option<(Real, Real)> {
        let mut t0 = Real::NEG_INFINITY;
        let mut t1 = Real::INFINITY;
        for k in 0..3 {
            if dir[k].abs() < tol::LENGTH_EPS * 1e-3 {
                if origin[k] < self.min[k] || origin[k] > self.max[k] {
                    return None;
                }
            } else {
                let a = (self.min[k] - origin[k]) / dir[k];
                let b = (self.max[k] - origin[k]) / dir[k];
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        (t0 <= t1).then_some((t0, t1))
    }

    /// [`Aabb::ray_interval`] for `dir` the unit vector along `axis` (a dexel ray), without
    /// its six divisions: the same result bit for bit (a division by one is exact).
    #[inline]
    pub fn axis_ray_interval(&self, origin: &Point3, axis: usize) -> Option<(Real, Real)> {
        for k in 0..3 {
            if k != axis && (origin[k] < self.min[k] || origin[k] > self.max[k]) {
                return None;
            }
        }
        let a = self.min[axis] - origin[axis];
        let b = self.max[axis] - origin[axis];
        let t0 = Real::NEG_INFINITY.max(a.min(b));
        let t1 = Real::INFINITY.min(a.max(b));
        (t0 <= t1).then_some((t0, t1))
    }

    /// The axis `dir` is exactly the unit vector of, if any.
    pub fn unit_axis(dir: &Vector3) -> Option<usize> {
        (0..3).find(|&k| dir[k] == 1.0 && dir[(k + 1) % 3] == 0.0 && dir[(k + 2) % 3] == 0.0)
    }
}

/// Counter-based pseudo-random numbers: the value for index `i` depends only on
/// `(seed, i)`, so results are identical whatever the thread count or evaluation order.
///
/// SplitMix64 finaliser (Steele, Lea & Flood 2014) over `seed ⊕ golden·i`; Gaussian
/// deviates by the Box–Muller transform.
#[derive(Clone, Copy, Debug)]
pub struct CounterRng {
    seed: u64,
}

impl CounterRng {
    /// A generator for the given seed.
    pub fn new(seed: u64) -> Self {
        Self { seed }
    }

    fn mix(mut z: u64) -> u64 {
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// The `k`-th 64-bit word of stream `i`.
    pub fn word(&self, i: u64, k: u64) -> u64 {
        let key = self
            .seed
            .wrapping_add(Self::mix(i.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ k));
        Self::mix(key.wrapping_add(0x9e37_79b9_7f4a_7c15))
    }

    /// A uniform deviate in (0, 1) for stream `i`, word `k` (never exactly 0 or 1).
    pub fn uniform(&self, i: u64, k: u64) -> Real {
        ((self.word(i, k) >> 11) as Real + 0.5) / (1u64 << 53) as Real
    }

    /// A standard normal deviate for stream `i` (Box–Muller on words 0 and 1).
    pub fn normal(&self, i: u64) -> Real {
        let u1 = self.uniform(i, 0);
        let u2 = self.uniform(i, 1);
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Runs `f` on a rayon pool of `threads` threads: the tests that results do not depend on
/// the thread count.
#[cfg(test)]
pub(crate) fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool")
        .install(f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ray_interval_of_unit_box() {
        let b = Aabb {
            min: Point3::origin(),
            max: Point3::new(1.0, 1.0, 1.0),
        };
        let (t0, t1) = b
            .ray_interval(&Point3::new(-1.0, 0.5, 0.5), &Vector3::x())
            .expect("hits");
        assert_eq!((t0, t1), (1.0, 2.0));
        assert!(
            b.ray_interval(&Point3::new(-1.0, 2.0, 0.5), &Vector3::x())
                .is_none()
        );
    }

    /// The dexel-ray form gives exactly the general slab method's interval, also for
    /// origins on a box face, in a degenerate box and outside it.
    #[test]
    fn axis_ray_interval_is_the_slab_methods() {
        let rng = CounterRng::new(3);
        let grid = |i: u64, k: u64| ((rng.uniform(i, k) * 8.0).floor() - 4.0) * 0.25;
        let mut hits = 0;
        for i in 0..20_000u64 {
            let (p, q) = (
                Point3::new(grid(i, 0), grid(i, 1), grid(i, 2)),
                Point3::new(grid(i, 3), grid(i, 4), grid(i, 5)),
            );
            let b = Aabb {
                min: p.inf(&q),
                max: p.sup(&q),
            };
            let o = Point3::new(grid(i, 6), grid(i, 7), rng.uniform(i, 8) * 3.0 - 1.5);
            for axis in 0..3 {
                let mut e = Vector3::zeros();
                e[axis] = 1.0;
                assert_eq!(Aabb::unit_axis(&e), Some(axis));
                let general = b.ray_interval(&o, &e);
                let axial = b.axis_ray_interval(&o, axis);
                assert_eq!(
                    general.map(|(a, b)| (a.to_bits(), b.to_bits())),
                    axial.map(|(a, b)| (a.to_bits(), b.to_bits())),
                    "{b:?} {o:?} {axis}"
                );
                hits += general.is_some() as usize;
            }
        }
        assert!(hits > 1000, "{hits}");
        assert_eq!(Aabb::unit_axis(&Vector3::new(1.0, 1e-300, 0.0)), None);
        assert_eq!(Aabb::unit_axis(&Vector3::new(-1.0, 0.0, 0.0)), None);
    }

    #[test]
    fn counter_rng_normal_has_unit_moments() {
        let rng = CounterRng::new(7);
        let n = 200_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let x = rng.normal(i);
            s += x;
            s2 += x * x;
        }
        let mean = s / n as Real;
        let var = s2 / n as Real - mean * mean;
        // Standard errors: mean 1/sqrt(n) = 0.0022, variance sqrt(2/n) = 0.0032.
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.015, "var {var}");
    }
}
