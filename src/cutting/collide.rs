//! Collisions along a program: rapids through material, the shank or holder touching the
//! stock, and any part of the tool, shank or holder touching a fixture. The checks ride on
//! the one sweep driver ([`crate::cutting::sweep::sweep_observed`]) as its observer, so the material
//! is removed exactly as [`crate::cutting::sweep::sweep_program`] removes it (same arcs as chords,
//! joined collinear runs, rotary envelope or sub-steps) and each move is checked against the
//! stock as it is then.
//!
//! **Stock.** A part's swept volume over a move (exact for straight moves at fixed rotary
//! values: a translation, see [`crate::cutting::sweep`]) is intersected with the dexels ray by ray,
//! removing nothing: the overlap lengths times the ray cell areas, averaged over the three
//! grids, estimate the overlapping volume; per grid the longest overlap along one ray,
//! smallest over the grids, is the depth estimate.
//! The *first* contact is found by bisection on the move fraction (the swept volume grows with
//! it) to [`CONTACT_RESOLUTION`] of travel; the contact point is an end of an overlap on a ray
//! that lies on the partial sweep's boundary. Resolution across rays is the dexel spacing: an
//! overlap that reaches no ray is not seen.
//!
//! **Fixtures** are closed meshes kept as parry3d shapes and never cut. Each convex part
//! (flute cylinder, ball, shank, each holder section as an exact frustum) is cast linearly
//! along the move against each fixture (parry's time of impact); the event gives the first
//! contact point and, as the overlap estimate, the travel after first contact. A part that
//! starts inside a fixture is reported at the move's start.
//!
//! **Order per move.** A rapid's cutting part is checked against the stock *before* the move
//! cuts (a rapid never joins the moves before it, so that stock is the one it meets; a rapid
//! that turns a rotary axis is checked with the same envelope, or the same sub-steps, that
//! cut it); the move's material is removed; then shank and holder are checked against what
//! remains, and all parts against the fixtures. For a run of joined collinear moves the
//! after-checks run for each of its moves, in program order, against the stock after the
//! whole run: flutes later in a straight run can clear material the shank passed earlier only
//! when the run moves towards the spindle, the same approximation as within one move. One
//! event per kind, part and fixture per move (arcs: per chord).
//!
//! **Rotary moves** are checked (not cut) in translations: the sub-steps of
//! [`crate::cutting::sweep::rotary_substeps`], as many as make every point of the whole assembly
//! (not only the flutes) stay within [`ROTARY_CHECK_BOUND`] (or the sweep's bound, if
//! coarser) of its true path; the achieved bound is [`CollisionReport::check_error_bound_mm`], so a
//! contact deeper than it is not missed (within the dexel spacing across rays). Sub-steps
//! whose whole assembly stays clear of the stock's box and every fixture's box are skipped,
//! screened first in coarse groups.
//!
//! **Invariant:** collision checks only read the stock and the fixtures (the stock comes out
//! bit-identical to [`crate::cutting::sweep::sweep_program`]'s); they never parse text or touch files.

use crate::cutting::envelope::RotaryEnvelope;
use crate::cutting::shape::{ClosedMesh, Solid};
use crate::cutting::stock::{Cutter, TriDexel};
use crate::cutting::sweep::{
    Piece, RotaryBound, SweepError, SweepObserver, SweepOptions, SweepReport, TranslatedTool,
    rotary_substeps, sweep_observed,
};
use crate::cutting::tool::{ProfileStep, Tool, ToolKind};
use crate::machine::chain::{AxisKind, Chain};
use crate::math::{Aabb, Isometry3, Point3, Real, Rotation3, UnitVector3, Vector3, tol};
use crate::nc::{AxisValues, Move};
use crate::progress::Progress;
use parry3d_f64::query::{ShapeCastOptions, cast_shapes};
use parry3d_f64::shape::{Ball, Cylinder as PCylinder, Shape};

