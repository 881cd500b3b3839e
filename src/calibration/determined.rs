//! What a whitened Jacobian determines, for every identification: its parameters scaled by
//! their realistic magnitudes, the nuisance unknowns' columns projected out, the singular
//! values, the parameters identified on their own, the determined and undetermined
//! directions as named combinations, the borderline ones and the rank's margin; and the
//! values with σ of what is determined, at a solution with its covariance.
//!
//! A direction is *determined* when its standard uncertainty is below
//! [`DETERMINED_FRACTION`] of its realistic magnitude. A parameter lying in the determined
//! subspace is identified on its own; the rest of the subspace is reported as named
//! combinations (e.g. `gamma_AY + gamma_YX`); the complement is *not determined*, reported
//! in named form, and never given a value.
//!
//! **Invariant:** a parameter or combination is called determined only from the scaled
//! Jacobian's spectrum, never from solved values; knows nothing of machines, features or
//! instruments.

use crate::calibration::goodness::RankMargin;
use crate::math::Real;
use nalgebra::{DMatrix, DVector};

/// A direction of parameter space is determined when its standard uncertainty is below
/// this fraction of its realistic magnitude: it is then known to a tenth of what it could
/// plausibly be.
pub const DETERMINED_FRACTION: Real = 0.1;
/// A direction whose singular value lies within this factor of the threshold of
/// determination (either side) is *borderline*: its uncertainty is judged from the scan's
/// own residuals (σ, and its inflation for correlated noise by block averaging), which
/// another scan of the same part estimates differently — by about ±5 % on the designed
/// scenes, so a factor 1.25 is a few of those spreads — and another scan may decide it the
/// other way. Both `design` and `identify` name borderline directions.
pub const BORDERLINE_FACTOR: Real = 1.25;
/// A parameter counts as identified on its own when the part of its unit direction (in
/// scaled units) outside the determined subspace is below this: then the undetermined
/// directions, held at their prior, move its value by at most this fraction of their
/// realistic size.
pub const LEAKAGE: Real = 2e-3;
/// Coefficients of a named combination below this (relative to the largest, in scaled
/// units) are dropped from its name and value: they are second-order couplings.
pub const COMBINATION_CUTOFF: Real = 1e-2;

/// A linear combination of deviations, named like `gamma_AY + gamma_YX`.
#[derive(Clone, Debug, PartialEq)]
pub struct Combination {
    /// Readable name.
    pub name: String,
    /// Coefficients in physical units, one per solved parameter (the leading one is 1); the
    /// name omits terms below [`COMBINATION_CUTOFF`], the coefficients keep them.
    pub coefficients: Vec<Real>,
}

/// What the features determine.
#[derive(Clone, Debug, PartialEq)]
pub struct Identifiability {
    /// Parameter names, in solve order.
    pub parameters: Vec<String>,
    /// Singular values of the scaled, registration-free whitened Jacobian (descending).
    pub singular_values: Vec<Real>,
    /// Largest over smallest singular value (infinite if one is zero).
    pub condition_number: Real,
    /// Condition number within the determined subspace.
    pub condition_number_determined: Real,
    /// Dimension of the determined subspace.
    pub rank: usize,
    /// Parameters identified on their own.
    pub identified: Vec<String>,
    /// Determined combinations that are not single parameters.
    pub determined_combinations: Vec<Combination>,
    /// Directions not determined (named), held at their prior values.
    pub undetermined_combinations: Vec<Combination>,
    /// Directions whose singular value is within [`BORDERLINE_FACTOR`] of the threshold
    /// (named, with their singular values): determined or not, another scan may decide
    /// them the other way.
    pub borderline: Vec<(Combination, Real)>,
    /// Parameters not identified on their own (they may still enter a determined
    /// combination).
    pub not_identified: Vec<String>,
    /// What the registration absorbs: for each registration component, the deviations'
    /// combination it mimics (empty names when it absorbs nothing of them).
    pub registration_absorbs: Vec<String>,
    /// Parameters no feature depends on at all (no data): not identified.
    pub no_data: Vec<String>,
    /// Orthonormal basis (scaled units) of the determined subspace, columns.
    pub determined_basis: DMatrix<Real>,
    /// Per parameter, the leakage of its direction outside the determined subspace.
    pub leakage: Vec<Real>,
    /// How clearly the determined subspace is separated: the singular values either side
    /// of the threshold of determination.
    pub margin: RankMargin,
}

