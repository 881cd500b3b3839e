//! Circular tests evaluated as ISO 230-4 says, with the diagnostics ball-bar software
//! reports, from a radial-deviation trace of any source (a real ball bar's export or the
//! twin's).
//!
//! # Trace
//!
//! A trace is the measured radius minus the nominal radius `R` at angles `θ` around the
//! circle, one or both directions: `θ` is measured from the plane's first axis towards its
//! second (XY: from +X towards +Y), counter-clockwise (`ccw`) is `θ` increasing. The point
//! of a sample is `(R + Δr)(cos θ, sin θ)` about the ball bar's centre ball. [`parse_trace`]
//! reads a CSV with a header `direction,angle,deviation` (`ccw`/`cw`, degrees, mm; a unit in
//! brackets after a header name, `deviation[um]`, `angle[rad]`, applies to its column).
//!
//! # Figures
//!
//! Per direction: the least-squares circle (centre and radius, Gauss–Newton on the points'
//! distances); the **circular deviation G** — the radial width of the two concentric circles
//! about the least-squares centre that enclose the path; the **radial deviation F** — the
//! largest and smallest Δr about the ball bar's centre. With both directions, the **circular
//! hysteresis H**: the largest radial difference between the two paths at the same angle (one
//! path interpolated linearly at the other's angles, about the common centre ball).
//!
//! # Diagnostics
//!
//! Each direction's Δr(θ) is fitted by linear least squares to the first-order signatures of
//! the machine's errors on a circle of radius R (with x = R cos θ, y = R sin θ):
//!
//! | term | basis | meaning of its coefficient c |
//! |---|---|---|
//! | radius | 1 | mean radius error (ball bar length, mean scale) |
//! | centre | cos θ, sin θ | the set-up's centre offset |
//! | scale mismatch | cos 2θ | c = R(s₁ − s₂)/2, s the scale error of each axis |
//! | squareness | sin 2θ | c = Rα/2, α the angle by which the axes' angle is less than 90° |
//! | reversal of axis 1 | ±½ sgn(sin θ) cos θ | c = the step at axis 1's reversals (0°, 180°) |
//! | reversal of axis 2 | ∓½ sgn(cos θ) sin θ | c = the step at axis 2's reversals (90°, 270°) |
//! | straightness of axis 1 | cos²θ sin θ | c = k R², the bow k x² across axis 1's travel |
//! | straightness of axis 2 | sin²θ cos θ | c = k R², the bow k y² across axis 2's travel |
//! | cyclic error (with a pitch p) | sin, cos(2πx/p)·cos θ; (2πy/p)·sin θ | amplitude per axis |
//!
//! (the reversal signs are for `ccw`; `cw` runs each axis the other way, so they flip). With
//! both directions the sin 2θ term splits into squareness (the part both directions share)
//! and servo mismatch (the part that changes sign with the direction); from one direction it
//! cannot be split, and the report says so. A lost motion b (the table lagging b/2 behind the
//! command after a reversal) shows as a step of +b at the reversal. A sample taken at a
//! reversal itself (θ on an axis, as a trace sampled at whole degrees has) carries the state
//! it arrived with.
//!
//! **Invariant:** only finite traces of at least 8 points per direction, covering at least
//! 90° of the circle, are evaluated; a term the trace cannot separate (an arc that does not
//! reach an axis's reversal, a rank-deficient fit) is reported as not determined, never as
//! a number.

use super::table::{FieldError, fields, length_unit, name_and_unit, number, rows};
use crate::math::Real;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// The direction the circle is run in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Turn {
    /// Counter-clockwise: θ increasing.
    Ccw,
    /// Clockwise: θ decreasing.
    Cw,
}

/// One sample of a trace.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Direction of travel.
    pub turn: Turn,
    /// Angle from the plane's first axis towards its second (rad).
    pub angle_rad: Real,
    /// Measured radius minus the nominal radius (mm).
    pub deviation_mm: Real,
}

/// A problem with a trace file or a trace.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TraceError {
    /// A line cannot be read.
    #[error(transparent)]
    Syntax(#[from] FieldError),
    /// The trace cannot be evaluated (too few points, too short an arc, bad radius).
    #[error("{}: {message}", path.display())]
    Unusable {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
}

/// Options of [`evaluate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CircularOptions {
    /// Nominal radius of the circle (mm, > 0).
    pub radius_mm: Real,
    /// Lead of the axes' screws for the cyclic-error terms (mm); `None`: no cyclic terms.
    pub pitch_mm: Option<Real>,
}

/// A diagnostic term: its value, or why there is none.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Diagnosis {
    /// The fitted value with its standard uncertainty from the residuals.
    Value {
        /// The value (unit in the field's name).
        value: Real,
        /// Its standard uncertainty.
        sigma: Real,
    },
    /// The trace cannot determine it.
    NotDetermined {
        /// Why.
        not_determined: String,
    },
}

