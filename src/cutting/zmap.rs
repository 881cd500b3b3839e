//! Z-map: the fast path for pure 3-axis programs. The stock is a height field, one height
//! per cell of a regular XY grid, sampled at the cell centres (the same centres as the
//! tri-dexel's z rays for the same box and pitch, so the two can be compared ray by ray).
//!
//! **Exact heights.** With the tool axis along +Z and no rotary motion, a move translates
//! the tool, and the new height of a cell is the lowest point of the swept tool on the
//! vertical line through the cell centre, in closed form:
//!
//! * flat end mill, tip from `p0` by `d`: the bottom disc covers the centre for the move
//!   parameters `s` where `|w − s·d_xy|² ≤ R²` (`w` = centre − `p0` in xy), an interval found
//!   by a quadratic; the tip height `z0 + s·d_z` is linear in `s`, so its minimum is at an
//!   end of that interval;
//! * ball end mill: the swept ball is a capsule (the segment of ball centres grown by `R`);
//!   the vertical line enters it on one of the two end spheres or on the cylinder about the
//!   segment (with the foot of the perpendicular inside the segment). The lowest valid
//!   candidate of those three quadratics is the entry. The shank above the ball never
//!   reaches lower than the ball under the same centre, so it does not matter.
//!
//! No sampling along the move. The cut follows the tri-dexel's rules: material left
//! thinner than [`tol::SLIVER`] above the stock bottom is removed.
//!
//! **Height field limits.** A cell holds material from the stock bottom up to its height:
//! no undercuts. Moves whose tool top could end below the stock top while cutting (the
//! shank buried in the material) are refused, as are tilted tool axes and rotary motion.
//!
//! **Speed and determinism.** Each move's XY footprint is a stadium (the tool disc swept
//! along `d_xy`); every grid row is cut only over the footprint's exact x span. The grid is
//! split in fixed bands of rows; bands run in parallel and each applies the moves in
//! program order, so the result is bit-identical for any thread count.
//!
//! **Invariant:** the Z-map knows nothing about G-code text or files: it reads moves and
//! poses from the chain, and tool geometry.

use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::chain::{AxisKind, Chain};
use crate::math::{Aabb, Point3, Real, Vector3, tol};
use crate::nc::{AxisLetter, Move};
use rayon::prelude::*;

/// Largest tilt (rad) of the tool axis from +Z that still counts as parallel: over a 50 mm
/// tool radius it moves the tool's bottom by 5e-11 mm, far below [`tol::LENGTH_EPS`]; any
/// real deviation (µrad) is refused rather than silently ignored.
pub const AXIS_TILT: Real = 1e-12;

/// Grid rows per band of parallel work: small enough to spread a 2,000-row map over many
/// threads, large enough that skipping the moves outside a band costs little.
const BAND_ROWS: usize = 16;

/// Errors of the Z-map.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ZMapError {
    /// The box is empty, inverted or not finite.
    #[error("Z-map box must be finite with min < max on every axis")]
    BadBox,
    /// The arc chord tolerance is not positive and finite.
    #[error("Z-map arc sagitta must be positive and finite, got {0} mm")]
    BadSagitta(Real),
    /// The pitch is not positive and finite.
    #[error("Z-map pitch must be positive and finite, got {0} mm")]
    BadPitch(Real),
    /// The height field would not fit in the memory budget.
    #[error(
        "the Z-map at pitch {pitch} mm would need {needed_mib:.0} MiB, more than the {budget_mib:.0} MiB available"
    )]
    TooMuchMemory {
        /// Requested pitch (mm).
        pitch: Real,
        /// Estimated need (MiB).
        needed_mib: Real,
        /// Budget (MiB).
        budget_mib: Real,
    },
    /// A move names an axis the machine does not have.
    #[error("line {line}: the machine has no {axis} axis")]
    MissingAxis {
        /// Source line.
        line: usize,
        /// Axis letter.
        axis: char,
    },
    /// A move turns a rotary axis: not a 3-axis program.
    #[error(
        "line {line}: the move turns the {axis} axis; the Z-map handles 3-axis programs only (use the tri-dexel sweep)"
    )]
    RotaryMotion {
        /// Source line.
        line: usize,
        /// Axis letter.
        axis: char,
    },
    /// The tool axis is not parallel to +Z in the workpiece frame.
    #[error(
        "line {line}: the tool axis is tilted {tilt_rad:.3e} rad from +Z; the Z-map needs it parallel (use the tri-dexel sweep)"
    )]
    TiltedAxis {
        /// Source line.
        line: usize,
        /// Angle between the tool axis and +Z (rad).
        tilt_rad: Real,
    },
    /// The tool's top could end below the stock top while cutting: the material above the
    /// shank would stay, which a height field cannot hold.
    #[error(
        "line {line}: the tool top reaches down to z = {tool_top_mm} mm, below the stock top z = {stock_top_mm} mm; a height field cannot keep material above the shank (use the tri-dexel sweep or a longer tool)"
    )]
    ToolTooShort {
        /// Source line.
        line: usize,
        /// Lowest tool top over the move (mm).
        tool_top_mm: Real,
        /// Stock top (mm).
        stock_top_mm: Real,
    },
    /// The tool is not a flat or ball end mill (the closed forms cover only those).
    #[error("the Z-map cuts only flat and ball end mills; use the tri-dexel for other tools")]
    UnsupportedTool,
    /// A position is NaN or infinite.
    #[error("line {line}: the tool position is not finite")]
    NotFinite {
        /// Source line.
        line: usize,
    },
}

impl ZMapError {
    /// The NC line the error is about, if any.
    pub fn line(&self) -> Option<usize> {
        match self {
            ZMapError::MissingAxis { line, .. }
            | ZMapError::RotaryMotion { line, .. }
            | ZMapError::TiltedAxis { line, .. }
            | ZMapError::ToolTooShort { line, .. }
            | ZMapError::NotFinite { line } => Some(*line),
            _ => None,
        }
    }
}

