//! Arcs (G2/G3): the centre from I/J/K or R, checked with LinuxCNC's tolerances and
//! messages, full turns (P), helices, and the machine geometry of the arc after the offsets
//! and the XY rotation.

use crate::math::{Point3, Real, Vector3};
use crate::nc::AxisValues;
use crate::nc::comp::{PlaneMove, PlaneMoveKind};
use crate::nc::lex::Block;
use crate::nc::output::{ArcGeom, Motion, MotionKind, Plane};

use super::errors::LR;
use super::{FeedMode, Interpreter, MM_PER_INCH};

/// Center-format arc: allowed difference of start and end radius, inch programs (LinuxCNC
/// default `CENTER_ARC_RADIUS_TOLERANCE_INCH`).
const ARC_CENTER_TOL_INCH: Real = 2.0 * 0.001 * std::f64::consts::SQRT_2;
/// Same for mm programs.
const ARC_CENTER_TOL_MM: Real = 2.0 * 0.01 * std::f64::consts::SQRT_2;
/// Above this relative radius difference a center-format arc is rejected (0.1 %).
const ARC_CENTER_REL_TOL: Real = 0.001;
/// R-format arc: how much the chord may exceed the diameter (inch).
const ARC_R_TOL_INCH: Real = 0.00005;
/// Same, mm.
const ARC_R_TOL_MM: Real = 0.00127;
/// A zero-length-radius test used by LinuxCNC's R-format arcs.
const ARC_TINY: Real = 1e-12;
/// Angle tolerance when computing an arc's sweep (radians).
const SWEEP_EPS: Real = 1e-12;

impl Interpreter {
    pub(super) fn arc(&mut self, m: i32, b: &Block) -> LR<()> {
        let (a1, a2, _) = self.plane.axes();
        let off_letters = match self.plane {
            Plane::Xy => (b'i', b'j'),
            Plane::Xz => (b'k', b'i'),
            Plane::Yz => (b'j', b'k'),
        };
        let start_p = self.prog();
        let end_p = self.target(b)?;
        let inch = self.u != 1.0;
        let r_word = b.word(b'r');
        let o1 = b.word(off_letters.0);
        let o2 = b.word(off_letters.1);
        let code = m;
        let axis_letters = [b'x', b'y', b'z'];
        let in_plane_given =
            b.word(axis_letters[a1]).is_some() || b.word(axis_letters[a2]).is_some();
        if r_word.is_none() && o1.is_none() && o2.is_none() {
            return Err(self.err_g(b, code, "R i j k words all missing for arc"));
        }
        let rotation_mag = match b.word(b'p') {
            Some(p) => {
                let pi = p.round();
                if pi < 1.0 || (p - pi).abs() > 1e-4 {
                    return Err(self.err_word(b, b'p', "P value not an integer with G2 or G3"));
                }
                pi as i32
            }
            None => 1,
        };
        let turn = if m == 20 { -rotation_mag } else { rotation_mag };
        let (s1, s2) = (start_p[a1], start_p[a2]);
        let (e1, e2) = (end_p[a1], end_p[a2]);
        let (c1, c2);
        if let Some(r) = r_word {
            if !in_plane_given {
                return Err(self.err_g(
                    b,
                    code,
                    "First axis and second axis both missing with R-format arc",
                ));
            }
            let r = r * self.u;
            let tol = if inch {
                ARC_R_TOL_INCH * MM_PER_INCH
            } else {
                ARC_R_TOL_MM
            };
            if e1 == s1 && e2 == s2 {
                return Err(self.err_g(b, code, "Current point same as end point of arc"));
            }
            let abs_r = r.abs();
            let (m1, m2) = ((e1 + s1) / 2.0, (e2 + s2) / 2.0);
            let mut half = ((m1 - e1).powi(2) + (m2 - e2).powi(2)).sqrt();
            if half - abs_r > tol {
                return Err(self.err_word(b, b'r', "Arc radius too small to reach end point"));
            }
            if half / abs_r > 1.0 - ARC_TINY {
                half = abs_r;
            }
            let base = (e2 - s2).atan2(e1 - s1);
            let theta = if (m == 20 && r > 0.0) || (m == 30 && r < 0.0) {
                base - std::f64::consts::FRAC_PI_2
            } else {
                base + std::f64::consts::FRAC_PI_2
            };
            let t2 = (half / abs_r).asin();
            let off = abs_r * t2.cos();
            c1 = m1 + off * theta.cos();
            c2 = m2 + off * theta.sin();
        } else {
            let i1 = o1.unwrap_or(0.0) * self.u;
            let i2 = o2.unwrap_or(0.0) * self.u;
            if self.arc_incremental {
                c1 = s1 + i1;
                c2 = s2 + i2;
            } else {
                c1 = i1;
                c2 = i2;
            }
            let r1 = ((c1 - s1).powi(2) + (c2 - s2).powi(2)).sqrt();
            let r2 = ((c1 - e1).powi(2) + (c2 - e2).powi(2)).sqrt();
            let tol = if inch {
                ARC_CENTER_TOL_INCH * MM_PER_INCH
            } else {
                ARC_CENTER_TOL_MM
            };
            if r1 < 0.1 * tol * 1e-3 || r2 < 0.1 * tol * 1e-3 {
                return Err(self.err_g(b, code, "Zero radius arc"));
            }
            let abs_err = (r1 - r2).abs();
            let rel_err = abs_err / r1.max(r2);
            if abs_err > 100.0 * tol || (abs_err > tol && rel_err > ARC_CENTER_REL_TOL) {
                let u = self.u;
                let (n1, n2) = (arc_name(self.plane, true), arc_name(self.plane, false));
                let msg = format!(
                    "Radius to end of arc differs from radius to start: start=({n1}{:.4},{n2}{:.4}) center=({n1}{:.4},{n2}{:.4}) end=({n1}{:.4},{n2}{:.4}) r1={:.4} r2={:.4} abs_err={} rel_err={}%",
                    s1 / u,
                    s2 / u,
                    c1 / u,
                    c2 / u,
                    e1 / u,
                    e2 / u,
                    r1 / u,
                    r2 / u,
                    fmt_g4(abs_err / u),
                    fmt_g4(rel_err * 100.0)
                );
                return Err(self.err_g(b, code, msg));
            }
        }
        let (end_m, geom, len) = self.arc_geometry(&end_p, c1, c2, turn);
        let f = self.feed_for(b, code, len)?;
        if self.comp.is_some() {
            let plane = self.comp_plane;
            let (end2, along) = plane.split([end_p[0], end_p[1], end_p[2]]);
            let mut cen = end_p;
            cen[a1] = c1;
            cen[a2] = c2;
            let (center, _) = plane.split([cen[0], cen[1], cen[2]]);
            let payload = self.payload(Some(f), &end_p);
            let mv = PlaneMove {
                kind: PlaneMoveKind::Arc {
                    center,
                    ccw: turn > 0,
                    turns: turn.unsigned_abs(),
                },
                end: end2,
                along,
                payload,
            };
            self.push_comp(mv, b, code)?;
            self.prog_override = Some(end_p);
            return Ok(());
        }
        let mot = Motion {
            kind: MotionKind::Arc,
            start: AxisValues::from_array(self.mpos),
            end: AxisValues::from_array(end_m),
            feed: Some(f),
            feed_per_rev: self.feed_mode == FeedMode::PerRev,
            arc: Some(geom),
        };
        self.motion(mot);
        self.mpos = end_m;
        Ok(())
    }

