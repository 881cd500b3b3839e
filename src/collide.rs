//! Collisions along a program: rapids through material, the shank or holder touching the
//! stock, and any part of the tool, shank or holder touching a fixture. The material is
//! removed as the program runs, so each move is checked against the stock as it is then.
//!
//! **Stock.** A part's swept volume over a move (exact for straight moves at fixed rotary
//! values: a translation, see [`crate::sweep`]) is intersected with the dexels ray by ray,
//! removing nothing: the overlap lengths times the ray cell areas, averaged over the three
//! grids, estimate the overlapping volume, per grid the longest overlap along one ray, smallest over the grids, is the depth
//! estimate.
//! The *first* contact is found by bisection on the move fraction (the swept volume grows with
//! it) to [`CONTACT_RESOLUTION`] of travel; the contact point is an end of an overlap on a ray
//! that lies on the partial sweep's boundary. Resolution across rays is the dexel spacing: an
//! overlap that reaches no ray is not seen.
//!
//! **Fixtures** are closed meshes kept as parry3d shapes and never cut. Each convex part
//! (flute cylinder, ball, shank, holder) is cast linearly along the move against each fixture
//! (parry's time of impact); the event gives the first contact point and, as the overlap
//! estimate, the travel after first contact. A part that starts inside a fixture is reported
//! at the move's start.
//!
//! **Rotary moves** are split into the sub-steps the sweep uses for its bound
//! ([`RotaryBound`]: the tool's mid point moves straight between its true positions, the axis
//! held at the mid-step orientation); each is checked as that translation. Arcs are swept as
//! chords. Sub-steps whose whole assembly stays clear of the stock's box and every fixture's
//! box are skipped, screened first in coarse groups.
//!
//! Order per move: a rapid's cutting part is checked before the move cuts; the move's
//! material is removed; then shank and holder are checked against what remains, and all parts
//! against the fixtures. One event per kind, part and fixture per move.
//!
//! **Invariant:** collision checks change the stock exactly as [`crate::sweep`] would and only
//! read the fixtures; they never parse text or touch files.

use crate::kinematics::{AxisKind, Chain};
use crate::math::{Aabb, Isometry3, Point3, Real, UnitVector3, Vector3, tol};
use crate::nc::{AxisLetter, Move, MoveKind};
use crate::progress::Progress;
use crate::shape::{ClosedMesh, Solid};
use crate::stock::{Cutter, TriDexel};
use crate::sweep::{RotaryBound, SweepError, SweepOptions, SweepReport, TranslatedTool};
use crate::tool::{Tool, ToolKind};
use parry3d_f64::query::{ShapeCastOptions, cast_shapes};
use parry3d_f64::shape::{Ball, Cylinder as PCylinder, Shape};

/// Travel (mm) to which the first contact along a move is located by bisection: 1 µm,
/// well below any dexel spacing, so the ray sampling, not the bisection, limits the answer.
pub const CONTACT_RESOLUTION: Real = 1e-3;

/// Errors in describing what can collide.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CollideError {
    /// A shank or holder size that is not finite and positive, or a cylinder not longer
    /// than its radius (the swept-cylinder code needs length > radius).
    #[error(
        "{what}: radius and length must be finite and positive, with length > radius (got radius {radius} mm, length {length} mm)"
    )]
    BadHolder {
        /// `shank` or `holder`.
        what: &'static str,
        /// Radius (mm).
        radius: Real,
        /// Length (mm).
        length: Real,
    },
    /// parry3d refused the fixture mesh.
    #[error("fixture '{0}' cannot be used for collision checks")]
    BadFixture(String),
}

/// The non-cutting parts above the flutes: a shank cylinder from the top of the flutes, then
/// a holder cylinder from the top of the shank (mm).
#[derive(Clone, Debug, PartialEq)]
pub struct Holder {
    shank: Tool,
    holder: Tool,
}