/// Projects the columns of `a` onto the orthogonal complement of the column space of `b`.
fn project_out(a: &DMatrix<Real>, b: &DMatrix<Real>) -> DMatrix<Real> {
    if b.ncols() == 0 {
        return a.clone();
    }
    let svd = b.clone().svd(true, false);
    let u = svd.u.expect("requested");
    let smax = svd.singular_values.max();
    let mut out = a.clone();
    for (k, s) in svd.singular_values.iter().enumerate() {
        if *s > smax * RANK_EPS {
            let uk = u.column(k);
            let proj = uk.transpose() * &out;
            out -= uk * proj;
        }
    }
    out
}

/// Relative singular value below which a matrix's direction is numerically null: a few
/// hundred ulps of the largest.
pub const RANK_EPS: Real = 1e-12;

fn combo_name(names: &[String], c: &[Real]) -> String {
    let mut s = String::new();
    for (name, &k) in names.iter().zip(c) {
        if k == 0.0 {
            continue;
        }
        let sign = if k < 0.0 { "−" } else { "+" };
        let mag = k.abs();
        let coef = if (mag - 1.0).abs() < 1e-3 {
            String::new()
        } else {
            format!("{mag:.4}·")
        };
        if s.is_empty() {
            if k < 0.0 {
                s.push('−');
            }
            s.push_str(&format!("{coef}{name}"));
        } else {
            s.push_str(&format!(" {sign} {coef}{name}"));
        }
    }
    s
}

/// Named combinations spanning the row space of `rows` (scaled units, each row a
/// direction): reduced row echelon with the largest pivot, small coefficients dropped,
/// converted to physical units with the first coefficient 1.
fn named_combinations(rows: &DMatrix<Real>, scale: &[Real], names: &[String]) -> Vec<Combination> {
    let mut m = rows.clone();
    let (nr, nc) = m.shape();
    let mut out = Vec::new();
    let mut used = vec![false; nc];
    for r in 0..nr {
        // Pivot: largest entry in an unused column of this or a later row.
        let mut best = (0.0, r, 0);
        for i in r..nr {
            for j in 0..nc {
                if !used[j] && m[(i, j)].abs() > best.0 {
                    best = (m[(i, j)].abs(), i, j);
                }
            }
        }
        if best.0 < RANK_EPS {
            break;
        }
        let (_, pi, pj) = best;
        m.swap_rows(r, pi);
        used[pj] = true;
        let piv = m[(r, pj)];
        for j in 0..nc {
            m[(r, j)] /= piv;
        }
        for i in 0..nr {
            if i != r {
                let f = m[(i, pj)];
                if f != 0.0 {
                    for j in 0..nc {
                        let v = m[(r, j)];
                        m[(i, j)] -= f * v;
                    }
                }
            }
        }
    }
    for r in 0..nr {
        let row: Vec<Real> = (0..nc).map(|j| m[(r, j)]).collect();
        let big = row.iter().fold(0.0, |a: Real, b| a.max(b.abs()));
        if big < RANK_EPS {
            continue;
        }
        // Scaled coefficient a_j on q_j = p_j / s_j → a_j / s_j on p_j. The name drops
        // the small terms; the coefficients keep them (values must not depend on the
        // undetermined directions).
        // A coefficient below the numerical rank's resolution is the elimination's
        // rounding, not a coupling: exactly 0 (so a parameter the combination does not
        // contain does not enter its value, or its injected value, at 1e-19).
        let mut c: Vec<Real> = row
            .iter()
            .zip(scale)
            .map(|(a, s)| if a.abs() < RANK_EPS * big { 0.0 } else { a / s })
            .collect();
        let lead_at = row
            .iter()
            .position(|a| a.abs() >= COMBINATION_CUTOFF * big)
            .unwrap_or(0);
        let lead = c[lead_at];
        for v in &mut c {
            *v /= lead;
        }
        let shown: Vec<Real> = row
            .iter()
            .zip(&c)
            .map(|(a, v)| {
                if a.abs() < COMBINATION_CUTOFF * big {
                    0.0
                } else {
                    *v
                }
            })
            .collect();
        out.push(Combination {
            name: combo_name(names, &shown),
            coefficients: c,
        });
    }
    out
}

