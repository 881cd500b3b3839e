//! The tool translated along a straight segment at a constant orientation: the closed-form
//! interval of a ray in a flat or ball end mill's convex sweep (the quadric and line
//! candidates of the module docs of [`crate::cutting::sweep`]), the piecewise exact sweep of
//! [`crate::cutting::cutter`] for other shapes, and each crossing's NC line in a joined run.
//!
//! **Invariant:** a function of the tool, its start, its travel and the ray only; knows no
//! chain, program or observer.

use super::*;
/// The tool translated from `start` (tip position) by `d`, with constant axis `v`.
/// Flat and ball end mills use the closed form below; every other shape the piecewise
/// exact sweep of [`crate::cutting::cutter`].
#[derive(Clone, Debug)]
pub struct TranslatedTool {
    pub(super) tool: Tool,
    pub(super) start: Point3,
    pub(super) d: Vector3,
    pub(super) v: UnitVector3,
    pub(super) bounds: Aabb,
    pub(super) general: Option<SweptTool>,
    /// For a run of joined moves: each move's end parameter along `d` and its NC line.
    pub(super) parts: Vec<(Real, u32)>,
    /// The grid axis the tool axis lies on, when the move is square to it (`d` has no
    /// component along it): rays along it then have the short closed form
    /// [`TranslatedTool::along_axis_cut`].
    pub(super) square_axis: Option<usize>,
}

impl TranslatedTool {
    /// Whether `tool` has the closed form (flat, or ball reaching above its sphere); other
    /// shapes go through [`SweptTool`].
    pub fn has_closed_form(tool: &Tool) -> bool {
        match tool.kind() {
            ToolKind::Flat => true,
            // The closed form takes the ball as a whole sphere: exact only if the tool
            // reaches above it (L ≥ 2R).
            ToolKind::Ball => tool.length() >= 2.0 * tool.radius(),
            _ => false,
        }
    }

    /// Consecutive collinear moves swept as one: the tip moves from `start` to `start + d`;
    /// `parts` lists each move's end as a fraction of `d` (increasing, the last 1) with its
    /// NC line. Every crossing is tagged with the line of the earliest move whose tool
    /// position reaches it. Only for tools with [`TranslatedTool::has_closed_form`].
    pub fn joined(
        tool: Tool,
        start: Point3,
        d: Vector3,
        v: UnitVector3,
        parts: Vec<(Real, u32)>,
    ) -> Self {
        debug_assert!(Self::has_closed_form(&tool));
        Self {
            parts,
            ..Self::new(tool, start, d, v)
        }
    }

    /// The NC line of the move at parameter `s` (the first whose end is at or past `s`).
    fn line_at(&self, s: Real, line: u32) -> u32 {
        // The first part whose end is not below `s` (a binary search's partition point):
        // the parts are about evenly spaced, so the walk from the even guess is short.
        let n = self.parts.len();
        let mut k = if s > 0.0 {
            ((s * n as Real) as usize).min(n)
        } else {
            0
        };
        while k > 0 && self.parts[k - 1].0 >= s {
            k -= 1;
        }
        while k < n && self.parts[k].0 < s {
            k += 1;
        }
        self.parts
            .get(k)
            .or(self.parts.last())
            .map_or(line, |&(_, l)| l)
    }

    /// The tool with its tip moving from `start` to `start + d`, axis `v`.
    pub fn new(tool: Tool, start: Point3, d: Vector3, v: UnitVector3) -> Self {
        let mut bounds = tool_bounds(&tool, &start, &v);
        let b1 = tool_bounds(&tool, &(start + d), &v);
        bounds.grow(&b1.min);
        bounds.grow(&b1.max);
        let general = (!Self::has_closed_form(&tool)).then(|| SweptTool::new(&tool, start, d, v));
        Self {
            tool,
            start,
            d,
            v,
            bounds,
            general,
            parts: Vec::new(),
            square_axis: (0..3).find(|&k| {
                v[k].abs() == 1.0 && d[k] == 0.0 && (0..3).all(|j| j == k || v[j] == 0.0)
            }),
        }
    }
}

