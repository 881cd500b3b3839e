//! Positioning accuracy and repeatability of a linear axis, evaluated as ISO 230-2 (= GB/T
//! 17421.2) says, from readings of any source: a laser interferometer on the twin, or a
//! real instrument's export.
//!
//! # Readings
//!
//! A reading is the deviation `x_ij = position reached − target` of run `j` at target `i`,
//! approached in one direction (`+`, ↑, or `−`, ↓). [`parse_readings`] takes two CSV layouts:
//!
//! - **long**: a header `target,direction,run,deviation`, then one reading a row: target
//!   position, `+` or `-`, run number from 1, deviation;
//! - **wide** (what laser systems export): a header `target,+run1,…,+runN,-run1,…,-runN`
//!   (or `+1 … -N`), then one target a row with its deviation in every run.
//!
//! Values are in mm; a header name may carry a unit in brackets, `target[mm]`,
//! `deviation[um]` (`µm`, `um`, `mm`, `in`), which then applies to that column. Commas,
//! semicolons or tabs separate fields; blank lines and lines starting with `#` are skipped.
//!
//! # Figures (ISO 230-2, mm)
//!
//! Per target: the mean deviations `x̄↑`, `x̄↓` and `x̄ = (x̄↑ + x̄↓)/2`, the reversal value
//! `B_i = x̄↑ − x̄↓`, the sample standard uncertainties `s↑`, `s↓` (n − 1), the
//! repeatabilities `R↑ = 4s↑`, `R↓ = 4s↓` and `R_i = max(2s↑ + 2s↓ + |B_i|, R↑, R↓)`.
//! For the axis: `B = max |B_i|`, `B̄ = mean B_i`, `R↑ = max R_i↑`, `R↓`, `R = max R_i`,
//! `E↑ = max x̄↑ − min x̄↑`, `E↓`, `E = max(x̄↑, x̄↓) − min(x̄↑, x̄↓)` over all targets,
//! `M = max x̄ − min x̄`, `A↑ = max(x̄↑ + 2s↑) − min(x̄↑ − 2s↑)`, `A↓`, and `A` the same over
//! both directions.
//!
//! **Invariant:** a reading set is evaluated only when it is complete: every target in both
//! directions, the same runs `1..n` (n ≥ 2) everywhere, each exactly once, every value
//! finite. Anything else is an error naming what is missing — never a figure from part of the
//! data.

use super::table::{FieldError, fields, length_unit, name_and_unit, number, rows};
use crate::math::Real;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The direction a target is approached in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub enum Direction {
    /// Approached in the positive direction (↑, `+`).
    #[serde(rename = "+")]
    Forward,
    /// Approached in the negative direction (↓, `-`).
    #[serde(rename = "-")]
    Backward,
}

impl Direction {
    /// `+` or `-`.
    pub fn sign(self) -> char {
        match self {
            Direction::Forward => '+',
            Direction::Backward => '-',
        }
    }
}

/// One reading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reading {
    /// Target position (mm).
    pub target_mm: Real,
    /// Approach direction.
    pub direction: Direction,
    /// Run number, from 1.
    pub run: u32,
    /// Position reached minus target (mm).
    pub deviation_mm: Real,
}

/// A problem with a readings file or a reading set.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ReadingsError {
    /// A line cannot be read (syntax, a non-finite number, an unknown unit or direction).
    #[error(transparent)]
    Syntax(#[from] FieldError),
    /// The readings do not form a complete bidirectional test.
    #[error("{}: {message}", path.display())]
    Incomplete {
        /// The file (or a name for readings that did not come from one).
        path: PathBuf,
        /// What is missing or inconsistent.
        message: String,
    },
}

