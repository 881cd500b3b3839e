//! Test-cut design: given the deviations a user wants, propose cuts that make them
//! observable with the best conditioning, as an NC program.
//!
//! **Family of cuts.** The part is a square bar along the rotary axis (the workpiece sits on
//! a rotary axis about W x, indexed in 90° steps, so the bar's cross-section looks the same
//! at every index). At an index the tool works on the bar's top side:
//!
//! - an *X-shoulder* on one long edge (base `−y` or `+y`): a straight cut along X, `width`
//!   into the side and `depth` down, leaving a flank (a wall along X) and a floor (measured
//!   only when the wall, seen at 45°, leaves enough of it in view);
//! - a *Y-shoulder* across the `+x` end: a cut along Y leaving a wall facing `+x` and a floor.
//!
//! Depths come from [`DesignOptions::depths_mm`], limited to the tool's cutting length less a
//! margin. Two cuts are combined only if the parts of the cross-section they remove (in W,
//! grown by the face margin) do not meet, so no face is touched by another cut; X-shoulders
//! stop short of the end shoulders.
//!
//! **Choice.** A candidate set is evaluated on the model chain: synthetic plane features with
//! the uncertainties the scanner would give (points on the face from its area and the scan
//! pitch, range noise σ), the identifiability analysis of [`crate::calibration::calibrate`] with the
//! registration estimated. Ranking: fewest undetermined directions, then fewest parameters
//! not identified alone, then the largest information (sum of the logs of the capped
//! singular values). A beam search keeps the best few sets each round and extends each by
//! every compatible cut; it stops when a round adds no determined direction and does not
//! double the information along any direction. (A greedy search of width one settled on two
//! end shoulders of one depth, which leaves `beta_XZ − beta_ZS` exactly unseen.)
//!
//! **The tip-height lever.** To first order, a deviation turn ω at a joint moves the tool by
//! ω × (p − c), c the joint's origin. The Z-to-X squareness `beta_XZ` turns about the X
//! carriage's origin `(x, y, 0)`, the spindle tilt `beta_ZS` about the programmed tip
//! `(x, y, z)`; the two give the tool the same tilt, and `beta_XZ = −beta_ZS = b` moves the
//! whole tool by `b·e_y × (0, 0, z) = b·z·e_x`: a slide along X by the *programmed tip height*
//! z times the angle, whatever the index, the position and the direction of the cut.
//! Likewise `alpha_YX = −alpha_ZS = b` (about `(0, y, 0)` and the tip) slides the tool by
//! `b·e_x × (x, 0, z) = −b·z·e_y`, exactly what `dy_AY = −b·z` does. So on every face
//!
//! ```text
//! ∂f/∂beta_XZ − ∂f/∂beta_ZS = z·∂f/∂dx_AY      ∂f/∂alpha_YX − ∂f/∂alpha_ZS = −z·∂f/∂dy_AY
//! ```
//!
//! (checked on the model's own Jacobian at random poses in the tests). A slide along X is
//! what the registration absorbs (X is the rotary axis: the same slide at every index), so
//! `beta_XZ − beta_ZS` is seen only through *differences* of z between faces across X (the
//! Y-shoulder walls), and `alpha_YX − alpha_ZS` only through differences of z between faces
//! across Y at one index (separating it from `dy_AY`). With all cuts at one tip height both
//! are exactly unseen. In this chain the tool frame is the tip and the axis values are tip
//! positions, so a longer tool at the same tip height is the same lever; only the spread of
//! tip heights counts. On the standard bar with a Ø6 × 25 mm tool the tips reach 17 … −3 mm
//! (Y-shoulder pairs at 0° and 180° must leave a margin of the section between them); with an
//! EinScan-class scanner (σ 0.025 mm, 0.185 mm pitch) the end walls measure
//! `(beta_XZ − beta_ZS)/√2` to about 12 % of 5e-4 rad — just short of the tenth that counts
//! as determined; a scanner of σ 0.01 mm at 0.3 mm pitch determines all nine. [`Design::notes`]
//! states the spread and the expected uncertainty for the pairs asked for.
//!
//! **Invariant:** plans and writes text; runs no sweep or scan and touches no files.

use crate::calibration::calibrate::{
    ANGLE_MAGNITUDE_RAD, CalibrateError, Feature, Identifiability, IsoTerm, Model, PlaneFeature,
    Registration, identifiability, synthetic_plane_feature,
};
use crate::calibration::identify::{FaceKind, FaceRegion, FaceSpec};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::chain::{AxisKind, Chain, DeviationId};
use crate::math::{Aabb, Point3, Real, Vector3};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// Errors of test-cut design.
#[derive(Debug, thiserror::Error)]
pub enum DesignError {
    /// The machine is not of the supported layout.
    #[error("test-cut design needs {0}")]
    Machine(String),
    /// The tool cannot cut the family.
    #[error("test-cut design needs a flat end mill (floors are measured)")]
    Tool,
    /// The identifiability analysis failed.
    #[error("{0}")]
    Calibrate(#[from] CalibrateError),
}

/// Design settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DesignOptions {
    /// Half the bar's square cross-section (mm): the bar is `2·half × 2·half`.
    pub half_section_mm: Real,
    /// Bar length along the rotary axis (mm).
    pub length_mm: Real,
    /// Shoulder width into the side (mm); must exceed twice the face margin. The tool
    /// overshoots the bar's edge by its diameter less this width, at least [`CLEARANCE_MM`]:
    /// a wider shoulder is narrowed to that.
    pub width_mm: Real,
    /// The shoulder depths the design chooses from (mm). A depth is used only where the
    /// tool's cutting length reaches it with a margin to spare and it leaves a margin of
    /// the bar's section; cuts whose removed cross-sections would meet are not combined.
    pub depths_mm: [Real; 5],
    /// Scanner range noise σ (mm), for the expected face uncertainties.
    pub noise_sigma_mm: Real,
    /// Scanner point pitch (mm).
    pub pitch_mm: Real,
    /// Margin kept from face edges (mm).
    pub margin_mm: Real,
    /// Height of the rapid plane above the rotary axis (mm).
    pub safe_z_mm: Real,
}

impl DesignOptions {
    /// The bar and scanner used by `twinmill design` by default: 40 × 40 × 80 mm bar,
    /// 5 mm shoulders (cut by the Ø6 tool 1 mm beyond the bar's edge) 3, 8, 13, 18 or 23 mm
    /// deep (tip heights 17 … −3 mm above the rotary axis: the lever that separates the
    /// spindle's tilt from the squareness of Z), EinScan-class noise 0.025 mm at 0.185 mm
    /// pitch.
    pub fn standard() -> Self {
        DesignOptions {
            half_section_mm: 20.0,
            length_mm: 80.0,
            width_mm: 5.0,
            depths_mm: [3.0, 8.0, 13.0, 18.0, 23.0],
            noise_sigma_mm: 0.025,
            pitch_mm: 0.185,
            margin_mm: 1.0,
            safe_z_mm: 40.0,
        }
    }