    /// Machine geometry of an arc from the machine position to program point `end_p`
    /// about the program-plane centre (`c1`, `c2`): end, geometry, length (mm).
    pub(super) fn arc_geometry(
        &self,
        end_p: &[Real; 6],
        c1: Real,
        c2: Real,
        turn: i32,
    ) -> ([Real; 6], ArcGeom, Real) {
        self.arc_geometry_from(&self.mpos, end_p, c1, c2, turn)
    }

    /// [`Interpreter::arc_geometry`] of an arc that starts at machine position `start_m`.
    pub(super) fn arc_geometry_from(
        &self,
        start_m: &[Real; 6],
        end_p: &[Real; 6],
        c1: Real,
        c2: Real,
        turn: i32,
    ) -> ([Real; 6], ArcGeom, Real) {
        let (a1, a2, an) = self.plane.axes();
        let mut cen_p = *end_p;
        cen_p[a1] = c1;
        cen_p[a2] = c2;
        let cm = self.to_machine(&cen_p);
        let end_m = self.to_machine(end_p);
        let mut normal = [0.0; 3];
        normal[an] = 1.0;
        let mut ux = [0.0; 3];
        ux[a1] = 1.0;
        let mut uy = [0.0; 3];
        uy[a2] = 1.0;
        let (s, c) = self.rot.to_radians().sin_cos();
        let rz = |v: [Real; 3]| [v[0] * c - v[1] * s, v[0] * s + v[1] * c, v[2]];
        let (normal, ux, uy) = (rz(normal), rz(ux), rz(uy));
        let proj = |p: &[Real; 6]| {
            let d = [p[0] - cm[0], p[1] - cm[1], p[2] - cm[2]];
            (
                d[0] * ux[0] + d[1] * ux[1] + d[2] * ux[2],
                d[0] * uy[0] + d[1] * uy[1] + d[2] * uy[2],
            )
        };
        let (q1, q2) = proj(start_m);
        let (w1, w2) = proj(&end_m);
        let radius = q1.hypot(q2);
        let radius_end = w1.hypot(w2);
        let ts = q2.atan2(q1);
        let mut te = w2.atan2(w1);
        if turn < 0 {
            if te + SWEEP_EPS >= ts {
                te -= 2.0 * std::f64::consts::PI;
            }
        } else if te - SWEEP_EPS <= ts {
            te += 2.0 * std::f64::consts::PI;
        }
        let full = if turn > 1 {
            turn - 1
        } else if turn < -1 {
            turn + 1
        } else {
            0
        };
        let sweep = te - ts + 2.0 * std::f64::consts::PI * full as Real;
        let helix = end_m[an] - start_m[an];
        let len = ((sweep * radius).powi(2) + helix * helix).sqrt();
        let geom = ArcGeom {
            center: Point3::new(cm[0], cm[1], cm[2]),
            normal: Vector3::new(normal[0], normal[1], normal[2]),
            plane: self.plane,
            rotation: turn,
            radius,
            radius_end,
            sweep_deg: sweep.to_degrees(),
        };
        (end_m, geom, len)
    }
}

fn arc_name(plane: Plane, first: bool) -> char {
    match (plane, first) {
        (Plane::Xy, true) => 'X',
        (Plane::Xy, false) => 'Y',
        (Plane::Xz, true) => 'Z',
        (Plane::Xz, false) => 'X',
        (Plane::Yz, true) => 'Y',
        (Plane::Yz, false) => 'Z',
    }
}

/// `%.4g`-like formatting used in LinuxCNC's arc error message.
fn fmt_g4(v: Real) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let mag = v.abs().log10().floor() as i32;
    let decimals = (3 - mag).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}