impl Holder {
    /// A shank of `shank_radius` × `shank_length` above the flutes and a holder of
    /// `holder_radius` × `holder_length` above it (mm; each length must exceed its radius).
    pub fn try_new(
        shank_radius: Real,
        shank_length: Real,
        holder_radius: Real,
        holder_length: Real,
    ) -> Result<Self, CollideError> {
        let cyl = |what, radius: Real, length: Real| {
            Tool::try_new(ToolKind::Flat, 2.0 * radius, length).map_err(|_| {
                CollideError::BadHolder {
                    what,
                    radius,
                    length,
                }
            })
        };
        Ok(Self {
            shank: cyl("shank", shank_radius, shank_length)?,
            holder: cyl("holder", holder_radius, holder_length)?,
        })
    }

    /// Shank radius (mm).
    pub fn shank_radius(&self) -> Real {
        self.shank.radius()
    }

    /// Shank length (mm).
    pub fn shank_length(&self) -> Real {
        self.shank.length()
    }

    /// Holder radius (mm).
    pub fn holder_radius(&self) -> Real {
        self.holder.radius()
    }

    /// Holder length (mm).
    pub fn holder_length(&self) -> Real {
        self.holder.length()
    }
}

/// A fixture: a closed mesh in the workpiece frame, never cut.
#[derive(Clone)]
pub struct Fixture {
    name: String,
    mesh: ClosedMesh,
    shape: parry3d_f64::shape::TriMesh,
}

impl std::fmt::Debug for Fixture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fixture").field("name", &self.name).finish()
    }
}

impl Fixture {
    /// A fixture named `name` (used in reports) from a closed mesh.
    pub fn try_new(name: &str, mesh: ClosedMesh) -> Result<Self, CollideError> {
        let shape = mesh
            .to_parry()
            .ok_or_else(|| CollideError::BadFixture(name.to_string()))?;
        Ok(Self {
            name: name.to_string(),
            mesh,
            shape,
        })
    }

    /// The name.
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// Which part of the spindle assembly.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Part {
    /// The cutting part (flutes, ball).
    Tool,
    /// The shank above the flutes.
    Shank,
    /// The holder above the shank.
    Holder,
}

/// What happened.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub enum EventKind {
    /// A rapid (G0) whose cutting part sweeps through remaining stock.
    RapidThroughMaterial,
    /// The shank or holder sweeps through stock.
    NonCuttingInStock(Part),
    /// A part touches a fixture.
    FixtureHit {
        /// The part.
        part: Part,
        /// The fixture's name.
        fixture: String,
    },
}

/// One collision.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Event {
    /// What collided.
    pub kind: EventKind,
    /// NC line of the move.
    pub line: usize,
    /// First contact point (mm, workpiece frame W).
    pub point: [Real; 3],
    /// Stock: penetration depth estimate ([`Overlap::depth_mm`], mm). Fixture: travel after first contact
    /// (mm), an upper bound on the penetration along the move.
    pub depth_mm: Real,
    /// Stock: estimated overlap volume (mm³); fixtures: `None`.
    pub volume_mm3: Option<Real>,
}

/// Result of a checked run.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct CollisionReport {
    /// Events in program order.
    pub events: Vec<Event>,
    /// Moves processed (arcs counted once per chord).
    pub moves: usize,
    /// What the sweep did (as [`crate::sweep::sweep_program`] reports it; `sweeps` counts
    /// the straight pieces evaluated, those clear of the stock and fixtures excluded).
    pub sweep: SweepReport,
}

/// Overlap of a cutter's volume with the material (nothing removed).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Overlap {
    /// Estimated volume (mm³): per-grid overlap lengths × cell area, mean of the three grids.
    pub volume_mm3: Real,
    /// Penetration depth estimate (mm): per grid the longest overlap along one of its rays,
    /// the smallest over the grids that see any overlap (exact to the spacing for a contact
    /// on a face normal to a grid axis; otherwise an upper bound along the best axis).
    pub depth_mm: Real,
    /// An overlap end on the cutter's boundary (the first in grid order), else on the stock's.
    pub point: Point3,
}

fn index_range(lo: Real, hi: Real, first: Real, step: Real, n: usize) -> Option<(usize, usize)> {
    let a = ((lo - first) / step).ceil().max(0.0);
    let b = ((hi - first) / step).floor();
    if !(a.is_finite() && b.is_finite()) || b < a || a >= n as Real || b < 0.0 {
        return None;
    }
    Some((a as usize, (b as usize).min(n - 1)))
}

