//! The non-contact ball sensor of seed 003: two crossed LED/CCD optical micrometers and a
//! master ball on the spindle give the ball's centre in three dimensions without touching it.
//!
//! # Geometry
//!
//! The sensor frame has its origin O₁ at the centre of the crossing of the two light bands.
//! Each micrometer sends a flat sheet of parallel light (direction `beam`) over a band of
//! width `L_0` (along `band`) and reports where a body shadows it: `L_1`, the distance from
//! the band's edge to the shadow, and `L_2`, the shadow's length. Micrometer **B** measures X
//! (beam along +Y, band along X); micrometer **A** measures Y (beam along +X, band along Y);
//! both sheets lie nominally in the plane Z₁ = 0 and the ball is on the +Z₁ side.
//!
//! A sphere of radius R whose centre C is at a distance d < R from a sheet cuts it in a disc
//! of radius ρ = √(R² − d²) about the foot of C; seen along the beam, that disc shadows the band
//! over `s ± ρ`, with `s` the position of C along the band. So the readings are exactly
//!
//! ```text
//! L_1 = s − ρ + L_0/2,   L_2 = 2ρ.
//! ```
//!
//! and the ball's centre follows seed 003's eq. (1)–(3):
//!
//! ```text
//! X_b = L_x1 + L_x2/2 − L_x0/2,   Y_b = L_y1 + L_y2/2 − L_y0/2,   Z_b = √(R² − (L_y2/2)²)
//! ```
//!
//! (Z from micrometer A, as the paper; B gives a second Z, reported as a check). The
//! micrometers' mounting errors (a sheet offset along Z₁, tilted, or its band skewed) enter
//! the readings through the exact geometry above; eq. (1)–(3) do not know them, which is what
//! the sensor's own calibration is for.
//!
//! # Z uncertainty and the working window
//!
//! Z comes from a chord of the ball: dZ/dL₂ = −L₂/(4Z) = −√(R² − Z²)/(2Z), which grows without
//! bound as the sheet nears the ball's equator (Z → 0) — the paper's Fig. 6(b)/7. With
//! micrometer errors within ±a, the Z error is at most
//! `e(Z) = max over ±a of |√(R² − ((L₂ ± a)/2)²) − Z|` (exact, not linearised).
//! [`BallSensor::working_window`] gives the Z range where e(Z) ≤ a tolerance: from the lowest
//! Z meeting it (the paper's 0.6 mm for ±0.5 µm and ±1 µm) up to where the chord is still at
//! least `min_chord_mm` (the paper loses accuracy near the ball's tip, 1.8–2.0 mm, which the
//! thin-sheet model does not explain; the setting bounds it).
//!
//! **Invariant:** a reading is produced only when the ball cuts both sheets and both shadows
//! lie inside the micrometers' measuring range; readings are converted only when they are
//! finite and geometrically possible (0 < L₂ ≤ 2R + a, the shadow inside the band; a chord
//! between 2R and 2R + a is the equator's read long, Z = 0);
//! anything else is an error naming what is wrong, never a number.

use super::table::{FieldError, fields, length_unit, name_and_unit, number, rows};
use crate::math::{Point3, Real, UnitVector3, Vector3};
use serde::Serialize;
use std::path::Path;

/// One optical micrometer: a sheet of light through `origin`, beams along `beam`, the band
/// (measured direction) along `band`, `width` wide (L₀), accurate over the central `range`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Micrometer {
    /// Centre of the band (sensor frame, mm).
    pub origin: Point3,
    /// Direction the light travels.
    pub beam: UnitVector3,
    /// Direction along which the band is measured (perpendicular to `beam`).
    pub band: UnitVector3,
    /// Width of the light band L₀ (mm).
    pub width_mm: Real,
    /// Central part of the band over which the accuracy holds (mm).
    pub range_mm: Real,
}

/// The two readings of one micrometer (mm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Reading {
    /// Band edge to the shadow's start, L₁.
    pub l1: Real,
    /// Length of the shadow, L₂.
    pub l2: Real,
}