/// A straight move of the tool tip in the workpiece frame, tool axis +Z.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TipMove {
    /// Tip position at the start (mm, W).
    pub start: Point3,
    /// Tip position at the end (mm, W).
    pub end: Point3,
    /// NC line, for messages.
    pub line: usize,
}

/// Options of the Z-map sweep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZMapOptions {
    /// Join consecutive moves that continue one straight line in the same direction (every
    /// joint within [`tol::LENGTH_EPS`] of the line through the run's start along its first
    /// move) into one cut. The union of the sweeps along the pieces is the sweep along the
    /// whole run, so heights change by at most 2·LENGTH_EPS (rounding aside), while each
    /// cell is evaluated once per run instead of once per overlapping move. Default: true.
    pub merge_collinear: bool,
    /// Arcs and helices are cut as chords whose sagitta is at most this (mm, > 0). Default:
    /// 1e-4 mm, the tri-dexel sweep's default step bound.
    pub arc_sagitta_mm: Real,
}

impl Default for ZMapOptions {
    fn default() -> Self {
        Self {
            merge_collinear: true,
            arc_sagitta_mm: 1e-4,
        }
    }
}

/// What a Z-map sweep did.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ZMapReport {
    /// Moves processed.
    pub moves: usize,
    /// Moves whose footprint meets the stock below its top (the others were skipped).
    pub moves_in_stock: usize,
    /// Straight cuts applied after joining collinear moves.
    pub cuts: usize,
}

/// A height-field stock over a box.
#[derive(Clone, Debug, PartialEq)]
pub struct ZMap {
    bounds: Aabb,
    nx: usize,
    ny: usize,
    x0: Real,
    y0: Real,
    dx: Real,
    dy: Real,
    heights: Vec<Real>,
}

/// One move prepared for the bands: geometry in the cut's own terms.
#[derive(Clone, Copy, Debug)]
struct Prepared {
    /// Tip at the start (flat) or ball centre at the start (ball).
    p0: Point3,
    /// Displacement.
    d: Vector3,
    /// |d_xy|².
    a: Real,
    /// |d|².
    l2: Real,
    /// y range of the footprint.
    y_lo: Real,
    y_hi: Real,
    /// Straight along xy at constant height (the common case, with a faster cell rule).
    level: bool,
}

impl ZMap {
    /// A box stock at `pitch` (mm), refusing if it would exceed `budget_bytes`. The cell
    /// layout equals the tri-dexel's z grid: `round(size/pitch)` cells per side (at least 1),
    /// spacing `size/cells`, centres half a spacing in from the box.
    pub fn new_box(bounds: Aabb, pitch: Real, budget_bytes: Real) -> Result<Self, ZMapError> {
        if !bounds.is_proper_box() {
            return Err(ZMapError::BadBox);
        }
        if !(pitch.is_finite() && pitch > 0.0) {
            return Err(ZMapError::BadPitch(pitch));
        }
        let count = |k: usize| (((bounds.max[k] - bounds.min[k]) / pitch).round()).max(1.0);
        let (fx, fy) = (count(0), count(1));
        let needed = fx * fy * std::mem::size_of::<Real>() as Real;
        if needed > budget_bytes {
            return Err(ZMapError::TooMuchMemory {
                pitch,
                needed_mib: needed / 1048576.0,
                budget_mib: budget_bytes / 1048576.0,
            });
        }
        let (nx, ny) = (fx as usize, fy as usize);
        let dx = (bounds.max.x - bounds.min.x) / nx as Real;
        let dy = (bounds.max.y - bounds.min.y) / ny as Real;
        Ok(Self {
            bounds,
            nx,
            ny,
            x0: bounds.min.x + dx / 2.0,
            y0: bounds.min.y + dy / 2.0,
            dx,
            dy,
            heights: vec![bounds.max.z; nx * ny],
        })
    }

    /// The initial box.
    pub fn bounds(&self) -> &Aabb {
        &self.bounds
    }

    /// Number of cells along x and y.
    pub fn dims(&self) -> (usize, usize) {
        (self.nx, self.ny)
    }

    /// Cell spacings along x and y (mm).
    pub fn pitches(&self) -> (Real, Real) {
        (self.dx, self.dy)
    }

    /// The centre (x, y) of cell `(ix, iy)` (mm).
    pub fn cell_centre(&self, ix: usize, iy: usize) -> (Real, Real) {
        (
            self.x0 + ix as Real * self.dx,
            self.y0 + iy as Real * self.dy,
        )
    }

    /// Material top of cell `(ix, iy)` (mm); the stock bottom if the column is empty.
    pub fn height(&self, ix: usize, iy: usize) -> Real {
        self.heights[iy * self.nx + ix]
    }

    /// All heights, row by row (`iy · nx + ix`).
    pub fn heights(&self) -> &[Real] {
        &self.heights
    }

    /// Material volume (mm³): summed column heights times the cell area.
    pub fn volume(&self) -> Real {
        let zmin = self.bounds.min.z;
        self.heights.iter().map(|h| h - zmin).sum::<Real>() * self.dx * self.dy
    }

    /// Volume removed from the initial box (mm³).
    pub fn removed_volume(&self) -> Real {
        let zmax = self.bounds.max.z;
        self.heights.iter().map(|h| zmax - h).sum::<Real>() * self.dx * self.dy
    }

