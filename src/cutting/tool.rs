//! Cutting tools as solids of revolution in the tool frame T: the tip at the origin, the
//! axis along +z (towards the spindle).
//!
//! Every tool is described by its *profile*: the boundary of its half-section in the
//! (r, h) half-plane (r the distance from the axis, h the height above the tip), traced from
//! the tip up and closed at the axis. Flat, ball, bull-nose (torus corner), tapered flat and
//! tapered ball end mills are built from their catalogue sizes; any other cutter from a
//! validated list of lines and circular arcs ([`ProfileStep`]). Each tool also carries its
//! decomposition into convex revolved pieces ([`ConvexPiece`]: frusta and outward-convex
//! sphere/torus zones), which the exact ray/sweep code works on.
//!
//! Shank and holder are separate, non-cutting bodies ([`RevolvedBody`], gathered in a
//! [`ToolAssembly`]) for collision checks.
//!
//! **Invariant:** a `Tool` is always valid (finite, positive sizes, a monotone profile
//! closed at the axis); it is built only through its `try_*` constructors.
//! **Invariant:** the union of a tool's convex pieces is the tool, except on inward
//! (concave) arcs, where chords over-approximate it by at most [`CONCAVE_ARC_BOUND`].

use crate::math::Real;
use std::sync::Arc;

/// Largest distance (mm, Hausdorff) by which the chord frusta replacing an inward (concave)
/// profile arc may stand proud of the true arc: 0.1 µm, the same budget as the rotary
/// sub-step bound, five times below the 0.5 µm the face tests resolve.
pub const CONCAVE_ARC_BOUND: Real = 1e-4;

/// Most chords for one concave arc: beyond this the arc is too large for its radius to
/// meet [`CONCAVE_ARC_BOUND`] at a sane cost, and the profile is refused.
const MAX_CHORDS: usize = 4096;

/// The shape family of a tool.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ToolKind {
    /// Flat end mill: a cylinder of the tool radius from the tip up.
    Flat,
    /// Ball end mill: a hemisphere of the tool radius at the tip, then a cylinder.
    Ball,
    /// Bull-nose (torus) end mill: a flat bottom, a corner of radius `rc ≤ R`, a cylinder.
    BullNose,
    /// Tapered flat end mill: a flat tip of a given radius, then a cone widening upward.
    TaperedFlat,
    /// Tapered ball end mill: a ball tip with the cone tangent to it.
    TaperedBall,
    /// Any revolved profile of lines and arcs.
    Profile,
}

/// Errors for impossible tool geometry. Sizes are in mm, angles in degrees.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ToolError {
    /// Radius not positive or not finite.
    #[error("tool diameter must be positive and finite, got {0} mm")]
    BadDiameter(Real),
    /// Length too short for the shape, or not finite.
    #[error("tool length must be finite and exceed {min} mm for this shape, got {length} mm")]
    BadLength {
        /// The smallest admissible length (mm), exclusive.
        min: Real,
        /// The given length (mm).
        length: Real,
    },
    /// Corner radius not in [0, R] (R the tool radius) or not finite.
    #[error("corner radius must be in [0, {radius}] mm, got {corner} mm")]
    BadCornerRadius {
        /// The tool radius (mm).
        radius: Real,
        /// The given corner radius (mm).
        corner: Real,
    },
    /// Taper half-angle outside (0°, 90°) or not finite.
    #[error("taper half-angle must be in (0, 90) degrees, got {0}")]
    BadTaperAngle(Real),
    /// [`Tool::try_new`] only builds flat and ball tools; the others need more sizes.
    #[error("tool kind {0:?} needs its own constructor (corner radius, taper angle or profile)")]
    NeedsMoreSizes(ToolKind),
    /// A profile or body is invalid; `step` is the 0-based index of the offending step
    /// (the number of steps for problems of the whole profile).
    #[error("tool profile step {step}: {reason}")]
    BadProfile {
        /// Index of the offending step.
        step: usize,
        /// What is wrong.
        reason: String,
    },
}

/// One step of a profile, from the current point to `to` = [r, h] (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ProfileStep {
    /// A straight line.
    Line {
        /// End point [r, h].
        to: [Real; 2],
    },
    /// A circular arc about `center` = [r, h]. `convex` arcs bulge outward (away from the
    /// axis; counter-clockwise in the (r, h) plane going up), the others inward.
    Arc {
        /// End point [r, h].
        to: [Real; 2],
        /// Centre [r, h]; both ends must lie at the same distance from it.
        center: [Real; 2],
        /// Whether the arc bulges outward.
        convex: bool,
    },
}

/// A validated profile element, with its start point (r, h).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Element {
    /// A line from `a` to `b`.
    Line {
        /// Start [r, h].
        a: [Real; 2],
        /// End [r, h].
        b: [Real; 2],
    },
    /// An arc of radius `rho` about `c` from angle `th0` to `th1` (rad, measured from +r
    /// towards +h). Convex arcs have `−π/2 ≤ th0 < th1 ≤ π/2`, concave ones
    /// `π/2 ≤ th1 < th0 ≤ 3π/2` (h grows along the arc in both cases).
    Arc {
        /// Centre [r, h].
        c: [Real; 2],
        /// Radius (mm).
        rho: Real,
        /// Start angle (rad).
        th0: Real,
        /// End angle (rad).
        th1: Real,
    },
}

impl Element {
    fn point(c: [Real; 2], rho: Real, th: Real) -> [Real; 2] {
        [c[0] + rho * th.cos(), c[1] + rho * th.sin()]
    }

    /// Start point [r, h].
    pub fn start(&self) -> [Real; 2] {
        match *self {
            Element::Line { a, .. } => a,
            Element::Arc { c, rho, th0, .. } => Self::point(c, rho, th0),
        }
    }

    /// End point [r, h].
    pub fn end(&self) -> [Real; 2] {
        match *self {
            Element::Line { b, .. } => b,
            Element::Arc { c, rho, th1, .. } => Self::point(c, rho, th1),
        }
    }

    /// The element's radius at height `h`, if the element spans `h` (for a horizontal line,
    /// its larger end).
    pub fn radius_at(&self, h: Real) -> Option<Real> {
        let (s, e) = (self.start(), self.end());
        if h < s[1] || h > e[1] {
            return None;
        }
        match *self {
            Element::Line { a, b } => Some(if b[1] == a[1] {
                a[0].max(b[0])
            } else {
                a[0] + (b[0] - a[0]) * (h - a[1]) / (b[1] - a[1])
            }),
            Element::Arc { c, rho, th0, th1 } => {
                let w = (rho * rho - (h - c[1]).powi(2)).max(0.0).sqrt();
                Some(if th1 > th0 { c[0] + w } else { c[0] - w })
            }
        }
    }