/// Where `cutter` overlaps the stock's material by more than a sliver, if anywhere.
pub fn overlap(stock: &TriDexel, cutter: &dyn Cutter) -> Option<Overlap> {
    let b = cutter.bounds();
    if !b.intersects(stock.bounds()) {
        return None;
    }
    let (mut volume, mut depth) = (0.0, Real::INFINITY);
    let mut on_cutter: Option<Point3> = None;
    let mut on_stock: Option<Point3> = None;
    for g in stock.grids() {
        let axis = g.axis();
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let (nu, nv) = g.dims();
        let (du, dv) = g.pitches();
        let o0 = g.ray_origin(0, 0);
        let Some((iu0, iu1)) = index_range(b.min[u], b.max[u], o0[u], du, nu) else {
            continue;
        };
        let Some((iv0, iv1)) = index_range(b.min[v], b.max[v], o0[v], dv, nv) else {
            continue;
        };
        let (mut len_sum, mut grid_depth) = (0.0, 0.0);
        for iv in iv0..=iv1 {
            for iu in iu0..=iu1 {
                let segs = g.ray(iu, iv);
                if segs.is_empty() {
                    continue;
                }
                let o = g.ray_origin(iu, iv);
                let Some(c) = cutter.ray_cut(&o, axis) else {
                    continue;
                };
                for s in segs {
                    let (lo, hi) = (s.lo.t.max(c.t_in), s.hi.t.min(c.t_out));
                    if hi - lo < tol::SLIVER {
                        continue;
                    }
                    len_sum += hi - lo;
                    grid_depth = Real::max(grid_depth, hi - lo);
                    let at = |t: Real| {
                        let mut p = o;
                        p[axis] = t;
                        p
                    };
                    if on_cutter.is_none() {
                        if lo == c.t_in {
                            on_cutter = Some(at(lo));
                        } else if hi == c.t_out {
                            on_cutter = Some(at(hi));
                        }
                    }
                    on_stock.get_or_insert(at(lo));
                }
            }
        }
        volume += len_sum * du * dv / 3.0;
        if grid_depth > 0.0 {
            depth = depth.min(grid_depth);
        }
    }
    Some(Overlap {
        volume_mm3: volume,
        depth_mm: depth,
        point: on_cutter.or(on_stock)?,
    })
}

/// The part `piece` (a cylinder tool) of the assembly with its tip `offset` above the tool
/// tip, translated from `tip` by `d` with axis `v`.
fn swept(piece: &Tool, offset: Real, tip: Point3, d: Vector3, v: UnitVector3) -> TranslatedTool {
    TranslatedTool::new(piece.clone(), tip + v.into_inner() * offset, d, v)
}

/// First contact of `piece` swept from `tip` by `d` with the stock, by bisection on the
/// move fraction; the overlap of the whole move gives volume and depth.
fn first_stock_contact(
    stock: &TriDexel,
    piece: &Tool,
    offset: Real,
    tip: Point3,
    d: Vector3,
    v: UnitVector3,
) -> Option<Overlap> {
    let whole = overlap(stock, &swept(piece, offset, tip, d, v))?;
    let (mut lo, mut hi) = (0.0, 1.0);
    let mut best = overlap(stock, &swept(piece, offset, tip, Vector3::zeros(), v));
    if best.is_none() {
        best = Some(whole);
        while d.norm() * (hi - lo) > CONTACT_RESOLUTION {
            let mid = 0.5 * (lo + hi);
            match overlap(stock, &swept(piece, offset, tip, d * mid, v)) {
                Some(o) => {
                    hi = mid;
                    best = Some(o);
                }
                None => lo = mid,
            }
        }
    }
    Some(Overlap {
        point: best?.point,
        ..whole
    })
}