/// The whole ray: the span of an exact cut.
const EVERYWHERE: (Real, Real) = (Real::NEG_INFINITY, Real::INFINITY);

/// Bounding box of the tool with its tip at `tip` and axis `v`.
fn tool_bounds(tool: &Tool, tip: &Point3, v: &UnitVector3) -> Aabb {
    let top = tip + v.into_inner() * tool.length();
    let mut b = Aabb::empty();
    let ext = Vector3::from_fn(|k, _| tool.radius() * (1.0 - v[k] * v[k]).max(0.0).sqrt());
    for p in [tip, &top] {
        b.grow(&(p - ext));
        b.grow(&(p + ext));
    }
    if tool.kind() == ToolKind::Ball {
        // The hemisphere reaches one radius below its centre in every direction.
        let c = tip + v.into_inner() * tool.radius();
        b.grow(&(c - Vector3::repeat(tool.radius())));
    }
    b
}

/// One convex piece of the tool (a cylinder part or the ball) swept along `d`.
#[derive(Clone, Copy)]
struct ConvexSweep {
    quad: Quadric,
    lines: [Line; 4],
    n_lines: usize,
    /// Radial normal from the 3-D point at (t, s).
    radial: Radial,
}

#[derive(Clone, Copy)]
enum Radial {
    /// Cylinder about the line `base + s·d + h·v`.
    Cylinder { base: Point3, v: Vector3 },
    /// Sphere about `centre + s·d`.
    Sphere { centre: Point3 },
}

impl TranslatedTool {
    /// The convex pieces of the tool's sweep as 2-D problems for this ray: the cylinder, and
    /// for a ball end mill the swept ball. Returned in a fixed array (no allocation per ray).
    fn pieces(&self, origin: &Point3, e: &Vector3) -> ([Option<ConvexSweep>; 2], usize) {
        let mut out = [None, None];
        let mut count = 0;
        let v = self.v.into_inner();
        let r = self.tool.radius();
        let tol_q = tol::FEASIBILITY * (1.0 + r * r);
        let s_lines = [
            Line {
                p: 0.0,
                q: -1.0,
                r: 0.0,
                tol: tol::PARAMETER,
                normal: None,
            },
            Line {
                p: 0.0,
                q: 1.0,
                r: -1.0,
                tol: tol::PARAMETER,
                normal: None,
            },
        ];
        let h0 = match self.tool.kind() {
            ToolKind::Ball => r,
            _ => 0.0,
        };
        // Cylinder part between heights h0 and L above the tip.
        {
            let base = self.start;
            let w0 = origin - base;
            // projections perpendicular to v
            let perp = |x: Vector3| x - v * v.dot(&x);
            let (pw0, pe, pd) = (perp(w0), perp(*e), perp(-self.d));
            let quad = Quadric {
                a: pe.dot(&pe),
                b: pe.dot(&pd),
                c: pd.dot(&pd),
                d: pw0.dot(&pe),
                e: pw0.dot(&pd),
                f: pw0.dot(&pw0) - r * r,
                tol: tol_q,
            };
            // axial a(t,s) = v·w0 + t v·e − s v·d ∈ [h0, L]
            let (av, ae, ad) = (v.dot(&w0), v.dot(e), -v.dot(&self.d));
            let lines = [
                s_lines[0],
                s_lines[1],
                Line {
                    p: -ae,
                    q: -ad,
                    r: h0 - av,
                    tol: tol::FEASIBILITY,
                    normal: Some(-v),
                },
                Line {
                    p: ae,
                    q: ad,
                    r: av - self.tool.length(),
                    tol: tol::FEASIBILITY,
                    normal: Some(v),
                },
            ];
            out[count] = Some(ConvexSweep {
                quad,
                lines,
                n_lines: 4,
                radial: Radial::Cylinder { base, v },
            });
            count += 1;
        }
        if self.tool.kind() == ToolKind::Ball {
            let centre = self.start + v * r;
            let w0 = origin - centre;
            let md = -self.d;
            let quad = Quadric {
                a: e.dot(e),
                b: e.dot(&md),
                c: md.dot(&md),
                d: w0.dot(e),
                e: w0.dot(&md),
                f: w0.dot(&w0) - r * r,
                tol: tol_q,
            };
            let lines = [s_lines[0], s_lines[1], s_lines[0], s_lines[0]];
            out[count] = Some(ConvexSweep {
                quad,
                lines,
                n_lines: 2,
                radial: Radial::Sphere { centre },
            });
            count += 1;
        }
        (out, count)
    }