/// Why a reading or a conversion is impossible.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SensorError {
    /// The ball does not cut a micrometer's sheet of light.
    #[error(
        "micrometer {which}: the ball does not reach its light (centre {distance_mm:.4} mm from the sheet, radius {radius_mm:.4} mm)"
    )]
    NotInLight {
        /// `A` or `B`.
        which: char,
        /// Distance of the ball's centre from the sheet (mm).
        distance_mm: Real,
        /// Ball radius (mm).
        radius_mm: Real,
    },
    /// The shadow is not inside the micrometer's measuring range.
    #[error(
        "micrometer {which}: the shadow {from_mm:.4} … {to_mm:.4} mm is outside its measuring range ±{half_range_mm} mm"
    )]
    OutsideRange {
        /// `A` or `B`.
        which: char,
        /// Shadow start along the band, from the band's centre (mm).
        from_mm: Real,
        /// Shadow end (mm).
        to_mm: Real,
        /// Half the measuring range (mm).
        half_range_mm: Real,
    },
    /// Readings that no ball position can give.
    #[error("{0}")]
    Impossible(String),
}

/// A readings file that cannot be used, at its line and column.
pub type ReadingsError = FieldError;

/// The sensor: micrometer A (measures Y), micrometer B (measures X), the master ball, and
/// the micrometers' accuracy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BallSensor {
    /// Micrometer A: beam along X, band along Y.
    pub a: Micrometer,
    /// Micrometer B: beam along Y, band along X.
    pub b: Micrometer,
    /// Master ball diameter (mm): seed 003's 4.0002.
    pub ball_diameter_mm: Real,
    /// Bound of each micrometer reading's error (mm): ±0.5 µm.
    pub accuracy_mm: Real,
    /// Shortest chord the micrometers measure within their accuracy (mm); 0: no limit.
    pub min_chord_mm: Real,
}

/// A ball centre from one set of readings, with what bounds it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Centre {
    /// X_b, Y_b, Z_b (eq. 1–3, sensor frame, mm).
    pub centre_mm: [Real; 3],
    /// Z from micrometer B's chord, the second opinion (mm).
    pub z_from_b_mm: Real,
    /// Bound of the Z error from the micrometers' accuracy at this Z (mm).
    pub z_error_bound_mm: Real,
}

/// The Z error bound at one height: Z from a chord read `accuracy` short and long.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ZError {
    /// True Z of the ball's centre above the sheet (mm).
    pub z_mm: Real,
    /// Z computed when the chord reads `accuracy` short, minus the true Z (mm).
    pub chord_short_mm: Real,
    /// Z computed when the chord reads `accuracy` long, minus the true Z (mm); a chord longer
    /// than the ball's diameter gives Z = 0 (the centre taken to be in the sheet), as
    /// [`BallSensor::centre`] does.
    pub chord_long_mm: Real,
}

/// The Z range over which the sensor meets a tolerance.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Window {
    /// Lowest Z of the ball's centre above the sheet (mm).
    pub z_min_mm: Real,
    /// Highest Z (mm).
    pub z_max_mm: Real,
    /// The tolerance on Z (mm).
    pub tolerance_mm: Real,
}

impl Micrometer {
    /// The unit normal of the sheet, `beam × band`.
    pub fn normal(&self) -> Vector3 {
        self.beam.cross(&self.band).normalize()
    }

    /// The readings for a ball of radius `r` centred at `c` (sensor frame); `which` names the
    /// micrometer in errors.
    pub fn read(&self, c: &Point3, r: Real, which: char) -> Result<Reading, SensorError> {
        let rel = c - self.origin;
        let d = rel.dot(&self.normal());
        if !d.is_finite() || d.abs() >= r {
            return Err(SensorError::NotInLight {
                which,
                distance_mm: d.abs(),
                radius_mm: r,
            });
        }
        let rho = (r * r - d * d).sqrt();
        let s = rel.dot(&self.band);
        let half = 0.5 * self.range_mm;
        if s - rho < -half || s + rho > half {
            return Err(SensorError::OutsideRange {
                which,
                from_mm: s - rho,
                to_mm: s + rho,
                half_range_mm: half,
            });
        }
        Ok(Reading {
            l1: s - rho + 0.5 * self.width_mm,
            l2: 2.0 * rho,
        })
    }
}