/// Travel (mm) to which the first contact along a move is located by bisection: 1 µm,
/// well below any dexel spacing, so the ray sampling, not the bisection, limits the answer.
pub const CONTACT_RESOLUTION: Real = 1e-3;

/// Largest distance (mm) between the true and the checked position of any point of the
/// tool assembly on a move that turns a rotary axis (or the sweep's own bound, when that is
/// coarser): the contact resolution along a move, since a check cannot locate a contact
/// better than that anyway.
pub const ROTARY_CHECK_BOUND: Real = CONTACT_RESOLUTION;

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
    /// A holder section with a size that is not finite and positive.
    #[error("holder section {index}: {field} must be finite and positive, got {value} mm")]
    BadSection {
        /// The section's index (0 = the lowest).
        index: usize,
        /// `length`, `radius_bottom` or `radius_top`.
        field: &'static str,
        /// The value given (mm).
        value: Real,
    },
    /// A holder given with no sections.
    #[error("a holder needs at least one section")]
    NoSections,
    /// parry3d refused the fixture mesh.
    #[error("fixture '{0}' cannot be used for collision checks")]
    BadFixture(String),
}

/// One section of a holder: a frustum on the tool axis (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HolderSection {
    /// Length along the tool axis (mm).
    pub length: Real,
    /// Radius at the section's bottom, nearer the tool (mm).
    pub radius_bottom: Real,
    /// Radius at the section's top (mm).
    pub radius_top: Real,
}

/// The non-cutting parts above the flutes: a shank cylinder from the top of the flutes, then
/// a holder from the top of the shank: a cylinder, or a stack of frustum sections (mm).
#[derive(Clone, Debug, PartialEq)]
pub struct Holder {
    shank: Tool,
    /// The holder as one revolved solid with its tip at the holder's bottom.
    holder: Tool,
    sections: Vec<HolderSection>,
}

impl Holder {
    /// A shank of `shank_radius` × `shank_length` above the flutes and a holder cylinder of
    /// `holder_radius` × `holder_length` above it (mm; each length must exceed its radius).
    pub fn try_new(
        shank_radius: Real,
        shank_length: Real,
        holder_radius: Real,
        holder_length: Real,
    ) -> Result<Self, CollideError> {
        let cyl = |what, radius: Real, length: Real| {
            let ok = radius.is_finite() && length.is_finite() && radius > 0.0 && length > radius;
            ok.then(|| Tool::try_new(ToolKind::Flat, 2.0 * radius, length).ok())
                .flatten()
                .ok_or(CollideError::BadHolder {
                    what,
                    radius,
                    length,
                })
        };
        Ok(Self {
            shank: cyl("shank", shank_radius, shank_length)?,
            holder: cyl("holder", holder_radius, holder_length)?,
            sections: vec![HolderSection {
                length: holder_length,
                radius_bottom: holder_radius,
                radius_top: holder_radius,
            }],
        })
    }

