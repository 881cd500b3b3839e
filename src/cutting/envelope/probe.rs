//! The tool at one pose against one ray, in closed form in the tool frame: the interval of
//! the cylinder between the end planes (and the ball's sphere), which face bounds each end
//! and its outward normal, each end's rate, the edge circles' `φ`, and the tool's box.
//!
//! **Invariant:** exact for the pose it is given; knows no move, cell or solve.

use super::*;

/// Distance from the line `p + t·u` (`u` unit) to the segment of the z axis from `z0` to `z1`.
pub(super) fn line_segment_distance(p: &Vector3, u: &Vector3, z0: Real, z1: Real) -> Real {
    // For the axis point (0, 0, z) the squared distance to the line is |w|² − (w·u)² with
    // w = (0, 0, z) − p: a convex quadratic in z, least at z* (clamped to the segment).
    let a = -p.dot(u);
    let k = 1.0 - u.z * u.z;
    let z = if k > tol::RELATIVE_EPS {
        ((p.z + u.z * a) / k).clamp(z0, z1)
    } else {
        z0
    };
    let wu = a + z * u.z;
    let d2 = p.x * p.x + p.y * p.y + (z - p.z) * (z - p.z) - wu * wu;
    d2.max(0.0).sqrt()
}

/// The convex tools the envelope solves in closed form.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Shape {
    Flat,
    /// A ball end mill reaching at least one diameter above its tip.
    Ball,
}

/// Which face bounds an interval end (tool frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Face {
    Side,
    Bottom,
    Top,
    Sphere,
    /// The ray runs inside the infinite cylinder: no face (only for grown tools).
    None,
}

impl Face {
    /// Faces that meet smoothly (the sphere and the side of a ball end mill are tangent)
    /// share a family: the rate of an interval end is continuous within one family.
    pub(super) fn family(self) -> u8 {
        match self {
            Face::Side | Face::Sphere => 0,
            Face::Bottom => 1,
            Face::Top => 2,
            Face::None => 3,
        }
    }
}

/// The exact tool interval along a ray at one pose (the rate of each end: [`Probe::g_in`],
/// [`Probe::g_out`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct Hit {
    pub(super) t_in: Real,
    pub(super) face_in: Face,
    pub(super) t_out: Real,
    pub(super) face_out: Face,
}

/// A ray evaluated at one pose: its interval (if any) and, per edge circle (bottom, top),
/// the squared radius where the ray crosses the edge's plane (`+∞` for no edge or a ray
/// parallel to the plane), from which [`Probe::phi`] is read.
#[derive(Clone, Debug)]
pub(super) struct Probe {
    pub(super) lambda: Real,
    pub(super) hit: Option<Hit>,
    pub(super) edge_r2: [Real; 2],
    /// The ray's origin and direction in the tool frame.
    pub(super) p: Vector3,
    pub(super) u: Vector3,
    /// The pose's rotation (`w_from_t`).
    pub(super) rot: Matrix3,
    /// The pose's angular velocity and tip velocity (tool frame), for the rates.
    pub(super) w_t: Vector3,
    pub(super) v_t: Vector3,
    /// `dt_in/dλ` and `dt_out/dλ` of the hit, each worked out when first read (bit `k` of
    /// `known`): many are never read, the ray's end being outside the material there.
    pub(super) rates: Cell<[Real; 2]>,
    pub(super) known: Cell<u8>,
}

impl Probe {
    /// `φ` of edge circle `edge` (0 bottom, 1 top): the radius where the ray crosses the
    /// edge's plane minus the tool radius `r` (`+∞` for no edge or a ray parallel to the
    /// plane). Its sign is [`EdgeSign::inside`]'s, without the square root.
    #[inline(always)]
    pub(super) fn phi(&self, edge: usize, r: Real) -> Real {
        self.edge_r2[edge].sqrt() - r
    }

    /// `dt_in/dλ` of the hit (the tool radius `r`).
    #[inline(always)]
    pub(super) fn g_in(&self, r: Real) -> Real {
        self.rate(0, r)
    }

    /// `dt_out/dλ` of the hit.
    #[inline(always)]
    pub(super) fn g_out(&self, r: Real) -> Real {
        self.rate(1, r)
    }