    /// The block of [`Family::Block`] (workpiece frame): a cube of the bar's section,
    /// `2·half` on each side, standing on the W xy plane and centred on W z.
    pub fn block(&self) -> Aabb {
        let h = self.half_section_mm;
        Aabb {
            min: Point3::new(-h, -h, 0.0),
            max: Point3::new(h, h, 2.0 * h),
        }
    }

    /// The bar (workpiece frame).
    pub fn stock(&self) -> Aabb {
        let (h, l) = (self.half_section_mm, self.length_mm / 2.0);
        Aabb {
            min: Point3::new(-l, -h, -h),
            max: Point3::new(l, h, h),
        }
    }
}

/// How far the tool reaches beyond the bar's edge at least (mm): twice a realistic offset
/// deviation ([`crate::calibration::calibrate::OFFSET_MAGNITUDE_MM`]). A tool that ends at
/// the edge leaves, on a machine whose axes are offset, a sliver of the edge standing
/// beside the shoulder, which hides most of its wall from the scanner.
pub const CLEARANCE_MM: Real = 2.0 * crate::calibration::calibrate::OFFSET_MAGNITUDE_MM;

/// Narrowest floor strip measured (mm, after the margins).
const MIN_FLOOR_MM: Real = 1.0;

/// One designed cut.
#[derive(Clone, Debug, PartialEq)]
pub struct DesignedCut {
    /// Name stem of its faces (e.g. `a0-ym-d4`).
    pub name: String,
    /// Rotary index (degrees).
    pub index_deg: Real,
    /// The straight cut, in axis values (line filled when the program is written).
    pub cut: Move,
    /// Which faces are measured.
    pub faces: Vec<FaceKind>,
}

/// A design: cuts, their program, and what they determine.
#[derive(Clone, Debug)]
pub struct Design {
    /// The cuts, in program order.
    pub cuts: Vec<DesignedCut>,
    /// The NC program.
    pub program: String,
    /// The faces to measure: name, NC line, kind.
    pub faces: Vec<FaceSpec>,
    /// What the design determines (expected scanner noise, registration estimated).
    pub identifiability: Identifiability,
    /// Expected standard uncertainty per identified parameter, relative to its realistic
    /// magnitude.
    pub relative_sigma: Vec<(String, Real)>,
    /// Candidates evaluated.
    pub evaluated: usize,
    /// Why what is weak is weak: for each requested pair that only the spread of tip
    /// heights separates (`beta_XZ`/`beta_ZS`, `alpha_YX`/`alpha_ZS`), that spread and the
    /// expected standard uncertainty of the difference.
    pub notes: Vec<String>,
    /// The family of test part.
    pub family: Family,
    /// The part (workpiece frame): the bar or the block.
    pub stock: Aabb,
    /// The program's rapid plane (Z, mm).
    pub safe_z_mm: Real,
}

#[expect(
    clippy::large_enum_variant,
    reason = "a few hundred candidates, copied by the search; boxing buys nothing"
)]
#[derive(Clone, Copy, Debug, PartialEq)]
enum Cut {
    /// X-shoulder at `index`, on the base edge `side` (±1), at depth `depth`.
    XShoulder {
        index: Real,
        side: Real,
        depth: Real,
    },
    /// Y-shoulder across the +x end at `index`, depth `depth`.
    YShoulder { index: Real, depth: Real },
    /// A shoulder on an edge of the block (the family for any chain with a rotary axis).
    Block(BlockCut),
}

/// A shoulder on the block at one rotary pose: a straight cut along the linear axis
/// `along` (0 X, 1 Y, perpendicular to the tool there), its flank `width` in from the
/// block's face on the side `side` of the cut and its tip `depth` below the block's top
/// along the tool axis.
#[derive(Clone, Copy, Debug, PartialEq)]
struct BlockCut {
    /// The rotary axes' letters and values (degrees), in chain order.
    pose: [(AxisLetter, Real); 3],
    /// How many entries of `pose` are used.
    rotaries: usize,
    /// The pose's place in the candidate order (program order).
    order: usize,
    /// The linear axis moved: 0 X, 1 Y, 2 Z.
    along: usize,
    /// Which side of the cut the shoulder is on (±1: along ±(cut direction × tool axis)).
    side: Real,
    /// Which way the cut runs along its axis (±1): from the block's low end towards its
    /// high end, or back.
    from: Real,
    /// Depth of the tip below the block's top along the tool axis (mm).
    depth: Real,
    /// The straight cut in axis values.
    mv: Move,
    /// The part of the block the cut removes, as a box in W (for conflicts).
    removed: Aabb,
    /// The face's length along the cut inside the block (mm).
    length: Real,
}

/// The family of test parts a chain is designed with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// The square bar along a rotary axis about W x through the origin, first in the chain.
    Bar,
    /// The block on (or under) any other rotary axes: shoulders cut at several positions of
    /// each rotary axis.
    Block,
}

fn check_machine(chain: &Chain) -> Result<Family, DesignError> {
    let axes = chain.axes();
    for (letter, dir) in [
        (AxisLetter::X, Vector3::x()),
        (AxisLetter::Y, Vector3::y()),
        (AxisLetter::Z, Vector3::z()),
    ] {
        if !axes.iter().any(|a| {
            a.letter == letter
                && a.kind == AxisKind::Linear
                && (a.direction.into_inner() - dir).norm() < 1e-12
        }) {
            return Err(DesignError::Machine(format!(
                "a linear {} axis along {dir:?}",
                letter.as_char()
            )));
        }
    }
    let rotaries = axes.iter().filter(|a| a.kind == AxisKind::Rotary).count();
    if rotaries == 0 || rotaries > 3 {
        return Err(DesignError::Machine(
            "one to three rotary axes (a rotary table or head to index the part or tool)".into(),
        ));
    }
    let first = &axes[0];
    let bar = first.kind == AxisKind::Rotary
        && first.letter == AxisLetter::A
        && rotaries == 1
        && (first.direction.into_inner() - Vector3::x()).norm() <= 1e-12
        && first.origin.y == 0.0
        && first.origin.z == 0.0;
    Ok(if bar { Family::Bar } else { Family::Block })
}

fn axes(a: Real, x: Real, y: Real, z: Real) -> AxisValues {
    AxisValues::default()
        .with(AxisLetter::A, a)
        .with(AxisLetter::X, x)
        .with(AxisLetter::Y, y)
        .with(AxisLetter::Z, z)
}