/// The figures of one direction.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DirectionFigures {
    /// Which direction.
    pub direction: Turn,
    /// Samples.
    pub points: usize,
    /// Angular span of the samples (degrees).
    pub span_deg: Real,
    /// Least-squares centre in the plane (mm, relative to the centre ball).
    pub centre_mm: [Real; 2],
    /// Least-squares radius minus the nominal radius (mm).
    pub radius_deviation_mm: Real,
    /// Circular deviation G about the least-squares centre (mm).
    #[serde(rename = "G")]
    pub g: Real,
    /// Largest radial deviation F about the centre ball (mm).
    #[serde(rename = "F_max")]
    pub f_max: Real,
    /// Smallest radial deviation F about the centre ball (mm).
    #[serde(rename = "F_min")]
    pub f_min: Real,
    /// Scale mismatch s₁ − s₂ (µm/m).
    pub scale_mismatch_um_per_m: Diagnosis,
    /// Squareness as this direction alone sees it (µrad, = µm/m): sin 2θ term · 2/R,
    /// servo mismatch included.
    pub sin2_term_urad: Diagnosis,
    /// Reversal step of the first axis (mm).
    pub reversal_1_mm: Diagnosis,
    /// Reversal step of the second axis (mm).
    pub reversal_2_mm: Diagnosis,
    /// Straightness (bow k R²) of the first axis over ±R (mm).
    pub straightness_1_mm: Diagnosis,
    /// Straightness of the second axis (mm).
    pub straightness_2_mm: Diagnosis,
    /// Cyclic error amplitude of the first axis (mm), with a pitch.
    pub cyclic_1_mm: Diagnosis,
    /// Cyclic error amplitude of the second axis (mm).
    pub cyclic_2_mm: Diagnosis,
    /// RMS of what the diagnostic model leaves (mm).
    pub residual_rms_mm: Real,
}

/// The evaluation of a trace.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CircularFigures {
    /// Nominal radius (mm).
    pub radius_mm: Real,
    /// Per direction present, `ccw` first.
    pub directions: Vec<DirectionFigures>,
    /// Circular hysteresis H (mm), with both directions.
    #[serde(rename = "H")]
    pub h: Option<Real>,
    /// Squareness (µrad = µm/m): positive when the axes' angle is less than 90°. With both
    /// directions the part they share; with one, not separable from servo mismatch.
    pub squareness_urad: Diagnosis,
    /// Servo mismatch (µrad of the sin 2θ term that flips with the direction).
    pub servo_mismatch_urad: Diagnosis,
}

fn unit_factor(unit: &str, angle: bool) -> Option<Real> {
    match (unit, angle) {
        ("deg", true) => Some(1.0_f64.to_radians()),
        ("rad", true) => Some(1.0),
        (u, false) => length_unit(u),
        _ => None,
    }
}

/// Reads a trace file's text (see the module documentation); `path` names it in messages.
pub fn parse_trace(text: &str, path: &Path) -> Result<Vec<Sample>, TraceError> {
    let syntax = |line: usize, column: usize, message: String| {
        TraceError::Syntax(FieldError::at(path, line, column, message))
    };
    let mut rows = rows(text);
    let Some((hline, header)) = rows.next() else {
        return Err(TraceError::Unusable {
            path: path.to_path_buf(),
            message: "no header and no samples".into(),
        });
    };
    let head = fields(header);
    let mut factors = [1.0_f64.to_radians(), 1.0];
    let expected = ["direction", "angle", "deviation"];
    if head.len() != 3 {
        return Err(syntax(
            hline,
            1,
            "the header must be 'direction,angle,deviation'".into(),
        ));
    }
    for (k, ((col, cell), want)) in head.iter().zip(expected).enumerate() {
        let (name, unit) = name_and_unit(cell).map_err(|m| syntax(hline, *col, m))?;
        if !name.eq_ignore_ascii_case(want) {
            return Err(syntax(
                hline,
                *col,
                format!("expected '{want}', got '{name}' (header: direction,angle,deviation)"),
            ));
        }
        if let Some(u) = unit {
            let f = unit_factor(u, k == 1).ok_or_else(|| {
                syntax(
                    hline,
                    *col,
                    format!(
                        "unknown unit '{u}' for {want} (use {})",
                        if k == 1 {
                            "deg or rad"
                        } else {
                            "mm, um, µm or in"
                        }
                    ),
                )
            })?;
            if k == 0 {
                return Err(syntax(hline, *col, "direction takes no unit".into()));
            }
            factors[k - 1] = f;
        }
    }
    let mut out = Vec::new();
    for (line, l) in rows {
        let f = fields(l);
        if f.len() != 3 {
            return Err(syntax(
                line,
                1,
                format!(
                    "expected 3 fields (direction,angle,deviation), got {}",
                    f.len()
                ),
            ));
        }
        let turn = match f[0].1.to_ascii_lowercase().as_str() {
            "ccw" | "+" => Turn::Ccw,
            "cw" | "-" => Turn::Cw,
            other => {
                return Err(syntax(
                    line,
                    f[0].0,
                    format!("direction must be 'ccw' or 'cw', got '{other}'"),
                ));
            }
        };
        let num = |&(col, s): &(usize, &str), what: &str| -> Result<Real, TraceError> {
            number(s, what).map_err(|m| syntax(line, col, m))
        };
        out.push(Sample {
            turn,
            angle_rad: num(&f[1], "angle")? * factors[0],
            deviation_mm: num(&f[2], "deviation")? * factors[1],
        });
    }
    Ok(out)
}