    /// The rate of the hit's end `end` (0 in, 1 out): the end's normal speed over the
    /// normal's component along the ray; NaN without a normal or a hit.
    #[inline(always)]
    fn rate(&self, end: usize, r: Real) -> Real {
        if self.known.get() & (1 << end) == 0 {
            let g = match self.hit {
                Some(h) => {
                    let (t, face) = if end == 0 {
                        (h.t_in, h.face_in)
                    } else {
                        (h.t_out, h.face_out)
                    };
                    let q = self.p + self.u * t;
                    match tool_normal(&q, face, r) {
                        Some(n) => n.dot(&(self.w_t.cross(&q) + self.v_t)) / n.dot(&self.u),
                        None => Real::NAN,
                    }
                }
                None => Real::NAN,
            };
            let mut rates = self.rates.get();
            rates[end] = g;
            self.rates.set(rates);
            self.known.set(self.known.get() | 1 << end);
        }
        self.rates.get()[end]
    }
}

/// A ray `o + t·e` with `e` a unit vector, and the span of `t` where the answer matters.
pub(super) struct Ray<'a> {
    pub(super) o: &'a Point3,
    pub(super) e: &'a Vector3,
    pub(super) span: (Real, Real),
    /// The axis `e` is, if it is one (its direction in a stored pose's tool frame is kept).
    pub(super) axis: Option<usize>,
}

/// The tool's outward normal (tool frame) on `face` at the tool-frame point `q` (`r` the
/// tool radius).
#[inline(always)]
pub(super) fn tool_normal(q: &Vector3, face: Face, r: Real) -> Option<Vector3> {
    match face {
        Face::Side => Vector3::new(q.x, q.y, 0.0).try_normalize(0.0),
        Face::Bottom => Some(-Vector3::z()),
        Face::Top => Some(Vector3::z()),
        Face::Sphere => (q - Vector3::new(0.0, 0.0, r)).try_normalize(0.0),
        Face::None => None,
    }
}

/// Box of the tool (grown by `margin`) at a pose.
pub(super) fn frame_box(f: &Sample, shape: Shape, r: Real, l: Real, margin: Real) -> Aabb {
    let v = f.rot.column(2).into_owned();
    let ext = Vector3::from_fn(|k, _| r * (1.0 - v[k] * v[k]).max(0.0).sqrt() + margin);
    let mut b = Aabb::empty();
    let lo = if shape == Shape::Ball { r } else { 0.0 };
    for h in [lo, l] {
        let c = f.tip + v * h;
        b.grow(&(c - ext));
        b.grow(&(c + ext));
    }
    if shape == Shape::Ball {
        let c = f.tip + v * r;
        b.grow(&(c - Vector3::repeat(r + margin)));
        b.grow(&(c + Vector3::repeat(r + margin)));
    }
    b
}