impl Cut {
    fn name(&self) -> String {
        match *self {
            Cut::XShoulder { index, side, depth } => format!(
                "a{index:.0}-x{}-d{depth:.0}",
                if side < 0.0 { "m" } else { "p" }
            ),
            Cut::YShoulder { index, depth } => format!("a{index:.0}-end-d{depth:.0}"),
            Cut::Block(b) => {
                let pose: String = b.pose[..b.rotaries]
                    .iter()
                    .map(|(l, v)| format!("{}{v:.0}", l.as_char().to_ascii_lowercase()))
                    .collect();
                format!(
                    "{pose}-{}{}{}-d{:.0}",
                    ["x", "y", "z"][b.along],
                    if b.side < 0.0 { "m" } else { "p" },
                    if b.from < 0.0 { "r" } else { "" },
                    b.depth
                )
            }
        }
    }

    fn index(&self) -> Real {
        match *self {
            Cut::XShoulder { index, .. } | Cut::YShoulder { index, .. } => index,
            // The first rotary value that is not zero (the axis this pose turns).
            Cut::Block(b) => b.pose[..b.rotaries]
                .iter()
                .map(|p| p.1)
                .find(|v| *v != 0.0)
                .unwrap_or(0.0),
        }
    }

    /// Program order: the bar's by index, the block's by pose.
    fn order(&self) -> Real {
        match self {
            Cut::Block(b) => b.order as Real,
            _ => self.index(),
        }
    }

    /// The part of the bar's cross-section (W y, z: min and max corners) the cut removes.
    fn section(&self, o: &DesignOptions) -> ([Real; 2], [Real; 2]) {
        let h = o.half_section_mm;
        let (ys, index, depth) = match *self {
            Cut::XShoulder { index, side, depth } => {
                ([side * (h - o.width_mm), side * h], index, depth)
            }
            Cut::YShoulder { index, depth } => ([-h, h], index, depth),
            Cut::Block(b) => {
                return (
                    [b.removed.min.y, b.removed.min.z],
                    [b.removed.max.y, b.removed.max.z],
                );
            }
        };
        let (s, c) = index.to_radians().sin_cos();
        let mut lo = [Real::INFINITY; 2];
        let mut hi = [Real::NEG_INFINITY; 2];
        for y in ys {
            for z in [h - depth, h] {
                let w = [y * c - z * s, y * s + z * c];
                for k in 0..2 {
                    lo[k] = lo[k].min(w[k]);
                    hi[k] = hi[k].max(w[k]);
                }
            }
        }
        (lo, hi)
    }

    /// The straight cut in axis values (base frame = axis values at this index).
    fn motion(&self, o: &DesignOptions, r: Real) -> Move {
        let (h, l) = (o.half_section_mm, o.length_mm / 2.0);
        let (start, end) = match *self {
            Cut::Block(b) => return b.mv,
            Cut::XShoulder { index, side, depth } => {
                let y = side * (h - o.width_mm + r);
                let z = h - depth;
                // From outside the −x end to short of the end shoulder's wall.
                let x1 = l - o.width_mm - r - 1.0;
                (axes(index, -l - r - 1.0, y, z), axes(index, x1, y, z))
            }
            Cut::YShoulder { index, depth } => {
                let x = l - o.width_mm + r;
                let z = h - depth;
                (
                    axes(index, x, -h - r - 1.0, z),
                    axes(index, x, h + r + 1.0, z),
                )
            }
        };
        Move {
            kind: MoveKind::Linear,
            start,
            end,
            feed_mm_per_min: Some(FEED_MM_PER_MIN),
            line: 0,
        }
    }

    /// The faces a scanner can measure: the flank always; the floor when its strip, the
    /// shoulder's width less two margins, is at least [`MIN_FLOOR_MM`] wide (the shoulder
    /// opens towards the bar's corner, and the views at the corners see into it).
    fn faces(&self, o: &DesignOptions) -> Vec<FaceKind> {
        if o.width_mm - 2.0 * o.margin_mm >= MIN_FLOOR_MM {
            vec![FaceKind::Flank, FaceKind::Floor]
        } else {
            vec![FaceKind::Flank]
        }
    }

    /// Expected face sizes (along the cut, across it) in mm, after margins.
    fn face_sizes(&self, o: &DesignOptions, kind: FaceKind) -> (Real, Real) {
        let (h, l) = (o.half_section_mm, o.length_mm);
        let m = 2.0 * o.margin_mm;
        let (along, depth) = match *self {
            Cut::XShoulder { depth, .. } => (l - o.width_mm - 2.0, depth),
            Cut::YShoulder { depth, .. } => (2.0 * h, depth),
            Cut::Block(b) => (b.length, b.depth),
        };
        match kind {
            FaceKind::Flank => ((along - m).max(0.0), (depth - m).max(0.0)),
            FaceKind::Floor => ((along - m).max(0.0), (o.width_mm - m).max(0.0)),
        }
    }
}

/// Ranking of a candidate: undetermined directions, parameters not identified alone,
/// information score (higher is better).
pub type Key = (usize, usize, Real);

/// A candidate design's ranking, identifiability and relative uncertainties.
type Evaluated = (Key, Identifiability, Vec<(String, Real)>);

/// Feed of the designed cuts (mm/min).
const FEED_MM_PER_MIN: Real = 600.0;

/// Points per mm² of a face seen at 45° by a scanner of pitch p: cos 45° / p².
fn expected_points(area: Real, pitch: Real) -> Real {
    area * std::f64::consts::FRAC_1_SQRT_2 / (pitch * pitch)
}

/// The candidate cuts: X-shoulders on both edges and Y-shoulders across the +x end at the
/// four indices, at every depth the tool reaches (its cutting length less a margin) that
/// leaves a margin of the section.
fn candidates(o: &DesignOptions, tool: &Tool) -> Vec<Cut> {
    let reach = tool.length() - o.margin_mm;
    let depths: Vec<Real> = o
        .depths_mm
        .iter()
        .copied()
        .filter(|d| *d > 0.0 && *d <= reach && *d < 2.0 * o.half_section_mm - o.margin_mm)
        .collect();
    let mut out = Vec::new();
    for index in INDICES_DEG {
        for side in [-1.0, 1.0] {
            for &depth in &depths {
                out.push(Cut::XShoulder { index, side, depth });
            }
        }
    }
    for index in INDICES_DEG {
        for &depth in &depths {
            out.push(Cut::YShoulder { index, depth });
        }
    }
    out
}

