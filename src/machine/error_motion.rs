//! Error motions of an axis as functions of its position (ISO 230-1 component errors) and
//! its reversal (ISO 230-2 lost motion); the direction each axis last moved.
//!
//! Each axis carries six functions of its value `q` (mm or degrees), named as ISO 230-1
//! names them for a linear axis X: `EXX` (positioning), `EYX`, `EZX` (straightness),
//! `EAX`, `EBX`, `ECX` (roll, pitch, yaw); likewise `E?Y`, `E?Z`, and for rotary axes
//! `E?A`, `E?B`, `E?C` (functions of the angle; `EAA` is A's indexing error). The first
//! letter after `E` names the component: `X Y Z` offsets along the frame's axes (mm),
//! `A B C` rotations about them (rad). A function is a sum of terms: a table interpolated
//! linearly and held at its end values outside its range, a polynomial in `q`, periodic
//! terms `A·sin(2π·q/P + φ)`.
//!
//! The six values at `q` make the exact rigid transform
//! `Err = Trans(EX, EY, EZ)·Rx(EA)·Ry(EB)·Rz(EC)`, the convention of every joint
//! deviation, placed right after the axis motion in the chain; angular values turn about
//! the origin of the frame after a linear axis, about the `origin` of a rotary axis.
//!
//! **Reversal.** `reversal` is ISO 230-2's reversal value `B = x̄↑ − x̄↓`: the positioning
//! value is `E(q) + B/2` after the axis last moved in `+`, `E(q) − B/2` after it moved in
//! `−` (negative B: the axis lags behind its motion, the usual lost motion). A laser
//! reading the axis both ways therefore measures B back exactly.
//!
//! **Invariant:** values and their rates are exact functions of `q` and the direction; a
//! validated set never yields a non-finite number for a finite `q`.

use crate::machine::Component;
use crate::math::{Isometry3, Point3, Real, Rotation3, Vector3};
use crate::nc::{AxisLetter, AxisValues};

/// Errors in building error motions.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ErrorMotionError {
    /// A name that is not `E` + component letter + axis letter.
    #[error(
        "unknown error motion '{0}' (expected E, a component X Y Z A B C and an axis letter, e.g. EXX, EBX, EAA)"
    )]
    UnknownName(String),
    /// A table whose positions do not increase strictly or whose lengths differ.
    #[error("{0}")]
    BadTable(String),
    /// A non-finite or out-of-range number.
    #[error("{0}")]
    BadValue(String),
}

/// The direction an axis last moved.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Increasing values (the default before any motion).
    #[default]
    Positive,
    /// Decreasing values.
    Negative,
}

impl Direction {
    /// +1 or −1.
    pub fn sign(self) -> Real {
        match self {
            Direction::Positive => 1.0,
            Direction::Negative => -1.0,
        }
    }
}

/// The direction each axis last moved, indexed by [`AxisLetter::index`]; all `+` by default.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Directions(pub [Direction; 6]);

impl Directions {
    /// The direction of `letter`.
    pub fn get(&self, letter: AxisLetter) -> Direction {
        self.0[letter.index()]
    }

    /// Sets the direction of `letter`.
    pub fn set(&mut self, letter: AxisLetter, d: Direction) {
        self.0[letter.index()] = d;
    }

    /// The same with `letter` set to `d`.
    pub fn with(mut self, letter: AxisLetter, d: Direction) -> Self {
        self.set(letter, d);
        self
    }

    /// The directions after a move from `start` to `end`: each axis that moves takes the
    /// direction of its motion, the others keep theirs.
    pub fn after_move(&self, start: &AxisValues, end: &AxisValues) -> Self {
        let mut out = *self;
        for l in AxisLetter::ALL {
            let (a, b) = (start.get(l), end.get(l));
            if b > a {
                out.set(l, Direction::Positive);
            } else if b < a {
                out.set(l, Direction::Negative);
            }
        }
        out
    }
}