/// The figures of one target (mm).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TargetFigures {
    /// Target position.
    pub target: Real,
    /// Mean deviation approaching in `+` (x̄↑).
    pub mean_fwd: Real,
    /// Mean deviation approaching in `−` (x̄↓).
    pub mean_bwd: Real,
    /// Mean bidirectional deviation (x̄↑ + x̄↓)/2.
    pub mean: Real,
    /// Reversal value x̄↑ − x̄↓.
    #[serde(rename = "B")]
    pub b: Real,
    /// Standard uncertainty in `+` (s↑, n − 1).
    pub s_fwd: Real,
    /// Standard uncertainty in `−` (s↓).
    pub s_bwd: Real,
    /// Unidirectional repeatability in `+` (4 s↑).
    #[serde(rename = "R_fwd")]
    pub r_fwd: Real,
    /// Unidirectional repeatability in `−` (4 s↓).
    #[serde(rename = "R_bwd")]
    pub r_bwd: Real,
    /// Bidirectional repeatability max(2s↑ + 2s↓ + |B|, R↑, R↓).
    #[serde(rename = "R")]
    pub r: Real,
}

/// The axis figures of ISO 230-2 (mm), under the names other tools read.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PositioningFigures {
    /// Bidirectional accuracy of positioning.
    #[serde(rename = "A")]
    pub a: Real,
    /// Unidirectional accuracy in `+` (A↑).
    #[serde(rename = "A_fwd")]
    pub a_fwd: Real,
    /// Unidirectional accuracy in `−` (A↓).
    #[serde(rename = "A_bwd")]
    pub a_bwd: Real,
    /// Reversal value of the axis, max |B_i|.
    #[serde(rename = "B")]
    pub b: Real,
    /// Mean reversal value, mean B_i.
    #[serde(rename = "B_mean")]
    pub b_mean: Real,
    /// Bidirectional systematic positioning error.
    #[serde(rename = "E")]
    pub e: Real,
    /// Unidirectional systematic positioning error in `+` (E↑).
    #[serde(rename = "E_fwd")]
    pub e_fwd: Real,
    /// Unidirectional systematic positioning error in `−` (E↓).
    #[serde(rename = "E_bwd")]
    pub e_bwd: Real,
    /// Mean bidirectional positioning error, max x̄ − min x̄.
    #[serde(rename = "M")]
    pub m: Real,
    /// Bidirectional repeatability, max R_i.
    #[serde(rename = "R")]
    pub r: Real,
    /// Unidirectional repeatability in `+`, max R_i↑.
    #[serde(rename = "R_fwd")]
    pub r_fwd: Real,
    /// Unidirectional repeatability in `−`, max R_i↓.
    #[serde(rename = "R_bwd")]
    pub r_bwd: Real,
    /// Runs per target and direction.
    pub runs: usize,
    /// Per target, in ascending target order.
    pub targets: Vec<TargetFigures>,
}

/// A header cell: its name (lower case) and unit factor, or the unit problem.
fn header_cell(cell: &str) -> Result<(String, Real), String> {
    let (name, unit) = name_and_unit(cell)?;
    let f = match unit {
        None => 1.0,
        Some(u) => length_unit(u).ok_or_else(|| {
            format!(
                "unknown unit '{u}' in '{}' (use mm, um, µm or in)",
                cell.trim()
            )
        })?,
    };
    Ok((name.to_ascii_lowercase(), f))
}