    /// The point of the element nearest `p` = [r, h].
    pub fn nearest(&self, p: [Real; 2]) -> [Real; 2] {
        match *self {
            Element::Line { a, b } => {
                let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                let len2 = ex * ex + ey * ey;
                let s = if len2 > 0.0 {
                    (((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                [a[0] + s * ex, a[1] + s * ey]
            }
            Element::Arc { c, rho, th0, th1 } => {
                let (lo, hi) = (th0.min(th1), th0.max(th1));
                let mut th = (p[1] - c[1]).atan2(p[0] - c[0]);
                // Concave arcs lie in [π/2, 3π/2]: angles below −π/2 are taken one turn up.
                if lo >= std::f64::consts::FRAC_PI_2 && th < -std::f64::consts::FRAC_PI_2 {
                    th += std::f64::consts::TAU;
                }
                let (vr, vh) = (p[0] - c[0], p[1] - c[1]);
                let len = (vr * vr + vh * vh).sqrt();
                if (lo..=hi).contains(&th) && len > 0.0 {
                    [c[0] + vr * rho / len, c[1] + vh * rho / len]
                } else {
                    let d = |q: [Real; 2]| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
                    let (s, e) = (self.start(), self.end());
                    if d(s) <= d(e) { s } else { e }
                }
            }
        }
    }

    /// The largest distance of the element from the point (0, `hc`) on the axis.
    fn farthest_from(&self, hc: Real) -> Real {
        let d = |p: [Real; 2]| p[0].hypot(p[1] - hc);
        let ends = d(self.start()).max(d(self.end()));
        match *self {
            Element::Line { .. } => ends,
            Element::Arc { c, rho, th0, th1 } => {
                // The circle's farthest point from (0, hc) is along the ray from it through c.
                let th = (c[1] - hc).atan2(c[0]);
                let (lo, hi) = (th0.min(th1), th0.max(th1));
                let inside = [th, th + std::f64::consts::TAU, th - std::f64::consts::TAU]
                    .iter()
                    .any(|t| (lo..=hi).contains(t));
                if inside {
                    ends.max(c[0].hypot(c[1] - hc) + rho)
                } else {
                    ends
                }
            }
        }
    }
}

/// A validated profile: elements from the tip (0, 0) up, closed at the axis.
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    elements: Vec<Element>,
    radius: Real,
    height: Real,
}

/// Snap tolerance for profile validation (mm): ends of consecutive elements, an arc's two
/// radii and "on the axis" agree within this; 1 nm, far below any catalogue dimension and
/// far above rounding of sizes given in mm.
const PROFILE_SNAP: Real = 1e-6;

impl Profile {
    /// Validates `steps` starting at the tip (0, 0). Every point must be finite with r ≥ 0,
    /// h must never decrease, no step may be empty or retrace the previous one, and the
    /// last step must end on the axis.
    pub fn try_new(steps: &[ProfileStep]) -> Result<Self, ToolError> {
        let bad = |step: usize, reason: &str| ToolError::BadProfile {
            step,
            reason: reason.to_string(),
        };
        if steps.is_empty() {
            return Err(bad(0, "a profile needs at least one step"));
        }
        let mut at = [0.0, 0.0];
        let mut elements = Vec::with_capacity(steps.len());
        let mut prev_dir: Option<Real> = None;
        for (i, step) in steps.iter().enumerate() {
            let to = match step {
                ProfileStep::Line { to } | ProfileStep::Arc { to, .. } => *to,
            };
            if !to.iter().all(|x| x.is_finite()) {
                return Err(bad(i, "end point is not finite"));
            }
            if to[0] < 0.0 {
                return Err(bad(i, "end point has r < 0 (left of the axis)"));
            }
            if to[1] < at[1] {
                return Err(bad(i, "height decreases (profiles go from the tip up)"));
            }
            if (to[0] - at[0]).hypot(to[1] - at[1]) <= PROFILE_SNAP {
                return Err(bad(i, "step has zero length"));
            }
            let el = match step {
                ProfileStep::Line { .. } => {
                    if to[1] == at[1] {
                        // Horizontal: going back over the previous horizontal step retraces it.
                        let dir = (to[0] - at[0]).signum();
                        if prev_dir == Some(-dir) {
                            return Err(bad(i, "horizontal step retraces the previous one"));
                        }
                        prev_dir = Some(dir);
                    } else {
                        prev_dir = None;
                    }
                    Element::Line { a: at, b: to }
                }
                ProfileStep::Arc { center, convex, .. } => {
                    prev_dir = None;
                    if !center.iter().all(|x| x.is_finite()) {
                        return Err(bad(i, "arc centre is not finite"));
                    }
                    let r0 = (at[0] - center[0]).hypot(at[1] - center[1]);
                    let r1 = (to[0] - center[0]).hypot(to[1] - center[1]);
                    if (r0 - r1).abs() > PROFILE_SNAP || r0 <= PROFILE_SNAP {
                        return Err(bad(i, "arc ends are not on one circle about the centre"));
                    }
                    let rho = 0.5 * (r0 + r1);
                    let a0 = (at[1] - center[1]).atan2(at[0] - center[0]);
                    let a1 = (to[1] - center[1]).atan2(to[0] - center[0]);
                    let half = std::f64::consts::FRAC_PI_2;
                    let snap = PROFILE_SNAP / rho;
                    let (th0, th1) = if *convex {
                        // Right half of the circle: angles in [−π/2, π/2], increasing.
                        let fix = |a: Real| {
                            if a < -half && a > -half - snap {
                                -half
                            } else if a > half && a < half + snap {
                                half
                            } else {
                                a
                            }
                        };
                        (fix(a0), fix(a1))
                    } else {
                        // Left half: angles in [π/2, 3π/2], decreasing along the arc.
                        let wrap = |a: Real| {
                            if a < 0.0 {
                                a + std::f64::consts::TAU
                            } else {
                                a
                            }
                        };
                        let fix = |a: Real| {
                            let a = wrap(a);
                            if a < half && a > half - snap {
                                half
                            } else if a > 3.0 * half && a < 3.0 * half + snap {
                                3.0 * half
                            } else {
                                a
                            }
                        };
                        (fix(a0), fix(a1))
                    };
                    let ok = if *convex {
                        (-half..=half).contains(&th0) && (-half..=half).contains(&th1) && th1 > th0
                    } else {
                        (half..=3.0 * half).contains(&th0)
                            && (half..=3.0 * half).contains(&th1)
                            && th1 < th0
                    };
                    if !ok {
                        return Err(bad(
                            i,
                            "arc is not monotone in h (it would turn back down) for its bulge",
                        ));
                    }
                    // Lowest r on the arc: ends for convex arcs; the leftmost point (angle π)
                    // for concave arcs that pass it.
                    if !*convex
                        && th1 <= std::f64::consts::PI
                        && std::f64::consts::PI <= th0
                        && center[0] - rho < -PROFILE_SNAP
                    {
                        return Err(bad(i, "arc crosses the axis (r < 0)"));
                    }
                    Element::Arc {
                        c: *center,
                        rho,
                        th0,
                        th1,
                    }
                }
            };
            elements.push(el);
            at = to;
        }
        if at[0] > PROFILE_SNAP {
            return Err(bad(
                steps.len(),
                "profile must end on the axis (r = 0) to close the solid",
            ));
        }
        let height = at[1];
        let mut radius: Real = 0.0;
        for e in &elements {
            radius = radius.max(e.start()[0]).max(e.end()[0]);
            if let Element::Arc { c, rho, th0, th1 } = *e
                && th0.min(th1) <= 0.0
                && 0.0 <= th0.max(th1)
            {
                radius = radius.max(c[0] + rho);
            }
        }
        if !(height > PROFILE_SNAP && radius > PROFILE_SNAP) {
            return Err(bad(steps.len(), "profile encloses no volume"));
        }
        Ok(Self {
            elements,
            radius,
            height,
        })
    }

    /// The elements, from the tip up.
    pub fn elements(&self) -> &[Element] {
        &self.elements
    }

    /// Largest radius (mm).
    pub fn radius(&self) -> Real {
        self.radius
    }

    /// Height of the top (mm).
    pub fn height(&self) -> Real {
        self.height
    }

    /// The solid's radius at height `h`: the largest element radius there (`None` outside
    /// [0, height]).
    pub fn radius_at(&self, h: Real) -> Option<Real> {
        self.elements
            .iter()
            .filter_map(|e| e.radius_at(h))
            .reduce(Real::max)
    }

    /// Whether (r, h) is inside the solid.
    pub fn contains(&self, r: Real, h: Real) -> bool {
        self.radius_at(h).is_some_and(|rad| r <= rad)
    }

    /// The signed distance (mm; + outside, − inside) of the point [r, h] (r ≥ 0) from the
    /// solid's surface, and the surface point nearest it: the nearest point of the elements
    /// (a surface of revolution's nearest point lies in the point's own meridian plane),
    /// negative where the solid holds the point.
    pub fn signed_distance(&self, r: Real, h: Real) -> (Real, [Real; 2]) {
        let (d, q) = self
            .elements
            .iter()
            .map(|e| {
                let q = e.nearest([r, h]);
                ((r - q[0]).powi(2) + (h - q[1]).powi(2), q)
            })
            .fold(
                (Real::INFINITY, [r, h]),
                |a, b| if b.0 < a.0 { b } else { a },
            );
        let d = d.sqrt();
        (if self.contains(r, h) { -d } else { d }, q)
    }

    /// The largest distance of a point of the solid from the axis point at height `hc`.
    pub fn farthest_from(&self, hc: Real) -> Real {
        self.elements
            .iter()
            .map(|e| e.farthest_from(hc))
            .fold(0.0, Real::max)
    }

    /// The convex revolved pieces whose union is the solid (concave arcs replaced by chord
    /// frusta within [`CONCAVE_ARC_BOUND`]).
    pub fn convex_pieces(&self) -> Result<Vec<ConvexPiece>, ToolError> {
        let mut out = Vec::new();
        for (i, e) in self.elements.iter().enumerate() {
            match *e {
                Element::Line { a, b } => {
                    if b[1] > a[1] {
                        out.push(ConvexPiece::Frustum {
                            h0: a[1],
                            h1: b[1],
                            r0: a[0],
                            r1: b[0],
                        });
                    }
                }
                Element::Arc { c, rho, th0, th1 } if th1 > th0 => {
                    out.push(ConvexPiece::Zone { c, rho, th0, th1 });
                }
                Element::Arc { c, rho, th0, th1 } => {
                    // Concave: chords of angle δ stand proud by the sagitta ρ(1 − cos δ/2).
                    let sweep = th0 - th1;
                    let max_step = 2.0 * (1.0 - CONCAVE_ARC_BOUND / rho).clamp(-1.0, 1.0).acos();
                    let n = (sweep / max_step).ceil().max(1.0);
                    if n.is_nan() || n > MAX_CHORDS as Real {
                        return Err(ToolError::BadProfile {
                            step: i,
                            reason: format!(
                                "concave arc needs more than {MAX_CHORDS} chords to stay within {CONCAVE_ARC_BOUND} mm"
                            ),
                        });
                    }
                    let n = n as usize;
                    let mut p = Element::point(c, rho, th0);
                    for k in 1..=n {
                        let q = Element::point(c, rho, th0 - sweep * k as Real / n as Real);
                        if q[1] > p[1] {
                            out.push(ConvexPiece::Frustum {
                                h0: p[1],
                                h1: q[1],
                                r0: p[0].max(0.0),
                                r1: q[0].max(0.0),
                            });
                        }
                        p = q;
                    }
                }
            }
        }
        Ok(out)
    }
}

/// A convex solid of revolution about the tool axis (heights above the tip, mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ConvexPiece {
    /// `h0 ≤ h ≤ h1`, `r ≤ r0 + (r1 − r0)(h − h0)/(h1 − h0)`: a cylinder, cone or frustum.
    Frustum {
        /// Bottom height.
        h0: Real,
        /// Top height (> h0).
        h1: Real,
        /// Bottom radius.
        r0: Real,
        /// Top radius.
        r1: Real,
    },
    /// The slab of an outward arc: `h` between the arc's ends, `r ≤ c_r + sqrt(ρ² − (h − c_h)²)`.
    /// A sphere zone when `c_r = 0`, a torus zone otherwise. Angles as in [`Element::Arc`].
    Zone {
        /// Centre [r, h].
        c: [Real; 2],
        /// Radius.
        rho: Real,
        /// Lower angle (rad).
        th0: Real,
        /// Upper angle (rad).
        th1: Real,
    },
}

impl ConvexPiece {
    /// The height range [h0, h1].
    pub fn heights(&self) -> (Real, Real) {
        match *self {
            ConvexPiece::Frustum { h0, h1, .. } => (h0, h1),
            ConvexPiece::Zone { c, rho, th0, th1 } => {
                (c[1] + rho * th0.sin(), c[1] + rho * th1.sin())
            }
        }
    }

    /// The largest radius.
    pub fn max_radius(&self) -> Real {
        match *self {
            ConvexPiece::Frustum { r0, r1, .. } => r0.max(r1),
            ConvexPiece::Zone { c, rho, th0, th1 } => {
                if th0 <= 0.0 && 0.0 <= th1 {
                    c[0] + rho
                } else {
                    c[0] + rho * th0.cos().max(th1.cos())
                }
            }
        }
    }

    /// The point of the half-section (r ≥ 0) maximising `ur·r + uh·h` for `ur ≥ 0`: the
    /// support point of the revolved piece in a direction with radial part `ur` and axial
    /// part `uh`.
    pub fn support_rh(&self, ur: Real, uh: Real) -> [Real; 2] {
        match *self {
            ConvexPiece::Frustum { h0, h1, r0, r1 } => {
                if ur * r0 + uh * h0 >= ur * r1 + uh * h1 {
                    [r0, h0]
                } else {
                    [r1, h1]
                }
            }
            ConvexPiece::Zone { c, rho, th0, th1 } => {
                let th = uh.atan2(ur).clamp(th0, th1);
                [c[0] + rho * th.cos(), c[1] + rho * th.sin()]
            }
        }
    }
}

/// Catalogue sizes of a tool (mm, degrees), as given to its constructor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ToolSizes {
    /// Flat or ball: diameter.
    Plain {
        /// Diameter (mm).
        diameter: Real,
    },
    /// Bull-nose: diameter and corner radius.
    BullNose {
        /// Diameter (mm).
        diameter: Real,
        /// Corner radius (mm).
        corner_radius: Real,
    },
    /// Tapered flat: tip diameter and taper half-angle.
    TaperedFlat {
        /// Tip diameter (mm).
        tip_diameter: Real,
        /// Half-angle (degrees).
        half_angle_deg: Real,
    },
    /// Tapered ball: ball diameter and taper half-angle.
    TaperedBall {
        /// Ball diameter (mm).
        ball_diameter: Real,
        /// Half-angle (degrees).
        half_angle_deg: Real,
    },
    /// A general profile (no catalogue sizes).
    Profile,
}

/// A cutting tool.
#[derive(Clone, Debug, PartialEq)]
pub struct Tool {
    kind: ToolKind,
    sizes: ToolSizes,
    radius: Real,
    length: Real,
    profile: Arc<Profile>,
    pieces: Arc<[ConvexPiece]>,
}

fn check_length(length: Real, min: Real) -> Result<(), ToolError> {
    if length.is_finite() && length > min {
        Ok(())
    } else {
        Err(ToolError::BadLength { min, length })
    }
}

fn check_diameter(diameter: Real) -> Result<Real, ToolError> {
    if diameter.is_finite() && diameter > 0.0 {
        Ok(diameter / 2.0)
    } else {
        Err(ToolError::BadDiameter(diameter))
    }
}

fn check_taper(deg: Real) -> Result<Real, ToolError> {
    if deg.is_finite() && deg > 0.0 && deg < 90.0 {
        Ok(deg.to_radians())
    } else {
        Err(ToolError::BadTaperAngle(deg))
    }
}

impl Tool {
    fn from_profile(
        kind: ToolKind,
        sizes: ToolSizes,
        steps: &[ProfileStep],
    ) -> Result<Self, ToolError> {
        let profile = Profile::try_new(steps)?;
        let pieces = profile.convex_pieces()?;
        Ok(Self {
            kind,
            sizes,
            radius: profile.radius(),
            length: profile.height(),
            profile: Arc::new(profile),
            pieces: pieces.into(),
        })
    }