/// One term of an error-motion function.
#[derive(Clone, Debug, PartialEq)]
pub enum Term {
    /// Values at strictly increasing positions, interpolated linearly; held at the first
    /// and last value outside the table.
    Table {
        /// Positions (mm or degrees), strictly increasing, at least two.
        q: Vec<Real>,
        /// Values (mm or rad).
        v: Vec<Real>,
    },
    /// `Σ c_k·q^k`, coefficients from the constant term up.
    Polynomial(Vec<Real>),
    /// `amplitude·sin(2π·q/period + phase)`: a screw's cyclic error with `period` its pitch.
    Periodic {
        /// Amplitude (mm or rad).
        amplitude: Real,
        /// Period (mm or degrees), positive.
        period: Real,
        /// Phase (degrees).
        phase_deg: Real,
    },
}

impl Term {
    /// A table, validated: at least two points, same lengths, finite, strictly increasing.
    pub fn table(q: Vec<Real>, v: Vec<Real>) -> Result<Self, ErrorMotionError> {
        if q.len() != v.len() {
            return Err(ErrorMotionError::BadTable(format!(
                "table has {} positions but {} values",
                q.len(),
                v.len()
            )));
        }
        if q.len() < 2 {
            return Err(ErrorMotionError::BadTable(
                "table needs at least two points".into(),
            ));
        }
        if let Some(k) = q.iter().chain(&v).position(|x| !x.is_finite()) {
            return Err(ErrorMotionError::BadValue(format!(
                "table entry {} is not finite",
                k % q.len()
            )));
        }
        if let Some(k) = (1..q.len()).find(|&k| q[k] <= q[k - 1]) {
            return Err(ErrorMotionError::BadTable(format!(
                "table positions must increase strictly: q[{k}] = {} after q[{}] = {}",
                q[k],
                k - 1,
                q[k - 1]
            )));
        }
        Ok(Term::Table { q, v })
    }

    /// A polynomial, validated: finite coefficients.
    pub fn polynomial(c: Vec<Real>) -> Result<Self, ErrorMotionError> {
        if c.iter().any(|x| !x.is_finite()) {
            return Err(ErrorMotionError::BadValue(
                "polynomial coefficients must be finite".into(),
            ));
        }
        Ok(Term::Polynomial(c))
    }

    /// A periodic term, validated: finite, period positive.
    pub fn periodic(
        amplitude: Real,
        period: Real,
        phase_deg: Real,
    ) -> Result<Self, ErrorMotionError> {
        if !(amplitude.is_finite() && phase_deg.is_finite() && period.is_finite()) {
            return Err(ErrorMotionError::BadValue(
                "periodic term values must be finite".into(),
            ));
        }
        if period <= 0.0 {
            return Err(ErrorMotionError::BadValue(format!(
                "period must be positive, got {period}"
            )));
        }
        Ok(Term::Periodic {
            amplitude,
            period,
            phase_deg,
        })
    }

    /// Value and slope (right derivative, per unit `q`) at `q`.
    fn eval(&self, q: Real) -> (Real, Real) {
        match self {
            Term::Table { q: xs, v } => {
                let n = xs.len();
                if q <= xs[0] {
                    return (v[0], if q < xs[0] { 0.0 } else { slope(xs, v, 0) });
                }
                if q >= xs[n - 1] {
                    return (v[n - 1], 0.0);
                }
                // The segment k with xs[k] <= q < xs[k + 1].
                let k = xs.partition_point(|&x| x <= q) - 1;
                let s = slope(xs, v, k);
                (v[k] + s * (q - xs[k]), s)
            }
            Term::Polynomial(c) => {
                let (mut val, mut der) = (0.0, 0.0);
                for &ck in c.iter().rev() {
                    der = der * q + val;
                    val = val * q + ck;
                }
                (val, der)
            }
            Term::Periodic {
                amplitude,
                period,
                phase_deg,
            } => {
                let w = std::f64::consts::TAU / period;
                let (s, c) = (w * q + phase_deg.to_radians()).sin_cos();
                (amplitude * s, amplitude * w * c)
            }
        }
    }

