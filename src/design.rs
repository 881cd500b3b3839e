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
//! Each of the bar's four long corners takes at most one X-shoulder (two indices reach each
//! corner); Y-shoulders are cut only at indices 0° and 180° (opposite sides, never
//! touching). X-shoulders stop short of the Y-shoulders. Depths vary so that faces of the same
//! orientation are cut with the tool's tip at different heights (the lever arm that separates
//! the spindle's tilt from the squareness of the axes).
//!
//! **Choice.** Every compatible combination is evaluated on the model chain: synthetic plane
//! features with the uncertainties the scanner would give (points on the face from its area
//! and the scan pitch, range noise σ), the identifiability analysis of [`crate::calibrate`]
//! with the registration estimated. The design that determines the most of what was asked,
//! then with the smallest worst relative uncertainty, then with the fewest cuts, wins.
//!
//! **Invariant:** plans and writes text; runs no sweep or scan and touches no files.

use crate::calibrate::{
    CalibrateError, Feature, Identifiability, Model, Registration, identifiability, magnitude,
    synthetic_plane_feature,
};
use crate::identify::{FaceKind, FaceRegion, FaceSpec};
use crate::kinematics::{AxisKind, Chain, DeviationId};
use crate::math::{Aabb, Point3, Real, Vector3};
use crate::nc::{AxisLetter, AxisValues, Move, MoveKind};
use crate::tool::{Tool, ToolKind};
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
    /// Shoulder width into the side (mm); must exceed twice the face margin.
    pub width_mm: Real,
    /// The shoulder depths the design chooses from (mm); each below `half_section_mm`.
    pub depths_mm: [Real; 3],
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
    /// 6 mm shoulders 3, 9 or 15 mm deep, EinScan-class noise 0.025 mm at 0.185 mm pitch.
    pub fn standard() -> Self {
        DesignOptions {
            half_section_mm: 20.0,
            length_mm: 80.0,
            width_mm: 6.0,
            depths_mm: [3.0, 9.0, 15.0],
            noise_sigma_mm: 0.025,
            pitch_mm: 0.185,
            margin_mm: 1.0,
            safe_z_mm: 40.0,
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
}

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
}