/// The trace file of `samples` (see the module documentation): `comments` first, each as
/// a `#` line, then the header `direction,angle[rad],deviation` and one sample a row, the
/// angle in radians and the deviation in mm. Every number is written in its shortest exact
/// form, so [`parse_trace`] reads back the same samples bit for bit.
pub fn trace_csv(samples: &[Sample], comments: &[String]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    for c in comments {
        for line in c.lines() {
            let _ = writeln!(s, "# {line}");
        }
    }
    s.push_str("direction,angle[rad],deviation\n");
    for x in samples {
        let _ = writeln!(s, "{},{:?},{:?}", name(x.turn), x.angle_rad, x.deviation_mm);
    }
    s
}

/// Fewest samples per direction.
const MIN_POINTS: usize = 8;

/// Shortest arc a direction must cover (rad): a quarter circle.
const MIN_SPAN: Real = std::f64::consts::FRAC_PI_2;

/// A sample whose angle is within this of an axis (rad: |sin θ| or |cos θ| below it) is at
/// that axis's reversal: 1e-9 rad is 0.1 nm of arc on a 100 mm circle, far inside the travel
/// over which any lost motion is taken up, and far above the rounding of an angle given in
/// degrees (sin of π in f64 is 1.2e-16, not 0).
const AT_REVERSAL: Real = 1e-9;

/// A diagnostic basis column is used only when its values span at least this fraction of
/// its largest possible magnitude over the samples (an arc that never reaches an axis's
/// reversal leaves that column constant in sign, hence not separable from the rest).
const SEPARABLE: Real = 1e-9;

/// The least-squares circle of points (x, y): centre and radius, Gauss–Newton from the
/// centre ball (the trace's centre is within a few µm of it on any real test).
fn lsc(pts: &[(Real, Real)], r0: Real) -> (Real, Real, Real) {
    let (mut cx, mut cy, mut r) = (0.0, 0.0, r0);
    for _ in 0..50 {
        let mut jtj = nalgebra::Matrix3::<Real>::zeros();
        let mut jtr = nalgebra::Vector3::<Real>::zeros();
        for &(x, y) in pts {
            let (dx, dy) = (x - cx, y - cy);
            let d = dx.hypot(dy);
            if d == 0.0 {
                continue;
            }
            let res = d - r;
            let j = nalgebra::Vector3::new(-dx / d, -dy / d, -1.0);
            jtj += j * j.transpose();
            jtr += j * res;
        }
        let Some(step) = jtj.lu().solve(&(-jtr)) else {
            break;
        };
        cx += step[0];
        cy += step[1];
        r += step[2];
        if step.norm() < 1e-13 * r0.max(1.0) {
            break;
        }
    }
    (cx, cy, r)
}

/// The diagnostic basis at θ for a direction; cyclic columns (two each) only with a pitch.
fn basis(turn: Turn, t: Real, r: Real, pitch: Option<Real>) -> Vec<Real> {
    let (s, c) = t.sin_cos();
    let sgn = |v: Real| if v > 0.0 { 1.0 } else { -1.0 };
    let dir = match turn {
        Turn::Ccw => 1.0,
        Turn::Cw => -1.0,
    };
    // The side of each axis's reversal a sample is on: that of sin θ (axis 1) and cos θ
    // (axis 2); a sample at the reversal itself carries the state it arrived with, the side
    // of the angles just before it in the direction of travel (sin(θ − dir·δ) ≈ −dir·δ·cos θ,
    // cos(θ − dir·δ) ≈ dir·δ·sin θ).
    let side_1 = if s.abs() > AT_REVERSAL {
        sgn(s)
    } else {
        sgn(-dir * c)
    };
    let side_2 = if c.abs() > AT_REVERSAL {
        sgn(c)
    } else {
        sgn(dir * s)
    };
    let mut b = vec![
        1.0,
        c,
        s,
        (2.0 * t).cos(),
        (2.0 * t).sin(),
        dir * 0.5 * side_1 * c,
        -dir * 0.5 * side_2 * s,
        c * c * s,
        s * s * c,
    ];
    if let Some(p) = pitch {
        let (a1, a2) = (
            std::f64::consts::TAU * r * c / p,
            std::f64::consts::TAU * r * s / p,
        );
        b.extend([a1.sin() * c, a1.cos() * c, a2.sin() * s, a2.cos() * s]);
    }
    b
}