/// The convex parry pieces of the assembly, each with its pose relative to the tool frame
/// (tip at origin, axis +z).
fn parry_parts(tool: &Tool, holder: Option<&Holder>) -> Vec<(Part, Box<dyn Shape>, Isometry3)> {
    // parry cylinders stand along +y about their centre.
    let upright = Isometry3::rotation(Vector3::x() * std::f64::consts::FRAC_PI_2);
    let cyl = |z0: Real, len: Real, r: Real| -> (Box<dyn Shape>, Isometry3) {
        (
            Box::new(PCylinder::new(len / 2.0, r)),
            Isometry3::translation(0.0, 0.0, z0 + len / 2.0) * upright,
        )
    };
    let mut out = Vec::new();
    let r = tool.radius();
    match tool.kind() {
        ToolKind::Flat => {
            let (s, p) = cyl(0.0, tool.length(), r);
            out.push((Part::Tool, s, p));
        }
        ToolKind::Ball => {
            out.push((
                Part::Tool,
                Box::new(Ball::new(r)) as Box<dyn Shape>,
                Isometry3::translation(0.0, 0.0, r),
            ));
            let (s, p) = cyl(r, tool.length() - r, r);
            out.push((Part::Tool, s, p));
        }
        // Other shapes: their enclosing cylinder (largest radius, full length), so a
        // fixture contact is never missed; it may be reported up to the profile's largest
        // inset early.
        _ => {
            let (s, p) = cyl(0.0, tool.length(), r);
            out.push((Part::Tool, s, p));
        }
    }
    if let Some(h) = holder {
        let (s, p) = cyl(tool.length(), h.shank.length(), h.shank.radius());
        out.push((Part::Shank, s, p));
        let (s, p) = cyl(
            tool.length() + h.shank.length(),
            h.holder.length(),
            h.holder.radius(),
        );
        out.push((Part::Holder, s, p));
    }
    out
}

/// First contact of a parry part moving by `d` (W) from pose `w_from_part` with a fixture:
/// (move fraction, point in W).
fn fixture_contact(
    part: &dyn Shape,
    w_from_part: &Isometry3,
    d: &Vector3,
    fixture: &Fixture,
) -> Option<(Real, Point3)> {
    let opts = ShapeCastOptions {
        max_time_of_impact: 1.0,
        target_distance: 0.0,
        stop_at_penetration: true,
        compute_impact_geometry_on_penetration: true,
    };
    let hit = cast_shapes(
        w_from_part,
        d,
        part,
        &Isometry3::identity(),
        &Vector3::zeros(),
        &fixture.shape,
        opts,
    )
    .ok()
    .flatten();
    if let Some(h) = hit {
        let at = Isometry3::translation(
            d.x * h.time_of_impact,
            d.y * h.time_of_impact,
            d.z * h.time_of_impact,
        ) * w_from_part;
        return Some((h.time_of_impact, at * h.witness1));
    }
    // Wholly inside the fixture: no surface contact, but a collision from the start.
    let centre = w_from_part * Point3::origin();
    fixture.mesh.contains(&centre).then_some((0.0, centre))
}

/// One straight piece of a move: the tool tip from `tip` by `d` with axis `v` (W).
#[derive(Clone, Copy)]
struct Step {
    tip: Point3,
    d: Vector3,
    v: UnitVector3,
    w_from_t: Isometry3,
}

fn pose_at(chain: &Chain, mv: &Move, lambda: Real) -> Isometry3 {
    let mut q = mv.start;
    for axis in chain.axes() {
        let (a, b) = (mv.start.get(axis.letter), mv.end.get(axis.letter));
        q.set(axis.letter, a + (b - a) * lambda);
    }
    chain.w_from_t(&q)
}

/// Coarse groups of a rotary move's sub-steps, each skipped as a whole when far from the
/// stock and the fixtures (n is a multiple of it, see [`RotaryBound::steps_for`]).
const COARSE: usize = 64;

/// The reach of the spindle assembly: all of it lies within `radius` of the segment from the
/// tip to `length` up the tool axis (mm).
#[derive(Clone, Copy)]
struct Envelope {
    length: Real,
    radius: Real,
}

impl Envelope {
    /// The box of the envelope moving by `d` from `tip` with axis `v`, grown by `margin`.
    fn swept_box(&self, tip: Point3, d: Vector3, v: UnitVector3, margin: Real) -> Aabb {
        let mut b = Aabb::empty();
        let top = v.into_inner() * self.length;
        for p in [tip, tip + d, tip + top, tip + d + top] {
            b.grow(&p);
        }
        b.inflated(self.radius + margin)
    }
}