/// Reads a readings file's text (`path` names it in messages): the long or the wide layout
/// (see the module documentation). Checks syntax, units and finiteness; completeness is
/// checked by [`evaluate`].
pub fn parse_readings(text: &str, path: &Path) -> Result<Vec<Reading>, ReadingsError> {
    let syntax = |line: usize, column: usize, message: String| {
        ReadingsError::Syntax(FieldError::at(path, line, column, message))
    };
    let mut rows = rows(text);
    let Some((hline, header)) = rows.next() else {
        return Err(ReadingsError::Incomplete {
            path: path.to_path_buf(),
            message: "no header and no readings".into(),
        });
    };
    let cells: Vec<(usize, String, Real)> = fields(header)
        .into_iter()
        .map(|(col, c)| {
            header_cell(c)
                .map(|(n, f)| (col, n, f))
                .map_err(|m| syntax(hline, col, m))
        })
        .collect::<Result<_, _>>()?;
    let number = |line: usize, col: usize, s: &str, what: &str| -> Result<Real, ReadingsError> {
        number(s, what).map_err(|m| syntax(line, col, m))
    };
    let names: Vec<&str> = cells.iter().map(|(_, n, _)| n.as_str()).collect();
    let mut out = Vec::new();
    if names == ["target", "direction", "run", "deviation"] {
        let (ft, fd) = (cells[0].2, cells[3].2);
        for (line, l) in rows {
            let f = fields(l);
            if f.len() != 4 {
                return Err(syntax(
                    line,
                    1,
                    format!(
                        "expected 4 fields (target,direction,run,deviation), got {}",
                        f.len()
                    ),
                ));
            }
            let target_mm = number(line, f[0].0, f[0].1, "target")? * ft;
            let direction = match f[1].1 {
                "+" | "fwd" | "forward" => Direction::Forward,
                "-" | "bwd" | "backward" => Direction::Backward,
                other => {
                    return Err(syntax(
                        line,
                        f[1].0,
                        format!("direction must be '+' or '-', got '{other}'"),
                    ));
                }
            };
            let run = match f[2].1.parse::<u32>() {
                Ok(r) if r >= 1 => r,
                _ => {
                    return Err(syntax(
                        line,
                        f[2].0,
                        format!("run must be a whole number from 1, got '{}'", f[2].1),
                    ));
                }
            };
            let deviation_mm = number(line, f[3].0, f[3].1, "deviation")? * fd;
            out.push(Reading {
                target_mm,
                direction,
                run,
                deviation_mm,
            });
        }
        return Ok(out);
    }
    // The wide layout: target, then +runK / -runK columns.
    if names.first() != Some(&"target") || names.len() < 2 {
        return Err(syntax(
            hline,
            1,
            "the header must be 'target,direction,run,deviation' or 'target,+run1,…,-runN'".into(),
        ));
    }
    let mut columns = Vec::new();
    for (col, name, factor) in &cells[1..] {
        let (direction, rest) = match name.split_at_checked(1) {
            Some(("+", r)) => (Direction::Forward, r),
            Some(("-", r)) => (Direction::Backward, r),
            _ => {
                return Err(syntax(
                    hline,
                    *col,
                    format!("column '{name}' must be '+runK' or '-runK'"),
                ));
            }
        };
        let digits = rest.strip_prefix("run").unwrap_or(rest);
        let run = match digits.parse::<u32>() {
            Ok(r) if r >= 1 => r,
            _ => {
                return Err(syntax(
                    hline,
                    *col,
                    format!("column '{name}' must be '+runK' or '-runK' with K from 1"),
                ));
            }
        };
        columns.push((direction, run, *factor));
    }
    let ft = cells[0].2;
    for (line, l) in rows {
        let f = fields(l);
        if f.len() != cells.len() {
            return Err(syntax(
                line,
                1,
                format!(
                    "expected {} fields as in the header, got {} (a missing run?)",
                    cells.len(),
                    f.len()
                ),
            ));
        }
        let target_mm = number(line, f[0].0, f[0].1, "target")? * ft;
        for ((col, s), (direction, run, factor)) in f[1..].iter().zip(&columns) {
            out.push(Reading {
                target_mm,
                direction: *direction,
                run: *run,
                deviation_mm: number(line, *col, s, "deviation")? * factor,
            });
        }
    }
    Ok(out)
}