/// Fits one direction's diagnostic model; returns per-term (value, σ) or None when not
/// separable, and the residual RMS.
fn diagnose(
    turn: Turn,
    samples: &[(Real, Real)],
    opts: &CircularOptions,
) -> (Vec<Option<(Real, Real)>>, Real) {
    let r = opts.radius_mm;
    let rows: Vec<Vec<Real>> = samples
        .iter()
        .map(|&(t, _)| basis(turn, t, r, opts.pitch_mm))
        .collect();
    let ncol = rows[0].len();
    // Keep a column only if it varies over the samples and is not a copy of the constant
    // (a reversal column whose sign never changes on this arc).
    let mut keep = Vec::new();
    for k in 0..ncol {
        let col: Vec<Real> = rows.iter().map(|row| row[k]).collect();
        let max = col.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let mean = col.iter().sum::<Real>() / col.len() as Real;
        let spread = col.iter().map(|v| (v - mean).abs()).fold(0.0, Real::max);
        let distinct = k == 0 || (max > 0.0 && spread > SEPARABLE * max.max(1.0));
        // A reversal is seen only with samples on both sides of it: axis 1 reverses where
        // sin θ changes sign, axis 2 where cos θ does.
        let sides = |f: fn(Real) -> Real| {
            samples.iter().any(|x| f(x.0) > 0.0) && samples.iter().any(|x| f(x.0) < 0.0)
        };
        let reversal_seen = match k {
            5 => sides(Real::sin),
            6 => sides(Real::cos),
            _ => true,
        };
        if distinct && reversal_seen {
            keep.push(k);
        }
    }
    let a = DMatrix::from_fn(samples.len(), keep.len(), |i, j| rows[i][keep[j]]);
    let y = DVector::from_iterator(samples.len(), samples.iter().map(|s| s.1));
    let svd = a.clone().svd(true, true);
    let smax = svd.singular_values.max();
    let rank_ok = svd.singular_values.iter().all(|s| *s > 1e-10 * smax);
    let mut out = vec![None; ncol];
    if !rank_ok {
        let rms = (y.norm_squared() / samples.len() as Real).sqrt();
        return (out, rms);
    }
    let Ok(x) = svd.solve(&y, 1e-12 * smax) else {
        return (out, Real::NAN);
    };
    let resid = &y - &a * &x;
    let dof = samples.len().saturating_sub(keep.len()).max(1) as Real;
    let s2 = resid.norm_squared() / dof;
    let cov = (a.transpose() * &a).try_inverse();
    for (j, &k) in keep.iter().enumerate() {
        let sigma = cov.as_ref().map_or(Real::NAN, |c| (s2 * c[(j, j)]).sqrt());
        out[k] = Some((x[j], sigma));
    }
    let rms = (resid.norm_squared() / samples.len() as Real).sqrt();
    (out, rms)
}

fn value(v: Option<(Real, Real)>, scale: Real, why: &str) -> Diagnosis {
    match v {
        Some((x, s)) => Diagnosis::Value {
            value: x * scale,
            sigma: s * scale,
        },
        None => Diagnosis::NotDetermined {
            not_determined: why.to_string(),
        },
    }
}

/// Radial deviation of `samples` (sorted by angle, one direction) at angle `t`, linearly
/// interpolated, or None outside their span.
fn interpolate(samples: &[(Real, Real)], t: Real) -> Option<Real> {
    let tau = std::f64::consts::TAU;
    let first = samples.first()?.0;
    let t = first + (t - first).rem_euclid(tau);
    let i = samples.partition_point(|s| s.0 <= t);
    if i == 0 || i == samples.len() {
        // Wrap between the last and the first sample when the trace closes the circle.
        let (a, b) = (samples.last()?, samples.first()?);
        let gap = b.0 + tau - a.0;
        if gap <= 0.0 || gap > 0.1 {
            return None;
        }
        let u = ((t - a.0).rem_euclid(tau)) / gap;
        return Some(a.1 + u * (b.1 - a.1));
    }
    let (a, b) = (samples[i - 1], samples[i]);
    let u = (t - a.0) / (b.0 - a.0);
    Some(a.1 + u * (b.1 - a.1))
}