/// The straight pieces of a move that may touch something (`near` says which boxes may):
/// one for a move at fixed rotary values, else the sweep's sub-steps for the rotary bound
/// (the tool's mid point moves straight between its true positions at the sub-step ends, the
/// axis held at the mid-step orientation); with the sub-steps' error bound for a rotary
/// move. Sub-steps are first screened in [`COARSE`] groups, each group's box grown by the
/// coarse and fine approximation errors of the whole envelope.
fn steps(
    chain: &Chain,
    tool: &Tool,
    envelope: Envelope,
    mv: &Move,
    bound: Real,
    near: impl Fn(&Aabb) -> bool,
) -> Result<(Vec<Step>, Option<Real>), SweepError> {
    let rotary = chain
        .axes()
        .iter()
        .any(|a| a.kind == AxisKind::Rotary && mv.start.get(a.letter) != mv.end.get(a.letter));
    let half = tool.length() / 2.0;
    let mid_point = Point3::new(0.0, 0.0, half);
    let step = |pa: Point3, pb: Point3, rotation: crate::math::Rotation3| {
        let v = UnitVector3::new_normalize(rotation * Vector3::z());
        let tip = pa - v.into_inner() * half;
        Step {
            tip,
            d: pb - pa,
            v,
            w_from_t: Isometry3::from_parts(tip.coords.into(), rotation),
        }
    };
    if !rotary {
        let (p0, p1) = (pose_at(chain, mv, 0.0), pose_at(chain, mv, 1.0));
        let st = step(p0 * mid_point, p1 * mid_point, p0.rotation);
        let keep = near(&envelope.swept_box(st.tip, st.d, st.v, tol::SLIVER));
        return Ok((if keep { vec![st] } else { Vec::new() }, None));
    }
    let rb = RotaryBound::of(chain, tool, mv);
    let n = rb.steps_for(bound, mv.line)?;
    // The envelope's points lie within `length + radius` of the mid point: holding the
    // orientation over a rotation ω moves them by at most ω·(length + radius).
    let omega: Real = chain
        .axes()
        .iter()
        .filter(|a| a.kind == AxisKind::Rotary)
        .map(|a| {
            (mv.end.get(a.letter) - mv.start.get(a.letter))
                .abs()
                .to_radians()
        })
        .sum();
    let err = |k: usize| {
        let k = k as Real;
        omega * (envelope.length + envelope.radius) / k + rb.b / (k * k)
    };
    let margin = err(COARSE) + err(n) + tol::SLIVER;
    let per = n / COARSE;
    let mut out = Vec::new();
    for j in 0..COARSE {
        let (l0, l1) = (j as Real / COARSE as Real, (j + 1) as Real / COARSE as Real);
        let coarse = step(
            pose_at(chain, mv, l0) * mid_point,
            pose_at(chain, mv, l1) * mid_point,
            pose_at(chain, mv, (l0 + l1) / 2.0).rotation,
        );
        if !near(&envelope.swept_box(coarse.tip, coarse.d, coarse.v, margin)) {
            continue;
        }
        let mut prev = pose_at(chain, mv, l0) * mid_point;
        for k in 0..per {
            let i = j * per + k;
            let (la, lb) = (i as Real / n as Real, (i + 1) as Real / n as Real);
            let next = pose_at(chain, mv, lb) * mid_point;
            let st = step(prev, next, pose_at(chain, mv, (la + lb) / 2.0).rotation);
            prev = next;
            if near(&envelope.swept_box(st.tip, st.d, st.v, tol::SLIVER)) {
                out.push(st);
            }
        }
    }
    Ok((out, Some(rb.at(n))))
}