fn check_machine(chain: &Chain) -> Result<(), DesignError> {
    let axes = chain.axes();
    let first = axes
        .first()
        .ok_or_else(|| DesignError::Machine("a chain".into()))?;
    if first.kind != AxisKind::Rotary
        || (first.direction.into_inner() - Vector3::x()).norm() > 1e-12
        || first.origin.y != 0.0
        || first.origin.z != 0.0
    {
        return Err(DesignError::Machine(
            "the workpiece on a rotary axis about W x through the origin (first in the chain)"
                .into(),
        ));
    }
    for (letter, dir) in [
        (AxisLetter::X, Vector3::x()),
        (AxisLetter::Y, Vector3::y()),
        (AxisLetter::Z, Vector3::z()),
    ] {
        if !axes
            .iter()
            .any(|a| a.letter == letter && (a.direction.into_inner() - dir).norm() < 1e-12)
        {
            return Err(DesignError::Machine(format!(
                "a linear {} axis along {dir:?}",
                letter.as_char()
            )));
        }
    }
    Ok(())
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
        }
    }

    fn index(&self) -> Real {
        match *self {
            Cut::XShoulder { index, .. } | Cut::YShoulder { index, .. } => index,
        }
    }

    /// The W corner (sign of y, sign of z) an X-shoulder cuts.
    fn corner(&self, o: &DesignOptions) -> Option<(i32, i32)> {
        match *self {
            Cut::XShoulder { index, side, .. } => {
                let (s, c) = index.to_radians().sin_cos();
                let (y, z) = (side * o.half_section_mm, o.half_section_mm);
                let (yw, zw) = (y * c - z * s, y * s + z * c);
                Some((yw.signum() as i32, zw.signum() as i32))
            }
            Cut::YShoulder { .. } => None,
        }
    }

    /// The straight cut in axis values (base frame = axis values at this index).
    fn motion(&self, o: &DesignOptions, r: Real) -> Move {
        let (h, l) = (o.half_section_mm, o.length_mm / 2.0);
        let (start, end) = match *self {
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

    /// The faces a scanner can measure: the flank always; the floor only when the wall
    /// beside it, seen at 45°, leaves more than two margins of it in view (depth + 2·margin
    /// below the shoulder's width).
    fn faces(&self, o: &DesignOptions) -> Vec<FaceKind> {
        let depth = match *self {
            Cut::XShoulder { depth, .. } | Cut::YShoulder { depth, .. } => depth,
        };
        if depth + 2.0 * o.margin_mm < o.width_mm {
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
        };
        match kind {
            FaceKind::Flank => ((along - m).max(0.0), (depth - m).max(0.0)),
            FaceKind::Floor => ((along - m).max(0.0), (o.width_mm - depth - m).max(0.0)),
        }
    }
}

/// Ranking of a candidate: undetermined directions, parameters not identified alone,
/// information score (higher is better).
type Key = (usize, usize, Real);

/// A candidate design's ranking, identifiability and relative uncertainties.
type Evaluated = (Key, Identifiability, Vec<(String, Real)>);

/// Feed of the designed cuts (mm/min).
const FEED_MM_PER_MIN: Real = 600.0;

/// Points per mm² of a face seen at 45° by a scanner of pitch p: cos 45° / p².
fn expected_points(area: Real, pitch: Real) -> Real {
    area * std::f64::consts::FRAC_1_SQRT_2 / (pitch * pitch)
}

fn candidates(o: &DesignOptions) -> Vec<Cut> {
    let mut out = Vec::new();
    for index in [0.0, 90.0, 180.0, 270.0] {
        for side in [-1.0, 1.0] {
            for depth in o.depths_mm {
                out.push(Cut::XShoulder { index, side, depth });
            }
        }
    }
    for index in [0.0, 180.0] {
        for depth in o.depths_mm {
            out.push(Cut::YShoulder { index, depth });
        }
    }
    out
}

fn features_of(
    cuts: &[Cut],
    o: &DesignOptions,
    model: &Chain,
    tool: &Tool,
) -> Option<Vec<Feature>> {
    let stock = o.stock();
    let r = tool.radius();
    let mut out = Vec::new();
    for c in cuts {
        let mv = c.motion(o, r);
        for kind in c.faces(o) {
            let (a, b) = c.face_sizes(o, kind);
            let n = expected_points(a * b, o.pitch_mm).max(3.0);
            let s = o.noise_sigma_mm;
            let spec = FaceSpec {
                name: format!("{}-{}", c.name(), kind_name(kind)),
                line: 0,
                region: FaceRegion::Auto,
                kind,
            };
            // Floors: the part of the track inside the stock, across the feed (symmetric
            // when the shoulder is one tool diameter wide).
            let half = ((o.width_mm.min(2.0 * r) - depth_of(c)) / 2.0 - o.margin_mm).max(0.0);
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

fn depth_of(c: &Cut) -> Real {
    match *c {
        Cut::XShoulder { depth, .. } | Cut::YShoulder { depth, .. } => depth,
    }
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
    o: &DesignOptions,
    model: &Chain,
    tool: &Tool,
    ids: &[DeviationId],
) -> Option<(Identifiability, Vec<(String, Real)>)> {
    let feats = features_of(cuts, o, model, tool)?;
    let m = Model {
        chain: model,
        ids,
        tool,
        features: &feats,
        registration: Registration::Estimate,
    };
    let x = m.start();
    let ident = identifiability(&m, &x).ok()?;
    // Relative uncertainty of each parameter from the scaled information in the
    // determined subspace.
    let j = m.jacobian(&x)?;
    let np = ids.len();
    let mut js = j.clone();
    for (k, id) in ids.iter().enumerate() {
        js.column_mut(k).scale_mut(magnitude(*id));
    }
    let info = js.transpose() * &js;
    let cov = info.pseudo_inverse(1e-12).ok()?;
    let rel = (0..np)
        .filter(|&k| ident.identified.contains(&ident.parameters[k]))
        .map(|k| (ident.parameters[k].clone(), cov[(k, k)].max(0.0).sqrt()))
        .collect();
    Some((ident, rel))
}

/// Designs test cuts that make `params` observable on `model` (see the module docs).
pub fn design(
    model: &Chain,
    tool: &Tool,
    params: &[DeviationId],
    o: &DesignOptions,
) -> Result<Design, DesignError> {
    check_machine(model)?;
    if tool.kind() != ToolKind::Flat {
        return Err(DesignError::Tool);
    }
    if params.is_empty() {
        return Err(DesignError::Calibrate(CalibrateError::NoParameters));
    }
    let pool = candidates(o);
    let mut chosen: Vec<Cut> = Vec::new();
    let mut evaluated = 0;
    let mut best: Option<Evaluated> = None;
    loop {
        let mut round: Option<(Cut, Evaluated)> = None;
        for c in &pool {
            if chosen.iter().any(|k| conflicts(k, c, o)) {
                continue;
            }
            let mut cuts = chosen.clone();
            cuts.push(*c);
            evaluated += 1;
            let Some((ident, rel)) = evaluate(&cuts, o, model, tool, params) else {
                continue;
            };
            let key = key_of(&ident, params.len());
            if round.as_ref().is_none_or(|(_, (k, ..))| better(&key, k)) {
                round = Some((*c, (key, ident, rel)));
            }
        }
        let Some((cut, (key, ident, rel))) = round else {
            break;
        };
        // Stop when a cut adds no determined direction and hardly strengthens the weak ones.
        if let Some((k, ..)) = &best
            && (key.0, key.1) == (k.0, k.1)
            && key.2 < k.2 + MIN_GAIN
        {
            break;
        }
        chosen.push(cut);
        best = Some((key, ident, rel));
    }
    let (_, ident, rel) =
        best.ok_or_else(|| DesignError::Machine("a bar the candidate cuts can reach".into()))?;
    chosen.sort_by(|a, b| a.index().total_cmp(&b.index()));
    Ok(finish(chosen, ident, rel, o, tool, evaluated))
}

/// A cut that determines nothing new is added only if it raises the information score (the
/// sum of the logs of the capped singular values) by at least this: ln 2, a doubling of the
/// information along some direction.
const MIN_GAIN: Real = std::f64::consts::LN_2;
/// Singular values are credited between these (scaled whitened units): below, a direction is
/// as good as unseen; above, it is determined to a hundredth of its realistic size and more
/// precision is not needed.
const SCORE_FLOOR: Real = 1e-3;
const SCORE_CAP: Real = 100.0;

fn key_of(ident: &Identifiability, np: usize) -> Key {
    let score = ident
        .singular_values
        .iter()
        .map(|s| s.clamp(SCORE_FLOOR, SCORE_CAP).ln())
        .sum();
    (np - ident.rank, np - ident.identified.len(), score)
}

fn better(a: &Key, b: &Key) -> bool {
    (a.0, a.1) < (b.0, b.1) || ((a.0, a.1) == (b.0, b.1) && a.2 > b.2)
}

/// Whether two cuts touch each other's faces.
fn conflicts(a: &Cut, b: &Cut, o: &DesignOptions) -> bool {
    match (a, b) {
        (Cut::XShoulder { .. }, Cut::XShoulder { .. }) => a.corner(o) == b.corner(o),
        (Cut::YShoulder { index: i, depth: d }, Cut::YShoulder { index: j, depth: e }) => {
            i == j || d + e > 2.0 * o.half_section_mm - 2.0 * o.margin_mm
        }
        _ => false,
    }
}

fn finish(
    cuts: Vec<Cut>,
    identifiability: Identifiability,
    relative_sigma: Vec<(String, Real)>,
    o: &DesignOptions,
    tool: &Tool,
    evaluated: usize,
) -> Design {
    let r = tool.radius();
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
        "(twinmill test cuts: shoulders on a square bar about the A axis)".into(),
    );
    push(&mut text, "G21 G90".into());
    push(&mut text, format!("G0 Z{} A0", o.safe_z_mm));
    let mut designed = Vec::new();
    let mut faces = Vec::new();
    for c in &cuts {
        let mut mv = c.motion(o, r);
        let (s, e) = (mv.start, mv.end);
        push(&mut text, format!("G0 A{}", fmt(c.index())));
        push(
            &mut text,
            format!(
                "G0 X{} Y{}",
                fmt(s.get(AxisLetter::X)),
                fmt(s.get(AxisLetter::Y))
            ),
        );
        push(&mut text, format!("G0 Z{}", fmt(s.get(AxisLetter::Z))));
        let l = push(
            &mut text,
            format!(
                "G1 X{} Y{} F{} ({})",
                fmt(e.get(AxisLetter::X)),
                fmt(e.get(AxisLetter::Y)),
                FEED_MM_PER_MIN,
                c.name()
            ),
        );
        push(&mut text, format!("G0 Z{}", o.safe_z_mm));
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
    push(&mut text, "G0 A0".into());
    push(&mut text, "M30".into());
    push(&mut text, "%".into());
    Design {
        cuts: designed,
        program: text,
        faces,
        identifiability,
        relative_sigma,
        evaluated,
    }
}

fn fmt(v: Real) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.').to_string();
    if s == "-0" { "0".into() } else { s }
}