impl BallSensor {
    /// Seed 003's sensor, perfectly mounted: 6 mm measuring range, ±0.5 µm, Ø 4.0002 mm ball,
    /// light bands `band_mm` wide (L_x0 = L_y0; wider than the range, as the paper says).
    pub fn seed003(band_mm: Real) -> Self {
        let mic = |beam: Vector3, band: Vector3| Micrometer {
            origin: Point3::origin(),
            beam: UnitVector3::new_normalize(beam),
            band: UnitVector3::new_normalize(band),
            width_mm: band_mm,
            range_mm: 6.0,
        };
        Self {
            a: mic(Vector3::x(), Vector3::y()),
            b: mic(Vector3::y(), Vector3::x()),
            ball_diameter_mm: 4.0002,
            accuracy_mm: 0.5e-3,
            min_chord_mm: 0.0,
        }
    }

    /// The ball's radius (mm).
    pub fn radius(&self) -> Real {
        0.5 * self.ball_diameter_mm
    }

    /// The four readings (A: Y; B: X) for a ball centred at `c`, exact.
    pub fn read(&self, c: &Point3) -> Result<(Reading, Reading), SensorError> {
        let r = self.radius();
        Ok((self.a.read(c, r, 'A')?, self.b.read(c, r, 'B')?))
    }

    /// The ball's centre from readings by seed 003's eq. (1)–(3).
    pub fn centre(&self, a: &Reading, b: &Reading) -> Result<Centre, SensorError> {
        let r = self.radius();
        let z_of = |l2: Real, which: char| -> Result<Real, SensorError> {
            let h = 0.5 * l2;
            if !(l2.is_finite() && l2 > 0.0) {
                return Err(SensorError::Impossible(format!(
                    "micrometer {which}: a shadow of {l2} mm is not a ball's"
                )));
            }
            // A reading is the true chord (at most the diameter D) read within ±a: a chord
            // longer than D + a cannot be a ball's; between D and D + a it is the equator's
            // read long, and the centre is taken to be in the sheet (Z = 0).
            if l2 > 2.0 * r + self.accuracy_mm {
                return Err(SensorError::Impossible(format!(
                    "micrometer {which}: a shadow of {l2:.4} mm is longer than the ball's diameter {:.4} mm plus the micrometer's accuracy {:.3} µm",
                    2.0 * r,
                    self.accuracy_mm * 1e3
                )));
            }
            Ok((r * r - h * h).max(0.0).sqrt())
        };
        let z = z_of(a.l2, 'A')?;
        let zb = z_of(b.l2, 'B')?;
        // Eq. (1) and (2): the centre along each band is L₁ + L₂/2 − L₀/2.
        let sa = a.l1 + 0.5 * a.l2 - 0.5 * self.a.width_mm;
        let sb = b.l1 + 0.5 * b.l2 - 0.5 * self.b.width_mm;
        for (s, m, which) in [(sa, &self.a, 'A'), (sb, &self.b, 'B')] {
            let (lo, hi) = (s - 0.5 * m.width_mm, s + 0.5 * m.width_mm);
            if !(s.is_finite() && lo <= 0.0 && hi >= 0.0) {
                return Err(SensorError::Impossible(format!(
                    "micrometer {which}: the shadow's centre {s:.4} mm is outside its band"
                )));
            }
        }
        Ok(Centre {
            centre_mm: [sb, sa, z],
            z_from_b_mm: zb,
            z_error_bound_mm: self.z_error(z).bound(),
        })
    }