    /// Tool-outward normals active at (t, s) of a piece; picks the one most against (entry)
    /// or along (exit) the ray.
    fn normal_at(
        &self,
        piece: &ConvexSweep,
        origin: &Point3,
        e: &Vector3,
        t: Real,
        s: Real,
        entry: bool,
    ) -> Vector3 {
        let x = origin + e * t;
        let mut cands: [Option<Vector3>; 3] = [None; 3];
        if piece.quad.eval(t, s).abs() <= piece.quad.tol.max(tol::ON_SURFACE) {
            cands[0] = match piece.radial {
                Radial::Cylinder { base, v } => {
                    let w = x - (base + self.d * s);
                    let w = w - v * v.dot(&w);
                    w.try_normalize(0.0)
                }
                Radial::Sphere { centre } => (x - (centre + self.d * s)).try_normalize(0.0),
            };
        }
        for (k, l) in piece.lines[..piece.n_lines].iter().enumerate().skip(2) {
            if l.eval(t, s).abs() <= tol::ON_SURFACE {
                cands[k - 1] = l.normal;
            }
        }
        let score = |n: &Vector3| if entry { n.dot(e) } else { -n.dot(e) };
        cands
            .iter()
            .flatten()
            .min_by(|a, b| score(a).total_cmp(&score(b)))
            .copied()
            .unwrap_or(if entry { -e } else { *e })
    }
}

impl TranslatedTool {
    /// The cut of a ray along the tool axis when the move is square to it (`square_axis`).
    /// With `w` the ray's offset from the tip's path in the plane across the axis, the tool
    /// covers the ray for the move parameters `s` with `|w − s·d| ≤ R`: a flat end mill from
    /// its tip to its top, the earliest such `s` making both ends; a ball end mill reaches
    /// lowest where its centre passes nearest (`s*`), `R − sqrt(R² − |w − s*·d|²)` above
    /// the tip, and to its top.
    fn along_axis_cut(
        &self,
        origin: &Point3,
        axis: usize,
        span: (Real, Real),
    ) -> Option<(RayCut, Real, Real)> {
        let sigma = self.v[axis];
        let r = self.tool.radius();
        let w = {
            let mut w = origin - self.start;
            w[axis] = 0.0;
            w
        };
        let dd = self.d.norm_squared();
        let wd = w.dot(&self.d);
        let ww = w.norm_squared();
        // The s interval inside the radius, clipped to [0, 1].
        let (sa, sb) = if dd == 0.0 {
            if ww > r * r {
                return None;
            }
            (0.0, 1.0)
        } else {
            let disc = wd * wd - dd * (ww - r * r);
            if disc < 0.0 {
                return None;
            }
            let sq = disc.sqrt();
            ((wd - sq) / dd, (wd + sq) / dd)
        };
        let (sa, sb) = (sa.max(0.0), sb.min(1.0));
        if sa > sb {
            return None;
        }
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let tip = self.start[axis];
        let top = tip + sigma * self.tool.length();
        // The end of the tool's tip side along the ray, its s, and the ball's centre there.
        let (t_tip, s_tip, centre) = match self.tool.kind() {
            ToolKind::Ball => {
                let s_star = if dd == 0.0 {
                    0.0
                } else {
                    (wd / dd).clamp(0.0, 1.0)
                };
                let rho2 = (w - self.d * s_star).norm_squared();
                let depth = (r * r - rho2).max(0.0).sqrt();
                let centre = self.start + self.v.into_inner() * r + self.d * s_star;
                (centre[axis] - sigma * depth, s_star, Some(centre))
            }
            _ => (tip, sa, None),
        };
        // The material normal at the tip side's end: against the ball's outward normal (the
        // ray if grazing), the ray for a flat end.
        let n_tip = || match centre {
            Some(centre) => {
                let mut x = *origin;
                x[axis] = t_tip;
                (centre - x).try_normalize(0.0).unwrap_or(e * sigma)
            }
            None => e * sigma,
        };
        let (t_in, t_out) = if sigma > 0.0 {
            (t_tip, top)
        } else {
            (top, t_tip)
        };
        // Not `t_out - t_in <= …`: a NaN length is no cut either.
        let long = t_out - t_in > tol::LENGTH_EPS;
        if !long || t_in > span.1 || t_out < span.0 {
            return None;
        }
        let (s_in, n_in, s_out, n_out) = if sigma > 0.0 {
            (s_tip, n_tip(), sa, -e)
        } else {
            (sa, e, s_tip, n_tip())
        };
        Some((
            RayCut {
                t_in,
                t_out,
                n_in,
                n_out,
            },
            s_in,
            s_out,
        ))
    }