    /// A flat or ball tool of `diameter` and cutting `length` from the tip (mm). Other kinds
    /// need their own constructor ([`ToolError::NeedsMoreSizes`]).
    pub fn try_new(kind: ToolKind, diameter: Real, length: Real) -> Result<Self, ToolError> {
        let r = check_diameter(diameter)?;
        check_length(length, r)?;
        let sizes = ToolSizes::Plain { diameter };
        match kind {
            ToolKind::Flat => Self::from_profile(
                kind,
                sizes,
                &[
                    ProfileStep::Line { to: [r, 0.0] },
                    ProfileStep::Line { to: [r, length] },
                    ProfileStep::Line { to: [0.0, length] },
                ],
            ),
            ToolKind::Ball => Self::from_profile(
                kind,
                sizes,
                &[
                    ProfileStep::Arc {
                        to: [r, r],
                        center: [0.0, r],
                        convex: true,
                    },
                    ProfileStep::Line { to: [r, length] },
                    ProfileStep::Line { to: [0.0, length] },
                ],
            ),
            other => Err(ToolError::NeedsMoreSizes(other)),
        }
    }

    /// A bull-nose end mill: `diameter`, corner radius `corner_radius` ∈ [0, R] (a flat end
    /// mill at 0, a ball end mill at R), cutting `length` > corner radius (mm).
    pub fn try_bull_nose(
        diameter: Real,
        corner_radius: Real,
        length: Real,
    ) -> Result<Self, ToolError> {
        let r = check_diameter(diameter)?;
        if !(corner_radius.is_finite() && corner_radius >= 0.0 && corner_radius <= r) {
            return Err(ToolError::BadCornerRadius {
                radius: r,
                corner: corner_radius,
            });
        }
        check_length(length, corner_radius)?;
        let a = r - corner_radius;
        let mut steps = Vec::with_capacity(4);
        if a > PROFILE_SNAP {
            steps.push(ProfileStep::Line { to: [a, 0.0] });
        }
        if corner_radius > PROFILE_SNAP {
            steps.push(ProfileStep::Arc {
                to: [r, corner_radius],
                center: [if a > PROFILE_SNAP { a } else { 0.0 }, corner_radius],
                convex: true,
            });
        }
        steps.push(ProfileStep::Line { to: [r, length] });
        steps.push(ProfileStep::Line { to: [0.0, length] });
        Self::from_profile(
            ToolKind::BullNose,
            ToolSizes::BullNose {
                diameter,
                corner_radius,
            },
            &steps,
        )
    }