    /// A shank of `shank_radius` × `shank_length` above the flutes (its length must exceed
    /// its radius) and a holder stacked from `sections`, the first at the shank's top (mm).
    pub fn try_sections(
        shank_radius: Real,
        shank_length: Real,
        sections: &[HolderSection],
    ) -> Result<Self, CollideError> {
        if sections.is_empty() {
            return Err(CollideError::NoSections);
        }
        for (index, s) in sections.iter().enumerate() {
            for (field, value) in [
                ("length", s.length),
                ("radius_bottom", s.radius_bottom),
                ("radius_top", s.radius_top),
            ] {
                if !(value.is_finite() && value > 0.0) {
                    return Err(CollideError::BadSection {
                        index,
                        field,
                        value,
                    });
                }
            }
        }
        let shank = Self::try_new(shank_radius, shank_length, 1.0, 2.0)?.shank;
        // The profile from the axis at the holder's bottom up each section's flank, with a
        // flat step where a section starts at another radius than the one below ended.
        let mut steps = Vec::new();
        let (mut h, mut r) = (0.0, 0.0);
        for s in sections {
            if s.radius_bottom != r {
                steps.push(ProfileStep::Line {
                    to: [s.radius_bottom, h],
                });
            }
            h += s.length;
            r = s.radius_top;
            steps.push(ProfileStep::Line { to: [r, h] });
        }
        steps.push(ProfileStep::Line { to: [0.0, h] });
        let holder = Tool::try_profile(&steps).map_err(|_| CollideError::BadSection {
            index: 0,
            field: "length",
            value: sections[0].length,
        })?;
        Ok(Self {
            shank,
            holder,
            sections: sections.to_vec(),
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

    /// Largest holder radius (mm).
    pub fn holder_radius(&self) -> Real {
        self.holder.radius()
    }

    /// Holder length (mm).
    pub fn holder_length(&self) -> Real {
        self.holder.length()
    }

    /// The holder's sections, lowest first (one for a cylinder holder).
    pub fn sections(&self) -> &[HolderSection] {
        &self.sections
    }
}

/// A frustum on the local +z axis, bottom disc at z = 0: an exact convex shape for parry's
/// shape casts through its support function (the farther of its two rims' support points).
#[derive(Clone, Copy, Debug)]
struct Frustum {
    r0: Real,
    r1: Real,
    h: Real,
}

impl parry3d_f64::shape::SupportMap for Frustum {
    fn local_support_point(&self, dir: &Vector3) -> Point3 {
        let across = Vector3::new(dir.x, dir.y, 0.0);
        let n = across.norm();
        let u = if n > 0.0 {
            across / n
        } else {
            Vector3::zeros()
        };
        let bottom = Point3::from(u * self.r0);
        let top = Point3::from(u * self.r1 + Vector3::z() * self.h);
        if top.coords.dot(dir) > bottom.coords.dot(dir) {
            top
        } else {
            bottom
        }
    }
}

impl parry3d_f64::query::PointQuery for Frustum {
    fn project_local_point(
        &self,
        point: &Point3,
        solid: bool,
    ) -> parry3d_f64::query::PointProjection {
        parry3d_f64::query::point::local_point_projection_on_support_map(
            self,
            &mut parry3d_f64::query::gjk::VoronoiSimplex::new(),
            point,
            solid,
        )
    }

    fn project_local_point_and_get_feature(
        &self,
        point: &Point3,
    ) -> (
        parry3d_f64::query::PointProjection,
        parry3d_f64::shape::FeatureId,
    ) {
        (
            self.project_local_point(point, false),
            parry3d_f64::shape::FeatureId::Unknown,
        )
    }
}

impl parry3d_f64::query::RayCast for Frustum {
    fn cast_local_ray_and_get_normal(
        &self,
        ray: &parry3d_f64::query::Ray,
        max_time_of_impact: Real,
        solid: bool,
    ) -> Option<parry3d_f64::query::RayIntersection> {
        parry3d_f64::query::details::local_ray_intersection_with_support_map_with_params(
            self,
            &mut parry3d_f64::query::gjk::VoronoiSimplex::new(),
            ray,
            max_time_of_impact,
            solid,
        )
    }
}

impl Shape for Frustum {
    fn compute_local_aabb(&self) -> parry3d_f64::bounding_volume::Aabb {
        let r = self.r0.max(self.r1);
        parry3d_f64::bounding_volume::Aabb::new(Point3::new(-r, -r, 0.0), Point3::new(r, r, self.h))
    }

    fn compute_local_bounding_sphere(&self) -> parry3d_f64::bounding_volume::BoundingSphere {
        let r = self.r0.max(self.r1);
        parry3d_f64::bounding_volume::BoundingSphere::new(
            Point3::new(0.0, 0.0, self.h / 2.0),
            r.hypot(self.h / 2.0),
        )
    }

    fn clone_dyn(&self) -> Box<dyn Shape> {
        Box::new(*self)
    }

    fn scale_dyn(&self, _: &Vector3, _: u32) -> Option<Box<dyn Shape>> {
        None
    }

    fn mass_properties(&self, density: Real) -> parry3d_f64::mass_properties::MassProperties {
        // Only for dynamics, never used here: the enclosing cylinder's.
        parry3d_f64::mass_properties::MassProperties::from_cylinder(
            density,
            self.h / 2.0,
            self.r0.max(self.r1),
        )
    }

    fn is_convex(&self) -> bool {
        true
    }

    fn shape_type(&self) -> parry3d_f64::shape::ShapeType {
        parry3d_f64::shape::ShapeType::Custom
    }

    fn as_typed_shape(&self) -> parry3d_f64::shape::TypedShape<'_> {
        parry3d_f64::shape::TypedShape::Custom(self)
    }

    fn ccd_thickness(&self) -> Real {
        self.r0.min(self.r1).min(self.h / 2.0)
    }

    fn ccd_angular_thickness(&self) -> Real {
        std::f64::consts::FRAC_PI_4
    }

    fn as_support_map(&self) -> Option<&dyn parry3d_f64::shape::SupportMap> {
        Some(self as &dyn parry3d_f64::shape::SupportMap)
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
    /// What the sweep did (exactly as [`crate::cutting::sweep::sweep_program`] reports it).
    pub sweep: SweepReport,
    /// Largest distance (mm) between the true and the checked position of any point of the
    /// tool assembly on the moves that turn a rotary axis (sub-stepped checks); 0 if none.
    pub check_error_bound_mm: Real,
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
    let mut cuts = Vec::new();
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
                cuts.clear();
                cutter.ray_cuts(&o, axis, &mut cuts);
                for (s, c) in segs.iter().flat_map(|s| cuts.iter().map(move |c| (s, c))) {
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

/// The part `piece` of the assembly with its tip `offset` above the tool tip, translated
/// from `tip` by `d` with axis `v`.
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

/// The overlap of `piece` swept from `tip` by `d` with the stock: located by bisection
/// ([`first_stock_contact`]) unless the move already has its first contact of this kind
/// (`seen`: a later sub-step only adds depth and volume).
fn contact(
    stock: &TriDexel,
    seen: bool,
    piece: &Tool,
    offset: Real,
    tip: Point3,
    d: Vector3,
    v: UnitVector3,
) -> Option<Overlap> {
    if seen {
        overlap(stock, &swept(piece, offset, tip, d, v))
    } else {
        first_stock_contact(stock, piece, offset, tip, d, v)
    }
}

/// The axis values a fraction `f` along `mv` (rotary and linear axes of `chain` linearly
/// interpolated, as the chain and the envelope move them).
fn axes_at(chain: &Chain, mv: &Move, f: Real) -> AxisValues {
    let mut q = mv.start;
    for axis in chain.axes() {
        let (a, b) = (mv.start.get(axis.letter), mv.end.get(axis.letter));
        q.set(axis.letter, a + (b - a) * f);
    }
    q
}

/// First contact of the cutting part with the stock over a move that turns a rotary axis,
/// with the envelope that cuts it: the whole move's envelope gives volume and depth, the
/// envelopes of its first parts locate the contact by bisection to [`CONTACT_RESOLUTION`]
/// of any tool point's travel.
fn first_envelope_contact(
    stock: &TriDexel,
    chain: &Chain,
    tool: &Tool,
    mv: &Move,
    state: &[Real; 6],
) -> Option<Overlap> {
    let env = RotaryEnvelope::with_state(chain, tool, &mv.start, &mv.end, state).ok()?;
    let whole = overlap(stock, &env)?;
    let p0 = chain.w_from_t_state(&mv.start, state);
    let v = UnitVector3::new_normalize(p0.rotation * Vector3::z());
    let mut best = overlap(
        stock,
        &swept(tool, 0.0, p0 * Point3::origin(), Vector3::zeros(), v),
    );
    if best.is_none() {
        best = Some(whole);
        let (mut lo, mut hi) = (0.0, 1.0);
        while env.speed_bound() * (hi - lo) > CONTACT_RESOLUTION {
            let mid = 0.5 * (lo + hi);
            let part =
                RotaryEnvelope::with_state(chain, tool, &mv.start, &axes_at(chain, mv, mid), state)
                    .ok()?;
            match overlap(stock, &part) {
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
        let mut z = tool.length() + h.shank.length();
        for sec in &h.sections {
            let f = Frustum {
                r0: sec.radius_bottom,
                r1: sec.radius_top,
                h: sec.length,
            };
            out.push((
                Part::Holder,
                Box::new(f) as Box<dyn Shape>,
                Isometry3::translation(0.0, 0.0, z),
            ));
            z += sec.length;
        }
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

/// What the checks read: the machine, the assembly and the fixtures.
struct Scene<'a> {
    chain: &'a Chain,
    tool: &'a Tool,
    holder: Option<&'a Holder>,
    fixtures: &'a [Fixture],
    parts: Vec<(Part, Box<dyn Shape>, Isometry3)>,
    envelope: Envelope,
    fixture_bounds: Vec<Aabb>,
    /// The bound the rotary checks' sub-steps meet (mm).
    bound: Real,
}

impl Scene<'_> {
    /// Whether a box may touch the stock or a fixture.
    fn near(&self, stock: &TriDexel, b: &Aabb) -> bool {
        b.intersects(stock.bounds()) || self.fixture_bounds.iter().any(|f| b.intersects(f))
    }

    /// The after-checks of one translation of the tool (tip from `tip` by `d`, orientation
    /// `rotation`): shank and holder against the stock, every part against the fixtures.
    fn after(&self, stock: &TriDexel, log: &mut Log, tip: Point3, d: Vector3, rotation: Rotation3) {
        let v = Piece::axis(&rotation);
        if !self.near(stock, &self.envelope.swept_box(tip, d, v, tol::SLIVER)) {
            return;
        }
        if let Some(h) = self.holder {
            for (part, piece, offset) in [
                (Part::Shank, &h.shank, self.tool.length()),
                (
                    Part::Holder,
                    &h.holder,
                    self.tool.length() + h.shank.length(),
                ),
            ] {
                let kind = EventKind::NonCuttingInStock(part);
                if let Some(o) = contact(stock, log.has(&kind), piece, offset, tip, d, v) {
                    log.note(kind, o.point, o.depth_mm, Some(o.volume_mm3));
                }
            }
        }
        let w_from_t = Isometry3::from_parts(tip.coords.into(), rotation);
        for f in self.fixtures {
            for (part, shape, t_from_part) in &self.parts {
                let w_from_part = w_from_t * t_from_part;
                if let Some((toi, p)) = fixture_contact(shape.as_ref(), &w_from_part, &d, f) {
                    log.note(
                        EventKind::FixtureHit {
                            part: *part,
                            fixture: f.name.clone(),
                        },
                        p,
                        d.norm() * (1.0 - toi),
                        None,
                    );
                }
            }
        }
    }

    /// The after-checks of a move that turns a rotary axis, in sub-steps meeting
    /// [`Scene::bound`] for every point of the assembly; returns the achieved bound (mm).
    fn after_rotary(
        &self,
        stock: &TriDexel,
        log: &mut Log,
        mv: &Move,
        state: &[Real; 6],
    ) -> Result<Real, SweepError> {
        let rb = RotaryBound::of_state(self.chain, self.tool, mv, state);
        // The bound's first term grows with the distance of the farthest point from the
        // tool's mid point: the whole assembly's instead of the flutes'.
        let mid = self.tool.length() / 2.0;
        let reach_tool = self.tool.reach_from(mid);
        let reach = reach_tool.max(self.envelope.radius.hypot(self.envelope.length - mid));
        let rb = RotaryBound {
            a: if reach_tool > 0.0 {
                rb.a * reach / reach_tool
            } else {
                rb.a
            },
            b: rb.b,
        };
        let n = rb.steps_for(self.bound, mv.line)?;
        // The assembly's points lie within `length + radius` of the mid point: holding the
        // orientation over a rotation ω moves them by at most ω·(length + radius).
        let omega: Real = self
            .chain
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
            omega * (self.envelope.length + self.envelope.radius) / k + rb.b / (k * k)
        };
        let margin = err(64) + err(n) + tol::SLIVER;
        rotary_substeps(
            self.chain,
            self.tool,
            mv,
            state,
            n,
            |tip, d, rot| {
                self.near(
                    stock,
                    &self.envelope.swept_box(tip, d, Piece::axis(&rot), margin),
                )
            },
            |tip, d, rot| {
                self.after(stock, log, tip, d, rot);
                Ok::<(), SweepError>(())
            },
        )?;
        Ok(rb.at(n))
    }
}

/// The events found so far; those of the move being checked are merged per kind.
#[derive(Default)]
struct Log {
    events: Vec<Event>,
    /// The move (index, NC line) being checked and its events.
    current: Option<(usize, usize)>,
    pending: Vec<Event>,
    check_error: Real,
}

impl Log {
    /// Starts the events of move `k`, closing those of the previous move.
    fn at(&mut self, k: usize, line: usize) {
        if self.current.map(|c| c.0) != Some(k) {
            self.events.append(&mut self.pending);
            self.current = Some((k, line));
        }
    }

    /// Whether the move being checked already has an event of this kind.
    fn has(&self, kind: &EventKind) -> bool {
        self.pending.iter().any(|e| &e.kind == kind)
    }

    fn note(&mut self, kind: EventKind, point: Point3, depth: Real, volume: Option<Real>) {
        let line = self.current.map_or(0, |c| c.1);
        if let Some(e) = self.pending.iter_mut().find(|e| e.kind == kind) {
            e.depth_mm = e.depth_mm.max(depth);
            e.volume_mm3 = e.volume_mm3.zip(volume).map(|(a, b)| a + b);
        } else {
            self.pending.push(Event {
                kind,
                line,
                point: [point.x, point.y, point.z],
                depth_mm: depth,
                volume_mm3: volume,
            });
        }
    }
}

/// The collision checks as the sweep driver's observer.
struct Checks<'a> {
    scene: Scene<'a>,
    log: Log,
}

impl SweepObserver for Checks<'_> {
    fn before_rapid(
        &mut self,
        stock: &TriDexel,
        k: usize,
        mv: &Move,
        piece: &Piece,
    ) -> Result<(), SweepError> {
        self.log.at(k, mv.line);
        let tool = self.scene.tool;
        let contact = match *piece {
            Piece::Translation { tip, d, rotation } => {
                let v = Piece::axis(&rotation);
                let near = swept(tool, 0.0, tip, d, v)
                    .bounds()
                    .intersects(stock.bounds());
                let seen = self.log.has(&EventKind::RapidThroughMaterial);
                near.then(|| contact(stock, seen, tool, 0.0, tip, d, v))
                    .flatten()
            }
            Piece::Rotary { state, .. } => {
                first_envelope_contact(stock, self.scene.chain, tool, mv, &state)
            }
            // The checks drive a chain: a pose source's moves never reach them.
            Piece::Sampled => None,
        };
        if let Some(o) = contact {
            self.log.note(
                EventKind::RapidThroughMaterial,
                o.point,
                o.depth_mm,
                Some(o.volume_mm3),
            );
        }
        Ok(())
    }

    fn after_move(
        &mut self,
        stock: &TriDexel,
        k: usize,
        mv: &Move,
        piece: &Piece,
    ) -> Result<(), SweepError> {
        self.log.at(k, mv.line);
        if self.scene.holder.is_none() && self.scene.fixtures.is_empty() {
            // Nothing to check after a move: only the flutes, which cut.
            return Ok(());
        }
        match *piece {
            Piece::Translation { tip, d, rotation } => {
                self.scene.after(stock, &mut self.log, tip, d, rotation);
            }
            Piece::Rotary { state, .. } => {
                let e = self.scene.after_rotary(stock, &mut self.log, mv, &state)?;
                self.log.check_error = self.log.check_error.max(e);
            }
            // The checks drive a chain: a pose source's moves never reach them.
            Piece::Sampled => {}
        }
        Ok(())
    }

    /// Only a holder or fixtures are checked after a move ([`SweepObserver::after_move`]
    /// logs nothing else); rapids are checked before they cut either way.
    fn looks(&self) -> bool {
        self.scene.holder.is_some() || !self.scene.fixtures.is_empty()
    }
}

/// Runs `moves` through the sweep driver (removing material from `stock` exactly as
/// [`crate::cutting::sweep::sweep_program`] does) and reports the collisions described in the module
/// docs.
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
    let mut checks = Checks {
        scene: Scene {
            chain,
            tool,
            holder,
            fixtures,
            parts: parry_parts(tool, holder),
            envelope,
            fixture_bounds: fixtures.iter().map(|f| f.mesh.bounds()).collect(),
            bound: opts.rotary_step_bound_mm.max(ROTARY_CHECK_BOUND),
        },
        log: Log::default(),
    };
    let sweep = sweep_observed(stock, chain, tool, moves, opts, progress, &mut checks)?;
    let mut log = checks.log;
    log.events.append(&mut log.pending);
    Ok(CollisionReport {
        events: log.events,
        moves: sweep.moves,
        sweep,
        check_error_bound_mm: log.check_error,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cutting::shape::read_obj;

    /// A closed box mesh [min, max] as a fixture.
    fn box_fixture(min: [Real; 3], max: [Real; 3]) -> Fixture {
        let mut text = String::new();
        for k in 0..8 {
            let c = |i: usize| if k & (1 << i) == 0 { min[i] } else { max[i] };
            text.push_str(&format!("v {:?} {:?} {:?}\n", c(0), c(1), c(2)));
        }
        // Outward faces of the cube with corner index bits (x, y, z).
        for f in [
            [1, 3, 4, 2],
            [5, 6, 8, 7],
            [1, 2, 6, 5],
            [3, 7, 8, 4],
            [1, 5, 7, 3],
            [2, 4, 8, 6],
        ] {
            text.push_str(&format!(
                "f {} {} {}\nf {} {} {}\n",
                f[0], f[1], f[2], f[0], f[2], f[3]
            ));
        }
        let mesh = read_obj(&text, std::path::Path::new("box.obj")).expect("closed box");
        Fixture::try_new("box", mesh).expect("fixture")
    }

    /// A cone-shaped holder section (radius 2 at its bottom, 10 at its top, 10 long) moving
    /// along +x meets a plate that reaches only 1 mm above its bottom where its radius is
    /// 2.8: first contact after 5 − 2.8 = 2.2 mm of the 10 mm travel, where its enclosing
    /// cylinder (radius 10) would start inside the plate.
    #[test]
    fn frustum_section_meets_a_fixture_at_its_true_radius() {
        let plate = box_fixture([5.0, -20.0, -5.0], [30.0, 20.0, 1.0]);
        let cone = Frustum {
            r0: 2.0,
            r1: 10.0,
            h: 10.0,
        };
        let (toi, p) = fixture_contact(
            &cone,
            &Isometry3::identity(),
            &Vector3::new(10.0, 0.0, 0.0),
            &plate,
        )
        .expect("contact");
        assert!((toi - 0.22).abs() < 1e-6, "toi {toi}");
        assert!(
            (p.x - 5.0).abs() < 1e-6 && (p.z - 1.0).abs() < 1e-6,
            "{p:?}"
        );
        // Upside down (wide end first) it touches at once: radius 10 at the plate's height.
        let flipped = Frustum {
            r0: 10.0,
            r1: 2.0,
            h: 10.0,
        };
        let (toi, _) = fixture_contact(
            &flipped,
            &Isometry3::identity(),
            &Vector3::new(10.0, 0.0, 0.0),
            &plate,
        )
        .expect("contact");
        assert!(toi < 1e-9, "toi {toi}");
    }
}