/// The long readings file of `readings` (see the module documentation): `comments` first,
/// each as a `#` line, then the header `target,direction,run,deviation` and one reading a
/// row, in mm. Every number is written in its shortest exact form, so [`parse_readings`]
/// reads back the same values bit for bit.
pub fn readings_csv(readings: &[Reading], comments: &[String]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    for c in comments {
        for line in c.lines() {
            let _ = writeln!(s, "# {line}");
        }
    }
    s.push_str("target,direction,run,deviation\n");
    for r in readings {
        let _ = writeln!(
            s,
            "{:?},{},{},{:?}",
            r.target_mm,
            r.direction.sign(),
            r.run,
            r.deviation_mm
        );
    }
    s
}

/// The deviations of one target in one direction, by run.
type Runs = BTreeMap<u32, Real>;

/// Mean and sample standard deviation (n − 1) of at least two values.
fn mean_and_s(v: &[Real]) -> (Real, Real) {
    let n = v.len() as Real;
    let mean = v.iter().sum::<Real>() / n;
    let ss = v.iter().map(|x| (x - mean) * (x - mean)).sum::<Real>();
    (mean, (ss / (n - 1.0)).sqrt())
}

/// Largest minus smallest of an iterator of values.
fn range(v: impl Iterator<Item = Real> + Clone) -> Real {
    v.clone().fold(Real::NEG_INFINITY, Real::max) - v.fold(Real::INFINITY, Real::min)
}