    /// A tapered flat end mill: flat tip of `tip_diameter` > 0, flank widening at
    /// `half_angle_deg` ∈ (0°, 90°) from the axis, cutting `length` > 0 (mm).
    pub fn try_tapered_flat(
        tip_diameter: Real,
        half_angle_deg: Real,
        length: Real,
    ) -> Result<Self, ToolError> {
        let rt = check_diameter(tip_diameter)?;
        let alpha = check_taper(half_angle_deg)?;
        check_length(length, 0.0)?;
        let top = rt + length * alpha.tan();
        if !top.is_finite() {
            return Err(ToolError::BadTaperAngle(half_angle_deg));
        }
        Self::from_profile(
            ToolKind::TaperedFlat,
            ToolSizes::TaperedFlat {
                tip_diameter,
                half_angle_deg,
            },
            &[
                ProfileStep::Line { to: [rt, 0.0] },
                ProfileStep::Line { to: [top, length] },
                ProfileStep::Line { to: [0.0, length] },
            ],
        )
    }

    /// A tapered ball end mill: a ball tip of `ball_diameter`, the flank a cone of
    /// `half_angle_deg` ∈ (0°, 90°) tangent to the ball, cutting `length` (mm) above the
    /// tangency height ρ(1 − sin α).
    pub fn try_tapered_ball(
        ball_diameter: Real,
        half_angle_deg: Real,
        length: Real,
    ) -> Result<Self, ToolError> {
        let rho = check_diameter(ball_diameter)?;
        let alpha = check_taper(half_angle_deg)?;
        let (rt, ht) = Self::tapered_ball_tangency(rho, alpha);
        check_length(length, ht)?;
        let top = rt + (length - ht) * alpha.tan();
        if !top.is_finite() {
            return Err(ToolError::BadTaperAngle(half_angle_deg));
        }
        Self::from_profile(
            ToolKind::TaperedBall,
            ToolSizes::TaperedBall {
                ball_diameter,
                half_angle_deg,
            },
            &[
                ProfileStep::Arc {
                    to: [rt, ht],
                    center: [0.0, rho],
                    convex: true,
                },
                ProfileStep::Line { to: [top, length] },
                ProfileStep::Line { to: [0.0, length] },
            ],
        )
    }