    /// The cut of a ray across the tool axis when the move is square to it (`square_axis`
    /// = `a`). At the ray's height along the tool axis the tool is a disk of radius `ρ`
    /// (R, or the ball's section) whose centre moves straight from `c₀` to `c₀ + d`: the
    /// sweep's section is the set within `ρ` of that segment, bounded by the two end
    /// circles and the two sides parallel to `d`. The ray's extremes are among its points
    /// on the end circles and on the sides (foot parameter in [0, 1]), all inside the set.
    fn across_axis_cut(
        &self,
        origin: &Point3,
        axis: usize,
        a: usize,
    ) -> Option<(RayCut, Real, Real)> {
        let m = 3 - a - axis;
        let sigma = self.v[a];
        let r = self.tool.radius();
        let (ball, l) = (self.tool.kind() == ToolKind::Ball, self.tool.length());
        let h = sigma * (origin[a] - self.start[a]);
        if !(0.0..=l).contains(&h) {
            return None;
        }
        let in_ball = ball && h < r;
        let rho = if in_ball {
            (r * r - (r - h) * (r - h)).max(0.0).sqrt()
        } else {
            r
        };
        let (cx, cw, dx, dw, w) = (
            self.start[axis],
            self.start[m],
            self.d[axis],
            self.d[m],
            origin[m],
        );
        let (mut lo, mut hi) = ((Real::INFINITY, 0.0), (Real::NEG_INFINITY, 0.0));
        let mut offer = |t: Real, s: Real| {
            if t < lo.0 || (t == lo.0 && s < lo.1) {
                lo = (t, s);
            }
            if t > hi.0 || (t == hi.0 && s < hi.1) {
                hi = (t, s);
            }
        };
        for s in [0.0, 1.0] {
            let u = w - (cw + s * dw);
            if u.abs() <= rho {
                let half = (rho * rho - u * u).sqrt();
                let c = cx + s * dx;
                offer(c - half, s);
                offer(c + half, s);
            }
        }
        if dw != 0.0 {
            let len = dx.hypot(dw);
            // Unit normal of d in the section, (n_k, n_m).
            let (nk, nm) = (dw / len, -dx / len);
            for j in [-1.0, 1.0] {
                let s = (w - cw - j * rho * nm) / dw;
                if (0.0..=1.0).contains(&s) {
                    offer(cx + s * dx + j * rho * nk, s);
                }
            }
        }
        if hi.0 - lo.0 <= tol::LENGTH_EPS {
            return None;
        }
        // Material normal at (t, s): against the tool's outward normal there.
        let normal = |t: Real, s: Real, fallback: Vector3| {
            let mut x = *origin;
            x[axis] = t;
            let c = self.start + self.d * s;
            let out = if in_ball {
                x - (c + self.v.into_inner() * r)
            } else {
                let mut w = x - c;
                w[a] = 0.0;
                w
            };
            (-out).try_normalize(0.0).unwrap_or(fallback)
        };
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        Some((
            RayCut {
                t_in: lo.0,
                t_out: hi.0,
                n_in: normal(lo.0, lo.1, e),
                n_out: normal(hi.0, hi.1, -e),
            },
            lo.1,
            hi.1,
        ))
    }