    /// A bound on `|slope|` over `[lo, hi]`.
    fn slope_bound(&self, lo: Real, hi: Real) -> Real {
        match self {
            Term::Table { q: xs, v } => (0..xs.len() - 1)
                .filter(|&k| xs[k + 1] >= lo && xs[k] <= hi)
                .map(|k| slope(xs, v, k).abs())
                .fold(0.0, Real::max),
            Term::Polynomial(c) => {
                let m = lo.abs().max(hi.abs());
                c.iter()
                    .enumerate()
                    .skip(1)
                    .map(|(k, ck)| k as Real * ck.abs() * m.powi(k as i32 - 1))
                    .sum()
            }
            Term::Periodic {
                amplitude, period, ..
            } => amplitude.abs() * std::f64::consts::TAU / period,
        }
    }
}

fn slope(xs: &[Real], v: &[Real], k: usize) -> Real {
    (v[k + 1] - v[k]) / (xs[k + 1] - xs[k])
}

/// One error motion: a sum of terms (zero without terms).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ErrorFunction {
    /// The terms, summed.
    pub terms: Vec<Term>,
}

impl ErrorFunction {
    /// The value at `q`.
    pub fn value(&self, q: Real) -> Real {
        self.terms.iter().map(|t| t.eval(q).0).sum()
    }

    /// Value and slope (per unit `q`) at `q`.
    pub fn value_and_slope(&self, q: Real) -> (Real, Real) {
        self.terms.iter().fold((0.0, 0.0), |(a, b), t| {
            let (v, s) = t.eval(q);
            (a + v, b + s)
        })
    }

    /// A bound on `|slope|` over `[lo, hi]` (`lo ≤ hi`).
    pub fn slope_bound(&self, lo: Real, hi: Real) -> Real {
        self.terms.iter().map(|t| t.slope_bound(lo, hi)).sum()
    }

    /// Whether there are no terms.
    pub fn is_empty(&self) -> bool {
        self.terms.is_empty()
    }
}

/// The component of an error-motion name's letter: `X Y Z` offsets, `A B C` rotations.
pub fn component_of(letter: AxisLetter) -> Component {
    match letter {
        AxisLetter::X => Component::Dx,
        AxisLetter::Y => Component::Dy,
        AxisLetter::Z => Component::Dz,
        AxisLetter::A => Component::Alpha,
        AxisLetter::B => Component::Beta,
        AxisLetter::C => Component::Gamma,
    }
}

/// The letter that names a component in an error-motion name (`Dx` → `X`, `Alpha` → `A`).
pub fn letter_of(c: Component) -> char {
    match c {
        Component::Dx => 'X',
        Component::Dy => 'Y',
        Component::Dz => 'Z',
        Component::Alpha => 'A',
        Component::Beta => 'B',
        Component::Gamma => 'C',
    }
}

/// Parses an ISO 230-1 error-motion name (`EXX`, `EBX`, `EAA`): (component, axis).
pub fn parse_name(name: &str) -> Result<(Component, AxisLetter), ErrorMotionError> {
    let b = name.as_bytes();
    let letter = |c: u8| AxisLetter::from_char(c as char);
    match b {
        [b'E', c, a] => match (letter(*c), letter(*a)) {
            (Some(c), Some(a)) => Ok((component_of(c), a)),
            _ => Err(ErrorMotionError::UnknownName(name.to_string())),
        },
        _ => Err(ErrorMotionError::UnknownName(name.to_string())),
    }
}

/// The error motions of one axis: six functions of its value and its reversal.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AxisErrorMotions {
    /// `EX? EY? EZ? EA? EB? EC?`, in [`Component::ALL`] order.
    pub functions: [ErrorFunction; 6],
    /// ISO 230-2 reversal value `B = x̄↑ − x̄↓` (mm, rad for a rotary axis) on the
    /// positioning component.
    pub reversal: Real,
    /// The positioning component (the axis's own letter: `EXX` for X, `EAA` for A).
    pub positioning: Option<Component>,
}

impl AxisErrorMotions {
    /// No error motions for the axis `letter`.
    pub fn for_axis(letter: AxisLetter) -> Self {
        Self {
            positioning: Some(component_of(letter)),
            ..Self::default()
        }
    }