/// The rotary positions of the block family: per rotary axis, its values with the other
/// rotary axes at zero — the four quarter turns for an axis parallel to the tool at the
/// zero pose (a C table under a vertical spindle), −90°, 0 and 90° for one across it (a
/// trunnion's A, a head's B): every pose keeps the block's faces square to the tool, so
/// each shoulder's flank and floor are faces of the block.
fn block_poses(model: &Chain) -> Vec<[(AxisLetter, Real); 3]> {
    let rot: Vec<_> = model
        .axes()
        .iter()
        .filter(|a| a.kind == AxisKind::Rotary)
        .collect();
    let tool_axis = model.w_from_t(&AxisValues::default()).rotation * Vector3::z();
    let mut zero = [(AxisLetter::X, 0.0); 3];
    for (k, a) in rot.iter().enumerate() {
        zero[k] = (a.letter, 0.0);
    }
    let mut out = vec![zero];
    for (k, a) in rot.iter().enumerate() {
        let parallel = a.direction.dot(&tool_axis).abs() > 0.99;
        let values: &[Real] = if parallel {
            &[90.0, 180.0, 270.0]
        } else {
            &[-90.0, 90.0]
        };
        for &v in values {
            let mut p = zero;
            p[k].1 = v;
            out.push(p);
        }
    }
    out
}

/// The block family's candidate cuts: at every pose of [`block_poses`], shoulders along X
/// and along Y (where the cut is across the tool) on both sides, at every depth the tool
/// reaches that leaves a margin of the block, whose flank and floor face sideways or up in
/// W (the scanner looks from around and above). Each cut enters from outside one end of an
/// edge and stops short of the edge's middle: the shoulders compete for the block's few
/// edges, and half-edge cuts leave room for the positions of every axis.
fn block_candidates(
    model: &Chain,
    tool: &Tool,
    o: &DesignOptions,
) -> Result<Vec<Cut>, DesignError> {
    let stock = o.block();
    let r = tool.radius();
    let reach = tool.length() - o.margin_mm;
    let rotaries = model
        .axes()
        .iter()
        .filter(|a| a.kind == AxisKind::Rotary)
        .count();
    let corners: Vec<Point3> = (0..8)
        .map(|i| {
            Point3::new(
                if i & 1 == 0 { stock.min.x } else { stock.max.x },
                if i & 2 == 0 { stock.min.y } else { stock.max.y },
                if i & 4 == 0 { stock.min.z } else { stock.max.z },
            )
        })
        .collect();
    let range = |w: &Vector3| {
        corners
            .iter()
            .fold((Real::INFINITY, Real::NEG_INFINITY), |(lo, hi), c| {
                let x = w.dot(&c.coords);
                (lo.min(x), hi.max(x))
            })
    };
    let letters = [AxisLetter::X, AxisLetter::Y, AxisLetter::Z];
    let mut out = Vec::new();
    for (order, pose) in block_poses(model).into_iter().enumerate() {
        let mut q = AxisValues::default();
        for (l, v) in &pose[..rotaries] {
            q = q.with(*l, *v);
        }
        // The tip is affine in the linear axes at a fixed pose.
        let tip = |p: &[Real; 3]| {
            let mut a = q;
            for k in 0..3 {
                a = a.with(letters[k], p[k]);
            }
            model.w_from_t(&a) * Point3::origin()
        };
        let p0 = tip(&[0.0; 3]);
        let cols: Vec<Vector3> = (0..3)
            .map(|k| {
                let mut e = [0.0; 3];
                e[k] = 1.0;
                tip(&e) - p0
            })
            .collect();
        let m = crate::math::Matrix3::from_columns(&cols);
        let Some(inv) = m.try_inverse() else {
            continue;
        };
        let t = model.w_from_t(&q).rotation * Vector3::z();
        if t.z < -0.05 {
            continue;
        }
        for (along, col) in cols.iter().enumerate() {
            let d = col.normalize();
            if d.dot(&t).abs() > 1e-6 {
                continue;
            }
            for side in [-1.0, 1.0] {
                let n = (d.cross(&t) * side).normalize();
                // The flank faces +n (from the material towards the tool), the floor +t.
                if n.z < -0.05 {
                    continue;
                }
                let (s_lo, s_hi) = range(&n);
                let (h_lo, h_hi) = range(&t);
                let (d_lo, d_hi) = range(&d);
                // Half an edge: from outside one end to a face margin short of the edge's
                // middle, so the two halves of an edge are two cuts (the conflict test
                // grows the removed boxes by the margin).
                let mid = 0.5 * (d_lo + d_hi);
                for from in [1.0, -1.0] {
                    let (a0, a1) = if from > 0.0 {
                        (d_lo - r - 1.0, mid - r - o.margin_mm)
                    } else {
                        (d_hi + r + 1.0, mid + r + o.margin_mm)
                    };
                    let b = s_hi - o.width_mm + r;
                    for &depth in &o.depths_mm {
                        if depth <= 0.0
                            || depth > reach
                            || depth > (h_hi - h_lo) / 3.0
                            || depth >= (h_hi - h_lo) - o.margin_mm
                            || o.width_mm >= (s_hi - s_lo) - o.margin_mm
                        {
                            continue;
                        }
                        let c = h_hi - depth;
                        let axes_at = |a: Real| {
                            let p = d * a + n * b + t * c;
                            let v = inv * (p - p0.coords);
                            let mut out = q;
                            for k in 0..3 {
                                out = out.with(letters[k], v[k]);
                            }
                            out
                        };
                        let mut lo = Point3::new(Real::INFINITY, Real::INFINITY, Real::INFINITY);
                        let mut hi = -lo;
                        for a in [a0.min(a1) - r, a0.max(a1) + r] {
                            for bb in [s_hi - o.width_mm, s_hi] {
                                for cc in [c, h_hi] {
                                    let p = d * a + n * bb + t * cc;
                                    for k in 0..3 {
                                        lo[k] = lo[k].min(p[k]).max(stock.min[k]);
                                        hi[k] = hi[k].max(p[k]).min(stock.max[k]);
                                    }
                                }
                            }
                        }
                        // A cut along Z starts above its end: the rapid down to its start
                        // runs outside the block only then.
                        if along == 2
                            && axes_at(a0).get(AxisLetter::Z) < axes_at(a1).get(AxisLetter::Z)
                        {
                            continue;
                        }
                        out.push(Cut::Block(BlockCut {
                            pose,
                            rotaries,
                            order,
                            along,
                            side,
                            from,
                            depth,
                            mv: Move {
                                kind: MoveKind::Linear,
                                start: axes_at(a0),
                                end: axes_at(a1),
                                feed_mm_per_min: Some(FEED_MM_PER_MIN),
                                line: 0,
                            },
                            removed: Aabb { min: lo, max: hi },
                            length: if from > 0.0 { a1 - d_lo } else { d_hi - a1 },
                        }));
                    }
                }
            }
        }
    }
    if out.is_empty() {
        return Err(DesignError::Machine(
            "a pose at which the tool reaches the block's edges".into(),
        ));
    }
    Ok(out)
}