    /// Sweeps `tool` through `moves` on `chain`. Refuses (before cutting anything) a move
    /// that turns a rotary axis, whose tool axis is not parallel to +Z, that names an axis
    /// the machine lacks, or whose tool could be buried below the stock top.
    pub fn sweep_program(
        &mut self,
        chain: &Chain,
        tool: &Tool,
        moves: &[Move],
        opts: &ZMapOptions,
    ) -> Result<ZMapReport, ZMapError> {
        let sagitta = opts.arc_sagitta_mm;
        if !(sagitta.is_finite() && sagitta > 0.0) {
            return Err(ZMapError::BadSagitta(sagitta));
        }
        let mut tips = Vec::with_capacity(moves.len());
        for mv in moves.iter().flat_map(|m| m.chords(sagitta)) {
            let mv = &mv;
            if let Some(missing) = AxisLetter::ALL
                .into_iter()
                .find(|&l| !chain.has_axis(l) && mv.start.get(l) != mv.end.get(l))
            {
                return Err(ZMapError::MissingAxis {
                    line: mv.line,
                    axis: missing.as_char(),
                });
            }
            if let Some(axis) = chain.axes().iter().find(|a| {
                a.kind == AxisKind::Rotary && mv.start.get(a.letter) != mv.end.get(a.letter)
            }) {
                return Err(ZMapError::RotaryMotion {
                    line: mv.line,
                    axis: axis.letter.as_char(),
                });
            }
            let (p0, p1) = (chain.w_from_t(&mv.start), chain.w_from_t(&mv.end));
            for p in [&p0, &p1] {
                let v = p.rotation * Vector3::z();
                let tilt = v.x.hypot(v.y).atan2(v.z);
                if tilt.is_nan() || tilt.abs() > AXIS_TILT {
                    return Err(ZMapError::TiltedAxis {
                        line: mv.line,
                        tilt_rad: tilt,
                    });
                }
            }
            tips.push(TipMove {
                start: p0 * Point3::origin(),
                end: p1 * Point3::origin(),
                line: mv.line,
            });
        }
        self.cut(tool, &tips, opts)
    }

    /// Removes the tool swept along each tip move (axis +Z), in order. Checks every move
    /// before cutting anything.
    pub fn cut(
        &mut self,
        tool: &Tool,
        tips: &[TipMove],
        opts: &ZMapOptions,
    ) -> Result<ZMapReport, ZMapError> {
        if !matches!(tool.kind(), ToolKind::Flat | ToolKind::Ball) {
            return Err(ZMapError::UnsupportedTool);
        }
        let r = tool.radius();
        let ztop = self.bounds.max.z;
        let mut segments: Vec<(Point3, Point3)> = Vec::with_capacity(tips.len());
        for m in tips {
            let finite = m
                .start
                .coords
                .iter()
                .chain(m.end.coords.iter())
                .all(|c| c.is_finite());
            if !finite {
                return Err(ZMapError::NotFinite { line: m.line });
            }
            let (a, b) = (m.start, m.end);
            let xy_lo = (a.x.min(b.x) - r, a.y.min(b.y) - r);
            let xy_hi = (a.x.max(b.x) + r, a.y.max(b.y) + r);
            let z_lo = a.z.min(b.z);
            let meets = xy_lo.0 <= self.bounds.max.x
                && xy_hi.0 >= self.bounds.min.x
                && xy_lo.1 <= self.bounds.max.y
                && xy_hi.1 >= self.bounds.min.y
                && z_lo < ztop;
            if !meets {
                continue;
            }
            if z_lo + tool.length() < ztop {
                return Err(ZMapError::ToolTooShort {
                    line: m.line,
                    tool_top_mm: z_lo + tool.length(),
                    stock_top_mm: ztop,
                });
            }
            segments.push((a, b));
        }
        let moves_in_stock = segments.len();
        if opts.merge_collinear {
            segments = merge_collinear(&segments);
        }
        let lift = match tool.kind() {
            ToolKind::Ball => r,
            _ => 0.0,
        };
        let prepared: Vec<Prepared> = segments
            .iter()
            .map(|&(a, b)| {
                let d = b - a;
                Prepared {
                    p0: a + Vector3::z() * lift,
                    d,
                    a: d.x * d.x + d.y * d.y,
                    l2: d.norm_squared(),
                    y_lo: a.y.min(b.y) - r,
                    y_hi: a.y.max(b.y) + r,
                    level: d.z == 0.0,
                }
            })
            .collect();
        let report = ZMapReport {
            moves: tips.len(),
            moves_in_stock,
            cuts: prepared.len(),
        };
        let (nx, x0, y0, dx, dy) = (self.nx, self.x0, self.y0, self.dx, self.dy);
        let zmin = self.bounds.min.z;
        let kind = tool.kind();
        self.heights
            .par_chunks_mut(BAND_ROWS * nx)
            .enumerate()
            .for_each(|(band, cells)| {
                let iy0 = band * BAND_ROWS;
                let rows = cells.len() / nx;
                let (band_lo, band_hi) =
                    (y0 + iy0 as Real * dy, y0 + (iy0 + rows - 1) as Real * dy);
                for m in &prepared {
                    if m.y_hi < band_lo || m.y_lo > band_hi {
                        continue;
                    }
                    let j0 = (((m.y_lo - band_lo) / dy).ceil().max(0.0)) as usize;
                    let j1 = (((m.y_hi - band_lo) / dy).floor()).min((rows - 1) as Real);
                    if j1 < 0.0 {
                        continue;
                    }
                    for j in j0..=j1 as usize {
                        let y = band_lo + j as Real * dy;
                        let row = &mut cells[j * nx..(j + 1) * nx];
                        cut_row(row, m, kind, r, y, x0, dx, zmin);
                    }
                }
            });
        Ok(report)
    }
}

/// Joins consecutive segments that continue one straight line in the same direction
/// (see [`ZMapOptions::merge_collinear`]).
fn merge_collinear(segments: &[(Point3, Point3)]) -> Vec<(Point3, Point3)> {
    let mut out: Vec<(Point3, Point3)> = Vec::with_capacity(segments.len());
    // Unit direction of the current run's first segment.
    let mut dir: Option<Vector3> = None;
    for &(a, b) in segments {
        if let (Some((start, end)), Some(u)) = (out.last_mut(), dir) {
            let off_line = |p: Point3| {
                let w = p - *start;
                (w - u * u.dot(&w)).norm()
            };
            if (a - *end).norm() <= tol::LENGTH_EPS
                && (b - a).dot(&u) > 0.0
                && off_line(b) <= tol::LENGTH_EPS
            {
                *end = b;
                continue;
            }
        }
        dir = (b - a).try_normalize(0.0);
        out.push((a, b));
    }
    out
}