/// Evaluates a trace (`path` names it in messages).
pub fn evaluate(
    samples: &[Sample],
    opts: &CircularOptions,
    path: &Path,
) -> Result<CircularFigures, TraceError> {
    let unusable = |message: String| TraceError::Unusable {
        path: path.to_path_buf(),
        message,
    };
    let r = opts.radius_mm;
    if !(r.is_finite() && r > 0.0) {
        return Err(unusable(format!(
            "the nominal radius must be positive, got {r} mm"
        )));
    }
    if let Some(p) = opts.pitch_mm
        && !(p.is_finite() && p > 0.0)
    {
        return Err(unusable(format!("the pitch must be positive, got {p} mm")));
    }
    let mut directions = Vec::new();
    let mut sorted: Vec<(Turn, Vec<(Real, Real)>)> = Vec::new();
    for turn in [Turn::Ccw, Turn::Cw] {
        let mut s: Vec<(Real, Real)> = samples
            .iter()
            .filter(|x| x.turn == turn)
            .map(|x| (x.angle_rad, x.deviation_mm))
            .collect();
        if s.is_empty() {
            continue;
        }
        if let Some(bad) = s.iter().find(|x| !(x.0.is_finite() && x.1.is_finite())) {
            return Err(unusable(format!(
                "{turn:?}: a sample at {} rad is not finite",
                bad.0
            )));
        }
        if s.len() < MIN_POINTS {
            return Err(unusable(format!(
                "{}: {} samples, at least {MIN_POINTS} needed",
                name(turn),
                s.len()
            )));
        }
        if let Some(x) = s.iter().find(|x| x.1.abs() >= 0.5 * r) {
            return Err(unusable(format!(
                "{}: a deviation of {} mm is not small against the radius {r} mm",
                name(turn),
                x.1
            )));
        }
        s.sort_by(|a, b| a.0.total_cmp(&b.0));
        let span = (s[s.len() - 1].0 - s[0].0).min(std::f64::consts::TAU);
        if span < MIN_SPAN {
            return Err(unusable(format!(
                "{}: the samples cover {:.1}°, at least 90° needed",
                name(turn),
                span.to_degrees()
            )));
        }
        let pts: Vec<(Real, Real)> = s
            .iter()
            .map(|&(t, d)| ((r + d) * t.cos(), (r + d) * t.sin()))
            .collect();
        let (cx, cy, rr) = lsc(&pts, r);
        let radii: Vec<Real> = pts.iter().map(|(x, y)| (x - cx).hypot(y - cy)).collect();
        let g = radii.iter().fold(Real::NEG_INFINITY, |m, v| m.max(*v))
            - radii.iter().fold(Real::INFINITY, |m, v| m.min(*v));
        let f_max = s.iter().map(|x| x.1).fold(Real::NEG_INFINITY, Real::max);
        let f_min = s.iter().map(|x| x.1).fold(Real::INFINITY, Real::min);
        let (d, rms) = diagnose(turn, &s, opts);
        let per_m = 1e6 / r; // a coefficient in mm, times 2/R, in µm/m = µrad
        let sep = "the trace cannot separate it from the other terms";
        let no_rev = "the arc does not pass this axis's reversal";
        let no_pitch = "no pitch given";
        directions.push(DirectionFigures {
            direction: turn,
            points: s.len(),
            span_deg: span.to_degrees(),
            centre_mm: [cx, cy],
            radius_deviation_mm: rr - r,
            g,
            f_max,
            f_min,
            scale_mismatch_um_per_m: value(d[3], 2.0 * per_m, sep),
            sin2_term_urad: value(d[4], 2.0 * per_m, sep),
            reversal_1_mm: value(d[5], 1.0, no_rev),
            reversal_2_mm: value(d[6], 1.0, no_rev),
            straightness_1_mm: value(d[7], 1.0, sep),
            straightness_2_mm: value(d[8], 1.0, sep),
            cyclic_1_mm: amplitude(&d, 9, opts.pitch_mm.is_some(), no_pitch),
            cyclic_2_mm: amplitude(&d, 11, opts.pitch_mm.is_some(), no_pitch),
            residual_rms_mm: rms,
        });
        sorted.push((turn, s));
    }
    if directions.is_empty() {
        return Err(unusable("no samples".into()));
    }
    let h = if let [(_, a), (_, b)] = &sorted[..] {
        let mut h: Option<Real> = None;
        for &(t, d) in a {
            if let Some(e) = interpolate(b, t) {
                h = Some(h.map_or((d - e).abs(), |m| m.max((d - e).abs())));
            }
        }
        h
    } else {
        None
    };
    let sq = |f: &DirectionFigures| match f.sin2_term_urad {
        Diagnosis::Value { value, sigma } => Some((value, sigma)),
        Diagnosis::NotDetermined { .. } => None,
    };
    let both = "a direction cannot determine its sin 2θ term";
    let (squareness_urad, servo_mismatch_urad) = if let [a, b] = &directions[..] {
        match (sq(a), sq(b)) {
            (Some((va, sa)), Some((vb, sb))) => {
                let s = 0.5 * sa.hypot(sb);
                (
                    Diagnosis::Value {
                        value: 0.5 * (va + vb),
                        sigma: s,
                    },
                    Diagnosis::Value {
                        value: 0.5 * (va - vb),
                        sigma: s,
                    },
                )
            }
            _ => (value(None, 1.0, both), value(None, 1.0, both)),
        }
    } else {
        (
            value(
                directions.first().and_then(sq),
                1.0,
                "the trace cannot separate it from the other terms",
            ),
            value(
                None,
                1.0,
                "needs both directions (from one, servo mismatch and squareness add up)",
            ),
        )
    };
    Ok(CircularFigures {
        radius_mm: r,
        directions,
        h,
        squareness_urad,
        servo_mismatch_urad,
    })
}

fn name(turn: Turn) -> &'static str {
    match turn {
        Turn::Ccw => "ccw",
        Turn::Cw => "cw",
    }
}