/// Runs `moves` like [`crate::sweep::sweep_program`] (removing material from `stock`; arcs
/// as chords within the rotary step bound) and reports the collisions described in the
/// module docs.
#[expect(
    clippy::too_many_arguments,
    reason = "the sweep's arguments plus holder and fixtures"
)]
pub fn sweep_with_checks(
    stock: &mut TriDexel,
    chain: &Chain,
    tool: &Tool,
    holder: Option<&Holder>,
    fixtures: &[Fixture],
    moves: &[Move],
    opts: &SweepOptions,
    progress: &dyn Progress,
) -> Result<CollisionReport, SweepError> {
    let bound = opts.rotary_step_bound_mm;
    if !(bound > 0.0 && bound <= 1.0) {
        return Err(SweepError::BadBound(bound));
    }
    let parts = parry_parts(tool, holder);
    let envelope = match holder {
        Some(h) => Envelope {
            length: tool.length() + h.shank.length() + h.holder.length(),
            radius: tool.radius().max(h.shank.radius()).max(h.holder.radius()),
        },
        None => Envelope {
            length: tool.length(),
            radius: tool.radius(),
        },
    };
    let fixture_bounds: Vec<Aabb> = fixtures.iter().map(|f| f.mesh.bounds()).collect();
    let mut report = CollisionReport::default();
    // Arcs are swept as chords within the rotary step bound, as the sweep does.
    let moves = crate::sweep::as_chords(moves, bound);
    let moves: &[Move] = &moves;
    progress.start("collisions", moves.len() as u64);
    for mv in moves {
        if let Some(missing) = AxisLetter::ALL
            .into_iter()
            .find(|&l| !chain.has_axis(l) && mv.start.get(l) != mv.end.get(l))
        {
            return Err(SweepError::MissingAxis {
                line: mv.line,
                axis: missing.as_char(),
            });
        }
        report.moves += 1;
        report.sweep.moves += 1;
        let (pieces, rotary_error) = steps(chain, tool, envelope, mv, bound, |b| {
            b.intersects(stock.bounds()) || fixture_bounds.iter().any(|f| b.intersects(f))
        })?;
        if let Some(e) = rotary_error {
            report.sweep.rotary_moves += 1;
            report.sweep.rotary_error_bound_mm = report.sweep.rotary_error_bound_mm.max(e);
        }
        let mut cut = false;
        let mut events: Vec<Event> = Vec::new();
        let mut note = |kind: EventKind, point: Point3, depth: Real, volume: Option<Real>| {
            if let Some(e) = events.iter_mut().find(|e| e.kind == kind) {
                e.depth_mm = e.depth_mm.max(depth);
                e.volume_mm3 = e.volume_mm3.zip(volume).map(|(a, b)| a + b);
            } else {
                events.push(Event {
                    kind,
                    line: mv.line,
                    point: [point.x, point.y, point.z],
                    depth_mm: depth,
                    volume_mm3: volume,
                });
            }
        };
        for st in pieces {
            report.sweep.sweeps += 1;
            let swept = TranslatedTool::new(tool.clone(), st.tip, st.d, st.v);
            let near = swept.bounds().intersects(stock.bounds());
            if near
                && mv.kind == MoveKind::Rapid
                && let Some(o) = first_stock_contact(stock, tool, 0.0, st.tip, st.d, st.v)
            {
                note(
                    EventKind::RapidThroughMaterial,
                    o.point,
                    o.depth_mm,
                    Some(o.volume_mm3),
                );
            }
            cut |= stock.remove(&swept, mv.line as u32);
            if let Some(h) = holder {
                for (part, piece, offset) in [
                    (Part::Shank, &h.shank, tool.length()),
                    (Part::Holder, &h.holder, tool.length() + h.shank.length()),
                ] {
                    if let Some(o) = first_stock_contact(stock, piece, offset, st.tip, st.d, st.v) {
                        note(
                            EventKind::NonCuttingInStock(part),
                            o.point,
                            o.depth_mm,
                            Some(o.volume_mm3),
                        );
                    }
                }
            }
            for f in fixtures {
                for (part, shape, t_from_part) in &parts {
                    let w_from_part = st.w_from_t * t_from_part;
                    if let Some((toi, p)) = fixture_contact(shape.as_ref(), &w_from_part, &st.d, f)
                    {
                        note(
                            EventKind::FixtureHit {
                                part: *part,
                                fixture: f.name.clone(),
                            },
                            p,
                            st.d.norm() * (1.0 - toi),
                            None,
                        );
                    }
                }
            }
        }
        if cut {
            report.sweep.cutting_moves += 1;
        }
        report.events.extend(events);
        progress.advance(1);
    }
    progress.finish();
    Ok(report)
}