/// Evaluates a complete bidirectional reading set (`path` names it in messages).
pub fn evaluate(readings: &[Reading], path: &Path) -> Result<PositioningFigures, ReadingsError> {
    let incomplete = |message: String| ReadingsError::Incomplete {
        path: path.to_path_buf(),
        message,
    };
    if readings.is_empty() {
        return Err(incomplete("no readings".into()));
    }
    // target (keyed so that keys sort as the values) → (target, per direction: run → deviation)
    let mut by_target: BTreeMap<(i8, u64), (Real, [Runs; 2])> = BTreeMap::new();
    for r in readings {
        if !(r.target_mm.is_finite() && r.deviation_mm.is_finite()) {
            return Err(incomplete(format!(
                "a reading at target {} is not finite",
                r.target_mm
            )));
        }
        // Order by value: the key sorts like the number (sign, then magnitude bits).
        let t = if r.target_mm == 0.0 { 0.0 } else { r.target_mm };
        let key = if t < 0.0 {
            (-1, u64::MAX - (-t).to_bits())
        } else {
            (1, t.to_bits())
        };
        let entry = by_target
            .entry(key)
            .or_insert_with(|| (t, [BTreeMap::new(), BTreeMap::new()]));
        let d = r.direction as usize;
        if entry.1[d].insert(r.run, r.deviation_mm).is_some() {
            return Err(incomplete(format!(
                "target {} {} run {} is given twice",
                t,
                r.direction.sign(),
                r.run
            )));
        }
    }
    let runs = by_target
        .values()
        .map(|(_, d)| d[0].len())
        .next()
        .unwrap_or(0);
    if runs < 2 {
        return Err(incomplete(format!(
            "{runs} run per target and direction: the standard uncertainty needs at least 2 (ISO 230-2 asks for 5)"
        )));
    }
    let mut targets = Vec::with_capacity(by_target.len());
    for (t, dirs) in by_target.values() {
        let mut stats = [(0.0, 0.0); 2];
        for (k, (dir, d)) in [Direction::Forward, Direction::Backward]
            .iter()
            .zip(dirs)
            .enumerate()
        {
            if d.len() != runs || d.keys().copied().ne(1..=runs as u32) {
                let have: Vec<String> = d.keys().map(|r| r.to_string()).collect();
                return Err(incomplete(format!(
                    "target {t} {}: runs {{{}}}, expected 1 to {runs} as at the first target",
                    dir.sign(),
                    have.join(", ")
                )));
            }
            let v: Vec<Real> = d.values().copied().collect();
            stats[k] = mean_and_s(&v);
        }
        let ((mf, sf), (mb, sb)) = (stats[0], stats[1]);
        let b = mf - mb;
        let (rf, rb) = (4.0 * sf, 4.0 * sb);
        targets.push(TargetFigures {
            target: *t,
            mean_fwd: mf,
            mean_bwd: mb,
            mean: 0.5 * (mf + mb),
            b,
            s_fwd: sf,
            s_bwd: sb,
            r_fwd: rf,
            r_bwd: rb,
            r: (2.0 * sf + 2.0 * sb + b.abs()).max(rf).max(rb),
        });
    }
    let it = targets.iter();
    let max = |f: fn(&TargetFigures) -> Real| it.clone().map(f).fold(Real::NEG_INFINITY, Real::max);
    let min = |f: fn(&TargetFigures) -> Real| it.clone().map(f).fold(Real::INFINITY, Real::min);
    let both_hi = max(|t| t.mean_fwd + 2.0 * t.s_fwd).max(max(|t| t.mean_bwd + 2.0 * t.s_bwd));
    let both_lo = min(|t| t.mean_fwd - 2.0 * t.s_fwd).min(min(|t| t.mean_bwd - 2.0 * t.s_bwd));
    Ok(PositioningFigures {
        a: both_hi - both_lo,
        a_fwd: max(|t| t.mean_fwd + 2.0 * t.s_fwd) - min(|t| t.mean_fwd - 2.0 * t.s_fwd),
        a_bwd: max(|t| t.mean_bwd + 2.0 * t.s_bwd) - min(|t| t.mean_bwd - 2.0 * t.s_bwd),
        b: max(|t| t.b.abs()),
        b_mean: it.clone().map(|t| t.b).sum::<Real>() / targets.len() as Real,
        e: max(|t| t.mean_fwd.max(t.mean_bwd)) - min(|t| t.mean_fwd.min(t.mean_bwd)),
        e_fwd: range(it.clone().map(|t| t.mean_fwd)),
        e_bwd: range(it.clone().map(|t| t.mean_bwd)),
        m: range(it.clone().map(|t| t.mean)),
        r: max(|t| t.r),
        r_fwd: max(|t| t.r_fwd),
        r_bwd: max(|t| t.r_bwd),
        runs,
        targets,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The check vector of the project's brief: 5 targets, 5 runs, forward
    /// x = base + (−2, −1, 0, 1, 2), backward x = base − 3 + (−1, −0.5, 0, 0.5, 1),
    /// base = (0, 2, 4, 2, 0) µm.
    fn check_readings() -> Vec<Reading> {
        let base = [0.0, 2.0, 4.0, 2.0, 0.0];
        let fwd = [-2.0, -1.0, 0.0, 1.0, 2.0];
        let bwd = [-1.0, -0.5, 0.0, 0.5, 1.0];
        let mut out = Vec::new();
        for (i, b) in base.iter().enumerate() {
            for j in 0..5 {
                out.push(Reading {
                    target_mm: 100.0 * i as Real,
                    direction: Direction::Forward,
                    run: j as u32 + 1,
                    deviation_mm: (b + fwd[j]) * 1e-3,
                });
                out.push(Reading {
                    target_mm: 100.0 * i as Real,
                    direction: Direction::Backward,
                    run: j as u32 + 1,
                    deviation_mm: (b - 3.0 + bwd[j]) * 1e-3,
                });
            }
        }
        out
    }

    #[test]
    fn the_check_vector_gives_the_standards_figures() {
        let f = evaluate(&check_readings(), Path::new("check")).expect("complete");
        // By hand: s↑ = √(10/4) = 1.5811 µm, s↓ = √(2.5/4) = 0.7906 µm, B_i = 3 µm.
        let s_f = (10.0_f64 / 4.0).sqrt();
        let s_b = (2.5_f64 / 4.0).sqrt();
        let um = |x: Real| x * 1e3;
        let close = |a: Real, b: Real| (a - b).abs() < 1e-9;
        assert!(close(um(f.b), 3.0), "B {}", um(f.b));
        assert!(close(um(f.b_mean), 3.0));
        assert!(close(um(f.r), 2.0 * s_f + 2.0 * s_b + 3.0), "R {}", um(f.r));
        assert!((um(f.r) - 7.7434).abs() < 5e-5, "R {}", um(f.r));
        assert!(close(um(f.e), 7.0), "E {}", um(f.e));
        assert!(close(um(f.m), 4.0), "M {}", um(f.m));
        assert!((um(f.a) - 11.7434).abs() < 5e-5, "A {}", um(f.a));
        assert!(close(um(f.a), 4.0 + 2.0 * s_f + 3.0 + 2.0 * s_b));
        assert!(close(um(f.e_fwd), 4.0) && close(um(f.e_bwd), 4.0));
        assert!(close(um(f.r_fwd), 4.0 * s_f) && close(um(f.r_bwd), 4.0 * s_b));
        assert!(close(um(f.a_fwd), 4.0 + 4.0 * s_f));
        assert_eq!(f.runs, 5);
        assert_eq!(f.targets.len(), 5);
        assert!(f.targets.windows(2).all(|w| w[0].target < w[1].target));
    }

    #[test]
    fn long_and_wide_files_read_the_same_readings() {
        let long = "target,direction,run,deviation[um]\n# a comment\n\
                    0,+,1,1.5\n0,+,2,2.5\n0,-,1,-1\n0,-,2,0\n\
                    -10,+,1,0.5\n-10,+,2,1\n-10,-,1,0\n-10,-,2,-0.5\n";
        let wide = "target[mm];+run1;+run2;-run1;-run2\n0;1.5e-3;2.5e-3;-1e-3;0\n\
                    -10;0.5e-3;1e-3;0;-0.5e-3\n";
        let a = evaluate(
            &parse_readings(long, Path::new("l")).expect("long"),
            Path::new("l"),
        )
        .expect("complete");
        let b = evaluate(
            &parse_readings(wide, Path::new("w")).expect("wide"),
            Path::new("w"),
        )
        .expect("complete");
        assert_eq!(a.targets.len(), 2);
        assert_eq!(a.targets[0].target, -10.0, "ascending targets");
        for (x, y) in a.targets.iter().zip(&b.targets) {
            assert!((x.mean_fwd - y.mean_fwd).abs() < 1e-15);
            assert!((x.s_bwd - y.s_bwd).abs() < 1e-15);
        }
        assert!((a.a - b.a).abs() < 1e-15);
    }

    #[test]
    fn incomplete_or_bad_files_are_refused_with_their_place() {
        let p = Path::new("r.csv");
        let err = |t: &str| match parse_readings(t, p).and_then(|r| evaluate(&r, p)) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("accepted: {t}"),
        };
        assert!(err("target,direction,run,deviation\n0,+,1,nan\n").starts_with("r.csv:2:7:"));
        assert!(err("target,direction,run,deviation[furlong]\n").contains("unknown unit"));
        assert!(err("target,direction,run,deviation\n0,x,1,0\n").contains("direction"));
        assert!(err("target,+run1,+run2,-run1,-run2\n0,1,2,3\n").contains("missing run"));
        // Unequal run counts between targets.
        let e = err(
            "target,direction,run,deviation\n0,+,1,0\n0,+,2,0\n0,-,1,0\n0,-,2,0\n\
                     1,+,1,0\n1,-,1,0\n1,-,2,0\n",
        );
        assert!(e.contains("target 1 +: runs {1}"), "{e}");
        // Only one direction.
        let e = err("target,direction,run,deviation\n0,+,1,0\n0,+,2,0\n");
        assert!(e.contains("target 0 -"), "{e}");
        // A run given twice.
        assert!(err("target,direction,run,deviation\n0,+,1,0\n0,+,1,0\n").contains("twice"));
        assert!(err("").contains("no header"));
    }
}