/// The x span of the stadium (disc of radius `r` centred on the segment `p0 + s·d`,
/// s ∈ [0, 1], in xy) on the row at `y`: the hull of the spans of the two end discs and of
/// the band along the segment (the stadium is convex, so the hull is the span).
fn stadium_span(m: &Prepared, r: Real, y: Real) -> Option<(Real, Real)> {
    let mut lo = Real::INFINITY;
    let mut hi = Real::NEG_INFINITY;
    for (cx, cy) in [(m.p0.x, m.p0.y), (m.p0.x + m.d.x, m.p0.y + m.d.y)] {
        let h2 = r * r - (y - cy) * (y - cy);
        if h2 >= 0.0 {
            let h = h2.sqrt();
            lo = lo.min(cx - h);
            hi = hi.max(cx + h);
        }
    }
    if m.a > tol::LENGTH_EPS * tol::LENGTH_EPS {
        // Points (p0.x + u, y): |d_x·w − d_y·u| ≤ r·|d_xy| and 0 ≤ d_x·u + d_y·w ≤ |d_xy|².
        let (ddx, ddy) = (m.d.x, m.d.y);
        let w = y - m.p0.y;
        let rl = r * m.a.sqrt();
        let (mut u0, mut u1) = (Real::NEG_INFINITY, Real::INFINITY);
        let mut clip = |k: Real, lo_c: Real, hi_c: Real| {
            // lo_c ≤ k·u ≤ hi_c
            if k == 0.0 {
                if lo_c > 0.0 || hi_c < 0.0 {
                    u0 = Real::INFINITY;
                }
            } else {
                let (a, b) = (lo_c / k, hi_c / k);
                u0 = u0.max(a.min(b));
                u1 = u1.min(a.max(b));
            }
        };
        clip(-ddy, -rl - ddx * w, rl - ddx * w);
        clip(ddx, -ddy * w, m.a - ddy * w);
        if u0 <= u1 {
            lo = lo.min(m.p0.x + u0);
            hi = hi.max(m.p0.x + u1);
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// The lowest point of the swept flat tool on the vertical line at (x, y), if it meets it.
fn flat_lowest(m: &Prepared, r: Real, x: Real, y: Real) -> Option<Real> {
    let (wx, wy) = (x - m.p0.x, y - m.p0.y);
    let c = wx * wx + wy * wy - r * r;
    if m.a <= tol::LENGTH_EPS * tol::LENGTH_EPS {
        // Vertical (plunge): the disc stays put.
        return (c <= 0.0).then(|| m.p0.z + m.d.z.min(0.0));
    }
    // a s² − 2 b s + c ≤ 0.
    let b = wx * m.d.x + wy * m.d.y;
    let disc = b * b - m.a * c;
    if disc < 0.0 {
        return None;
    }
    let q = b + b.signum() * disc.sqrt();
    let (r1, r2) = if q == 0.0 {
        (0.0, 0.0)
    } else {
        (q / m.a, c / q)
    };
    let (s0, s1) = (r1.min(r2).max(0.0), r1.max(r2).min(1.0));
    if s0 > s1 {
        return None;
    }
    Some(m.p0.z + m.d.z * if m.d.z >= 0.0 { s0 } else { s1 })
}

/// The lowest point of the swept ball (centres `p0 + s·d`) on the vertical line at (x, y).
fn ball_lowest(m: &Prepared, r: Real, x: Real, y: Real) -> Option<Real> {
    let (wx, wy) = (x - m.p0.x, y - m.p0.y);
    let w2 = wx * wx + wy * wy;
    let r2 = r * r;
    let mut best = Real::INFINITY;
    // End spheres.
    let h2 = r2 - w2;
    if h2 >= 0.0 {
        best = best.min(m.p0.z - h2.sqrt());
    }
    let (ex, ey) = (wx - m.d.x, wy - m.d.y);
    let h2 = r2 - (ex * ex + ey * ey);
    if h2 >= 0.0 {
        best = best.min(m.p0.z + m.d.z - h2.sqrt());
    }
    if m.a > tol::LENGTH_EPS * tol::LENGTH_EPS {
        // Cylinder about the segment: with τ = z − p0.z and E = (w, τ),
        // |E|²·L2 − (E·d)² = r²·L2, i.e. a τ² − 2 (b d_z) τ + (L2 (|w|² − r²) − b²) = 0.
        let b = wx * m.d.x + wy * m.d.y;
        let bz = b * m.d.z;
        let c = m.l2 * (w2 - r2) - b * b;
        let disc = bz * bz - m.a * c;
        if disc >= 0.0 {
            let q = bz + bz.signum() * disc.sqrt();
            let roots = if q == 0.0 {
                [0.0, 0.0]
            } else {
                [q / m.a, c / q]
            };
            for tau in roots {
                let s = (b + tau * m.d.z) / m.l2;
                if (0.0..=1.0).contains(&s) {
                    best = best.min(m.p0.z + tau);
                }
            }
        }
    }
    best.is_finite().then_some(best)
}

/// Lowers one grid row at `y` by the move `m`.
#[allow(
    clippy::too_many_arguments,
    reason = "the hot loop's inputs, kept flat for speed"
)]
fn cut_row(
    row: &mut [Real],
    m: &Prepared,
    kind: ToolKind,
    r: Real,
    y: Real,
    x0: Real,
    dx: Real,
    zmin: Real,
) {
    let Some((xa, xb)) = stadium_span(m, r, y) else {
        return;
    };
    let n = row.len();
    let lower = |h: &mut Real, c: Real| {
        if c < *h {
            *h = if c - zmin < tol::SLIVER { zmin } else { c };
        }
    };
    if kind == ToolKind::Flat && m.level {
        // Constant tip height over the exact footprint span.
        let i0 = ((xa - x0) / dx).ceil().max(0.0);
        let i1 = ((xb - x0) / dx).floor().min((n - 1) as Real);
        if i1 < i0 {
            return;
        }
        let c = m.p0.z;
        let c = if c - zmin < tol::SLIVER { zmin } else { c };
        for h in &mut row[i0 as usize..=i1 as usize] {
            *h = h.min(c);
        }
        return;
    }
    // Other cases: every cell of the span (widened by one cell against rounding of the
    // span) is decided by its own exact rule.
    let i0 = ((xa - x0) / dx).ceil() - 1.0;
    let i1 = ((xb - x0) / dx).floor() + 1.0;
    let i0 = i0.max(0.0);
    let i1 = i1.min((n - 1) as Real);
    if i1 < i0 {
        return;
    }
    let (i0, i1) = (i0 as usize, i1 as usize);
    match kind {
        ToolKind::Flat => {
            for (i, h) in row[i0..=i1].iter_mut().enumerate() {
                let x = x0 + (i0 + i) as Real * dx;
                if let Some(c) = flat_lowest(m, r, x, y) {
                    lower(h, c);
                }
            }
        }
        ToolKind::Ball if m.level => {
            // Distance to the xy segment, then the sphere's bottom. Written without branches
            // so that it vectorises: heights are always the stock bottom or at least a
            // sliver above it, so `min` with the snapped candidate equals `lower`.
            let inv_a = if m.a > 0.0 { 1.0 / m.a } else { 0.0 };
            let wy = y - m.p0.y;
            let (r2, zc) = (r * r, m.p0.z);
            for (i, h) in row[i0..=i1].iter_mut().enumerate() {
                // Through i32 (exact: rows are far shorter than 2³¹ cells) so the conversion
                // vectorises too.
                let wx = x0 + Real::from((i0 + i) as i32) * dx - m.p0.x;
                let s = ((wx * m.d.x + wy * m.d.y) * inv_a).clamp(0.0, 1.0);
                let (ex, ey) = (wx - s * m.d.x, wy - s * m.d.y);
                let g = r2 - (ex * ex + ey * ey);
                let c = if g >= 0.0 {
                    zc - g.max(0.0).sqrt()
                } else {
                    Real::INFINITY
                };
                let c = if c - zmin < tol::SLIVER { zmin } else { c };
                *h = h.min(c);
            }
        }
        ToolKind::Ball => {
            for (i, h) in row[i0..=i1].iter_mut().enumerate() {
                let x = x0 + (i0 + i) as Real * dx;
                if let Some(c) = ball_lowest(m, r, x, y) {
                    lower(h, c);
                }
            }
        }
        // Refused by `ZMap::cut` before any row is touched.
        _ => {}
    }
}

#[cfg(test)]
#[path = "../../benches/support/p1.rs"]
mod p1;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cutting::stock::TriDexel;
    use crate::cutting::sweep::{SweepOptions, sweep_program};
    use crate::machine::chain::{Axis, AxisKind, Chain};
    use crate::math::{CounterRng, UnitVector3};
    use crate::nc::{AxisValues, MoveKind};
    use crate::progress::NoProgress;

    fn xyz_chain() -> Chain {
        Chain::cartesian([AxisLetter::Y, AxisLetter::X, AxisLetter::Z]).expect("valid chain")
    }

    fn mv(a: [Real; 3], b: [Real; 3], line: usize) -> Move {
        let at = |p: [Real; 3]| {
            AxisValues::default()
                .with(AxisLetter::X, p[0])
                .with(AxisLetter::Y, p[1])
                .with(AxisLetter::Z, p[2])
        };
        Move {
            kind: MoveKind::Linear,
            start: at(a),
            end: at(b),
            feed_mm_per_min: Some(100.0),
            line,
        }
    }

    fn small_box() -> Aabb {
        Aabb {
            min: Point3::new(0.0, 0.0, 0.0),
            max: Point3::new(10.0, 8.0, 5.0),
        }
    }

    /// Independent lowest point: dense sampling of the move parameter with, for each sample,
    /// the tool's lowest point over the vertical line (flat: the tip if the disc covers it;
    /// ball: the sphere's bottom). Error ≤ |d|/n·(1 + slope) for the flat tool, and for the
    /// ball the sphere moves at most |d|/n between samples.
    fn lowest_sampled(tool: &Tool, a: Point3, b: Point3, x: Real, y: Real, n: usize) -> Real {
        let r = tool.radius();
        (0..=n)
            .filter_map(|i| {
                let p = a + (b - a) * (i as Real / n as Real);
                let d2 = (x - p.x).powi(2) + (y - p.y).powi(2);
                (d2 <= r * r).then(|| match tool.kind() {
                    ToolKind::Ball => p.z + r - (r * r - d2).sqrt(),
                    _ => p.z,
                })
            })
            .fold(Real::INFINITY, Real::min)
    }

    #[test]
    fn single_moves_match_dense_sampling() {
        let rng = CounterRng::new(5);
        for case in 0..40u64 {
            let u = |k: u64| rng.uniform(case, k);
            let kind = if case % 2 == 0 {
                ToolKind::Flat
            } else {
                ToolKind::Ball
            };
            let tool = Tool::try_new(kind, 3.0, 30.0).expect("valid");
            let a = Point3::new(2.0 + 6.0 * u(0), 2.0 + 4.0 * u(1), 2.0 + 3.0 * u(2));
            // Every fourth move level, one in eight a plunge.
            let mut b = Point3::new(2.0 + 6.0 * u(3), 2.0 + 4.0 * u(4), 2.0 + 3.0 * u(5));
            if case % 4 == 0 {
                b.z = a.z;
            }
            if case % 8 == 1 {
                b.x = a.x;
                b.y = a.y;
            }
            let mut z = ZMap::new_box(small_box(), 0.25, 1e8).expect("fits");
            z.cut(
                &tool,
                &[TipMove {
                    start: a,
                    end: b,
                    line: 1,
                }],
                &ZMapOptions::default(),
            )
            .expect("cuts");
            let n = 20_000;
            // Sampling error bound: the tip moves |d|/n between samples; near the footprint's
            // edge a flat tool's covered interval can end up to one step early.
            let bound = 2.0 * (b - a).norm() / n as Real + 1e-12;
            let (nx, ny) = z.dims();
            let mut skipped = 0;
            for iy in 0..ny {
                for ix in 0..nx {
                    let (x, y) = z.cell_centre(ix, iy);
                    let expect = lowest_sampled(&tool, a, b, x, y, n).clamp(0.0, 5.0);
                    let got = z.height(ix, iy);
                    if (got - expect).abs() > bound {
                        // Only a cell on the footprint's rim may differ, where sampling
                        // misses a sliver of the move.
                        let near_rim = lowest_sampled(&tool, a, b, x, y, 8 * n).clamp(0.0, 5.0);
                        assert!(
                            (got - near_rim).abs() <= bound,
                            "case {case} {kind:?} cell ({ix},{iy}): {got} vs sampled {expect}"
                        );
                        skipped += 1;
                    }
                }
            }
            assert!(skipped <= 2, "case {case}: {skipped} rim cells");
        }
    }

    /// A chain of X, Y, Z with translation deviations and a rotation about Z: the tool axis
    /// stays parallel to Z, so the Z-map accepts it.
    fn deviated_chain(rng: &CounterRng, case: u64) -> Chain {
        let mut c = xyz_chain();
        for (name, scale) in [
            ("dx_YX", 0.3),
            ("dy_XZ", 0.3),
            ("dz_ZS", 0.2),
            ("gamma_YX", 1e-3),
        ] {
            let id = c.deviation_id(name).expect("known");
            c.set_deviation(
                id,
                scale * (2.0 * rng.uniform(case, 100 + id.joint as u64) - 1.0),
            );
        }
        c
    }

    #[test]
    fn heights_equal_the_tri_dexel_top_crossings() {
        let rng = CounterRng::new(21);
        let pitch = 0.2;
        let bx = small_box();
        for case in 0..12u64 {
            let kind = if case % 2 == 0 {
                ToolKind::Flat
            } else {
                ToolKind::Ball
            };
            let tool = Tool::try_new(kind, 2.0 + 2.0 * rng.uniform(case, 50), 12.0).expect("ok");
            let chain = if case < 6 {
                xyz_chain()
            } else {
                deviated_chain(&rng, case)
            };
            let mut p = [
                10.0 * rng.uniform(case, 1),
                8.0 * rng.uniform(case, 2),
                3.0 + 3.0 * rng.uniform(case, 3),
            ];
            let mut moves = Vec::new();
            for k in 0..8u64 {
                let mut q = [
                    10.0 * rng.uniform(case, 10 + 3 * k),
                    8.0 * rng.uniform(case, 11 + 3 * k),
                    2.0 + 4.0 * rng.uniform(case, 12 + 3 * k),
                ];
                if k % 3 == 0 {
                    q[2] = p[2];
                }
                if k % 4 == 3 {
                    // Continue the previous move's line: joined into one cut by the Z-map.
                    let prev = moves.last().map_or(p, |m: &Move| {
                        [
                            m.start.get(AxisLetter::X),
                            m.start.get(AxisLetter::Y),
                            m.start.get(AxisLetter::Z),
                        ]
                    });
                    q = std::array::from_fn(|i| p[i] + 0.4 * (p[i] - prev[i]));
                }
                moves.push(mv(p, q, 10 + k as usize));
                p = q;
            }
            let mut td = TriDexel::new_box(bx, pitch, 1e9).expect("fits");
            let opts = SweepOptions {
                rotary_step_bound_mm: 1e-4,
            };
            sweep_program(&mut td, &chain, &tool, &moves, &opts, &NoProgress).expect("sweeps");
            let mut zm = ZMap::new_box(bx, pitch, 1e8).expect("fits");
            let r = zm
                .sweep_program(&chain, &tool, &moves, &ZMapOptions::default())
                .expect("3-axis");
            assert!(
                r.cuts < r.moves_in_stock,
                "case {case}: continued moves joined"
            );
            let g = &td.grids()[2];
            assert_eq!(g.dims(), zm.dims());
            let (nx, ny) = zm.dims();
            for iy in 0..ny {
                for ix in 0..nx {
                    let segs = g.ray(ix, iy);
                    let h = zm.height(ix, iy);
                    match segs.last() {
                        Some(s) => {
                            assert_eq!(segs.len(), 1, "a 3-axis cut leaves one segment");
                            assert!(
                                (s.hi.t - h).abs() <= 1e-9,
                                "case {case} ({ix},{iy}): dexel {} vs zmap {h}",
                                s.hi.t
                            );
                        }
                        None => assert_eq!(h, bx.min.z, "case {case} ({ix},{iy}) empty"),
                    }
                    let o = g.ray_origin(ix, iy);
                    let (x, y) = zm.cell_centre(ix, iy);
                    assert!((o.x - x).abs() < 1e-12 && (o.y - y).abs() < 1e-12);
                }
            }
            // Same columns, same heights: the z grid's volume equals the Z-map's.
            let v = zm.volume();
            assert!((g.volume() - v).abs() <= 1e-9 * v, "case {case}");
        }
    }

    fn p1_map(kind: ToolKind, bx: Aabb, pitch: Real) -> (ZMap, Tool) {
        p1_map_with(kind, bx, pitch, &ZMapOptions::default())
    }

    fn p1_map_with(kind: ToolKind, bx: Aabb, pitch: Real, opts: &ZMapOptions) -> (ZMap, Tool) {
        let tool = Tool::try_new(kind, p1::TOOL_DIAMETER, 30.0).expect("valid");
        let mut zm = ZMap::new_box(bx, pitch, 1e9).expect("fits");
        let report = zm
            .sweep_program(&xyz_chain(), &tool, &p1::moves(), opts)
            .expect("3-axis");
        assert_eq!(report.moves, 3321);
        (zm, tool)
    }

    /// Distance from (x, y) to the segment a–b.
    fn dist_to_run(x: Real, y: Real, a: (Real, Real), b: (Real, Real)) -> Real {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let s = (((x - a.0) * dx + (y - a.1) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
        (x - a.0 - s * dx).hypot(y - a.1 - s * dy)
    }

    #[test]
    fn p1_flat_removed_volume() {
        let pitch = 0.05;
        let (zm, _) = p1_map(ToolKind::Flat, p1::stock_box(), pitch);
        let depth = p1::stock_box().max.z - p1::Z_CUT;
        // (1) Analytic: depth × area of the 3 mm offset of the path (README: 11,075.63 mm³).
        let exact = depth * p1::offset_area(p1::TOOL_DIAMETER / 2.0);
        assert!((exact - 11_075.63).abs() < 0.005);
        let removed = zm.removed_volume();
        // A cell-centre height field measures depth × (cells whose centre is within R of the
        // path) × cell area. The straight parts of the region's edge (x, y = 7 and 93) lie on
        // cell edges, so only the curved parts (4 quarter circles and 80 arcs of the bites,
        // ≈ 100 mm long) misclassify cells, with alternating sign; the expected error is of
        // order sqrt(100 mm / h) · h² · depth ≈ 0.2 mm³, the worst case 100 mm · h · depth =
        // 7.5 mm³ (0.07 %). 0.01 % = 1.1 mm³.
        let rel = (removed - exact) / exact;
        assert!(rel.abs() < 1e-4, "removed {removed} vs {exact}: {rel:e}");
        // (2) The same count done here cell by cell: the Z-map is exact at its cell centres.
        let runs = p1::runs();
        let r = p1::TOOL_DIAMETER / 2.0;
        let (nx, ny) = zm.dims();
        let mut inside = 0usize;
        for iy in 0..ny {
            for ix in 0..nx {
                let (x, y) = zm.cell_centre(ix, iy);
                if runs.iter().any(|&(a, b)| dist_to_run(x, y, a, b) <= r) {
                    inside += 1;
                    assert_eq!(zm.height(ix, iy), p1::Z_CUT);
                } else {
                    assert_eq!(zm.height(ix, iy), p1::stock_box().max.z);
                }
            }
        }
        let counted = depth * inside as Real * pitch * pitch;
        assert!((removed - counted).abs() < 1e-9 * counted);
    }

    /// P1-ball: the surface is min over the runs of z_tip + R − sqrt(R² − d²), capped by the
    /// stock top.
    fn p1_ball_oracle(x: Real, y: Real, runs: &[p1::Run]) -> Real {
        let r = p1::TOOL_DIAMETER / 2.0;
        let d = runs
            .iter()
            .map(|&(a, b)| dist_to_run(x, y, a, b))
            .fold(Real::INFINITY, Real::min);
        if d > r {
            return p1::stock_box().max.z;
        }
        (p1::Z_CUT + r - (r * r - d * d).sqrt()).min(p1::stock_box().max.z)
    }

    #[test]
    fn p1_ball_surface_and_scallop() {
        let runs = p1::runs();
        let r = p1::TOOL_DIAMETER / 2.0;
        let (zm, _) = p1_map(ToolKind::Ball, p1::stock_box(), 0.05);
        let (nx, ny) = zm.dims();
        let (mut sum2, mut worst) = (0.0, 0.0 as Real);
        for iy in 0..ny {
            for ix in 0..nx {
                let (x, y) = zm.cell_centre(ix, iy);
                let e = zm.height(ix, iy) - p1_ball_oracle(x, y, &runs);
                sum2 += e * e;
                worst = worst.max(e.abs());
            }
        }
        let rms = (sum2 / (nx * ny) as Real).sqrt();
        assert!(rms <= 1e-3 && worst <= 1e-3, "rms {rms} mm, max {worst} mm");
        // Scallop: cell centres on the crest lines y = 11, 13, … need a grid whose centres
        // are at multiples of 0.05: box [−0.025, 100.025]².
        let mut bx = p1::stock_box();
        bx.min.x -= 0.025;
        bx.min.y -= 0.025;
        bx.max.x += 0.025;
        bx.max.y += 0.025;
        let (zm, _) = p1_map(ToolKind::Ball, bx, 0.05);
        let expect = r - (r * r - 1.0).sqrt();
        let (nx, ny) = zm.dims();
        let mut crest: Real = 0.0;
        for iy in 0..ny {
            for ix in 0..nx {
                let (x, y) = zm.cell_centre(ix, iy);
                // Between rows, away from the step-overs.
                if (20.0..=80.0).contains(&x) && (11.0..=89.0).contains(&y) {
                    crest = crest.max(zm.height(ix, iy) - p1::Z_CUT);
                }
            }
        }
        assert!(
            (crest - expect).abs() <= 1e-3,
            "scallop {crest} vs {expect}"
        );
    }

    #[test]
    fn joining_collinear_moves_changes_no_height() {
        let joined = ZMapOptions {
            merge_collinear: true,
            ..ZMapOptions::default()
        };
        let apart = ZMapOptions {
            merge_collinear: false,
            ..ZMapOptions::default()
        };
        for kind in [ToolKind::Flat, ToolKind::Ball] {
            let (a, _) = p1_map_with(kind, p1::stock_box(), 0.1, &joined);
            let (b, _) = p1_map_with(kind, p1::stock_box(), 0.1, &apart);
            let worst = a
                .heights()
                .iter()
                .zip(b.heights())
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, Real::max);
            // Rounding of the two parametrisations only.
            assert!(worst <= 1e-12, "{kind:?}: {worst}");
        }
        // P1's 3,321 moves are 81 straight runs plus the plunge.
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 30.0).expect("valid");
        let mut z = ZMap::new_box(p1::stock_box(), 0.5, 1e8).expect("fits");
        let r = z
            .sweep_program(&xyz_chain(), &tool, &p1::moves(), &joined)
            .expect("3-axis");
        assert_eq!((r.moves, r.cuts), (3321, 82));
    }

    #[test]
    fn p1_gcode_parses_to_the_same_moves() {
        let prog = crate::nc::parse_program(
            &p1::gcode(),
            std::path::Path::new("p1.ngc"),
            p1::start_position(),
        )
        .expect("valid G-code");
        assert_eq!(prog.moves, p1::moves());
        assert_eq!(prog.moves.len(), 3321);
    }

    #[test]
    fn result_is_bit_identical_for_one_and_two_threads() {
        let run = |threads| {
            crate::math::in_pool(threads, || p1_map(ToolKind::Ball, p1::stock_box(), 0.1).0)
        };
        let (a, b) = (run(1), run(2));
        assert!(
            a.heights()
                .iter()
                .zip(b.heights())
                .all(|(x, y)| x.to_bits() == y.to_bits())
        );
    }

    #[test]
    fn refuses_what_a_height_field_cannot_do() {
        let tool = Tool::try_new(ToolKind::Flat, 4.0, 10.0).expect("valid");
        let mut zm = ZMap::new_box(small_box(), 0.5, 1e8).expect("fits");
        let o = ZMapOptions::default();
        // A tilted spindle (alpha_ZS) is not parallel to Z.
        let mut c = xyz_chain();
        c.set_deviation(c.deviation_id("alpha_ZS").expect("known"), 1e-5);
        let err = zm
            .sweep_program(&c, &tool, &[mv([1.0, 1.0, 4.0], [5.0, 1.0, 4.0], 7)], &o)
            .expect_err("tilted");
        assert!(
            matches!(err, ZMapError::TiltedAxis { line: 7, .. }),
            "{err}"
        );
        // A machine with an A axis turning.
        let ax = |letter, kind, d: Vector3| Axis {
            letter,
            kind,
            direction: UnitVector3::new_normalize(d),
            origin: Point3::origin(),
        };
        let c4 = Chain::new(
            vec![
                ax(AxisLetter::A, AxisKind::Rotary, Vector3::x()),
                ax(AxisLetter::Y, AxisKind::Linear, Vector3::y()),
                ax(AxisLetter::X, AxisKind::Linear, Vector3::x()),
                ax(AxisLetter::Z, AxisKind::Linear, Vector3::z()),
            ],
            "S",
        )
        .expect("chain");
        let mut turn = mv([1.0, 1.0, 4.0], [5.0, 1.0, 4.0], 8);
        turn.end.set(AxisLetter::A, 10.0);
        let err = zm
            .sweep_program(&c4, &tool, &[turn], &o)
            .expect_err("rotary");
        assert!(matches!(
            err,
            ZMapError::RotaryMotion { line: 8, axis: 'A' }
        ));
        // A at a fixed 0° is fine on the same machine.
        zm.sweep_program(&c4, &tool, &[mv([1.0, 1.0, 4.0], [5.0, 1.0, 4.0], 9)], &o)
            .expect("3-axis at A = 0");
        // An axis the machine lacks.
        let err = zm
            .sweep_program(&xyz_chain(), &tool, &[turn], &o)
            .expect_err("no A");
        assert!(matches!(err, ZMapError::MissingAxis { line: 8, axis: 'A' }));
        // The tool top (tip 1 mm + 3.5 mm) below the stock top (5 mm).
        let short = Tool::try_new(ToolKind::Flat, 4.0, 3.5).expect("valid");
        let before = zm.clone();
        let err = zm
            .sweep_program(
                &xyz_chain(),
                &short,
                &[
                    mv([1.0, 1.0, 4.0], [5.0, 1.0, 4.0], 10),
                    mv([5.0, 1.0, 4.0], [5.0, 1.0, 1.0], 11),
                ],
                &o,
            )
            .expect_err("buried");
        assert!(matches!(err, ZMapError::ToolTooShort { line: 11, .. }));
        assert_eq!(zm, before, "nothing cut when a move is refused");
        // Non-finite positions.
        let err = zm
            .sweep_program(
                &xyz_chain(),
                &tool,
                &[mv([1.0, 1.0, 4.0], [Real::NAN, 1.0, 4.0], 12)],
                &o,
            )
            .expect_err("nan");
        assert_eq!(err.line(), Some(12));
        assert!(ZMap::new_box(small_box(), 0.0, 1e8).is_err());
        assert!(ZMap::new_box(small_box(), 1e-4, 1e6).is_err());
    }

    #[test]
    fn full_circle_arc_cuts_an_annulus() {
        // G2 full circle of radius 10 about (0, 0) with a Ø6 flat tool, tip at z = -1 under a
        // top at z = 0: cells whose centre lies within R of the circle (less the chord
        // sagitta) are at z = -1; cells farther than R (plus the sagitta) are untouched.
        let text = "G21 G90 G17\nG0 X10 Y0 Z5\nG1 Z-1 F100\nG2 X10 Y0 I-10 J0\nG0 Z5\nM2\n";
        let program = crate::nc::parse_program(
            text,
            std::path::Path::new("ring.ngc"),
            AxisValues::default(),
        )
        .expect("valid program");
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("valid");
        let bx = Aabb {
            min: Point3::new(-15.0, -15.0, -5.0),
            max: Point3::new(15.0, 15.0, 0.0),
        };
        let mut zm = ZMap::new_box(bx, 0.1, 1e8).expect("fits");
        let opts = ZMapOptions {
            arc_sagitta_mm: 1e-3,
            ..ZMapOptions::default()
        };
        zm.sweep_program(&xyz_chain(), &tool, &program.moves, &opts)
            .expect("3-axis");
        let (nx, ny) = zm.dims();
        let (mut inside, mut outside) = (0, 0);
        for iy in 0..ny {
            for ix in 0..nx {
                let (x, y) = zm.cell_centre(ix, iy);
                let d = (x.hypot(y) - 10.0).abs();
                let h = zm.height(ix, iy);
                if d < 3.0 - 2e-3 {
                    inside += 1;
                    assert_eq!(h, -1.0, "cell ({x}, {y}) at {d} mm from the circle");
                } else if d > 3.0 + 2e-3 && x.hypot(y) > 0.0 {
                    outside += 1;
                    assert_eq!(h, 0.0, "cell ({x}, {y}) at {d} mm from the circle");
                }
            }
        }
        assert!(inside > 10_000 && outside > 10_000, "{inside} {outside}");
    }
}