    /// Where a cone of half-angle `alpha` (rad) touches a tip ball of radius `rho`:
    /// (r, h) = (ρ cos α, ρ(1 − sin α)).
    pub fn tapered_ball_tangency(rho: Real, alpha: Real) -> (Real, Real) {
        (rho * alpha.cos(), rho * (1.0 - alpha.sin()))
    }

    /// Any revolved cutter from its profile, traced from the tip (0, 0) up and closed at the
    /// axis (see [`Profile::try_new`]).
    pub fn try_profile(steps: &[ProfileStep]) -> Result<Self, ToolError> {
        Self::from_profile(ToolKind::Profile, ToolSizes::Profile, steps)
    }

    /// The shape family.
    pub fn kind(&self) -> ToolKind {
        self.kind
    }

    /// The catalogue sizes given to the constructor.
    pub fn sizes(&self) -> ToolSizes {
        self.sizes
    }

    /// Largest radius of the cutting part (mm): the tool radius for flat, ball and bull-nose.
    pub fn radius(&self) -> Real {
        self.radius
    }

    /// Cutting length from the tip (mm): the top of the profile.
    pub fn length(&self) -> Real {
        self.length
    }

    /// The validated profile.
    pub fn profile(&self) -> &Profile {
        &self.profile
    }

    /// The convex pieces the exact sweep works on.
    pub fn pieces(&self) -> &Arc<[ConvexPiece]> {
        &self.pieces
    }

    /// Height from which the tool is a cylinder of its full radius up to its length (the
    /// flank a side cut makes), if it has one.
    pub fn flank_start(&self) -> Option<Real> {
        let top = self
            .profile
            .elements()
            .iter()
            .rev()
            .find_map(|e| match *e {
                Element::Line { a, b }
                    if b[1] > a[1] && a[0] == self.radius && b[0] == self.radius =>
                {
                    Some(a[1])
                }
                _ => None,
            })?;
        (top < self.length).then_some(top)
    }

    /// The largest distance of a tool point from the tip (mm).
    pub fn reach(&self) -> Real {
        self.reach_from(0.0)
    }

    /// The largest distance of a tool point from the axis point at height `h` (mm).
    pub fn reach_from(&self, h: Real) -> Real {
        self.profile.farthest_from(h)
    }

    /// The signed distance (mm; + outside, − inside) of the tool-frame point `p` (the tip
    /// at the origin, the axis +z) from the tool's surface, and the tool's outward unit
    /// normal there (the direction from the nearest surface point to `p`, reversed inside;
    /// on the surface, or on the axis where every direction is nearest, the element's own
    /// normal is not known and the direction from the axis is taken).
    pub fn signed_distance(&self, p: &crate::math::Point3) -> (Real, crate::math::Vector3) {
        use crate::math::Vector3;
        let r = (p.x * p.x + p.y * p.y).sqrt();
        let (d, q) = match self.kind {
            ToolKind::Flat => flat_distance(self.radius, self.length, r, p.z),
            ToolKind::Ball => ball_distance(self.radius, self.length, r, p.z),
            _ => self.profile.signed_distance(r, p.z),
        };
        let radial = if r > 0.0 {
            Vector3::new(p.x / r, p.y / r, 0.0)
        } else {
            Vector3::x()
        };
        let (dr, dh) = (r - q[0], p.z - q[1]);
        let len = (dr * dr + dh * dh).sqrt();
        let n = if len > 0.0 {
            (radial * dr + Vector3::z() * dh) * (d.signum() / len)
        } else {
            radial
        };
        (d, n)
    }

    /// Whether the tool-frame point (radial distance `r`, height `h` above the tip) is inside.
    pub fn contains(&self, r: Real, h: Real) -> bool {
        if h > self.length || r > self.radius {
            return false;
        }
        match self.kind {
            ToolKind::Flat => h >= 0.0,
            ToolKind::Ball => {
                h >= self.radius || r * r + (h - self.radius).powi(2) <= self.radius * self.radius
            }
            _ => self.profile.contains(r, h),
        }
    }
}

/// [`Profile::signed_distance`] of a flat end mill's profile (radius `rad`, length `len`) in
/// closed form: the solid is the rectangle `r ≤ rad`, `0 ≤ h ≤ len` of the meridian plane.
/// Outside, its nearest point is the point clamped into it; inside, the nearest of the
/// bottom, the side and the top (in the profile's order on a tie).
fn flat_distance(rad: Real, len: Real, r: Real, h: Real) -> (Real, [Real; 2]) {
    if r > rad || h < 0.0 || h > len {
        let q = [r.min(rad), h.clamp(0.0, len)];
        return ((r - q[0]).hypot(h - q[1]), q);
    }
    let mut best = (h, [r, 0.0]);
    for c in [(rad - r, [rad, h]), (len - h, [r, len])] {
        if c.0 < best.0 {
            best = c;
        }
    }
    (-best.0, best.1)
}

/// [`Profile::signed_distance`] of a ball end mill's profile (radius `rad`, length
/// `len ≥ 2·rad`) in closed form: the solid is the half-disc `r² + (h − rad)² ≤ rad²` below
/// the centre height and the rectangle `r ≤ rad`, `rad ≤ h ≤ len` above it. Below the centre
/// the nearest point is on the circle (its radial projection, within the quarter arc for
/// every `r ≥ 0`): the side and the top are farther (the side's nearest point is the arc's
/// end, the top more than `rad` away). At or above it the arc's nearest point is its end
/// `(rad, rad)`, no nearer than the side, so the rectangle's sides decide as for a flat end
/// mill without a bottom.
fn ball_distance(rad: Real, len: Real, r: Real, h: Real) -> (Real, [Real; 2]) {
    if h < rad {
        let (vr, vh) = (r, h - rad);
        let dist = (vr * vr + vh * vh).sqrt();
        return (dist - rad, [vr * rad / dist, rad + vh * rad / dist]);
    }
    if r > rad || h > len {
        let q = [r.min(rad), h.clamp(rad, len)];
        return ((r - q[0]).hypot(h - q[1]), q);
    }
    if len - h < rad - r {
        (h - len, [r, len])
    } else {
        (r - rad, [rad, h])
    }
}

/// A non-cutting revolved body on the tool axis (shank, holder): a profile lifted to start
/// at height `base` above the tip.
#[derive(Clone, Debug, PartialEq)]
pub struct RevolvedBody {
    base: Real,
    profile: Profile,
}

impl RevolvedBody {
    /// A cylinder of `diameter` and `length` (mm) starting at height `base`.
    pub fn try_cylinder(base: Real, diameter: Real, length: Real) -> Result<Self, ToolError> {
        Self::try_frustum(base, diameter, diameter, length)
    }