/// The rotary indices the bar is cut at (degrees).
const INDICES_DEG: [Real; 4] = [0.0, 90.0, 180.0, 270.0];

/// Faces measured on a simulated scan of an earlier design, by face name: the search uses
/// them instead of its expectation for the same faces.
pub type MeasuredFaces = BTreeMap<String, PlaneFeature>;

fn features_of(
    cuts: &[Cut],
    o: &DesignOptions,
    stock: Aabb,
    model: &Chain,
    tool: &Tool,
    measured: &MeasuredFaces,
) -> Option<Vec<Feature>> {
    let r = tool.radius();
    let mut out = Vec::new();
    for c in cuts {
        let mv = c.motion(o, r);
        for kind in c.faces(o) {
            if let Some(f) = measured.get(&format!("{}-{}", c.name(), kind_name(kind))) {
                out.push(Feature::Plane(f.clone()));
                continue;
            }
            let (a, b) = c.face_sizes(o, kind);
            let n = expected_points(a * b, o.pitch_mm).max(3.0);
            let s = o.noise_sigma_mm;
            let spec = FaceSpec {
                name: format!("{}-{}", c.name(), kind_name(kind)),
                line: 0,
                region: FaceRegion::Auto,
                kind,
            };
            // Floors: the part of the track inside the stock, across the feed.
            let half = (o.width_mm.min(2.0 * r) / 2.0 - o.margin_mm).max(0.0);
            let cross = (-half, half);
            let f = synthetic_plane_feature(
                &spec,
                &mv,
                model,
                model,
                tool,
                &stock,
                s / n.sqrt(),
                [s / (n * a * a / 12.0).sqrt(), s / (n * b * b / 12.0).sqrt()],
                cross,
            )?;
            out.push(Feature::Plane(f));
        }
    }
    Some(out)
}

/// "flank" or "floor".
pub fn kind_name(kind: FaceKind) -> &'static str {
    match kind {
        FaceKind::Flank => "flank",
        FaceKind::Floor => "floor",
    }
}

fn evaluate(
    cuts: &[Cut],
    (o, stock): (&DesignOptions, Aabb),
    model: &Chain,
    tool: &Tool,
    (ids, iso): (&[DeviationId], &[IsoTerm]),
    measured: &MeasuredFaces,
) -> Option<(Identifiability, Vec<(String, Real)>)> {
    let feats = features_of(cuts, o, stock, model, tool, measured)?;
    let m = Model {
        chain: model,
        ids,
        iso_terms: iso,
        tool,
        features: &feats,
        registration: Registration::Estimate,
    };
    let x = m.start();
    let ident = identifiability(&m, &x).ok()?;
    // Relative uncertainty of each parameter from the scaled information in the
    // determined subspace.
    let j = m.jacobian(&x)?;
    let np = m.params();
    let mut js = j.clone();
    for (k, scale) in m.param_scales().into_iter().enumerate() {
        js.column_mut(k).scale_mut(scale);
    }
    // (JᵀJ)⁺ = J⁺·J⁺ᵀ, the rank from J's own singular values (a whitened direction below
    // 1e-6 is not seen: the 1e-12 of JᵀJ's eigenvalues it stands for).
    let pinv = js.pseudo_inverse(1e-6).ok()?;
    let cov = &pinv * pinv.transpose();
    let rel = (0..np)
        .filter(|&k| ident.identified.contains(&ident.parameters[k]))
        .map(|k| (ident.parameters[k].clone(), cov[(k, k)].max(0.0).sqrt()))
        .collect();
    Some((ident, rel))
}

/// Designs test cuts that make `params` observable on `model` (see the module docs), from
/// the faces' expected uncertainties.
pub fn design(
    model: &Chain,
    tool: &Tool,
    params: &[DeviationId],
    o: &DesignOptions,
) -> Result<Design, DesignError> {
    design_with(model, tool, params, &[], o, &MeasuredFaces::new())
}

/// [`design`] for the joint deviations `params` and the ISO location and squareness terms
/// `iso` (each one parameter), with the faces already measured on simulated scans of
/// earlier designs used instead of their expected uncertainties.
pub fn design_with(
    model: &Chain,
    tool: &Tool,
    params: &[DeviationId],
    iso: &[IsoTerm],
    o: &DesignOptions,
    measured: &MeasuredFaces,
) -> Result<Design, DesignError> {
    let family = check_machine(model)?;
    if tool.kind() != ToolKind::Flat {
        return Err(DesignError::Tool);
    }
    // The tool reaches CLEARANCE_MM beyond the bar's edge: the shoulder is its diameter
    // less that wide at most.
    let o = &DesignOptions {
        width_mm: o.width_mm.min(2.0 * tool.radius() - CLEARANCE_MM),
        ..*o
    };
    if o.width_mm <= 2.0 * o.margin_mm {
        return Err(DesignError::Machine(format!(
            "a tool of more than {} mm diameter (a shoulder wider than two face margins, cut \
             {CLEARANCE_MM} mm beyond the bar's edge)",
            2.0 * o.margin_mm + CLEARANCE_MM
        )));
    }
    if params.is_empty() && iso.is_empty() {
        return Err(DesignError::Calibrate(CalibrateError::NoParameters));
    }
    let (pool, stock) = match family {
        Family::Bar => (candidates(o, tool), o.stock()),
        Family::Block => (block_candidates(model, tool, o)?, o.block()),
    };
    // Beam search over sets of compatible cuts (indices into the pool, kept sorted): each
    // round extends every design in the beam by every compatible cut, keeps the BEAM_WIDTH
    // best distinct designs, and stops when the best no longer improves. A greedy search
    // (width 1) can settle on cuts that leave a direction exactly unseen (two end shoulders
    // at one depth); the beam keeps the alternatives that a later cut completes.
    let mut beam: Vec<(Vec<usize>, Evaluated)> = Vec::new();
    let mut best: Option<(Vec<usize>, Evaluated)> = None;
    let mut evaluated = 0;
    let mut seen = std::collections::BTreeSet::new();
    loop {
        let parents: Vec<Vec<usize>> = if beam.is_empty() && best.is_none() {
            vec![Vec::new()]
        } else {
            beam.iter().map(|(c, _)| c.clone()).collect()
        };
        let mut children: Vec<Vec<usize>> = Vec::new();
        for p in &parents {
            for c in 0..pool.len() {
                if p.contains(&c) || p.iter().any(|&k| conflicts(&pool[k], &pool[c], o)) {
                    continue;
                }
                let mut set = p.clone();
                set.push(c);
                set.sort_unstable();
                if seen.insert(set.clone()) {
                    children.push(set);
                }
            }
        }
        if children.is_empty() {
            break;
        }
        evaluated += children.len();
        let scored: Vec<Option<Evaluated>> = children
            .par_iter()
            .map(|set| {
                let cuts: Vec<Cut> = set.iter().map(|&k| pool[k]).collect();
                let (ident, rel) =
                    evaluate(&cuts, (o, stock), model, tool, (params, iso), measured)?;
                Some((key_of(&ident, params.len() + iso.len()), ident, rel))
            })
            .collect();
        let mut round: Vec<(Vec<usize>, Evaluated)> = children
            .into_iter()
            .zip(scored)
            .filter_map(|(c, e)| e.map(|e| (c, e)))
            .collect();
        // Stable sort: ties keep the pool order, so the design is deterministic.
        round.sort_by(|a, b| order(&a.1.0, &b.1.0));
        round.truncate(match family {
            Family::Bar => BEAM_WIDTH,
            Family::Block => BLOCK_BEAM_WIDTH,
        });
        let Some(top) = round.first() else {
            break;
        };
        // Stop when a cut adds no determined direction and hardly strengthens the weak ones.
        // A design whose weakest determined direction is close to the threshold keeps
        // growing while the weakest direction strengthens: a real scan (correlated noise,
        // points lost at edges) gives less than the expected uncertainties promise.
        if let Some((_, (k, bi, _))) = &best
            && (top.1.0.0, top.1.0.1) == (k.0, k.1)
            && top.1.0.2 < k.2 + MIN_GAIN
            && !(weakest(bi) < ROBUST_SINGULAR_VALUE && weakest(&top.1.1) > weakest(bi))
        {
            break;
        }
        best = Some(top.clone());
        beam = round;
    }
    let (set, (_, ident, rel)) =
        best.ok_or_else(|| DesignError::Machine("a bar the candidate cuts can reach".into()))?;
    let mut chosen: Vec<Cut> = set.iter().map(|&k| pool[k]).collect();
    chosen.sort_by(|a, b| a.order().total_cmp(&b.order()));
    let feats = features_of(&chosen, o, stock, model, tool, measured);
    let mut d = finish(chosen, ident, rel, o, (family, stock), tool, evaluated);
    d.notes = feats.map_or_else(Vec::new, |f| {
        lever_notes(&d.cuts, &f, model, tool, params, iso)
    });
    Ok(d)
}