/// What a whitened Jacobian `j` determines: its first `names.len()` columns are the
/// parameters (physical units, realistic magnitudes `scale`), the rest nuisance unknowns
/// (`nuisance_names`), projected out before the parameters' SVD (see the module
/// documentation). Every identification's report of what is and is not determined.
pub fn identifiability_of(
    j: &DMatrix<Real>,
    names: &[String],
    scale: &[Real],
    nuisance_names: &[String],
) -> Identifiability {
    let names = names.to_vec();
    let np = names.len();
    let mut jp = j.columns(0, np).into_owned();
    for (k, s) in scale.iter().enumerate() {
        jp.column_mut(k).scale_mut(*s);
    }
    let jr = j.columns(np, j.ncols() - np).into_owned();
    let jf = project_out(&jp, &jr);
    let svd = jf.clone().svd(false, true);
    let vt = svd.v_t.expect("requested");
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|a, b| svd.singular_values[*b].total_cmp(&svd.singular_values[*a]));
    let sv: Vec<Real> = order.iter().map(|&i| svd.singular_values[i]).collect();
    let mut full_sv = sv.clone();
    full_sv.resize(np, 0.0);
    let threshold = 1.0 / DETERMINED_FRACTION;
    let det: Vec<usize> = order
        .iter()
        .copied()
        .filter(|&i| svd.singular_values[i] >= threshold)
        .collect();
    let rank = det.len();
    let mut basis = DMatrix::zeros(np, rank);
    for (c, &i) in det.iter().enumerate() {
        basis.set_column(c, &vt.row(i).transpose());
    }
    let leakage: Vec<Real> = (0..np)
        .map(|k| {
            let proj = basis.row(k).norm_squared();
            (1.0 - proj).max(0.0).sqrt()
        })
        .collect();
    let identified_idx: Vec<usize> = (0..np).filter(|&k| leakage[k] < LEAKAGE).collect();
    // Determined combinations: the determined subspace with the identified axes removed.
    let mut reduced = basis.transpose();
    for &k in &identified_idx {
        reduced.column_mut(k).fill(0.0);
    }
    let reduced = if reduced.nrows() > 0 {
        let s = reduced.clone().svd(false, true);
        let vt = s.v_t.expect("requested");
        let big = s.singular_values.max();
        let keep: Vec<usize> = (0..s.singular_values.len())
            .filter(|&i| s.singular_values[i] > 0.5 * big.max(1.0))
            .collect();
        DMatrix::from_fn(keep.len(), np, |r, c| vt[(keep[r], c)])
    } else {
        DMatrix::zeros(0, np)
    };
    let determined_combinations = named_combinations(&reduced, scale, &names);
    // Undetermined: the complement of the determined subspace.
    let complement = {
        let mut eye = DMatrix::<Real>::identity(np, np);
        if rank > 0 {
            eye -= &basis * basis.transpose();
        }
        let s = eye.svd(false, true);
        let vt = s.v_t.expect("requested");
        let keep: Vec<usize> = (0..s.singular_values.len())
            .filter(|&i| s.singular_values[i] > 0.5)
            .collect();
        DMatrix::from_fn(keep.len(), np, |r, c| vt[(keep[r], c)])
    };
    let undetermined_combinations = named_combinations(&complement, scale, &names);
    let borderline = order
        .iter()
        .filter(|&&i| {
            let s = svd.singular_values[i];
            s >= threshold / BORDERLINE_FACTOR && s < threshold * BORDERLINE_FACTOR
        })
        .filter_map(|&i| {
            let row = DMatrix::from_fn(1, np, |_, c| vt[(i, c)]);
            named_combinations(&row, scale, &names)
                .pop()
                .map(|c| (c, svd.singular_values[i]))
        })
        .collect();
    // What the registration absorbs: the deviation combination each registration column
    // reproduces best (least squares), if it does so well.
    let mut registration_absorbs = Vec::new();
    if jr.ncols() > 0 {
        let reg_names = nuisance_names;
        let pinv = jp.clone().pseudo_inverse(RANK_EPS).ok();
        for (k, reg_name) in reg_names.iter().enumerate().take(jr.ncols()) {
            let col = jr.column(k).into_owned();
            let norm = col.norm();
            let text = match &pinv {
                Some(pi) if norm > 0.0 => {
                    let coef = pi * &col;
                    let fit = &jp * &coef;
                    let resid = (&col - fit).norm() / norm;
                    if resid < 0.1 {
                        let c: Vec<Real> = coef
                            .iter()
                            .zip(scale)
                            .map(|(a, s)| {
                                if a.abs() < COMBINATION_CUTOFF * coef.amax() {
                                    0.0
                                } else {
                                    a / s
                                }
                            })
                            .collect();
                        format!("{}: mimics {}", reg_name, combo_name(&names, &c))
                    } else {
                        format!("{}: absorbs no deviation", reg_name)
                    }
                }
                _ => format!("{}: not constrained by the features", reg_name),
            };
            registration_absorbs.push(text);
        }
    }
    let positive: Vec<Real> = sv.iter().copied().filter(|s| *s > 0.0).collect();
    let cond = |v: &[Real]| match (v.first(), v.last()) {
        (Some(a), Some(b)) if *b > 0.0 => a / b,
        _ => Real::INFINITY,
    };
    let condition_number = if positive.len() < np {
        Real::INFINITY
    } else {
        cond(&full_sv)
    };
    Identifiability {
        parameters: names.clone(),
        margin: RankMargin::new(&full_sv, rank, threshold),
        singular_values: full_sv,
        condition_number,
        condition_number_determined: cond(&sv[..rank]),
        rank,
        identified: identified_idx.iter().map(|&k| names[k].clone()).collect(),
        determined_combinations,
        undetermined_combinations,
        borderline,
        not_identified: (0..np)
            .filter(|k| !identified_idx.contains(k))
            .map(|k| names[k].clone())
            .collect(),
        registration_absorbs,
        no_data: (0..np)
            .filter(|&k| j.column(k).amax() * scale[k] < NO_DATA_SENSITIVITY)
            .map(|k| names[k].clone())
            .collect(),
        determined_basis: basis,
        leakage,
    }
}