    /// A frustum (cone when one diameter is zero) from `bottom_diameter` at height `base` to
    /// `top_diameter` at `base + length` (mm).
    pub fn try_frustum(
        base: Real,
        bottom_diameter: Real,
        top_diameter: Real,
        length: Real,
    ) -> Result<Self, ToolError> {
        if !base.is_finite() {
            return Err(ToolError::BadLength {
                min: 0.0,
                length: base,
            });
        }
        let ok = |d: Real| d.is_finite() && d >= 0.0;
        if !(ok(bottom_diameter) && ok(top_diameter) && bottom_diameter.max(top_diameter) > 0.0) {
            return Err(ToolError::BadDiameter(if ok(bottom_diameter) {
                top_diameter
            } else {
                bottom_diameter
            }));
        }
        check_length(length, 0.0)?;
        let mut steps = Vec::new();
        if bottom_diameter > 0.0 {
            steps.push(ProfileStep::Line {
                to: [bottom_diameter / 2.0, 0.0],
            });
        }
        steps.push(ProfileStep::Line {
            to: [top_diameter / 2.0, length],
        });
        if top_diameter > 0.0 {
            steps.push(ProfileStep::Line { to: [0.0, length] });
        }
        Ok(Self {
            base,
            profile: Profile::try_new(&steps)?,
        })
    }

    /// Height of the bottom above the tool tip (mm).
    pub fn base(&self) -> Real {
        self.base
    }

    /// Height of the top above the tool tip (mm).
    pub fn top(&self) -> Real {
        self.base + self.profile.height()
    }

    /// The body's profile, relative to its base.
    pub fn profile(&self) -> &Profile {
        &self.profile
    }

    /// Whether the tool-frame point (r, h) is inside.
    pub fn contains(&self, r: Real, h: Real) -> bool {
        self.profile.contains(r, h - self.base)
    }
}

/// A tool with its non-cutting shank and holder, for collision checks.
#[derive(Clone, Debug, PartialEq)]
pub struct ToolAssembly {
    /// The cutting part.
    pub tool: Tool,
    /// The shank, directly above the flutes.
    pub shank: Option<RevolvedBody>,
    /// The holder, above the shank (or the flutes).
    pub holder: Option<RevolvedBody>,
}

/// Sizes of shank and holder (mm); `None` fields mean no such body.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HolderSizes {
    /// Shank diameter and length above the flutes.
    pub shank: Option<(Real, Real)>,
    /// Holder bottom diameter, top diameter and length above the shank.
    pub holder: Option<(Real, Real, Real)>,
}

impl ToolAssembly {
    /// Stacks shank and holder on `tool`. The holder must not reach below the flutes' top.
    pub fn try_new(tool: Tool, sizes: HolderSizes) -> Result<Self, ToolError> {
        let mut base = tool.length();
        let shank = match sizes.shank {
            Some((d, l)) => {
                let b = RevolvedBody::try_cylinder(base, d, l)?;
                base = b.top();
                Some(b)
            }
            None => None,
        };
        let holder = match sizes.holder {
            Some((d0, d1, l)) => Some(RevolvedBody::try_frustum(base, d0, d1, l)?),
            None => None,
        };
        Ok(Self {
            tool,
            shank,
            holder,
        })
    }

    /// Whether (r, h) is inside a non-cutting body (shank or holder).
    pub fn non_cutting_contains(&self, r: Real, h: Real) -> bool {
        self.shank.as_ref().is_some_and(|b| b.contains(r, h))
            || self.holder.as_ref().is_some_and(|b| b.contains(r, h))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform numbers in [0, 1) from a xorshift generator started at `seed`.
    fn uniform(mut seed: u64) -> impl FnMut() -> Real {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as Real / (1u64 << 53) as Real
        }
    }

    #[test]
    fn flat_and_ball_closed_forms_agree_with_the_profile_elements() {
        // The closed forms against the general path through the profile's elements (each
        // element's nearest point, the least taken, the sign from `contains`), on random
        // points and on the ones where the nearest face changes: the axis, the faces, the
        // edges and the ball's centre.
        let (r, l) = (3.0, 20.0);
        let mut rand = uniform(0x9e37_79b9_7f4a_7c15);
        let mut points: Vec<[Real; 2]> = (0..20_000)
            .map(|_| [8.0 * rand(), 30.0 * rand() - 5.0])
            .collect();
        for x in [0.0, 1.5, r, r + 1.0] {
            for h in [-1.0, 0.0, 1.5, r, 10.0, l - 1.5, l, l + 1.0] {
                points.push([x, h]);
            }
        }
        for (kind, closed) in [
            (
                ToolKind::Flat,
                flat_distance as fn(Real, Real, Real, Real) -> _,
            ),
            (ToolKind::Ball, ball_distance),
        ] {
            let tool = Tool::try_new(kind, 2.0 * r, l).expect("valid");
            for &[x, h] in &points {
                let (d, q) = closed(r, l, x, h);
                let (want, _) = tool.profile().signed_distance(x, h);
                assert!(
                    (d - want).abs() <= 1e-12,
                    "{kind:?} at ({x}, {h}): {d} vs {want}"
                );
                // The point given is a nearest one: on the profile, at the distance found.
                assert!(((x - q[0]).hypot(h - q[1]) - d.abs()).abs() <= 1e-12);
                assert!(tool.profile().signed_distance(q[0], q[1]).0.abs() <= 1e-12);
            }
        }
    }