/// The weakest determined direction's singular value a design keeps growing towards: 2.5
/// times the threshold of determination, so that a real scan, which measures a face less
/// well than its expected uncertainties (correlated noise, points lost at edges), still
/// determines it.
const ROBUST_SINGULAR_VALUE: Real = 2.5 / crate::calibration::calibrate::DETERMINED_FRACTION;

/// The smallest singular value of the determined subspace (0 when nothing is determined).
fn weakest(i: &Identifiability) -> Real {
    i.rank
        .checked_sub(1)
        .and_then(|k| i.singular_values.get(k))
        .copied()
        .unwrap_or(0.0)
}

/// Designs kept per round of the beam search: enough to carry the alternatives a greedy
/// choice would drop, few enough that the nine deviations design in well under a second.
const BEAM_WIDTH: usize = 6;

/// Designs kept per round for the block: its shoulders compete for the block's few edges
/// (a cut on an edge excludes the others there), so a narrow beam settles on cuts that
/// leave no edge for an axis's other positions.
const BLOCK_BEAM_WIDTH: usize = 16;

/// A cut that determines nothing new is added only if it raises the information score (the
/// sum of the logs of the capped singular values) by at least this: ln 2, a doubling of the
/// information along some direction.
const MIN_GAIN: Real = std::f64::consts::LN_2;
/// Singular values are credited between these (scaled whitened units): below, a direction is
/// as good as unseen; above, it is determined to a hundredth of its realistic size and more
/// precision is not needed.
const SCORE_FLOOR: Real = 1e-3;
const SCORE_CAP: Real = 100.0;

/// The ranking of what `ident` determines for `np` parameters: undetermined directions,
/// parameters not identified alone, information score (see [`order`]).
pub fn key_of(ident: &Identifiability, np: usize) -> Key {
    let score = ident
        .singular_values
        .iter()
        .map(|s| s.clamp(SCORE_FLOOR, SCORE_CAP).ln())
        .sum();
    (np - ident.rank, np - ident.identified.len(), score)
}

/// Ranking: fewer undetermined directions, then fewer parameters not identified alone, then
/// the higher information score.
pub fn order(a: &Key, b: &Key) -> std::cmp::Ordering {
    (a.0, a.1).cmp(&(b.0, b.1)).then(b.2.total_cmp(&a.2))
}

/// Whether two cuts touch each other's faces: their removed cross-sections, grown by the
/// face margin, overlap (X-shoulders stop short of the end, so an X- and a Y-shoulder never
/// meet).
fn conflicts(a: &Cut, b: &Cut, o: &DesignOptions) -> bool {
    match (a, b) {
        (Cut::Block(a), Cut::Block(b)) => {
            let m = o.margin_mm;
            (0..3).all(|k| {
                a.removed.min[k] < b.removed.max[k] + m && b.removed.min[k] < a.removed.max[k] + m
            })
        }
        (Cut::XShoulder { .. }, Cut::XShoulder { .. })
        | (Cut::YShoulder { .. }, Cut::YShoulder { .. }) => {
            let ((alo, ahi), (blo, bhi)) = (a.section(o), b.section(o));
            let m = o.margin_mm;
            (0..2).all(|k| alo[k] < bhi[k] + m && blo[k] < ahi[k] + m)
        }
        _ => false,
    }
}

/// The pairs of deviations that only the spread of programmed tip heights separates, with
/// the faces that carry the lever: (first, second, `true` for faces across X (Y-shoulder
/// walls), `false` for faces across Y (X-shoulder walls)). See [`tip_height_lever`].
const LEVER_PAIRS: [(&str, &str, bool); 2] = [
    ("beta_XZ", "beta_ZS", true),
    ("alpha_YX", "alpha_ZS", false),
];