    /// The closed form's cut of the ray with the move parameters `s` of its two ends; a cut
    /// along the tool axis wholly outside `span` may be left out.
    fn closed_cut(
        &self,
        origin: &Point3,
        axis: usize,
        span: (Real, Real),
    ) -> Option<(RayCut, Real, Real)> {
        match self.square_axis {
            Some(a) if a == axis => return self.along_axis_cut(origin, axis, span),
            Some(a) => return self.across_axis_cut(origin, axis, a),
            None => {}
        }
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let (pieces, count) = self.pieces(origin, &e);
        let mut acc: Option<(Real, Vector3, Real, Real, Vector3, Real)> = None;
        for piece in pieces[..count].iter().flatten() {
            let Some((t0, s0, t1, s1)) = t_extremes(&piece.quad, &piece.lines[..piece.n_lines])
            else {
                continue;
            };
            let n_in = self.normal_at(piece, origin, &e, t0, s0, true);
            let n_out = self.normal_at(piece, origin, &e, t1, s1, false);
            acc = Some(match acc {
                None => (t0, n_in, s0, t1, n_out, s1),
                Some((a0, m0, r0, a1, m1, r1)) => {
                    // On a tie the earlier tool position, as within a piece.
                    let lo = if t0 < a0 || (t0 == a0 && s0 < r0) {
                        (t0, n_in, s0)
                    } else {
                        (a0, m0, r0)
                    };
                    let hi = if t1 > a1 || (t1 == a1 && s1 < r1) {
                        (t1, n_out, s1)
                    } else {
                        (a1, m1, r1)
                    };
                    (lo.0, lo.1, lo.2, hi.0, hi.1, hi.2)
                }
            });
        }
        let (t_in, tn_in, s_in, t_out, tn_out, s_out) = acc?;
        (t_out - t_in > tol::LENGTH_EPS).then_some((
            RayCut {
                t_in,
                t_out,
                // Material normals point into the removed region: opposite the tool's
                // outward normal.
                n_in: -tn_in,
                n_out: -tn_out,
            },
            s_in,
            s_out,
        ))
    }
}

impl Cutter for TranslatedTool {
    fn bounds(&self) -> Aabb {
        self.bounds
    }

    fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut> {
        match &self.general {
            Some(g) => g.ray_cut(origin, axis),
            None => self.closed_cut(origin, axis, EVERYWHERE).map(|(c, _, _)| c),
        }
    }

    fn ray_cuts(&self, origin: &Point3, axis: usize, out: &mut Vec<RayCut>) {
        match &self.general {
            Some(g) => g.ray_cuts(origin, axis, out),
            None => out.extend(self.ray_cut(origin, axis)),
        }
    }

    fn ray_cuts_lined(
        &self,
        origin: &Point3,
        axis: usize,
        line: u32,
        out: &mut Vec<RayCut>,
        lines: &mut Vec<[u32; 2]>,
    ) {
        if let Some(g) = &self.general {
            g.ray_cuts_lined(origin, axis, line, out, lines);
        } else if let Some((c, s_in, s_out)) = self.closed_cut(origin, axis, EVERYWHERE) {
            out.push(c);
            lines.push([self.line_at(s_in, line), self.line_at(s_out, line)]);
        }
    }

    /// Exact, except that a cut along the tool axis that lies wholly outside `span`, not
    /// touching it (so it cannot change the ray), is left out without working out its
    /// normals and NC lines.
    fn ray_cuts_in_span(
        &self,
        origin: &Point3,
        axis: usize,
        span: (Real, Real),
        line: u32,
        out: &mut Vec<RayCut>,
        lines: &mut Vec<[u32; 2]>,
    ) {
        if let Some(g) = &self.general {
            g.ray_cuts_lined(origin, axis, line, out, lines);
        } else if let Some((c, s_in, s_out)) = self.closed_cut(origin, axis, span) {
            out.push(c);
            let l_in = self.line_at(s_in, line);
            let l_out = if s_out == s_in {
                l_in
            } else {
                self.line_at(s_out, line)
            };
            lines.push([l_in, l_out]);
        }
    }
}