    #[test]
    fn the_signed_distance_is_the_distance_to_the_sampled_surface_and_its_foot_lies_on_it() {
        use crate::math::Point3;
        // (tool, its meridian outline sampled from its catalogue sizes, whether (r, h) is
        // inside): a flat and a ball end mill Ø6 × 20, a bull-nose Ø6 × 20 with a 1 mm corner.
        let (r, l, c) = (3.0, 20.0, 1.0);
        let steps = 4000;
        let line = |a: [Real; 2], b: [Real; 2]| -> Vec<[Real; 2]> {
            (0..=steps)
                .map(|k| {
                    let s = k as Real / steps as Real;
                    [a[0] + (b[0] - a[0]) * s, a[1] + (b[1] - a[1]) * s]
                })
                .collect()
        };
        let arc = |ctr: [Real; 2], rho: Real, t0: Real, t1: Real| -> Vec<[Real; 2]> {
            (0..=steps)
                .map(|k| {
                    let t = t0 + (t1 - t0) * k as Real / steps as Real;
                    [ctr[0] + rho * t.cos(), ctr[1] + rho * t.sin()]
                })
                .collect()
        };
        let top = line([r, l], [0.0, l]);
        let half = std::f64::consts::FRAC_PI_2;
        type Inside = fn(Real, Real) -> bool;
        let cases: [(Tool, Vec<[Real; 2]>, Inside); 3] = [
            (
                Tool::try_new(ToolKind::Flat, 2.0 * r, l).expect("valid"),
                [
                    line([0.0, 0.0], [r, 0.0]),
                    line([r, 0.0], [r, l]),
                    top.clone(),
                ]
                .concat(),
                |x, h| (0.0..=20.0).contains(&h) && x <= 3.0,
            ),
            (
                Tool::try_new(ToolKind::Ball, 2.0 * r, l).expect("valid"),
                [
                    arc([0.0, r], r, -half, 0.0),
                    line([r, r], [r, l]),
                    top.clone(),
                ]
                .concat(),
                |x, h| (3.0..=20.0).contains(&h) && x <= 3.0 || x * x + (h - 3.0).powi(2) <= 9.0,
            ),
            (
                Tool::try_bull_nose(2.0 * r, c, l).expect("valid"),
                [
                    line([0.0, 0.0], [r - c, 0.0]),
                    arc([r - c, c], c, -half, 0.0),
                    line([r, c], [r, l]),
                    top,
                ]
                .concat(),
                |x, h| {
                    (0.0..=20.0).contains(&h)
                        && x <= 3.0
                        && (h >= 1.0 || x <= 2.0 || (x - 2.0).powi(2) + (h - 1.0).powi(2) <= 1.0)
                },
            ),
        ];
        let spacing = 2.0 * std::f64::consts::PI * r / steps as Real;
        for (tool, outline, inside) in &cases {
            let mut rand = uniform(0x2545_f491_4f6c_dd1d);
            for _ in 0..400 {
                let p = Point3::new(
                    10.0 * rand() - 5.0,
                    10.0 * rand() - 5.0,
                    26.0 * rand() - 3.0,
                );
                let (x, h) = ((p.x * p.x + p.y * p.y).sqrt(), p.z);
                let (d, n) = tool.signed_distance(&p);
                let want = outline
                    .iter()
                    .map(|q| (x - q[0]).hypot(h - q[1]))
                    .fold(Real::INFINITY, Real::min);
                // The sampled outline's distance is at least the true one, and above it by
                // less than a sample spacing.
                assert!(d.abs() <= want + 1e-12, "{p:?}: {d} vs {want}");
                assert!(d.abs() >= want - spacing, "{p:?}: {d} vs {want}");
                assert_eq!(d < 0.0, inside(x, h), "{p:?}: {d}");
                // The outward normal is a unit vector and leads back to the surface.
                assert!((n.norm() - 1.0).abs() < 1e-12);
                let foot = p - n * d;
                assert!(tool.signed_distance(&foot).0.abs() < 1e-9, "{p:?}");
            }
        }
    }

    #[test]
    fn rejects_degenerate_tools() {
        assert!(Tool::try_new(ToolKind::Flat, 0.0, 10.0).is_err());
        assert!(Tool::try_new(ToolKind::Flat, Real::NAN, 10.0).is_err());
        assert!(Tool::try_new(ToolKind::Ball, 6.0, 2.0).is_err());
        assert!(Tool::try_new(ToolKind::Ball, 6.0, Real::INFINITY).is_err());
    }

    #[test]
    fn ball_contains_follows_the_hemisphere() {
        let t = Tool::try_new(ToolKind::Ball, 6.0, 20.0).expect("valid");
        assert!(t.contains(0.0, 0.0));
        assert!(!t.contains(2.9, 0.1));
        assert!(t.contains(2.9, 3.0));
    }

    /// Points on a grid of the (r, h) half-plane, avoiding the exact boundary.
    fn grid() -> impl Iterator<Item = (Real, Real)> {
        (0..=80).flat_map(|i| {
            (0..=130).map(move |j| (i as Real * 0.05 + 0.0013, j as Real * 0.05 - 0.3013))
        })
    }

    #[test]
    fn bull_nose_spans_flat_to_ball() {
        let ball = Tool::try_new(ToolKind::Ball, 6.0, 6.0).expect("valid");
        let flat = Tool::try_new(ToolKind::Flat, 6.0, 6.0).expect("valid");
        let b1 = Tool::try_bull_nose(6.0, 3.0, 6.0).expect("valid");
        let b0 = Tool::try_bull_nose(6.0, 0.0, 6.0).expect("valid");
        for (r, h) in grid() {
            assert_eq!(
                b1.contains(r, h),
                ball.contains(r, h),
                "rc = R at ({r}, {h})"
            );
            assert_eq!(
                b0.contains(r, h),
                flat.contains(r, h),
                "rc = 0 at ({r}, {h})"
            );
        }
        // Pieces: rc = R is one sphere zone and a cylinder, like the ball.
        assert_eq!(b1.pieces().len(), 2);
        assert!(matches!(
            b1.pieces()[0],
            ConvexPiece::Zone { c: [0.0, _], .. }
        ));
    }

    #[test]
    fn bull_nose_contains_the_torus_corner() {
        // R = 3, rc = 1: for h < 1, r ≤ 2 + sqrt(1 − (1 − h)²); above, r ≤ 3.
        let t = Tool::try_bull_nose(6.0, 1.0, 10.0).expect("valid");
        for (r, h) in grid() {
            let inside = (0.0..=10.0).contains(&h)
                && if h < 1.0 {
                    r <= 2.0 + (1.0 - (1.0 - h).powi(2)).sqrt()
                } else {
                    r <= 3.0
                };
            assert_eq!(t.contains(r, h), inside, "({r}, {h})");
        }
        // Reach from the tip: the top rim, hypot(3, 10).
        assert!((t.reach() - 3.0f64.hypot(10.0)).abs() < 1e-12);
        assert_eq!(t.flank_start(), Some(1.0));
    }

    #[test]
    fn tapered_tools_follow_their_cones() {
        // Tapered flat: tip radius 0.5, 10° half-angle, 12 long.
        let k = 10f64.to_radians().tan();
        let t = Tool::try_tapered_flat(1.0, 10.0, 12.0).expect("valid");
        assert!((t.radius() - (0.5 + 12.0 * k)).abs() < 1e-12);
        for (r, h) in grid() {
            let inside = (0.0..=12.0).contains(&h) && r <= 0.5 + h * k;
            assert_eq!(t.contains(r, h), inside, "({r}, {h})");
        }
        assert!((t.reach() - (0.5 + 12.0 * k).hypot(12.0)).abs() < 1e-12);
        assert_eq!(t.flank_start(), None);

        // Tapered ball: ball radius 1, 15°: tangency at (cos α, 1 − sin α).
        let al = 15f64.to_radians();
        let t = Tool::try_tapered_ball(2.0, 15.0, 10.0).expect("valid");
        let (rt, ht) = (al.cos(), 1.0 - al.sin());
        let p = t.profile();
        // Radius and slope are continuous at the tangency height.
        let eps = 1e-6;
        let below = p.radius_at(ht - eps).expect("inside");
        let above = p.radius_at(ht + eps).expect("inside");
        assert!((p.radius_at(ht).expect("inside") - rt).abs() < 1e-12);
        let slope_below = (rt - below) / eps;
        let slope_above = (above - rt) / eps;
        assert!((slope_below - al.tan()).abs() < 1e-4, "{slope_below}");
        assert!((slope_above - al.tan()).abs() < 1e-9, "{slope_above}");
        for (r, h) in grid() {
            let inside = (0.0..=10.0).contains(&h)
                && if h < ht {
                    r * r + (h - 1.0).powi(2) <= 1.0
                } else {
                    r <= rt + (h - ht) * al.tan()
                };
            assert_eq!(t.contains(r, h), inside, "({r}, {h})");
        }
    }