/// For the requested lever pairs: the tip-height spread of the faces that see them and the
/// standard uncertainty along their difference's unit direction `(p₁ − p₂)/√2` (the
/// quantity the identifiability threshold applies to) that `features` give: expected
/// ones, or those measured on the designed scene's simulated scan.
pub fn lever_notes(
    cuts: &[DesignedCut],
    features: &[Feature],
    model: &Chain,
    tool: &Tool,
    params: &[DeviationId],
    iso: &[IsoTerm],
) -> Vec<String> {
    let names: Vec<String> = params.iter().map(|id| model.deviation_name(*id)).collect();
    let cov = {
        let m = Model {
            chain: model,
            ids: params,
            iso_terms: iso,
            tool,
            features,
            registration: Registration::Estimate,
        };
        // (JᵀJ)⁺ = J⁺·J⁺ᵀ from J's own singular values (a whitened direction below 1e-6
        // is not seen: the 1e-12 of JᵀJ's eigenvalues it stands for).
        m.jacobian(&m.start())
            .and_then(|j| j.pseudo_inverse(1e-6).ok())
            .map(|p| &p * p.transpose())
    };
    let mut out = Vec::new();
    for (a, b, across_x) in LEVER_PAIRS {
        let (Some(i), Some(k)) = (
            names.iter().position(|n| n == a),
            names.iter().position(|n| n == b),
        ) else {
            continue;
        };
        // The programmed tip heights of the faces across X (Y-shoulder walls) or across Y.
        let tips: Vec<Real> = cuts
            .iter()
            .filter(|c| c.name.contains("-end-") == across_x)
            .map(|c| c.cut.start.get(AxisLetter::Z))
            .collect();
        let lo = tips.iter().copied().fold(Real::INFINITY, Real::min);
        let hi = tips.iter().copied().fold(Real::NEG_INFINITY, Real::max);
        let spread = if tips.is_empty() { 0.0 } else { hi - lo };
        let sigma = cov.as_ref().map(|c| {
            ((c[(i, i)] + c[(k, k)] - 2.0 * c[(i, k)]) / 2.0)
                .max(0.0)
                .sqrt()
        });
        let faces = if across_x { "across X" } else { "across Y" };
        let mut note = format!(
            "{a} − {b}: seen only through the spread of programmed tip heights of the faces \
             {faces} (here {spread:.1} mm)"
        );
        if let Some(s) = sigma {
            note.push_str(&format!(
                "; σ of ({a} − {b})/√2 {s:.2e} rad = {:.0} % of \
                 {ANGLE_MAGNITUDE_RAD:e} rad (determined below {:.0} %)",
                100.0 * s / ANGLE_MAGNITUDE_RAD,
                100.0 * crate::calibration::calibrate::DETERMINED_FRACTION
            ));
        }
        out.push(note);
    }
    out
}

/// The rotary words of a cut's pose (`A90`; `C90 A0` for the block family).
fn pose_words(c: &Cut) -> String {
    match c {
        Cut::Block(b) => b.pose[..b.rotaries]
            .iter()
            .map(|(l, v)| format!("{}{}", l.as_char(), fmt(*v)))
            .collect::<Vec<_>>()
            .join(" "),
        _ => format!("A{}", fmt(c.index())),
    }
}

/// The rapid plane of the block family (Z, mm): above the block turned about any rotary
/// axis (its corners' farthest reach from the workpiece origin, twice over for axes whose
/// lines lie away from it) and above every cut's start by the tool's length.
fn block_safe_z(cuts: &[Cut], o: &DesignOptions, tool: &Tool) -> Real {
    let b = o.block();
    let reach = b.min.coords.norm().max(b.max.coords.norm());
    cuts.iter()
        .map(|c| c.motion(o, tool.radius()).start.get(AxisLetter::Z) + tool.length() + 10.0)
        .fold(2.0 * reach + tool.length() + 10.0, Real::max)
        .ceil()
}

fn finish(
    cuts: Vec<Cut>,
    identifiability: Identifiability,
    relative_sigma: Vec<(String, Real)>,
    o: &DesignOptions,
    (family, stock): (Family, Aabb),
    tool: &Tool,
    evaluated: usize,
) -> Design {
    let r = tool.radius();
    let safe_z = match family {
        Family::Bar => o.safe_z_mm,
        Family::Block => block_safe_z(&cuts, o, tool),
    };
    let zero = cuts.first().map_or_else(
        || "A0".to_string(),
        |c| {
            pose_words(c)
                .split(' ')
                .map(|w| format!("{}0", &w[..1]))
                .collect::<Vec<_>>()
                .join(" ")
        },
    );
    let mut text = String::new();
    let mut line = 0;
    let mut push = |text: &mut String, s: String| {
        line += 1;
        let _ = writeln!(text, "{s}");
        line
    };
    push(&mut text, "%".into());
    push(
        &mut text,
        match family {
            Family::Bar => "(twinmill test cuts: shoulders on a square bar about the A axis)",
            Family::Block => {
                "(twinmill test cuts: shoulders on a block at positions of each rotary axis)"
            }
        }
        .into(),
    );
    push(&mut text, "G21 G90".into());
    push(&mut text, format!("G0 Z{safe_z} {zero}"));
    let mut designed = Vec::new();
    let mut faces = Vec::new();
    for c in &cuts {
        let mut mv = c.motion(o, r);
        let (s, e) = (mv.start, mv.end);
        push(&mut text, format!("G0 {}", pose_words(c)));
        push(
            &mut text,
            format!(
                "G0 X{} Y{}",
                fmt(s.get(AxisLetter::X)),
                fmt(s.get(AxisLetter::Y))
            ),
        );
        push(&mut text, format!("G0 Z{}", fmt(s.get(AxisLetter::Z))));
        let z = match c {
            Cut::Block(_) => format!(" Z{}", fmt(e.get(AxisLetter::Z))),
            _ => String::new(),
        };
        let l = push(
            &mut text,
            format!(
                "G1 X{} Y{}{z} F{} ({})",
                fmt(e.get(AxisLetter::X)),
                fmt(e.get(AxisLetter::Y)),
                FEED_MM_PER_MIN,
                c.name()
            ),
        );
        push(&mut text, format!("G0 Z{safe_z}"));
        mv.line = l;
        let kinds = c.faces(o);
        for &kind in &kinds {
            faces.push(FaceSpec {
                name: format!("{}-{}", c.name(), kind_name(kind)),
                line: l,
                region: FaceRegion::Auto,
                kind,
            });
        }
        designed.push(DesignedCut {
            name: c.name(),
            index_deg: c.index(),
            cut: mv,
            faces: kinds,
        });
    }
    push(&mut text, format!("G0 {zero}"));
    push(&mut text, "M30".into());
    push(&mut text, "%".into());
    Design {
        cuts: designed,
        program: text,
        faces,
        identifiability,
        relative_sigma,
        evaluated,
        notes: Vec::new(),
        family,
        stock,
        safe_z_mm: safe_z,
    }
}