/// One identified quantity: a parameter or a determined combination.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// Name (`dy_AY`, `gamma_AY + gamma_YX`).
    pub name: String,
    /// Value (mm or rad; for combinations in the units of their first parameter).
    pub value: Real,
    /// Standard uncertainty propagated from the features' uncertainties.
    pub sigma: Real,
    /// Coefficients over the solved parameters (a unit vector for a single parameter).
    pub coefficients: Vec<Real>,
}

/// The values with σ of what an identification determines, at the solution `x` (the
/// parameters, physical units) with the parameters' covariance `cov` and realistic
/// magnitudes `scale`: each parameter identified on its own, valued as the determined
/// combination nearest to it (its projection on the determined subspace, whose other
/// coefficients are below [`LEAKAGE`] in scaled units, so its value does not depend on the
/// undetermined directions), then each determined combination.
pub fn estimates_of(
    ident: &Identifiability,
    x: &[Real],
    cov: &DMatrix<Real>,
    scale: &[Real],
) -> (Vec<Estimate>, Vec<Estimate>) {
    let np = x.len();
    let xp = DVector::from_column_slice(x);
    let estimate = |name: String, c: Vec<Real>| {
        let cv = DVector::from_iterator(np, c.iter().copied());
        let value = cv.dot(&xp);
        let var = (cv.transpose() * cov * &cv)[0];
        Estimate {
            name,
            value,
            sigma: var.max(0.0).sqrt(),
            coefficients: c,
        }
    };
    let basis = &ident.determined_basis;
    let parameters = ident
        .identified
        .iter()
        .map(|name| {
            let k = ident.parameters.iter().position(|n| n == name).unwrap_or(0);
            let a = basis * basis.row(k).transpose();
            let c = (0..np)
                .map(|j| {
                    // A coupling below the numerical rank's resolution is the projection's
                    // rounding, not a coupling: exactly 0 (a parameter nothing couples to is
                    // valued, and compared with the truth, on its own).
                    let r = a[j] / a[k];
                    if j != k && r.abs() < RANK_EPS {
                        0.0
                    } else {
                        scale[k] * r / scale[j]
                    }
                })
                .collect();
            estimate(name.clone(), c)
        })
        .collect();
    let combinations = ident
        .determined_combinations
        .iter()
        .map(|c| estimate(c.name.clone(), c.coefficients.clone()))
        .collect();
    (parameters, combinations)
}

/// A parameter whose realistic magnitude moves no whitened residual by more than this has
/// no data at all (a thousandth of a standard uncertainty).
pub const NO_DATA_SENSITIVITY: Real = 1e-3;