    #[test]
    fn reach_from_a_height_is_the_farthest_rim() {
        let t = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("valid");
        assert!((t.reach_from(10.0) - 3.0f64.hypot(10.0)).abs() < 1e-12);
        // A ball's farthest point from the tip is the top rim.
        let b = Tool::try_new(ToolKind::Ball, 6.0, 20.0).expect("valid");
        assert!((b.reach() - 3.0f64.hypot(20.0)).abs() < 1e-12);
        // From the ball centre (h = R) of a short tool: the rim at the top, hypot(R, L − R).
        let s = Tool::try_new(ToolKind::Ball, 6.0, 3.5).expect("valid");
        assert!((s.reach_from(3.0) - 3.0f64.hypot(0.5)).abs() < 1e-12);
        // From above the top, the ball's bottom is farthest: the sphere point on the axis.
        assert!((s.reach_from(10.0) - 10.0f64.max(7.0f64.hypot(3.0))).abs() < 1e-12);
    }

    #[test]
    fn bad_tools_give_errors() {
        use ToolError as E;
        let bn = |d, rc, l| Tool::try_bull_nose(d, rc, l);
        assert!(matches!(bn(6.0, 3.5, 10.0), Err(E::BadCornerRadius { .. })));
        assert!(matches!(
            bn(6.0, -0.1, 10.0),
            Err(E::BadCornerRadius { .. })
        ));
        assert!(matches!(
            bn(6.0, Real::NAN, 10.0),
            Err(E::BadCornerRadius { .. })
        ));
        assert!(matches!(bn(-6.0, 1.0, 10.0), Err(E::BadDiameter(_))));
        assert!(matches!(bn(6.0, 1.0, 0.5), Err(E::BadLength { .. })));
        assert!(matches!(
            bn(6.0, 1.0, Real::INFINITY),
            Err(E::BadLength { .. })
        ));
        for deg in [0.0, 90.0, -5.0, 95.0, Real::NAN, Real::INFINITY] {
            assert!(
                matches!(
                    Tool::try_tapered_flat(1.0, deg, 10.0),
                    Err(E::BadTaperAngle(_))
                ),
                "{deg}"
            );
            assert!(
                matches!(
                    Tool::try_tapered_ball(1.0, deg, 10.0),
                    Err(E::BadTaperAngle(_))
                ),
                "{deg}"
            );
        }
        assert!(matches!(
            Tool::try_tapered_flat(0.0, 10.0, 10.0),
            Err(E::BadDiameter(_))
        ));
        assert!(matches!(
            Tool::try_tapered_flat(1.0, 10.0, 0.0),
            Err(E::BadLength { .. })
        ));
        assert!(matches!(
            Tool::try_tapered_ball(2.0, 10.0, 0.5),
            Err(E::BadLength { .. })
        ));
        // Near 90° the cone's top radius overflows.
        assert!(Tool::try_tapered_flat(1.0, 89.999_999_999_999, 1e300).is_err());
        assert!(matches!(
            Tool::try_new(ToolKind::BullNose, 6.0, 10.0),
            Err(E::NeedsMoreSizes(_))
        ));

        let line = |r, h| ProfileStep::Line { to: [r, h] };
        let prof = |steps: &[ProfileStep]| match Tool::try_profile(steps) {
            Err(E::BadProfile { step, .. }) => step,
            other => panic!("expected a profile error, got {other:?}"),
        };
        assert_eq!(prof(&[]), 0);
        assert_eq!(
            prof(&[line(1.0, 0.0), line(1.0, Real::NAN), line(0.0, 2.0)]),
            1
        );
        assert_eq!(prof(&[line(1.0, 0.0), line(-1.0, 1.0), line(0.0, 2.0)]), 1);
        // h decreasing: not monotone.
        assert_eq!(prof(&[line(1.0, 1.0), line(1.5, 0.5), line(0.0, 2.0)]), 1);
        // Not closed at the axis.
        assert_eq!(prof(&[line(1.0, 0.0), line(1.0, 2.0)]), 2);
        // Zero-length step.
        assert_eq!(prof(&[line(1.0, 0.0), line(1.0, 0.0), line(0.0, 2.0)]), 1);
        // Self-intersecting: a horizontal step retracing the previous one.
        assert_eq!(
            prof(&[
                line(2.0, 0.0),
                line(1.0, 0.0),
                line(1.0, 2.0),
                line(0.0, 2.0)
            ]),
            1
        );
        // No volume: straight up the axis.
        assert_eq!(prof(&[line(0.0, 2.0)]), 1);
        // Arc ends not on one circle.
        let arc = |to, center, convex| ProfileStep::Arc { to, center, convex };
        assert_eq!(
            prof(&[arc([1.0, 1.2], [0.0, 1.0], true), line(0.0, 2.0)]),
            0
        );
        // Convex arc turning back down (passes the circle's top): not monotone.
        assert_eq!(
            prof(&[
                line(1.0, 0.0),
                arc([0.5, 1.0 + 0.75f64.sqrt()], [1.0, 1.0], true),
                line(0.0, 3.0)
            ]),
            1
        );
        // Concave arc crossing the axis.
        assert_eq!(
            prof(&[
                line(0.5, 0.0),
                arc([0.5, 2.0], [1.0, 1.0], false),
                line(0.0, 2.0)
            ]),
            1
        );
        // Non-finite centre.
        assert_eq!(
            prof(&[arc([1.0, 1.0], [0.0, Real::NAN], true), line(0.0, 2.0)]),
            0
        );

        // Shank and holder.
        let t = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("valid");
        let sizes = |shank, holder| HolderSizes { shank, holder };
        assert!(ToolAssembly::try_new(t.clone(), sizes(Some((0.0, 10.0)), None)).is_err());
        assert!(ToolAssembly::try_new(t.clone(), sizes(Some((6.0, -1.0)), None)).is_err());
        assert!(
            ToolAssembly::try_new(t.clone(), sizes(None, Some((Real::NAN, 30.0, 40.0)))).is_err()
        );
        assert!(ToolAssembly::try_new(t.clone(), sizes(None, Some((0.0, 0.0, 40.0)))).is_err());
    }

    #[test]
    fn shank_and_holder_stack_above_the_flutes() {
        let t = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("valid");
        let a = ToolAssembly::try_new(
            t,
            HolderSizes {
                shank: Some((6.0, 15.0)),
                holder: Some((20.0, 40.0, 30.0)),
            },
        )
        .expect("valid");
        // Shank: r ≤ 3 for h ∈ [20, 35]; holder: r ≤ 10 + 10 (h − 35)/30 for h ∈ [35, 65].
        assert!(!a.non_cutting_contains(1.0, 19.9));
        assert!(a.non_cutting_contains(2.9, 25.0) && !a.non_cutting_contains(3.1, 25.0));
        assert!(a.non_cutting_contains(14.9, 50.0) && !a.non_cutting_contains(15.1, 50.0));
        assert!(!a.non_cutting_contains(1.0, 65.1));
        assert_eq!(a.holder.as_ref().map(RevolvedBody::top), Some(65.0));
    }
}