/// Interval of the line `p + t·u` (tool frame, `u` unit) inside the infinite cylinder of
/// radius `rad` about the z axis: `None` if it misses, infinite ends if parallel inside.
#[inline(always)]
fn cylinder(p: &Vector3, u: &Vector3, rad: Real) -> Option<(Real, Real)> {
    let a = u.x * u.x + u.y * u.y;
    let b = p.x * u.x + p.y * u.y;
    let c = p.x * p.x + p.y * p.y - rad * rad;
    if a <= tol::RELATIVE_EPS {
        return (c <= 0.0).then_some((Real::NEG_INFINITY, Real::INFINITY));
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let q = -(b + b.signum() * disc.sqrt());
    let (x0, x1) = if q == 0.0 { (0.0, 0.0) } else { (q / a, c / q) };
    Some((x0.min(x1), x0.max(x1)))
}

/// Interval of the line inside the slab `h0 ≤ z ≤ h1`, with the face at each end.
#[inline(always)]
fn slab(pz: Real, uz: Real, h0: Real, h1: Real) -> Option<(Real, Face, Real, Face)> {
    if uz.abs() <= tol::RELATIVE_EPS {
        return (h0 <= pz && pz <= h1).then_some((
            Real::NEG_INFINITY,
            Face::None,
            Real::INFINITY,
            Face::None,
        ));
    }
    let (a, b) = ((h0 - pz) / uz, (h1 - pz) / uz);
    Some(if uz > 0.0 {
        (a, Face::Bottom, b, Face::Top)
    } else {
        (b, Face::Top, a, Face::Bottom)
    })
}

/// The tool's interval along the line `p + t·u` (tool frame), the tool grown by `g`.
#[inline(always)]
pub(super) fn tool_interval(
    shape: Shape,
    r: Real,
    l: Real,
    p: &Vector3,
    u: &Vector3,
    g: Real,
) -> Option<(Real, Face, Real, Face)> {
    tool_interval_in(shape, r, p, u, g, || end_slab(shape, r, l, p, u, g))
}

/// The interval of the line `p + t·u` (tool frame, `u` unit) between the end planes of the
/// tool of `shape`, radius `r` and length `l` grown by `g` (the slab `tool_interval` clips the
/// cylinder to), with the face at each end.
#[inline(always)]
pub(super) fn end_slab(
    shape: Shape,
    r: Real,
    l: Real,
    p: &Vector3,
    u: &Vector3,
    g: Real,
) -> Option<(Real, Face, Real, Face)> {
    let h0 = match shape {
        Shape::Flat => -g,
        Shape::Ball => r - g,
    };
    slab(p.z, u.z, h0, l + g)
}

/// [`tool_interval`] with its end slab ([`end_slab`] of the same tool, line and growth)
/// from `slab` (asked only where the line meets the cylinder).
#[inline(always)]
pub(super) fn tool_interval_in(
    shape: Shape,
    r: Real,
    p: &Vector3,
    u: &Vector3,
    g: Real,
    slab: impl FnOnce() -> Option<(Real, Face, Real, Face)>,
) -> Option<(Real, Face, Real, Face)> {
    let cyl = cylinder(p, u, r + g).and_then(|(c0, c1)| {
        let (s0, f0, s1, f1) = slab()?;
        let (t0, face0) = if c0 >= s0 { (c0, Face::Side) } else { (s0, f0) };
        let (t1, face1) = if c1 <= s1 { (c1, Face::Side) } else { (s1, f1) };
        (t0 <= t1).then_some((t0, face0, t1, face1))
    });
    if shape == Shape::Flat {
        return cyl;
    }
    match (cyl, ball_sphere(r, p, u, g)) {
        (Some(a), Some(b)) => {
            let (t0, f0) = if a.0 <= b.0 { (a.0, a.1) } else { (b.0, b.1) };
            let (t1, f1) = if a.2 >= b.2 { (a.2, a.3) } else { (b.2, b.3) };
            Some((t0, f0, t1, f1))
        }
        (a, b) => a.or(b),
    }
}

/// The interval of the line `p + t·u` (tool frame, `u` unit) in a ball end mill's sphere
/// (about (0, 0, r), radius r + g): part of [`tool_interval`], which is its hull with the
/// shank's interval.
#[inline(always)]
pub(super) fn ball_sphere(
    r: Real,
    p: &Vector3,
    u: &Vector3,
    g: Real,
) -> Option<(Real, Face, Real, Face)> {
    let w = p - Vector3::new(0.0, 0.0, r);
    let rad = r + g;
    let b = w.dot(u);
    let c = w.dot(&w) - rad * rad;
    let disc = b * b - c;
    (disc >= 0.0).then(|| {
        let sq = disc.sqrt();
        (-b - sq, Face::Sphere, -b + sq, Face::Sphere)
    })
}

/// The sign of `φ = √s − r` read off the squared radius `s` alone: `√s − r < 0` exactly when
/// `s` is below the least `s` whose rounded root is not below `r` (the root is correctly
/// rounded, so it never falls as `s` grows; and `x − r < 0` exactly when `x < r`). The same
/// answer as the root's, bit for bit, for every `s`, NaN included (never inside).
#[derive(Clone, Copy, Debug)]
pub(super) struct EdgeSign {
    least_outside: Real,
}

impl EdgeSign {
    /// The sign test of `φ` for a tool of radius `r` (positive and finite).
    pub(super) fn new(r: Real) -> Self {
        let inside = |s: Real| s.sqrt() - r < 0.0;
        // r² is within an ulp or two of the threshold: step to the least s not inside
        let mut s = r * r;
        for _ in 0..64 {
            if inside(s) {
                s = s.next_up();
            } else if s > 0.0 && !inside(s.next_down()) {
                s = s.next_down();
            } else {
                break;
            }
        }
        Self { least_outside: s }
    }

    /// Whether `φ = √s − r < 0` (the ray crosses the edge's plane inside the circle).
    #[inline(always)]
    pub(super) fn inside(self, s: Real) -> bool {
        s < self.least_outside
    }
}
