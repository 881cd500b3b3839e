//! Goodness of fit: whether an identification's residuals can come from its model at the
//! stated noise (see docs/identification-and-correction.md, *A misfit is refused*). Every
//! identification in twinmill runs its result through this one check — the 0°/180° faces,
//! general identification from faces and balls, the hexapod's double-ball-bar lengths — and
//! a new one (laser readings, ball-bar circles) plugs in the same way: it states each
//! residual's standard uncertainty, whitens, and hands over the residuals, the whitened
//! Jacobian of all its unknowns and which rows are which file, circle or face.
//!
//! **The statistic.** With whitened residuals `r` (residual over its stated σ) at the
//! solution and the whitened Jacobian `J` of every unknown, the data fit the model when
//! `χ² = |r − P·r|²` — the residual left after the best linear fit over *all* unknowns,
//! `P` the projection onto `J`'s column space — is a plausible draw from χ² with
//! `m − rank J` degrees of freedom. The projection matters where an identification holds
//! an undetermined direction at its prior: that direction does not fit the data, and a
//! realistic value of it must not read as a misfit. Rank is decided on `J`'s own singular
//! values ([`RANK_EPS`]), never on `JᵀJ`'s.
//!
//! **The threshold.** A fit is refused when the upper-tail probability of its χ² is below
//! [`REFUSE_P`] = 1e-6: a fit with the model right and the noise as stated is refused once in
//! a million. The lower tail is not refused: a χ² far below its degrees of freedom means a
//! stated σ larger than the noise (uncertainties pessimistic), not a wrong model.
//!
//! **Each part on its own.** The rows of one file, circle or face are a *part*. Its
//! statistic is how much the whole χ² drops when the part is left out and the rest refitted
//! (the mean-shift outlier test of a group of rows): `eᵀ(I − U_pU_pᵀ)⁺e`, `e` the part's
//! share of the residual left and `U_p` its rows of an orthonormal basis of `J`'s columns.
//! Under the model it is exactly χ² with the part's row count less the directions only it
//! informs; it names the culprit where the shares of the residual would not (a wrong face
//! pulls the fit, and the fit spreads its residual over the others). A part is out of line
//! when its probability is below [`REFUSE_P`]` / parts` (Bonferroni: the chance that any
//! part of a good fit is flagged stays below 1e-6). The fit is refused when the whole χ² or
//! any part fails. A misfit spreads over the fit (two swapped circles pull the parameters,
//! and every circle then misses), so the refusal names the parts it is *blamed* on: left
//! out one after another, each time the one whose removal lowers χ² most against its limit,
//! until the rest fits (at most six named; then any other part out of line).
//!
//! **Scans.** A face fitted in a scan is a part of another kind: its points' RMS distance
//! from the fitted plane against the scanner's stated range noise ([`face_rms_check`]).
//! Range noise along the viewing ray is at most σ across the face (less off normal
//! incidence); views merged with a per-view misregistration add their offsets, bounded
//! from the stated registration σ. Refused at the same probability.
//!
//! **Invariant:** knows nothing of machines, files or units beyond the σ it is given; the
//! same residuals give the same verdict.

use crate::math::Real;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;
use std::ops::Range;

/// A fit whose χ² (or one of whose parts) has an upper-tail probability below this is
/// refused: one good fit in a million is refused; a misfit by a few standard deviations per
/// residual over hundreds of residuals is far beyond it.
pub const REFUSE_P: Real = 1e-6;

/// Relative singular value of the whitened, column-scaled Jacobian below which a direction
/// is numerically null for the goodness of fit (not fitted at all): far above the rounding
/// of a direct SVD (1e-16) and of the models' derivatives, far below any direction a
/// measurement sees.
pub const RANK_EPS: Real = 1e-9;

/// Largest count of parts named in a refusal; the rest are counted.
const NAMED_PARTS: usize = 6;

// ---------------------------------------------------------------------------------------
// The χ² distribution.