    /// Whether every function is empty and the reversal is zero.
    pub fn is_zero(&self) -> bool {
        self.reversal == 0.0 && self.functions.iter().all(ErrorFunction::is_empty)
    }

    /// The reversal's share after moving in `dir`: `±B/2`.
    pub fn settled_offset(&self, dir: Direction) -> Real {
        self.reversal * dir.sign() / 2.0
    }

    /// The six values at `q` after moving in `dir` (mm, rad).
    pub fn values(&self, q: Real, dir: Direction) -> [Real; 6] {
        self.values_with_offset(q, self.settled_offset(dir))
    }

    /// The six values at `q` with `offset` (the share of the reversal the axis carries,
    /// between `−|B|/2` and `|B|/2`) on the positioning component.
    pub fn values_with_offset(&self, q: Real, offset: Real) -> [Real; 6] {
        let mut out: [Real; 6] = std::array::from_fn(|k| self.functions[k].value(q));
        if let Some(p) = self.positioning {
            out[p as usize] += offset;
        }
        out
    }

    /// The six functions' values and slopes per unit `q` at `q` (no reversal).
    pub fn values_and_slopes(&self, q: Real) -> ([Real; 6], [Real; 6]) {
        let mut v = [0.0; 6];
        let mut s = [0.0; 6];
        for k in 0..6 {
            (v[k], s[k]) = self.functions[k].value_and_slope(q);
        }
        (v, s)
    }

    /// The reversal share after the axis moves by `dq` from a state carrying `offset`: it
    /// moves toward `sign(dq)·B/2` by `|dq|` at most (the lost motion is taken up at the
    /// commanded rate, so the axis dwells while it is).
    pub fn offset_after(&self, offset: Real, dq: Real) -> Real {
        if dq == 0.0 {
            return offset;
        }
        let target = self.reversal * dq.signum() / 2.0;
        let gap = target - offset;
        if gap.abs() <= dq.abs() {
            target
        } else {
            offset + gap.signum() * dq.abs()
        }
    }

    /// Bounds on the slopes over `[lo, hi]`: (offset components summed, mm per unit `q`;
    /// angular components summed, rad per unit `q`).
    pub fn slope_bounds(&self, lo: Real, hi: Real) -> (Real, Real) {
        let b: [Real; 6] = std::array::from_fn(|k| self.functions[k].slope_bound(lo, hi));
        (b[0] + b[1] + b[2], b[3] + b[4] + b[5])
    }

    /// A bound on `|EA| + |EB| + |EC|` over `[lo, hi]` (from the values at `lo` and the
    /// slopes), rad.
    pub fn angle_bound(&self, lo: Real, hi: Real) -> Real {
        let (_, s) = self.slope_bounds(lo, hi);
        let v = self.values(lo, Direction::Positive);
        v[3].abs() + v[4].abs() + v[5].abs() + s * (hi - lo)
    }
}

/// The exact transform `Trans(v0,v1,v2)·Rx(v3)·Ry(v4)·Rz(v5)`, turning about `centre`.
pub fn transform(v: &[Real; 6], centre: &Point3) -> Isometry3 {
    let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), v[3]);
    let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), v[4]);
    let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), v[5]);
    let rot = rx * ry * rz;
    let o = centre.coords;
    // Trans(o)·Trans(d)·R·Trans(−o)
    Isometry3::from_parts((Vector3::new(v[0], v[1], v[2]) + o - rot * o).into(), rot)
}