fn fmt(v: Real) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.').to_string();
    if s == "-0" { "0".into() } else { s }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn depth_of(c: &Cut) -> Real {
        match *c {
            Cut::XShoulder { depth, .. } | Cut::YShoulder { depth, .. } => depth,
            Cut::Block(b) => b.depth,
        }
    }

    const NINE: [&str; 9] = [
        "dy_AY", "dz_AY", "beta_AY", "gamma_AY", "alpha_YX", "gamma_YX", "beta_XZ", "alpha_ZS",
        "beta_ZS",
    ];

    fn nine(c: &Chain) -> Vec<DeviationId> {
        NINE.iter()
            .map(|n| c.deviation_id(n).expect("known"))
            .collect()
    }

    fn tool() -> Tool {
        Tool::try_new(ToolKind::Flat, 6.0, 25.0).expect("valid")
    }

    fn sharp() -> DesignOptions {
        DesignOptions {
            noise_sigma_mm: 0.01,
            pitch_mm: 0.3,
            ..DesignOptions::standard()
        }
    }

    #[test]
    fn the_nine_deviations_are_all_determined_by_the_designed_cuts() {
        let c = crate::machine::chain::mdx50_for_tests();
        let d = design(&c, &tool(), &nine(&c), &sharp()).expect("a design");
        let i = &d.identifiability;
        assert_eq!(i.rank, 9, "undetermined: {:?}", i.undetermined_combinations);
        assert_eq!(i.identified.len(), 9);
        assert!(i.undetermined_combinations.is_empty());
        assert!(i.condition_number.is_finite());
        // Each weakest direction is known to better than a tenth of its realistic size.
        let weakest = i
            .singular_values
            .iter()
            .copied()
            .fold(Real::INFINITY, Real::min);
        assert!(weakest >= 1.0 / crate::calibration::calibrate::DETERMINED_FRACTION);
        // The lever: faces across X and across Y at more than one tip height.
        for (across_x, what) in [(true, "Y-shoulders"), (false, "X-shoulders")] {
            let tips: Vec<Real> = d
                .cuts
                .iter()
                .filter(|k| k.name.contains("-end-") == across_x)
                .map(|k| k.cut.start.get(AxisLetter::Z))
                .collect();
            let spread = tips.iter().copied().fold(Real::NEG_INFINITY, Real::max)
                - tips.iter().copied().fold(Real::INFINITY, Real::min);
            assert!(spread >= 5.0, "{what} tips {tips:?}");
        }
        assert_eq!(d.notes.len(), 2);
    }

    #[test]
    fn designed_cuts_never_meet() {
        let c = crate::machine::chain::mdx50_for_tests();
        let o = DesignOptions::standard();
        let d = design(&c, &tool(), &nine(&c), &o).expect("a design");
        let pool = candidates(&o, &tool());
        let cuts: Vec<Cut> = d
            .cuts
            .iter()
            .map(|k| {
                *pool
                    .iter()
                    .find(|p| p.name() == k.name)
                    .expect("from the pool")
            })
            .collect();
        for (i, a) in cuts.iter().enumerate() {
            for b in &cuts[..i] {
                assert!(!conflicts(a, b, &o), "{} meets {}", a.name(), b.name());
            }
            // Within the tool's reach.
            assert!(depth_of(a) <= tool().length() - o.margin_mm);
        }
    }

    /// The derivation in the module docs, checked on the model's own Jacobian: at any pose,
    /// a Z-squareness turn and the same spindle-tilt turn the other way move every face like
    /// a slide of the tool by the tip height times the angle (along X for beta, along −Y
    /// for alpha), whatever the rotary index, the position and the cut direction.
    #[test]
    fn z_squareness_and_spindle_tilt_differ_only_by_the_tip_height_lever() {
        use crate::calibration::calibrate::{
            FaceKind, Model, Registration, synthetic_plane_feature,
        };
        use crate::calibration::identify::{FaceRegion, FaceSpec};
        use crate::nc::{AxisValues, Move, MoveKind};
        let c = crate::machine::chain::mdx50_for_tests();
        let ids: Vec<DeviationId> = [
            "beta_XZ", "beta_ZS", "dx_AY", "alpha_YX", "alpha_ZS", "dy_AY",
        ]
        .iter()
        .map(|n| c.deviation_id(n).expect("known"))
        .collect();
        let rng = crate::math::CounterRng::new(9);
        let stock = Aabb {
            min: Point3::new(-200.0, -200.0, -200.0),
            max: Point3::new(200.0, 200.0, 200.0),
        };
        for k in 0..200u64 {
            let u = |j| 2.0 * rng.uniform(k, j) - 1.0;
            let (a, x, y, z) = (180.0 * u(0), 60.0 * u(1), 60.0 * u(2), 40.0 * u(3));
            let along_x = u(4) > 0.0;
            let q = |s: Real| {
                let (dx, dy) = if along_x { (s, 0.0) } else { (0.0, s) };
                AxisValues::default()
                    .with(AxisLetter::A, a)
                    .with(AxisLetter::X, x + dx)
                    .with(AxisLetter::Y, y + dy)
                    .with(AxisLetter::Z, z)
            };
            let mv = Move {
                kind: MoveKind::Linear,
                start: q(-20.0),
                end: q(20.0),
                feed_mm_per_min: Some(600.0),
                line: 1,
            };
            let feats: Vec<Feature> = [FaceKind::Flank, FaceKind::Floor]
                .iter()
                .map(|&kind| {
                    let spec = FaceSpec {
                        name: "f".into(),
                        line: 1,
                        region: FaceRegion::Auto,
                        kind,
                    };
                    Feature::Plane(
                        synthetic_plane_feature(
                            &spec,
                            &mv,
                            &c,
                            &c,
                            &tool(),
                            &stock,
                            1e-3,
                            [1e-4, 1e-4],
                            (-1.0, 1.0),
                        )
                        .expect("a face"),
                    )
                })
                .collect();
            let m = Model {
                chain: &c,
                ids: &ids,
                iso_terms: &[],
                tool: &tool(),
                features: &feats,
                registration: Registration::Workpiece,
            };
            let j = m.jacobian(&m.start()).expect("defined");
            let scale = j.amax();
            let beta = j.column(0) - j.column(1) - j.column(2) * z;
            let alpha = j.column(3) - j.column(4) + j.column(5) * z;
            // Exact at the nominal chain (the two turns' generators differ by a pure
            // translation): only rounding of ~1e4-sized whitened entries remains.
            assert!(
                beta.amax() <= 1e-9 * scale,
                "pose {k}: beta {}",
                beta.amax()
            );
            assert!(
                alpha.amax() <= 1e-9 * scale,
                "pose {k}: alpha {}",
                alpha.amax()
            );
        }
    }

    #[test]
    fn cuts_at_one_tip_height_leave_the_lever_pairs_unseen() {
        // Every cut at the same depth: the two differences fall into the registration's
        // slide along X and dy_AY (the test above), so they are not determined.
        let c = crate::machine::chain::mdx50_for_tests();
        let o = DesignOptions {
            depths_mm: [3.0; 5],
            ..sharp()
        };
        let d = design(&c, &tool(), &nine(&c), &o).expect("a design");
        let i = &d.identifiability;
        assert!(i.rank <= 7, "rank {}", i.rank);
        for p in ["beta_XZ", "beta_ZS", "alpha_ZS"] {
            assert!(!i.identified.contains(&p.to_string()), "{p} identified");
        }
    }
}