/// ln Γ(x) for x > 0 (Lanczos, g = 7, nine terms: relative error below 1e-15).
pub fn ln_gamma(x: Real) -> Real {
    const G: Real = 7.0;
    const C: [Real; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection: Γ(x)Γ(1 − x) = π / sin(πx).
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + G + 0.5;
    for (k, c) in C.iter().enumerate().skip(1) {
        a += c / (x + k as Real);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Iterations of the series and the continued fraction at most: both converge in a few
/// times √a terms; 1e5 covers a up to 1e8.
const MAX_TERMS: usize = 100_000;

/// The regularized upper incomplete gamma function `Q(a, x) = Γ(a, x)/Γ(a)` for `a > 0`,
/// `x ≥ 0`: by its series where `x < a + 1` (as `1 − P`), by its continued fraction
/// (modified Lentz) elsewhere, so a small tail is computed directly, to relative accuracy.
pub fn gamma_q(a: Real, x: Real) -> Real {
    if x.is_nan() || a.is_nan() || a <= 0.0 {
        return Real::NAN;
    }
    if x <= 0.0 {
        return 1.0;
    }
    if x == Real::INFINITY {
        return 0.0;
    }
    let front = (a * x.ln() - x - ln_gamma(a)).exp();
    if x < a + 1.0 {
        // P(a, x) = e^{−x} x^a / Γ(a + 1) · Σ x^n / ((a + 1)…(a + n)).
        let (mut term, mut sum, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..MAX_TERMS {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (1.0 - sum * front).clamp(0.0, 1.0)
    } else {
        // Q(a, x) = e^{−x} x^a / Γ(a) · 1/(x + 1 − a − 1·(1 − a)/(x + 3 − a − …)).
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..MAX_TERMS {
            let an = -(i as Real) * (i as Real - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-16 {
                break;
            }
        }
        (front * h).clamp(0.0, 1.0)
    }
}

/// The upper-tail probability of χ² with `dof` degrees of freedom (any `dof > 0`, not only
/// whole numbers): `P(X ≥ chi2) = Q(dof/2, chi2/2)`.
pub fn chi2_upper_tail(chi2: Real, dof: Real) -> Real {
    gamma_q(0.5 * dof, 0.5 * chi2.max(0.0))
}

/// The χ² value with upper-tail probability `p` at `dof` degrees of freedom (the inverse of
/// [`chi2_upper_tail`], by bisection to 1e-12 relative).
pub fn chi2_upper_quantile(p: Real, dof: Real) -> Real {
    if !(p > 0.0 && p < 1.0 && dof > 0.0) {
        return Real::NAN;
    }
    let (mut lo, mut hi) = (0.0, dof.max(1.0));
    while chi2_upper_tail(hi, dof) > p {
        lo = hi;
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if chi2_upper_tail(mid, dof) > p {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo <= 1e-12 * hi {
            break;
        }
    }
    0.5 * (lo + hi)
}

// ---------------------------------------------------------------------------------------
// Rank.

/// How clearly an identification's rank was decided: the singular values either side of
/// its cut, and the gap between them as a ratio. A ratio near 1 means another measurement
/// of the same plan may decide the rank the other way; the numerically null directions
/// of a direct SVD lie near 1e-16 of the largest, so a rank decided on `J` shows a wide gap
/// where one decided on `JᵀJ` (whose spectrum is the square) shows a narrow one.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RankMargin {
    /// The cut the singular values were compared with (their units).
    pub cut: Real,
    /// The smallest singular value kept (`None`: none kept).
    pub last_kept: Option<Real>,
    /// The largest singular value dropped (`None`: none dropped).
    pub first_dropped: Option<Real>,
    /// `last_kept / first_dropped`; with nothing dropped `last_kept / cut`, with nothing
    /// kept `cut / first_dropped` (infinite for an exact zero).
    pub ratio: Real,
}

impl RankMargin {
    /// The margin of keeping the first `rank` of the singular values `sv` (descending) at
    /// the cut `cut`.
    pub fn new(sv: &[Real], rank: usize, cut: Real) -> Self {
        let last_kept = rank.checked_sub(1).and_then(|k| sv.get(k)).copied();
        let first_dropped = sv.get(rank).copied();
        let over = |a: Real, b: Real| if b > 0.0 { a / b } else { Real::INFINITY };
        let ratio = match (last_kept, first_dropped) {
            (Some(k), Some(d)) => over(k, d),
            (Some(k), None) => over(k, cut),
            (None, Some(d)) => over(cut, d),
            (None, None) => Real::NAN,
        };
        RankMargin {
            cut,
            last_kept,
            first_dropped,
            ratio,
        }
    }

    /// The margin in words: `gap ×3.2e8 (kept ≥ 2.1e-1, dropped ≤ 6.6e-10; cut 1e-7)`.
    pub fn describe(&self) -> String {
        let f = |v: Option<Real>| v.map_or("none".to_string(), |x| format!("{x:.2e}"));
        format!(
            "gap ×{:.2e} (last kept {}, first dropped {}; cut {:.1e})",
            self.ratio,
            f(self.last_kept),
            f(self.first_dropped),
            self.cut
        )
    }
}

// ---------------------------------------------------------------------------------------
// The verdict.

/// One file, circle or face of a fit, tested on its own.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PartFit {
    /// Its name (a file, `circle 3 (plate-3.csv)`, a face).
    pub name: String,
    /// What was tested: `chi2` (its share of the residual χ²) or `rms` (a face's points
    /// against the scanner's noise).
    pub kind: String,
    /// The statistic: the part's χ², or its RMS (mm).
    pub value: Real,
    /// What the stated noise leads one to expect: the mean of its χ² (the degrees of
    /// freedom it carries), or the RMS of the noise alone (mm).
    pub expected: Real,
    /// The largest value accepted (at probability [`REFUSE_P`]` / parts`).
    pub limit: Real,
    /// Upper-tail probability of the statistic under the model (for `rms`, a bound).
    pub p_value: Real,
    /// Whether it is out of line (beyond `limit`).
    pub out_of_line: bool,
}

/// The goodness of fit of one identification: the whole χ² and each part's.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FitCheck {
    /// What the statistic is of, in words (`bar lengths at σ 0.5 µm`).
    pub statistic: String,
    /// The whole χ² of the whitened residuals after the best fit over all unknowns;
    /// `None` when the unknowns match the measurements exactly (no residual to test).
    pub chi2: Option<Real>,
    /// Its degrees of freedom (residuals less the rank of the Jacobian).
    pub dof: Real,
    /// Upper-tail probability of `chi2`.
    pub p_value: Option<Real>,
    /// The largest χ² accepted (upper-tail probability [`REFUSE_P`]).
    pub limit: Option<Real>,
    /// Each part on its own.
    pub parts: Vec<PartFit>,
    /// Whether the data can come from the model at the stated noise.
    pub fits: bool,
    /// Set when a misfit was accepted on request (`--accept-misfit`): the results stand
    /// on a model the data contradict.
    pub misfit_accepted: bool,
    /// The parts the misfit is blamed on, worst first: left out one after another, each
    /// the one whose removal lowers χ² most, until the rest fits (at most six); a group of
    /// several when each of them alone would explain the rest (the data cannot tell which).
    /// Empty when the data fit.
    pub blame: Vec<Vec<String>>,
}

/// A fit refused: the one-line account.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct Misfit(pub String);

/// The whole-fit statistic from whitened residuals and Jacobian (see the module
/// documentation): the residual left by the best linear fit over every unknown, its
/// degrees of freedom, and per part (rows `range`) how much the χ² drops without it.
pub fn least_squares_check(
    statistic: &str,
    residuals: &DVector<Real>,
    jacobian: &DMatrix<Real>,
    parts: &[(String, Range<usize>)],
) -> FitCheck {
    let m = residuals.len();
    // Columns scaled to unit norm: the rank is a property of the directions, not of the
    // units the unknowns happen to be in.
    let mut j = jacobian.clone();
    for mut c in j.column_iter_mut() {
        let n = c.norm();
        if n > 0.0 {
            c /= n;
        }
    }
    let (u, rank) = column_space(&j);
    let left = residuals - &u * (u.transpose() * residuals);
    let chi2 = left.norm_squared();
    let dof = m.saturating_sub(rank) as Real;
    let p_limit = REFUSE_P / parts.len().max(1) as Real;
    let part_fits = parts
        .iter()
        .map(|(name, range)| {
            let (value, k) = deletion_chi2(&left, &u, range.clone());
            let (p, limit) = if k > 0 {
                let k = k as Real;
                (chi2_upper_tail(value, k), chi2_upper_quantile(p_limit, k))
            } else {
                (1.0, Real::INFINITY)
            };
            PartFit {
                name: name.clone(),
                kind: "chi2".into(),
                value,
                expected: k as Real,
                limit,
                p_value: p,
                out_of_line: p < p_limit,
            }
        })
        .collect();
    let mut check = FitCheck::new(statistic, Some(chi2), dof, part_fits);
    if !check.fits {
        check.blame = blame(&j, residuals, parts);
    }
    check
}

/// An orthonormal basis of the columns of `j` (its left singular vectors above
/// [`RANK_EPS`] of the largest singular value) and the rank.
fn column_space(j: &DMatrix<Real>) -> (DMatrix<Real>, usize) {
    let m = j.nrows();
    if j.ncols() == 0 || m == 0 {
        return (DMatrix::zeros(m, 0), 0);
    }
    let svd = j.clone().svd(true, false);
    let smax = svd.singular_values.max();
    let keep: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&k| svd.singular_values[k] > smax * RANK_EPS && smax > 0.0)
        .collect();
    let full = svd.u.unwrap_or_else(|| DMatrix::zeros(m, 0));
    let u = DMatrix::from_fn(m, keep.len(), |r, c| full[(r, keep[c])]);
    (u, keep.len())
}

/// The parts a misfit is blamed on, worst first: leave out the part whose removal lowers
/// χ² most against its limit, refit (linearly) without it, and repeat until the rest fits
/// or [`NAMED_PARTS`] are named. A misfit spreads over the fit (two swapped circles pull
/// the parameters, and every circle then misses), so one part's drop alone would name the
/// first culprit and then any of its victims; removing culprits one by one names the
/// second culprit next.
///
/// When several parts would each, left out alone, leave a fit the noise explains, the data
/// cannot tell which is wrong: they are named together as the last group.
fn blame(
    j: &DMatrix<Real>,
    r: &DVector<Real>,
    parts: &[(String, Range<usize>)],
) -> Vec<Vec<String>> {
    let p_limit = REFUSE_P / parts.len().max(1) as Real;
    let mut active = vec![true; parts.len()];
    let mut out = Vec::new();
    while out.len() < NAMED_PARTS {
        let rows: Vec<usize> = parts
            .iter()
            .zip(&active)
            .filter(|(_, a)| **a)
            .flat_map(|((_, range), _)| range.clone())
            .collect();
        if rows.is_empty() {
            break;
        }
        let jr = j.select_rows(rows.iter());
        let rr = r.select_rows(rows.iter());
        let (u, rank) = column_space(&jr);
        let left = &rr - &u * (u.transpose() * &rr);
        let chi2 = left.norm_squared();
        let dof = rows.len().saturating_sub(rank) as Real;
        if dof > 0.0 && chi2_upper_tail(chi2, dof) >= REFUSE_P {
            break;
        }
        let mut best: Option<(usize, Real)> = None;
        let mut explains = Vec::new();
        let mut offset = 0;
        for (k, (name, range)) in parts.iter().enumerate() {
            if !active[k] {
                continue;
            }
            let n = range.len();
            let (value, d) = deletion_chi2(&left, &u, offset..offset + n);
            offset += n;
            if d == 0 {
                continue;
            }
            let rest = dof - d as Real;
            if rest > 0.0 && chi2_upper_tail(chi2 - value, rest) >= REFUSE_P {
                explains.push(name.clone());
            }
            let score = value / chi2_upper_quantile(p_limit, d as Real);
            if score > 1.0 && best.is_none_or(|(_, s)| score > s) {
                best = Some((k, score));
            }
        }
        if explains.len() > 1 {
            out.push(explains);
            break;
        }
        let Some((k, _)) = best else { break };
        out.push(vec![parts[k].0.clone()]);
        active[k] = false;
    }
    out
}

/// How much the whole χ² drops when the rows `rows` are left out and the rest refitted
/// (the mean-shift outlier statistic of a group of rows), and its degrees of freedom. With
/// `e` the rows' share of the residual left (`left`) and `U_p` their rows of the column
/// space's orthonormal basis `u`, it is `eᵀ(I − U_pU_pᵀ)⁺e`: from the SVD `U_p = Q·Σ·Wᵀ`,
/// `|e|² + Σ σ²/(1 − σ²)·(qᵀe)²` over the directions the other rows also see, the
/// directions only these rows see (`σ = 1`) taking none of the freedom. Under the model it
/// is exactly χ² with `rows − #(σ = 1)` degrees of freedom.
fn deletion_chi2(left: &DVector<Real>, u: &DMatrix<Real>, rows: Range<usize>) -> (Real, usize) {
    let n = rows.len();
    let e = left.rows(rows.start, n).into_owned();
    let mut value = e.norm_squared();
    let mut alone = 0;
    if u.ncols() > 0 && n > 0 {
        let up = u.rows(rows.start, n).into_owned();
        let svd = up.svd(true, false);
        if let Some(q) = svd.u {
            for (j, &sv) in svd.singular_values.iter().enumerate() {
                let c = q.column(j).dot(&e);
                let free = 1.0 - sv * sv;
                if free <= ALONE_EPS {
                    alone += 1;
                    value -= c * c;
                } else {
                    value += sv * sv / free * c * c;
                }
            }
        }
    }
    (value.max(0.0), n.saturating_sub(alone))
}

/// `1 − σ²` below which a direction of a part's rows of the column space is seen by those
/// rows alone (an unknown only they inform, such as a circle's own table ball): rounding of
/// a direct SVD is near 1e-16.
const ALONE_EPS: Real = 1e-9;

/// What the scanner states about its points: range noise, how many views are merged and
/// each view's registration error (see [`face_rms_check`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanNoise {
    /// Range noise σ along the viewing ray (mm).
    pub sigma_mm: Real,
    /// Views merged into the cloud.
    pub views: usize,
    /// A view's registration error along a face's normal: translation σ (mm).
    pub translation_sigma_mm: Real,
    /// Rotation σ of a view's registration (rad), acting over the lever from the view's
    /// centre.
    pub rotation_sigma_rad: Real,
    /// The lever (mm): largest distance of a face point from the centre the views turn
    /// about.
    pub lever_mm: Real,
}

/// The twin's own accuracy (mm): a face or length computed by the twin is exact to this —
/// the sweep's bound on rotary moves and concave profile arcs (0.1 µm). Residuals below it
/// are not evidence against a model, whatever σ a noise-free measurement claims.
pub const MODEL_ACCURACY_MM: Real = 1e-4;

/// A face's points against the scanner's noise: with `n` points used at RMS distance
/// `rms_mm` (`√(Σd²/n)`) from their fitted plane (3 parameters), and the variance inflation
/// `inflation` (f ≥ 1) block averaging found for correlated residuals, `Σd²/(f·σ²)` is
/// tested against χ² with `ν = (n − 3)/f` degrees of freedom (σ is the noise along the ray,
/// at most σ across the face; correlated noise counted as fewer independent points). For a
/// cloud merged from `V ≥ 2` views, the views' offsets about their mean add at most
/// `Σ o_v²` with `o_v ~ N(0, σ_v²)`, `σ_v² = σ_t² + (σ_r·lever)²`: its χ²(V) quantile is
/// allowed on top. Each term at half the probability, so the limit holds at `p_limit`
/// (union bound); the reported probability is the noise term's after the views' allowance.
pub fn face_rms_check(
    name: &str,
    rms_mm: Real,
    n: usize,
    inflation: Real,
    noise: &ScanNoise,
    p_limit: Real,
) -> PartFit {
    let sigma = noise.sigma_mm.hypot(MODEL_ACCURACY_MM);
    let f = inflation.max(1.0);
    let nf = n.max(1) as Real;
    let nu = (n.saturating_sub(3) as Real / f).max(1.0);
    let views = if noise.views >= 2 {
        let sv2 = noise.translation_sigma_mm.powi(2)
            + (noise.rotation_sigma_rad * noise.lever_mm).powi(2);
        sv2 * chi2_upper_quantile(0.5 * p_limit, noise.views as Real)
    } else {
        0.0
    };
    let noise_q = f * sigma * sigma * chi2_upper_quantile(0.5 * p_limit, nu) / nf;
    let limit = (noise_q + views).sqrt();
    let excess = (rms_mm * rms_mm - views).max(0.0);
    let p = chi2_upper_tail(nf * excess / (f * sigma * sigma), nu);
    PartFit {
        name: name.to_string(),
        kind: "rms".into(),
        value: rms_mm,
        expected: sigma,
        limit,
        p_value: p,
        // A NaN RMS (no points) is out of line too.
        out_of_line: rms_mm.is_nan() || rms_mm > limit,
    }
}

impl FitCheck {
    /// A check from the whole χ² (if any) and the parts: the fit is refused if the whole
    /// χ² has probability below [`REFUSE_P`] or any part is out of line.
    pub fn new(statistic: &str, chi2: Option<Real>, dof: Real, parts: Vec<PartFit>) -> Self {
        let (p_value, limit) = match chi2 {
            Some(c) if dof > 0.0 => (
                Some(chi2_upper_tail(c, dof)),
                Some(chi2_upper_quantile(REFUSE_P, dof)),
            ),
            // No degrees of freedom: the residual should be rounding.
            Some(_) => (Some(1.0), None),
            None => (None, None),
        };
        let whole = p_value.is_none_or(|p| p >= REFUSE_P);
        let fits = whole && parts.iter().all(|p| !p.out_of_line);
        FitCheck {
            statistic: statistic.to_string(),
            chi2,
            dof,
            p_value,
            limit,
            parts,
            fits,
            misfit_accepted: false,
            blame: Vec::new(),
        }
    }

    /// Joins another check's parts and statistic into this one (a fit tested two ways:
    /// faces against the scanner and against each other); the whole χ² stays this one's.
    pub fn add_parts(&mut self, more: Vec<PartFit>) {
        self.fits &= more.iter().all(|p| !p.out_of_line);
        self.parts.extend(more);
    }

    /// Renames the parts `name` maps to a new name (a circle to its file), in the parts and
    /// in the blame alike.
    pub fn rename_parts(&mut self, name: impl Fn(&str) -> Option<String>) {
        for p in &mut self.parts {
            if let Some(n) = name(&p.name) {
                p.name = n;
            }
        }
        for b in self.blame.iter_mut().flatten() {
            if let Some(n) = name(b) {
                *b = n;
            }
        }
    }

    /// The parts a misfit is blamed on ([`FitCheck::blame`]) with the faces out of line
    /// against the scanner; without a blame, the parts out of line, or — when the whole
    /// fails and none alone does — the three with the largest statistic over its
    /// expectation.
    pub fn culprits(&self) -> Vec<&PartFit> {
        if !self.blame.is_empty() {
            // The blamed, worst first, then the faces out of line against the scanner (a
            // test of their own); the other parts' χ² drops are the blamed ones' pull.
            let mut out: Vec<&PartFit> = self
                .blame
                .iter()
                .flatten()
                .filter_map(|b| self.parts.iter().find(|p| &p.name == b))
                .collect();
            let mut rest: Vec<&PartFit> = self
                .parts
                .iter()
                .filter(|p| {
                    p.out_of_line
                        && p.kind == "rms"
                        && !self.blame.iter().flatten().any(|b| *b == p.name)
                })
                .collect();
            rest.sort_by(|a, b| excess(b).total_cmp(&excess(a)));
            out.extend(rest);
            return out;
        }
        let mut out: Vec<&PartFit> = self.parts.iter().filter(|p| p.out_of_line).collect();
        if out.is_empty() {
            out = self.parts.iter().collect();
            out.sort_by(|a, b| ratio(b).total_cmp(&ratio(a)));
            out.truncate(3);
        } else {
            out.sort_by(|a, b| excess(b).total_cmp(&excess(a)));
        }
        out
    }

    /// The account in one line: the statistic, its expected range, the parts out of line.
    pub fn describe(&self) -> String {
        let mut s = match (self.chi2, self.limit) {
            (Some(c), Some(l)) => format!(
                "χ² {} for {} dof (p {:.1e}; at the stated noise χ² stays below {})",
                sig(c),
                dof_text(self.dof),
                self.p_value.unwrap_or(Real::NAN),
                sig(l)
            ),
            (Some(c), None) => format!("χ² {} with no degree of freedom", sig(c)),
            _ => "no residual beyond the faces' own".to_string(),
        };
        s.push_str(&format!(" of the {}", self.statistic));
        let culprits = self.culprits();
        if !culprits.is_empty() && !self.fits {
            let mut named: Vec<String> = Vec::new();
            let mut shown = 0;
            for group in &self.blame {
                let members: Vec<String> = group
                    .iter()
                    .filter_map(|b| culprits.iter().find(|p| &p.name == b))
                    .map(|p| describe_part(p))
                    .collect();
                shown += members.len();
                if members.len() > 1 {
                    named.push(format!(
                        "one of {} (each alone explains the misfit)",
                        members.join(", ")
                    ));
                } else {
                    named.extend(members);
                }
            }
            for p in culprits
                .iter()
                .skip(shown)
                .take(NAMED_PARTS.saturating_sub(shown))
            {
                named.push(describe_part(p));
                shown += 1;
            }
            let more = culprits.len().saturating_sub(shown);
            s.push_str(
                if !self.blame.is_empty() || self.parts.iter().any(|p| p.out_of_line) {
                    "; out of line, worst first: "
                } else {
                    "; largest: "
                },
            );
            s.push_str(&named.join(", "));
            if more > 0 {
                s.push_str(&format!(" and {more} more"));
            }
        }
        s
    }

    /// `Ok` if the data fit, or if `accept` (then [`FitCheck::misfit_accepted`] is set);
    /// otherwise the refusal in one line, saying how to accept it anyway.
    pub fn enforce(&mut self, what: &str, accept: bool) -> Result<(), Misfit> {
        if self.fits {
            return Ok(());
        }
        if accept {
            self.misfit_accepted = true;
            return Ok(());
        }
        Err(Misfit(format!(
            "{what}: the data cannot come from the model at the stated noise, refused: {} \
             (--accept-misfit takes it anyway)",
            self.describe()
        )))
    }

    /// The first line of a report whose misfit was accepted, or `None`.
    pub fn accepted_line(&self) -> Option<String> {
        self.misfit_accepted.then(|| {
            format!(
                "MISFIT ACCEPTED (--accept-misfit): the data do not fit the model at the stated noise: {}",
                self.describe()
            )
        })
    }
}

/// How far beyond its limit a part is (its statistic over its limit, −log p where the
/// limit is not finite).
fn excess(p: &PartFit) -> Real {
    if p.limit.is_finite() && p.limit > 0.0 {
        p.value / p.limit
    } else {
        -p.p_value.ln()
    }
}

fn ratio(p: &PartFit) -> Real {
    if p.expected > 0.0 {
        p.value / p.expected
    } else {
        p.value
    }
}

fn describe_part(p: &PartFit) -> String {
    if p.kind == "rms" {
        format!(
            "{} RMS {:.4} mm (noise σ {:.4} mm allows ≤ {:.4})",
            p.name, p.value, p.expected, p.limit
        )
    } else {
        format!(
            "{} (leaving it out lowers χ² by {}, {} expected)",
            p.name,
            sig(p.value),
            dof_text(p.expected)
        )
    }
}

/// Degrees of freedom: a whole number as one, a fraction to four figures.
fn dof_text(dof: Real) -> String {
    if dof.fract() == 0.0 && dof.abs() < 1e15 {
        format!("{dof:.0}")
    } else {
        sig(dof)
    }
}

/// A number to four significant figures, plainly where that reads well.
fn sig(x: Real) -> String {
    if !x.is_finite() {
        return format!("{x}");
    }
    let a = x.abs();
    if a == 0.0 || (0.01..1e6).contains(&a) {
        let decimals = if a == 0.0 {
            0
        } else {
            (3 - a.log10().floor() as i32).clamp(0, 6) as usize
        };
        format!("{x:.decimals$}")
    } else {
        format!("{x:.3e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::CounterRng;

    /// Exact upper tail for even degrees of freedom `2k`: `e^{−x/2} Σ_{i<k} (x/2)^i / i!`
    /// (the Poisson sum), an oracle independent of the incomplete gamma code.
    fn even_tail(x: Real, k: usize) -> Real {
        let h = x / 2.0;
        let (mut term, mut sum) = (1.0, 0.0);
        for i in 0..k {
            if i > 0 {
                term *= h / i as Real;
            }
            sum += term;
        }
        (-h).exp() * sum
    }

    #[test]
    fn the_upper_tail_matches_the_poisson_sum_for_even_dof() {
        for k in [1usize, 2, 5, 20, 60] {
            for x in [
                0.1,
                1.0,
                5.0,
                2.0 * k as Real,
                4.0 * k as Real + 30.0,
                200.0,
            ] {
                let want = even_tail(x, k);
                let got = chi2_upper_tail(x, 2.0 * k as Real);
                assert!(
                    (got - want).abs() <= 1e-12 * want.max(1e-300) + 1e-15,
                    "dof {}, χ² {x}: {got} vs {want}",
                    2 * k
                );
            }
        }
    }

    #[test]
    fn quantiles_match_the_tables() {
        // Abramowitz & Stegun table 26.8 / NIST: (p, dof, χ²).
        let table = [
            (0.05, 1.0, 3.841_459),
            (0.001, 1.0, 10.827_566),
            (0.01, 5.0, 15.086_272),
            (0.001, 15.0, 37.697_30),
            (0.05, 100.0, 124.342_11),
            (0.001, 100.0, 149.449_2),
            // χ²(1) at 1e-6: z = 4.891 638 → z².
            (1e-6, 1.0, 4.891_638_5 * 4.891_638_5),
            // χ²(2) at 1e-6: −2 ln 1e-6.
            (1e-6, 2.0, 27.631_021),
        ];
        for (p, dof, want) in table {
            let got = chi2_upper_quantile(p, dof);
            assert!(
                (got - want).abs() < 2e-6 * want,
                "p {p}, dof {dof}: {got} vs {want}"
            );
            assert!((chi2_upper_tail(want, dof) / p - 1.0).abs() < 1e-4);
        }
        // ln Γ at half-integers and integers.
        assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-14);
        assert!((ln_gamma(10.0) - 362_880f64.ln()).abs() < 1e-12);
    }

    /// Ordinary least squares of a line `a + b·x` by its normal equations (the test's own
    /// oracle): the residual sum of squares.
    fn line_rss(xs: &[Real], ys: &[Real]) -> Real {
        let n = xs.len() as Real;
        let (sx, sy) = (xs.iter().sum::<Real>(), ys.iter().sum::<Real>());
        let sxx: Real = xs.iter().map(|x| x * x).sum();
        let sxy: Real = xs.iter().zip(ys).map(|(x, y)| x * y).sum();
        let b = (n * sxy - sx * sy) / (n * sxx - sx * sx);
        let a = (sy - b * sx) / n;
        xs.iter()
            .zip(ys)
            .map(|(x, y)| (y - a - b * x).powi(2))
            .sum()
    }

    /// A straight line fitted to noisy samples: the check's χ² is the classical residual
    /// sum of squares with n − 2 dof, and a part's statistic is what the sum drops by when
    /// the line is fitted without it.
    #[test]
    fn a_line_fit_gives_the_classical_residual_and_each_part_its_deletion() {
        let xs: Vec<Real> = (0..12).map(|i| i as Real).collect();
        let rng = CounterRng::new(5);
        let ys: Vec<Real> = xs
            .iter()
            .enumerate()
            .map(|(i, x)| 2.0 + 0.5 * x + rng.normal(i as u64))
            .collect();
        // Residual at the prior (0, 0); the check refits.
        let r = DVector::from_iterator(12, ys.iter().map(|y| -y));
        let j = DMatrix::from_fn(12, 2, |i, c| if c == 0 { 1.0 } else { xs[i] });
        let parts = vec![
            ("first".to_string(), 0..4),
            ("second".to_string(), 4..9),
            ("third".to_string(), 9..12),
        ];
        let c = least_squares_check("samples", &r, &j, &parts);
        let rss = line_rss(&xs, &ys);
        assert!((c.chi2.expect("χ²") - rss).abs() < 1e-10, "{c:?} vs {rss}");
        assert_eq!(c.dof, 10.0);
        for (k, (_, rows)) in parts.iter().enumerate() {
            let keep: Vec<usize> = (0..12).filter(|i| !rows.contains(i)).collect();
            let without = line_rss(
                &keep.iter().map(|&i| xs[i]).collect::<Vec<_>>(),
                &keep.iter().map(|&i| ys[i]).collect::<Vec<_>>(),
            );
            assert!(
                (c.parts[k].value - (rss - without)).abs() < 1e-9,
                "part {k}: {} vs {}",
                c.parts[k].value,
                rss - without
            );
            assert_eq!(c.parts[k].expected, rows.len() as Real);
        }
        assert!(c.fits);
    }

    #[test]
    fn a_misfit_is_refused_naming_the_part() {
        // Three parts of 20 samples of a constant; the third is off by 10σ.
        let mut r = DVector::from_fn(60, |i, _| CounterRng::new(9).normal(i as u64));
        for i in 40..60 {
            r[i] += 10.0;
        }
        let j = DMatrix::from_element(60, 1, 1.0);
        let parts: Vec<(String, Range<usize>)> = (0..3)
            .map(|k| (format!("file-{k}.csv"), 20 * k..20 * k + 20))
            .collect();
        let mut c = least_squares_check("readings at σ 1", &r, &j, &parts);
        assert!(!c.fits);
        let culprits: Vec<&str> = c.culprits().iter().map(|p| p.name.as_str()).collect();
        assert_eq!(culprits[0], "file-2.csv");
        let e = c.enforce("calibrate", false).expect_err("refused");
        assert!(e.0.contains("file-2.csv") && e.0.contains("χ²"), "{e}");
        assert!(!e.0.contains('\n'));
        assert!(c.enforce("calibrate", true).is_ok() && c.misfit_accepted);
        assert!(c.accepted_line().is_some());
    }

    /// Two of five parts of a line's samples swapped in effect (one 8σ up, one 8σ down):
    /// every part misses once the fit is pulled, but the blame names the two, and only
    /// them; two parts of a constant that disagree are named together, since either alone
    /// explains the misfit.
    #[test]
    fn the_blame_names_the_culprits_not_their_victims() {
        let rng = CounterRng::new(31);
        let xs: Vec<Real> = (0..100).map(|i| i as Real * 0.1).collect();
        let mut r = DVector::from_fn(100, |i, _| rng.normal(i as u64));
        for i in 20..40 {
            r[i] += 8.0;
        }
        for i in 60..80 {
            r[i] -= 8.0;
        }
        let j = DMatrix::from_fn(100, 2, |i, c| if c == 0 { 1.0 } else { xs[i] });
        let parts: Vec<(String, Range<usize>)> = (0..5)
            .map(|k| (format!("part {k}"), 20 * k..20 * k + 20))
            .collect();
        let c = least_squares_check("samples", &r, &j, &parts);
        assert!(!c.fits);
        let mut blamed: Vec<&str> = c.blame.iter().flatten().map(String::as_str).collect();
        blamed.sort();
        assert_eq!(blamed, ["part 1", "part 3"], "{:?}", c.blame);
        let named: Vec<&str> = c.culprits().iter().map(|p| p.name.as_str()).collect();
        assert_eq!(named.len(), 2, "{named:?}");
        // A constant measured twice, the second 10σ off: either part may be the wrong one.
        let mut r = DVector::from_fn(20, |i, _| rng.normal(1000 + i as u64));
        for i in 10..20 {
            r[i] += 10.0;
        }
        let j = DMatrix::from_element(20, 1, 1.0);
        let two = vec![("a".to_string(), 0..10), ("b".to_string(), 10..20)];
        let c = least_squares_check("samples", &r, &j, &two);
        assert_eq!(c.blame, vec![vec!["a".to_string(), "b".to_string()]]);
        assert!(c.describe().contains("one of a"), "{}", c.describe());
    }

    /// The refusal threshold in closed form: a line through four samples leaves 2 dof, whose
    /// χ² tail is `e^{−χ²/2}`, so the limit is `−2 ln 1e-6` = 27.631; each of two parts (its
    /// two rows see both of the line's directions, so 2 dof each) is held at `−2 ln(1e-6/2)`.
    /// A residual orthogonal to the line, scaled to χ² 27.0, fits; scaled to 28.5, refused.
    #[test]
    fn the_threshold_is_one_in_a_million_in_closed_form() {
        let j = DMatrix::from_fn(4, 2, |i, c| if c == 0 { 1.0 } else { i as Real });
        // Orthogonal to 1 and x = 0..3: (1, −1, −1, 1), norm 2.
        let v = DVector::from_vec(vec![0.5, -0.5, -0.5, 0.5]);
        let parts = vec![("a".to_string(), 0..2), ("b".to_string(), 2..4)];
        let limit = -2.0 * (1e-6 as Real).ln();
        let part_limit = -2.0 * (0.5e-6 as Real).ln();
        for (chi2, fits) in [(27.0 as Real, true), (28.5, false)] {
            let r = &v * chi2.sqrt() + &j * DVector::from_vec(vec![3.0, -0.7]);
            let c = least_squares_check("x", &r, &j, &parts);
            assert!((c.chi2.expect("χ²") - chi2).abs() < 1e-9, "{c:?}");
            assert_eq!(c.dof, 2.0);
            let l = c.limit.expect("limit");
            assert!((l - limit).abs() < 1e-6 * limit, "limit {l} vs {limit}");
            let p = c.p_value.expect("p");
            assert!((p / (-chi2 / 2.0).exp() - 1.0).abs() < 1e-9, "p {p}");
            assert_eq!(c.fits, fits, "χ² {chi2}: {}", c.describe());
            for part in &c.parts {
                // Left out, the other two rows fit a line exactly: χ² drops by all of it.
                assert!((part.value - chi2).abs() < 1e-9, "{part:?}");
                assert_eq!(part.expected, 2.0);
                assert!(
                    (part.limit - part_limit).abs() < 1e-6 * part_limit,
                    "{part:?} vs {part_limit}"
                );
            }
        }
    }

    /// The χ² quantile by bisection on the Poisson sum (even dof only): the test's own.
    fn even_quantile(p: Real, dof: usize) -> Real {
        let (mut lo, mut hi) = (0.0, 10_000.0);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if even_tail(mid, dof / 2) > p {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// The blame, against a brute force of the test's own: refit the line by its normal
    /// equations without each part still in, leave out the one whose removal lowers the
    /// residual sum most against its limit (Poisson-sum quantile at 1e-6 / parts), and
    /// repeat until the rest fits, or until several parts would each, left out alone,
    /// leave a rest that fits (named together). Two culprits, one at the end of the range
    /// (where it tilts the line and every other part then misses): the blame is the brute
    /// force's, step for step.
    #[test]
    fn the_blame_is_the_greedy_leave_one_out_refit() {
        let rng = CounterRng::new(41);
        let xs: Vec<Real> = (0..60).map(|i| i as Real * 0.1).collect();
        let mut ys: Vec<Real> = (0..60).map(|i| rng.normal(i as u64)).collect();
        for y in &mut ys[10..20] {
            *y -= 6.0;
        }
        for y in &mut ys[50..60] {
            *y += 5.0;
        }
        let parts: Vec<(String, Range<usize>)> = (0..6)
            .map(|k| (format!("part {k}"), 10 * k..10 * k + 10))
            .collect();
        let r = DVector::from_vec(ys.iter().map(|y| -y).collect());
        let j = DMatrix::from_fn(60, 2, |i, c| if c == 0 { 1.0 } else { xs[i] });
        let c = least_squares_check("samples", &r, &j, &parts);
        assert!(!c.fits);
        // The oracle.
        let p_limit = 1e-6 / parts.len() as Real;
        let rss_of = |active: &[bool]| {
            let rows: Vec<usize> = parts
                .iter()
                .zip(active)
                .filter(|(_, a)| **a)
                .flat_map(|((_, q), _)| q.clone())
                .collect();
            let (x, y): (Vec<Real>, Vec<Real>) = rows.iter().map(|&i| (xs[i], ys[i])).unzip();
            (line_rss(&x, &y), rows.len())
        };
        let mut active = vec![true; parts.len()];
        let mut want = Vec::new();
        loop {
            let (rss, n) = rss_of(&active);
            if even_tail(rss, (n - 2) / 2) >= 1e-6 {
                break;
            }
            // Parts each of which, left out alone, leaves a rest that fits: the data cannot
            // tell which is wrong, and they are named together.
            let explains: Vec<String> = (0..parts.len())
                .filter(|&k| active[k])
                .filter(|&k| {
                    let mut without = active.clone();
                    without[k] = false;
                    let (rest, m) = rss_of(&without);
                    even_tail(rest, (m - 2) / 2) >= 1e-6
                })
                .map(|k| parts[k].0.clone())
                .collect();
            if explains.len() > 1 {
                want.push(explains);
                break;
            }
            let best = (0..parts.len())
                .filter(|&k| active[k])
                .map(|k| {
                    let mut without = active.clone();
                    without[k] = false;
                    let drop = rss - rss_of(&without).0;
                    (k, drop / even_quantile(p_limit, parts[k].1.len()))
                })
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .expect("a part");
            want.push(vec![parts[best.0].0.clone()]);
            active[best.0] = false;
        }
        let mut two: Vec<String> = want.iter().flatten().cloned().collect();
        two.sort();
        assert!(
            two.contains(&"part 1".to_string()),
            "the oracle names the culprit"
        );
        assert_eq!(c.blame, want, "{}", c.describe());
        let named: Vec<&str> = c.culprits().iter().map(|p| p.name.as_str()).collect();
        assert_eq!(named.len(), two.len(), "{named:?}");
    }

    #[test]
    fn good_data_are_accepted_in_all_but_a_millionth_of_trials() {
        // 1,000 seeded trials of a 3-parameter fit to 50 samples in 5 parts.
        let j = DMatrix::from_fn(50, 3, |i, c| (i as Real * 0.1).powi(c as i32));
        let parts: Vec<(String, Range<usize>)> = (0..5)
            .map(|k| (format!("p{k}"), 10 * k..10 * k + 10))
            .collect();
        let mut refused = 0;
        for t in 0..1000u64 {
            let rng = CounterRng::new(t);
            let r = DVector::from_fn(50, |i, _| rng.normal(i as u64));
            if !least_squares_check("x", &r, &j, &parts).fits {
                refused += 1;
            }
        }
        assert!(refused <= 1, "{refused} of 1000 good fits refused");
    }

    #[test]
    fn a_face_is_judged_against_the_scanner_noise_and_its_views() {
        let one = ScanNoise {
            sigma_mm: 0.025,
            views: 1,
            translation_sigma_mm: 0.02,
            rotation_sigma_rad: 0.0,
            lever_mm: 0.0,
        };
        let ok = face_rms_check("A0", 0.024, 5000, 1.0, &one, REFUSE_P);
        assert!(!ok.out_of_line, "{ok:?}");
        // 24× the noise: out of line.
        let bad = face_rms_check("A0", 0.59, 5000, 1.0, &one, REFUSE_P);
        assert!(bad.out_of_line && bad.p_value < 1e-100, "{bad:?}");
        // 10 % above σ over 5,000 points is out of line for one view (the χ² quantile over
        // 4,997 dof at 1e-6 allows about 7 %), within three views' registration allowance.
        let above = face_rms_check("A0", 0.0275, 5000, 1.0, &one, REFUSE_P);
        assert!(above.out_of_line, "{above:?}");
        let three = ScanNoise { views: 3, ..one };
        assert!(!face_rms_check("A0", 0.0275, 5000, 1.0, &three, REFUSE_P).out_of_line);
    }
}