/// The spatial twist of [`transform`] per unit `q` given the values `v` and slopes `s`:
/// the angular velocity `w` and the velocity `u` of the point at the frame's origin, so a
/// point `x` of the transformed frame moves at `w × x + u`.
pub fn twist(v: &[Real; 6], s: &[Real; 6], centre: &Point3) -> (Vector3, Vector3) {
    let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), v[3]);
    let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), v[4]);
    let w = Vector3::x() * s[3] + rx * (Vector3::y() * s[4]) + rx * ry * (Vector3::z() * s[5]);
    // y ↦ o + d + R(y − o): velocity d' + w × (Y − o − d).
    let d = Vector3::new(v[0], v[1], v[2]);
    let u = Vector3::new(s[0], s[1], s[2]) - w.cross(&(centre.coords + d));
    (w, u)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_interpolates_and_holds_its_ends() {
        let t = Term::table(vec![0.0, 10.0, 20.0], vec![0.0, 1.0, -1.0]).expect("valid");
        let f = ErrorFunction { terms: vec![t] };
        assert_eq!(f.value(5.0), 0.5);
        assert_eq!(f.value(15.0), 0.0);
        assert_eq!(f.value(-5.0), 0.0);
        assert_eq!(f.value(25.0), -1.0);
        assert_eq!(f.value_and_slope(12.0).1, -0.2);
        assert_eq!(f.slope_bound(0.0, 9.0), 0.1);
        assert_eq!(f.slope_bound(0.0, 20.0), 0.2);
    }

    #[test]
    fn bad_tables_are_refused() {
        assert!(Term::table(vec![0.0, 0.0], vec![1.0, 2.0]).is_err());
        assert!(Term::table(vec![1.0, 0.0], vec![1.0, 2.0]).is_err());
        assert!(Term::table(vec![0.0], vec![1.0]).is_err());
        assert!(Term::table(vec![0.0, 1.0], vec![1.0]).is_err());
        assert!(Term::table(vec![0.0, Real::NAN], vec![1.0, 2.0]).is_err());
        assert!(Term::periodic(1.0, 0.0, 0.0).is_err());
    }

    #[test]
    fn polynomial_and_periodic_with_slopes() {
        let f = ErrorFunction {
            terms: vec![
                Term::polynomial(vec![1.0, 2.0, 3.0]).expect("valid"),
                Term::periodic(0.5, 4.0, 90.0).expect("valid"),
            ],
        };
        // 1 + 2·2 + 3·4 = 17; 0.5·sin(π + π/2) = −0.5.
        let (v, s) = f.value_and_slope(2.0);
        assert!((v - 16.5).abs() < 1e-12);
        // 2 + 6·2 = 14; 0.5·(2π/4)·cos(3π/2) = 0.
        assert!((s - 14.0).abs() < 1e-12);
    }

    #[test]
    fn names_parse() {
        assert_eq!(
            parse_name("EBX").expect("known"),
            (Component::Beta, AxisLetter::X)
        );
        assert_eq!(
            parse_name("EXX").expect("known"),
            (Component::Dx, AxisLetter::X)
        );
        assert!(parse_name("EQX").is_err());
        assert!(parse_name("EX").is_err());
        assert!(parse_name("dy_AY").is_err());
    }

    #[test]
    fn reversal_splits_symmetrically() {
        let mut e = AxisErrorMotions::for_axis(AxisLetter::X);
        e.reversal = -0.004;
        // B = x̄↑ − x̄↓.
        let up = e.values(0.0, Direction::Positive)[0];
        let down = e.values(0.0, Direction::Negative)[0];
        assert_eq!(up - down, -0.004);
        assert_eq!(up + down, 0.0);
    }

    #[test]
    fn twist_is_the_derivative_of_the_transform() {
        let v = [0.1, -0.2, 0.3, 1e-3, -2e-3, 3e-3];
        let s = [0.01, 0.02, -0.03, 1e-4, 2e-4, -3e-4];
        let c = Point3::new(5.0, -3.0, 2.0);
        let (w, u) = twist(&v, &s, &c);
        let h = 1e-6;
        let vp: [Real; 6] = std::array::from_fn(|k| v[k] + s[k] * h);
        let vm: [Real; 6] = std::array::from_fn(|k| v[k] - s[k] * h);
        let x = Point3::new(1.0, 2.0, 3.0);
        let (gp, gm, g) = (transform(&vp, &c), transform(&vm, &c), transform(&v, &c));
        let num = (gp * x - gm * x) / (2.0 * h);
        let y = g * x;
        let ana = w.cross(&y.coords) + u;
        assert!((num - ana).norm() < 1e-8, "{num} vs {ana}");
    }
}