    /// The Z error at height `z` (mm) for a chord read `accuracy` short and long (exact).
    pub fn z_error(&self, z: Real) -> ZError {
        let r = self.radius();
        let half = (r * r - z * z).max(0.0).sqrt();
        let a = self.accuracy_mm;
        let z_of = |h: Real| (r * r - h * h).max(0.0).sqrt();
        ZError {
            z_mm: z,
            chord_short_mm: z_of(half - 0.5 * a) - z,
            chord_long_mm: z_of(half + 0.5 * a) - z,
        }
    }

    /// The Z range where the Z error bound is at most `tolerance` (mm) and the chord at least
    /// `min_chord_mm`; `None` when no height meets both.
    pub fn working_window(&self, tolerance: Real) -> Option<Window> {
        let r = self.radius();
        let ok = |z: Real| self.z_error(z).bound() <= tolerance;
        // The bound falls monotonically with Z above √(R·a) (the chord changes faster the
        // nearer the tip), so the lowest acceptable Z is found by bisection; a tolerance below
        // the bound at the tip has no window.
        let top = if self.min_chord_mm > 0.0 {
            let h = 0.5 * self.min_chord_mm;
            if h >= r {
                return None;
            }
            (r * r - h * h).sqrt()
        } else {
            r
        };
        let mut hi = top * (1.0 - 1e-12);
        if !ok(hi) {
            return None;
        }
        let mut lo = 0.0;
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if ok(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Some(Window {
            z_min_mm: hi,
            z_max_mm: top,
            tolerance_mm: tolerance,
        })
    }
}

impl ZError {
    /// The larger of the two errors' magnitudes.
    pub fn bound(&self) -> Real {
        self.chord_long_mm.abs().max(self.chord_short_mm.abs())
    }
}

/// Parses a readings file: a header `Lx1,Lx2,Ly1,Ly2` (any order; a unit in brackets, e.g.
/// `Lx1[um]`, applies to its column; default mm), then one set of readings a row. Returns
/// `(line, B reading, A reading)` per row.
pub fn parse_readings(
    text: &str,
    path: &Path,
) -> Result<Vec<(usize, Reading, Reading)>, ReadingsError> {
    let err =
        |line: usize, column: usize, message: String| FieldError::at(path, line, column, message);
    let mut rows = rows(text);
    let Some((hline, header)) = rows.next() else {
        return Err(err(
            1,
            1,
            "no header (Lx1,Lx2,Ly1,Ly2) and no readings".into(),
        ));
    };
    let names = ["lx1", "lx2", "ly1", "ly2"];
    let mut index = [usize::MAX; 4];
    let mut scale = [1.0; 4];
    let head = fields(header);
    for (k, (col, cell)) in head.iter().enumerate() {
        let (name, unit) = name_and_unit(cell).map_err(|m| err(hline, *col, m))?;
        let Some(slot) = names.iter().position(|n| name.eq_ignore_ascii_case(n)) else {
            return Err(err(
                hline,
                *col,
                format!("unknown column '{name}' (the header is Lx1,Lx2,Ly1,Ly2)"),
            ));
        };
        if index[slot] != usize::MAX {
            return Err(err(hline, *col, format!("column '{name}' given twice")));
        }
        index[slot] = k;
        scale[slot] = match unit {
            None => 1.0,
            Some(u) => length_unit(u).ok_or_else(|| {
                err(
                    hline,
                    *col,
                    format!("unknown unit '{u}' (use mm, um, µm or in)"),
                )
            })?,
        };
    }
    if let Some(missing) = (0..4).find(|&k| index[k] == usize::MAX) {
        return Err(err(
            hline,
            1,
            format!(
                "column '{}' is missing (the header is Lx1,Lx2,Ly1,Ly2)",
                ["Lx1", "Lx2", "Ly1", "Ly2"][missing]
            ),
        ));
    }
    let mut out = Vec::new();
    for (line, l) in rows {
        let f = fields(l);
        if f.len() != head.len() {
            return Err(err(
                line,
                1,
                format!("expected {} fields, got {}", head.len(), f.len()),
            ));
        }
        let mut v = [0.0; 4];
        for k in 0..4 {
            let (col, s) = &f[index[k]];
            v[k] = number(s, ["Lx1", "Lx2", "Ly1", "Ly2"][k]).map_err(|m| err(line, *col, m))?
                * scale[k];
        }
        out.push((
            line,
            Reading { l1: v[0], l2: v[1] },
            Reading { l1: v[2], l2: v[3] },
        ));
    }
    if out.is_empty() {
        return Err(err(hline, 1, "no readings after the header".into()));
    }
    Ok(out)
}

/// Converts a readings file's rows to ball centres; the first impossible row fails with its
/// line.
pub fn centres(
    sensor: &BallSensor,
    rows: &[(usize, Reading, Reading)],
    path: &Path,
) -> Result<Vec<Centre>, ReadingsError> {
    rows.iter()
        .map(|(line, b, a)| {
            // The readings must lie inside the band: 0 ≤ L₁, L₁ + L₂ ≤ L₀.
            for (m, r, which) in [(&sensor.b, b, 'B'), (&sensor.a, a, 'A')] {
                if r.l1 < 0.0 || r.l2 <= 0.0 || r.l1 + r.l2 > m.width_mm {
                    return Err(FieldError::at(
                        path,
                        *line,
                        1,
                        format!(
                            "micrometer {which}: L1 {:.4} mm and L2 {:.4} mm are outside its band of {} mm",
                            r.l1, r.l2, m.width_mm
                        ),
                    ));
                }
            }
            sensor
                .centre(a, b)
                .map_err(|e| FieldError::at(path, *line, 1, e.to_string()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::CounterRng;

    fn sensor() -> BallSensor {
        BallSensor::seed003(10.0)
    }

    #[test]
    fn eq_1_to_3_give_back_the_centre_of_a_perfect_sensor() {
        let s = sensor();
        for (i, c) in [
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(0.4, -0.7, 0.6),
            Point3::new(-0.9, 0.95, 1.6),
        ]
        .iter()
        .enumerate()
        {
            let (a, b) = s.read(c).expect("in range");
            // The shadow of a sphere cut at height z: chord 2√(R² − z²), written out here.
            let r = 2.0001_f64;
            assert!(
                (a.l2 - 2.0 * (r * r - c.z * c.z).sqrt()).abs() < 1e-12,
                "{i}"
            );
            assert!((b.l1 - (c.x - (r * r - c.z * c.z).sqrt() + 5.0)).abs() < 1e-12);
            let got = s.centre(&a, &b).expect("possible");
            for k in 0..3 {
                assert!((got.centre_mm[k] - c[k]).abs() < 1e-12, "{i} {k}");
            }
            assert!((got.z_from_b_mm - c.z).abs() < 1e-12);
        }
    }

    #[test]
    fn z_error_grows_without_bound_at_the_equator_and_stays_within_1_um_over_0_6_to_1_6() {
        let s = sensor();
        // First order, by hand: dZ/dL₂ = −√(R² − Z²)/(2Z); a chord error of ±0.5 µm.
        let r = 2.0001_f64;
        let lin = |z: Real| 0.5e-3 * (r * r - z * z).sqrt() / (2.0 * z);
        let mut last = Real::INFINITY;
        for i in 1..=199 {
            let z = i as Real * 0.01;
            let e = s.z_error(z);
            let b = e.bound();
            // Below √(R·a) ≈ 0.032 mm the long chord has no answer and Z is taken as 0.
            if z >= 0.04 {
                assert!(b <= last, "the bound falls with z: {z}");
            }
            last = b;
            if z >= 0.1 {
                assert!(
                    (b - lin(z)).abs() < 0.05 * lin(z),
                    "z {z}: {b} vs {}",
                    lin(z)
                );
            }
            // A short chord puts the centre higher, a long one lower.
            assert!(e.chord_short_mm > 0.0 && e.chord_long_mm < 0.0);
            if (0.6..=1.6).contains(&z) {
                assert!(b <= 1e-3, "z {z}: {b}");
            }
        }
        // The sensitivity rises without bound as Z → 0; the error of a ±0.5 µm chord rises
        // to the chord's sagitta relation at the equator: √(R² − (R − a/2)²).
        for (z, at_least) in [(0.1, 4.5e-3), (0.05, 9e-3), (0.01, 2e-2)] {
            assert!(s.z_error(z).bound() > at_least, "z {z}");
        }
        let at_equator = (r * r - (r - 0.25e-3).powi(2)).sqrt();
        assert!((s.z_error(0.0).bound() - at_equator).abs() < 1e-12);
        assert!(at_equator > 0.03);
    }

    #[test]
    fn the_working_window_starts_where_the_bound_meets_the_tolerance() {
        let s = sensor();
        let w = s.working_window(1e-3).expect("a window");
        // √(R² − Z²)/(2Z)·a = t  ⇒  Z = R/√(1 + (2t/a)²) to first order: R/√17 for t = 2a.
        let r = 2.0001_f64;
        let z_first = r / 17.0_f64.sqrt();
        assert!((w.z_min_mm - z_first).abs() < 0.01, "{}", w.z_min_mm);
        assert!(w.z_min_mm < 0.6 && (w.z_max_mm - r).abs() < 1e-9);
        // A minimum chord of 2.4 mm ends the window at √(R² − 1.2²).
        let s = BallSensor {
            min_chord_mm: 2.4,
            ..sensor()
        };
        let w = s.working_window(1e-3).expect("a window");
        assert!((w.z_max_mm - (r * r - 1.44).sqrt()).abs() < 1e-12);
        // Impossible demands give no window.
        assert!(s.working_window(1e-9).is_none());
        let s = BallSensor {
            min_chord_mm: 4.1,
            ..sensor()
        };
        assert!(s.working_window(1e-3).is_none());
    }

    #[test]
    fn a_raised_sheet_shifts_z_and_a_skewed_band_mixes_x_into_y() {
        // Micrometer A's sheet 20 µm higher than B's: Z from A is 20 µm short, from B exact.
        let mut s = sensor();
        s.a.origin = Point3::new(0.0, 0.0, 0.02);
        let c = Point3::new(0.3, 0.2, 1.0);
        let (a, b) = s.read(&c).expect("in range");
        let got = s.centre(&a, &b).expect("possible");
        assert!((got.centre_mm[2] - 0.98).abs() < 1e-12);
        assert!((got.z_from_b_mm - 1.0).abs() < 1e-12);
        // A's band turned by ε about Z: Y reads y cos ε − x sin ε.
        let mut s = sensor();
        let e = 1e-3_f64;
        s.a.band = UnitVector3::new_normalize(Vector3::new(-e.sin(), e.cos(), 0.0));
        s.a.beam = UnitVector3::new_normalize(Vector3::new(e.cos(), e.sin(), 0.0));
        let (a, b) = s.read(&c).expect("in range");
        let got = s.centre(&a, &b).expect("possible");
        assert!((got.centre_mm[1] - (0.2 * e.cos() - 0.3 * e.sin())).abs() < 1e-12);
    }

    #[test]
    fn readings_outside_the_light_or_the_range_are_refused() {
        let s = sensor();
        assert!(matches!(
            s.read(&Point3::new(0.0, 0.0, 2.5)),
            Err(SensorError::NotInLight { which: 'A', .. })
        ));
        assert!(matches!(
            s.read(&Point3::new(0.0, 1.5, 0.5)),
            Err(SensorError::OutsideRange { which: 'A', .. })
        ));
        let long = Reading { l1: 3.0, l2: 4.01 };
        let ok = Reading { l1: 3.0, l2: 3.9 };
        assert!(s.centre(&long, &ok).is_err());
        assert!(
            s.centre(
                &ok,
                &Reading {
                    l1: 3.0,
                    l2: f64::NAN
                }
            )
            .is_err()
        );
    }

    #[test]
    fn a_chord_is_refused_only_beyond_the_diameter_plus_the_accuracy() {
        // A micrometer reads the true chord within ±a, and no chord of a ball is longer than
        // its diameter D: D + a is the longest possible reading (the equator read a long).
        let s = sensor();
        let (d, a) = (4.0002, 0.5e-3);
        let other = Reading { l1: 3.0, l2: 3.9 };
        let at = |l2: Real| {
            s.centre(
                &Reading {
                    l1: 5.0 - 0.5 * l2,
                    l2,
                },
                &other,
            )
        };
        // Just inside: the centre is taken to be in the sheet, Z = 0.
        for l2 in [d, d + 0.5 * a, d + 0.999 * a] {
            let c = at(l2).expect("a possible reading");
            assert_eq!(c.centre_mm[2], 0.0, "L2 = D + {} µm", (l2 - d) * 1e3);
        }
        // A chord read a long above the equator: Z from the half-chord (L2/2)² + Z² = R².
        let z = 0.01;
        let chord = 2.0 * (0.25 * d * d - z * z).sqrt();
        let c = at(chord + 0.5 * a).expect("possible");
        let half = 0.5 * (chord + 0.5 * a);
        assert!((c.centre_mm[2] - (0.25 * d * d - half * half).max(0.0).sqrt()).abs() < 1e-12);
        // Beyond D + a no ball gives the reading.
        for l2 in [d + 1.001 * a, d + 1.5 * a, d + 2.0 * a] {
            let e = at(l2).expect_err("longer than any chord read within ±a");
            assert!(
                e.to_string().contains("longer than the ball's diameter"),
                "{e}"
            );
        }
    }

    #[test]
    fn noisy_readings_scatter_z_as_the_propagated_uncertainty_says() {
        // Gaussian chord noise σ: Z scatters by σ·√(R² − Z²)/(2Z) (first order).
        let s = sensor();
        let rng = CounterRng::new(3);
        let sigma = 0.2e-3;
        for &z in &[0.6, 1.0, 1.6] {
            let c = Point3::new(0.1, -0.2, z);
            let (a, b) = s.read(&c).expect("in range");
            let n = 4000;
            let zs: Vec<Real> = (0..n)
                .map(|i| {
                    let a = Reading {
                        l2: a.l2 + sigma * rng.normal(i),
                        ..a
                    };
                    s.centre(&a, &b).expect("possible").centre_mm[2]
                })
                .collect();
            let m = zs.iter().sum::<Real>() / n as Real;
            let sd = (zs.iter().map(|v| (v - m).powi(2)).sum::<Real>() / (n - 1) as Real).sqrt();
            let r = 2.0001_f64;
            let want = sigma * (r * r - z * z).sqrt() / (2.0 * z);
            assert!((sd - want).abs() < 0.05 * want, "z {z}: {sd} vs {want}");
        }
    }

    #[test]
    fn readings_files_fail_with_their_place() {
        let p = Path::new("s.csv");
        let s = sensor();
        let run = |t: &str| {
            parse_readings(t, p)
                .and_then(|rows| centres(&s, &rows, p))
                .map(|_| ())
                .map_err(|e| e.to_string())
        };
        assert!(run("Lx1,Lx2,Ly1,Ly2\n3.1,3.8,3.0,3.9\n").is_ok());
        assert!(
            run("Lx1,Lx2,Ly1\n")
                .unwrap_err()
                .contains("'Ly2' is missing")
        );
        assert!(
            run("Lx1,Lx2,Ly1,Ly2\n3,nan,3,3.9\n")
                .unwrap_err()
                .starts_with("s.csv:2:3:")
        );
        assert!(
            run("Lx1[ft],Lx2,Ly1,Ly2\n")
                .unwrap_err()
                .contains("unknown unit")
        );
        // Outside the 10 mm band: L1 + L2 > L0.
        let e = run("Lx1,Lx2,Ly1,Ly2\n3.1,3.8,\n3.1,3.8,7.0,3.9\n").unwrap_err();
        assert!(e.starts_with("s.csv:2:1:"), "{e}");
        let e = run("Lx1,Lx2,Ly1,Ly2\n3.1,3.8,7.0,3.9\n").unwrap_err();
        assert!(
            e.starts_with("s.csv:2:1:") && e.contains("outside its band"),
            "{e}"
        );
    }
}