/// The amplitude of a sine/cosine pair of columns `k`, `k + 1`.
fn amplitude(d: &[Option<(Real, Real)>], k: usize, wanted: bool, why: &str) -> Diagnosis {
    if !wanted {
        return value(None, 1.0, why);
    }
    match (d.get(k).copied().flatten(), d.get(k + 1).copied().flatten()) {
        (Some((a, sa)), Some((b, sb))) => {
            let amp = a.hypot(b);
            Diagnosis::Value {
                value: amp,
                sigma: if amp > 0.0 {
                    ((a * sa).powi(2) + (b * sb).powi(2)).sqrt() / amp
                } else {
                    sa.max(sb)
                },
            }
        }
        _ => value(
            None,
            1.0,
            "the trace cannot separate it from the other terms",
        ),
    }
}

/// A test trace: 720 samples every 0.5°, alternately ccw and cw; the ccw run bulges
/// outwards by up to 5 µm around 0° (`5 µm · max(cos θ, 0)⁸`), the cw run is round. The
/// plots' tests check the bulge is drawn where it is.
#[cfg(test)]
pub(crate) fn bulge_trace() -> Vec<Sample> {
    (0..720)
        .map(|i| {
            let t = (i as Real * 0.5).to_radians();
            Sample {
                turn: if i % 2 == 0 { Turn::Ccw } else { Turn::Cw },
                angle_rad: t,
                deviation_mm: if i % 2 == 0 {
                    5e-3 * t.cos().max(0.0).powi(8)
                } else {
                    0.0
                },
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::CounterRng;

    /// Machine errors in the plane, applied exactly to the commanded point.
    #[derive(Clone, Copy, Default)]
    struct Errors {
        /// Angle by which the second axis leans towards the first (rad).
        squareness: Real,
        /// Scale errors of the two axes.
        scale: [Real; 2],
        /// Lost motion of each axis (mm): the table trails b/2 behind after a reversal.
        backlash: [Real; 2],
        /// Offset of the path's centre from the centre ball (mm).
        centre: [Real; 2],
    }

    /// A trace of `n` samples over the full circle, measured exactly (|actual point|
    /// minus R), with Gaussian noise σ (mm) keyed by `seed`.
    fn trace(turn: Turn, r: Real, n: usize, e: Errors, sigma: Real, seed: u64) -> Vec<Sample> {
        let rng = CounterRng::new(seed);
        (0..n)
            .map(|i| {
                let t = (i as Real + 0.5) / n as Real * std::f64::consts::TAU;
                let (s, c) = t.sin_cos();
                let (x, y) = (r * c, r * s);
                // Velocity direction of each axis along the path.
                let dir = if turn == Turn::Ccw { 1.0 } else { -1.0 };
                let (vx, vy) = (-s * dir, c * dir);
                let mut ax = x * (1.0 + e.scale[0]) + e.squareness * y;
                let mut ay = y * (1.0 + e.scale[1]);
                ax -= 0.5 * e.backlash[0] * vx.signum();
                ay -= 0.5 * e.backlash[1] * vy.signum();
                ax += e.centre[0];
                ay += e.centre[1];
                Sample {
                    turn,
                    angle_rad: t,
                    deviation_mm: ax.hypot(ay) - r + sigma * rng.normal(i as u64),
                }
            })
            .collect()
    }

    fn val(d: &Diagnosis) -> Real {
        match d {
            Diagnosis::Value { value, .. } => *value,
            Diagnosis::NotDetermined { not_determined } => {
                panic!("not determined: {not_determined}")
            }
        }
    }

    fn eval(samples: &[Sample], r: Real) -> CircularFigures {
        let opts = CircularOptions {
            radius_mm: r,
            pitch_mm: None,
        };
        evaluate(samples, &opts, Path::new("t")).expect("evaluates")
    }

    #[test]
    fn squareness_of_50_urad_reads_50_and_shows_2_5_um_at_45_degrees() {
        let e = Errors {
            squareness: 50e-6,
            ..Errors::default()
        };
        let noise = 1e-4; // 0.1 µm, a ball bar's resolution
        let mut s = trace(Turn::Ccw, 100.0, 360, e, noise, 1);
        // Without noise the radial deviation at 45° is R·α/2 = 2.5 µm, at 135° −2.5 µm.
        let clean = trace(Turn::Ccw, 100.0, 8, e, 0.0, 1);
        let at = |deg: Real| {
            let t = deg.to_radians();
            let (x, y) = (100.0 * t.cos(), 100.0 * t.sin());
            (x + 50e-6 * y).hypot(y) - 100.0
        };
        assert!((at(45.0) - 2.5e-3).abs() < 1e-6 && (at(135.0) + 2.5e-3).abs() < 1e-6);
        assert!(clean.iter().all(|x| x.deviation_mm.abs() < 2.6e-3));
        s.extend(trace(Turn::Cw, 100.0, 360, e, noise, 2));
        let f = eval(&s, 100.0);
        let sq = val(&f.squareness_urad);
        assert!((sq - 50.0).abs() < 0.02 * 50.0, "squareness {sq} µrad");
        assert!(val(&f.servo_mismatch_urad).abs() < 1.0);
        // G of an ellipse from squareness: R·α (first order).
        for d in &f.directions {
            assert!(
                (d.g - 100.0 * 50e-6).abs() < 1e-3 * 5e-3 + 6.0 * noise,
                "G {}",
                d.g
            );
        }
    }

    #[test]
    fn scale_mismatch_and_backlash_are_recovered_within_2_percent() {
        let e = Errors {
            scale: [10e-6, 0.0],
            backlash: [4e-3, 2e-3],
            ..Errors::default()
        };
        let noise = 1e-4;
        let mut s = trace(Turn::Ccw, 100.0, 720, e, noise, 3);
        s.extend(trace(Turn::Cw, 100.0, 720, e, noise, 4));
        let f = eval(&s, 100.0);
        for d in &f.directions {
            let m = val(&d.scale_mismatch_um_per_m);
            assert!(
                (m - 10.0).abs() < 0.2,
                "{:?} scale mismatch {m} µm/m",
                d.direction
            );
            let (b1, b2) = (val(&d.reversal_1_mm), val(&d.reversal_2_mm));
            assert!(
                (b1 - 4e-3).abs() < 0.02 * 4e-3,
                "{:?} reversal 1 {b1}",
                d.direction
            );
            assert!(
                (b2 - 2e-3).abs() < 0.02 * 2e-3,
                "{:?} reversal 2 {b2}",
                d.direction
            );
        }
        // The two directions are offset by the lost motion at every angle: H is at least the
        // larger step, and not more than the sum.
        let h = f.h.expect("both directions");
        assert!(h > 1.9e-3 && h < 6.5e-3, "H {h}");
    }

    #[test]
    fn a_centre_offset_is_the_least_squares_centre_and_leaves_no_circular_deviation() {
        // A circle of radius R about c, seen from the centre ball: along the direction u(θ)
        // the path is at ρ = c·u + √(R² − |c|² + (c·u)²).
        let (r, c) = (50.0_f64, [0.012_f64, -0.005_f64]);
        let s: Vec<Sample> = (0..360)
            .map(|i| {
                let t = (i as Real).to_radians();
                let cu = c[0] * t.cos() + c[1] * t.sin();
                let rho = cu + (r * r - c[0] * c[0] - c[1] * c[1] + cu * cu).sqrt();
                Sample {
                    turn: Turn::Ccw,
                    angle_rad: t,
                    deviation_mm: rho - r,
                }
            })
            .collect();
        let f = eval(&s, r);
        let d = &f.directions[0];
        assert!((d.centre_mm[0] - c[0]).abs() < 1e-9 && (d.centre_mm[1] - c[1]).abs() < 1e-9);
        assert!(d.g < 1e-9, "G {}", d.g);
        assert!(d.radius_deviation_mm.abs() < 1e-9);
        // F about the centre ball: ± the offset's length, to second order.
        let off = c[0].hypot(c[1]);
        assert!((d.f_max - off).abs() < 1e-5 && (d.f_min + off).abs() < 1e-5);
        // One direction: squareness and servo mismatch cannot be split.
        assert!(matches!(
            f.servo_mismatch_urad,
            Diagnosis::NotDetermined { .. }
        ));
        assert!(f.h.is_none());
    }

    /// A trace sampled at whole degrees has samples on the axes, where each axis reverses:
    /// there the machine still carries the state it arrived with. Read with a zero or
    /// rounding-signed column (sin π is +1.2e-16 in f64), the cw trace's reversal came out
    /// 4 % short while the ccw one was right.
    #[test]
    fn samples_at_the_reversals_carry_the_state_they_arrived_with() {
        let b = 4e-3;
        let r = 100.0;
        let mut s = Vec::new();
        for (turn, dir) in [(Turn::Ccw, 1.0), (Turn::Cw, -1.0)] {
            for k in 0..360 {
                let deg = (dir * k as Real).rem_euclid(360.0);
                let t = deg.to_radians();
                // X's last motion: against sin θ (ccw), with it (cw); on the axis, the way
                // it arrived: + at 0°, − at 180°.
                let vx = match deg {
                    0.0 => 1.0,
                    180.0 => -1.0,
                    _ => -dir * t.sin().signum(),
                };
                let x = r * t.cos() - 0.5 * b * vx;
                s.push(Sample {
                    turn,
                    angle_rad: t,
                    deviation_mm: x.hypot(r * t.sin()) - r,
                });
            }
        }
        let f = eval(&s, r);
        for d in &f.directions {
            let b1 = val(&d.reversal_1_mm);
            assert!((b1 - b).abs() < 1e-6, "{:?}: {b1}", d.direction);
            assert!(d.residual_rms_mm < 1e-6, "{:?}", d.direction);
        }
    }

    #[test]
    fn hysteresis_is_the_largest_gap_between_the_directions() {
        // Constant radius errors of +1 µm (ccw) and −2 µm (cw): H = 3 µm.
        let mk = |turn, d: Real| -> Vec<Sample> {
            (0..100)
                .map(|i| Sample {
                    turn,
                    angle_rad: i as Real * 0.0628,
                    deviation_mm: d,
                })
                .collect()
        };
        let mut s = mk(Turn::Ccw, 1e-3);
        s.extend(mk(Turn::Cw, -2e-3));
        let f = eval(&s, 100.0);
        assert!((f.h.expect("both") - 3e-3).abs() < 1e-12);
    }

    #[test]
    fn a_partial_arc_names_what_it_cannot_see() {
        // A 120° arc from 10° to 130°: axis 1 reverses at 0°/180° (not seen), axis 2 at 90°.
        let s: Vec<Sample> = (0..121)
            .map(|i| Sample {
                turn: Turn::Ccw,
                angle_rad: (10.0 + i as Real).to_radians(),
                deviation_mm: 1e-4 * (i as Real * 0.1).sin(),
            })
            .collect();
        let f = eval(&s, 100.0);
        let d = &f.directions[0];
        assert!(matches!(d.reversal_1_mm, Diagnosis::NotDetermined { .. }));
        assert!(matches!(d.reversal_2_mm, Diagnosis::Value { .. }));
    }

    #[test]
    fn straightness_bows_and_a_cyclic_error_are_recovered() {
        // Axis 1 (X) carries a cyclic positioning error A·sin(2πx/p) and a straightness bow
        // (Y error k·x²); axis 2 (Y) a bow (X error k₂·y²). The path point is the commanded
        // point plus these errors; the trace is its exact distance from the centre ball.
        let (r, p, a, k1, k2) = (100.0_f64, 5.0_f64, 1.5e-3_f64, 3e-7_f64, -2e-7_f64);
        let s: Vec<Sample> = (0..1440)
            .map(|i| {
                let t = (i as Real + 0.25) / 1440.0 * std::f64::consts::TAU;
                let (x, y) = (r * t.cos(), r * t.sin());
                let ax = x + a * (std::f64::consts::TAU * x / p).sin() + k2 * y * y;
                let ay = y + k1 * x * x;
                Sample {
                    turn: Turn::Ccw,
                    angle_rad: t,
                    deviation_mm: ax.hypot(ay) - r,
                }
            })
            .collect();
        let opts = CircularOptions {
            radius_mm: r,
            pitch_mm: Some(p),
        };
        let f = evaluate(&s, &opts, Path::new("t")).expect("evaluates");
        let d = &f.directions[0];
        let cyc = val(&d.cyclic_1_mm);
        assert!((cyc - a).abs() < 0.02 * a, "cyclic {cyc}");
        assert!(val(&d.cyclic_2_mm).abs() < 0.02 * a);
        let (s1, s2) = (val(&d.straightness_1_mm), val(&d.straightness_2_mm));
        assert!(
            (s1 - k1 * r * r).abs() < 0.02 * (k1 * r * r).abs(),
            "bow 1 {s1}"
        );
        assert!(
            (s2 - k2 * r * r).abs() < 0.02 * (k2 * r * r).abs(),
            "bow 2 {s2}"
        );
        // Without a pitch there is no cyclic figure, and the report says why.
        let f = eval(&s, r);
        assert!(matches!(
            f.directions[0].cyclic_1_mm,
            Diagnosis::NotDetermined { .. }
        ));
    }

    #[test]
    fn ten_ppm_of_scale_on_x_lengthens_the_x_diameter_by_2_um() {
        let e = Errors {
            scale: [10e-6, 0.0],
            ..Errors::default()
        };
        let f = eval(&trace(Turn::Ccw, 100.0, 360, e, 0.0, 0), 100.0);
        let d = &f.directions[0];
        // Δr = R·s·cos²θ: +1 µm at 0° and at 180°, 0 at 90° and 270° — the X diameter is
        // 2 µm long; F spans [0, 1 µm]; the least-squares radius is R·s/2 long.
        assert!((d.f_max - 1e-3).abs() < 1e-7 && d.f_min.abs() < 1e-7);
        assert!((2.0 * d.f_max - 2e-3).abs() < 2e-7);
        assert!((d.radius_deviation_mm - 0.5e-3).abs() < 1e-7);
        assert!((val(&d.scale_mismatch_um_per_m) - 10.0).abs() < 0.01);
    }

    #[test]
    fn bad_traces_fail_with_their_place() {
        let p = Path::new("b.csv");
        let opts = CircularOptions {
            radius_mm: 100.0,
            pitch_mm: None,
        };
        let err = |t: &str| match parse_trace(t, p).and_then(|s| evaluate(&s, &opts, p)) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("accepted: {t}"),
        };
        assert!(err("direction,angle,deviation\nccw,0,nan\n").starts_with("b.csv:2:7:"));
        assert!(err("direction,angle[grad],deviation\n").contains("unknown unit 'grad'"));
        assert!(err("direction,angle,deviation\nup,0,0\n").contains("'ccw' or 'cw'"));
        assert!(err("direction,angle,deviation\nccw,0,0\n").contains("at least 8"));
        let short: String = (0..20).map(|i| format!("ccw,{i},0\n")).collect();
        assert!(err(&format!("direction,angle,deviation\n{short}")).contains("at least 90°"));
        let r = CircularOptions {
            radius_mm: -1.0,
            pitch_mm: None,
        };
        let s = parse_trace("direction,angle,deviation\nccw,0,0\n", p).expect("parses");
        assert!(evaluate(&s, &r, p).is_err());
    }
}
