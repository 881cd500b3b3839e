//! Model correction for the A-axis 0°/180° experiment (seed 002 §4; see
//! docs/identification-and-correction.md): segment the two faces in a cloud, fit planes,
//! measure the step, identify dy_AY and gamma_AY + gamma_YX.
//!
//! **Faces.** Each face is named by the NC line of the straight cut that made it. The cut's
//! flank plane on the *model* chain (nominal plus known deviations) gives the face's
//! expected place: the region between the move's ends and between the tool tip and the
//! tool's length, clipped to the stock and shrunk by a margin, within a band around the
//! plane. Points there are fitted by orthogonal least squares with outlier rejection.
//!
//! **Measurements.** With `P` the midpoint of the two faces' centroids, `n` the first face's
//! model normal (into the material) and `u` its cut direction: the *step* is the distance
//! from the first plane to the second along the line through `P` in direction `n`, and the
//! *tilt* is `(n₂ − n₁)·u`, the relative rotation of the faces about the tool axis.
//! To first order (seed 002 eq. 6, 7, with y1 = −y2): step = −2·dy_AY,
//! tilt = 2·(gamma_AY + gamma_YX).
//!
//! **Identification** of the rotary joint's offset and angle sum from the two faces is
//! [`crate::calibration::step`]'s, on the identification engine; here are the faces, the
//! frame the step and tilt are measured in ([`StepFrame`]), the faces' goodness of fit
//! against the scanner's noise ([`faces_fit`]) and the step the exact chain predicts
//! ([`predicted_step`]).
//!
//! **Invariant:** reads a cloud and the program's moves; it never runs the
//! sweep or the scanner (it must work on clouds twinmill did not make).

use crate::calibration::goodness::{FitCheck, REFUSE_P, ScanNoise, face_rms_check};
use crate::cutting::stock::TriDexel;
use crate::cutting::tool::Tool;
use crate::machine::chain::{AxisKind, Chain};
use crate::math::{Aabb, Point3, Real, UnitVector3, Vector3, tol};
use crate::metrology::fit::{FitError, Plane, PlaneFit, RobustRule, fit_plane_robust};
use crate::metrology::segment::{PlaneSegmentOptions, select_box, select_region_from_seed};
use crate::nc::{Move, MoveKind};
use nalgebra::{Matrix2, Vector2};

/// Errors of face extraction and identification.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    /// The face names a line with no move on it.
    #[error("face '{face}': no move on NC line {line}")]
    NoMove {
        /// Face name.
        face: String,
        /// Line asked for.
        line: usize,
    },
    /// The move on the face's line is not a straight cut at fixed rotary values.
    #[error("face '{face}': line {line} is not a feed move at constant rotary position")]
    NotACut {
        /// Face name.
        face: String,
        /// Line.
        line: usize,
    },
    /// The face region, clipped to the stock and margins, is empty.
    #[error("face '{face}': the cut's flank does not cover the stock beyond the margin")]
    EmptyRegion {
        /// Face name.
        face: String,
    },
    /// The face's cut left none of its surface inside the face region: nothing was cut
    /// there, so there is no face to fit (checked on the cut stock of a simulated scan,
    /// whose crossings carry the NC line that cut them).
    #[error("face '{face}': line {line} cut nothing inside the face region ({detail})")]
    NotCut {
        /// Face name.
        face: String,
        /// The cut's NC line.
        line: usize,
        /// The region, and where the cut's surface is instead.
        detail: String,
    },
    /// Too few points of the cloud lie in the face region to fit a plane.
    #[error(
        "face '{face}': {found} points of the cloud inside the face region ({region}); a plane needs at least {MIN_FACE_POINTS}"
    )]
    FewPoints {
        /// Face name.
        face: String,
        /// Points found.
        found: usize,
        /// The region.
        region: String,
    },
    /// The plane fit failed (degenerate points).
    #[error("face '{face}': {source} ({points} points in the region)")]
    Fit {
        /// Face name.
        face: String,
        /// Points found in the region.
        points: usize,
        /// Why.
        source: FitError,
    },
    /// The experiment needs exactly two faces cut 180° apart about one rotary axis.
    #[error("the 0/180 experiment needs two faces cut 180° apart about one rotary axis: {0}")]
    NotAStepPair(String),
    /// The identification engine refused the step's problem (an uncertainty not finite,
    /// the model unable to predict the faces), in its words.
    #[error("the step's identification: {0}")]
    Solve(String),
}

/// Options for face extraction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceOptions {
    /// Distance kept from the face's edges (mm); ≥ 0. Typical 1.0.
    pub margin_mm: Real,
    /// Half-width of the band around the expected plane that points must fall in (mm); > 0.
    /// Must exceed the largest expected deviation of the face; typical 2.0.
    pub band_mm: Real,
    /// Outlier rejection.
    pub robust: RobustRule,
}

/// A face to extract: a name and the NC line of the cut that made it.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceSpec {
    /// Name used in reports.
    pub name: String,
    /// 1-based NC line of the cut.
    pub line: usize,
    /// Where the face's points are.
    pub region: FaceRegion,
    /// Which face of the cut: its flank (side) or its floor (bottom of a flat end mill).
    pub kind: FaceKind,
}

/// Which face of a straight cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FaceKind {
    /// The side: tangent to the tool cylinder, containing the tool axis and the path.
    #[default]
    Flank,
    /// The bottom of a flat end mill's track.
    Floor,
}

/// How a face's points are chosen from a cloud.
#[derive(Clone, Debug, PartialEq)]
pub enum FaceRegion {
    /// From the cut's flank on the model chain, clipped to the stock, shrunk by the margin,
    /// within the band around the expected plane.
    Auto,
    /// The points inside a box (W).
    Box(Aabb),
    /// The planar region grown from the point nearest to a seed point (W).
    Seed(Point3),
}

/// The flank plane of a straight cut, and the frame of its face.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Flank {
    /// The plane, normal pointing from the tool into the material.
    pub plane: Plane,
    /// Unit cut direction.
    pub u: UnitVector3,
    /// Unit tool axis (tip to shank).
    pub v: UnitVector3,
    /// A point on the tool axis at the tip, at the cut's start.
    pub tip: Point3,
    /// Length of the cut (mm).
    pub length: Real,
}

/// The flank plane of `mv` on `chain`: tangent to the tool cylinder, parallel to the tool
/// axis and the cut direction, on the side where more of `stock` lies. This decides which
/// side of the cut is its face from the geometry as planned (on the model chain); the same
/// face on another chain is [`flank_towards`] the model flank's normal.
pub fn flank(chain: &Chain, tool: &Tool, mv: &Move, stock: &Aabb) -> Option<Flank> {
    let (tip, _, _, side) = cut_frame(chain, mv)?;
    // Pick the side with the stock beyond it.
    let reach = |n: &Vector3| {
        corners(stock)
            .iter()
            .map(|c| n.dot(&(c - tip)) - tool.radius())
            .fold(Real::NEG_INFINITY, Real::max)
    };
    let toward = if reach(&side) >= reach(&-side.into_inner()) {
        side
    } else {
        -side
    };
    flank_towards(chain, tool, mv, &toward)
}

/// The flank plane of `mv` on `chain` on the side `toward` points to (its normal has a
/// positive component along `toward`): the same face of the cut on any chain, whatever the
/// deviations move it by. A side chosen afresh on a deviated chain (by where the stock
/// lies) would flip to the cut's other flank once the tool passes the stock's middle.
pub fn flank_towards(chain: &Chain, tool: &Tool, mv: &Move, toward: &UnitVector3) -> Option<Flank> {
    let (tip, d, v, side) = cut_frame(chain, mv)?;
    let length = d.norm();
    let u = UnitVector3::try_new(d, tol::LENGTH_EPS)?;
    let n = if side.dot(toward) >= 0.0 { side } else { -side };
    Some(Flank {
        plane: Plane::through(&(tip + n.into_inner() * tool.radius()), n),
        u,
        v,
        tip,
        length,
    })
}

/// The tip at the cut's start, the tip's travel, the tool axis and the unit normal
/// `u × v` of a straight cut on `chain`; `None` for a cut along the tool axis or no cut.
fn cut_frame(chain: &Chain, mv: &Move) -> Option<(Point3, Vector3, UnitVector3, UnitVector3)> {
    let p0 = chain.w_from_t(&mv.start);
    let p1 = chain.w_from_t(&mv.end);
    let tip = p0 * Point3::origin();
    let d = p1 * Point3::origin() - tip;
    let v = UnitVector3::new_normalize(p0.rotation * Vector3::z());
    let u = UnitVector3::try_new(d, tol::LENGTH_EPS)?;
    let side = UnitVector3::try_new(u.cross(&v), tol::LENGTH_EPS)?;
    Some((tip, d, v, side))
}

/// The range of `w · (x − origin)` over the box: its extent along `w` (mm).
pub fn extent(stock: &Aabb, origin: &Point3, w: &UnitVector3) -> (Real, Real) {
    corners(stock)
        .iter()
        .fold((Real::INFINITY, Real::NEG_INFINITY), |(lo, hi), c| {
            let x = w.dot(&(c - origin));
            (lo.min(x), hi.max(x))
        })
}

fn corners(b: &Aabb) -> [Point3; 8] {
    std::array::from_fn(|i| {
        Point3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        )
    })
}

/// A face found in a cloud.
#[derive(Clone, Debug, PartialEq)]
pub struct Face {
    /// Its name.
    pub name: String,
    /// The cut that made it.
    pub cut: Move,
    /// The model flank that defined its region.
    pub flank: Flank,
    /// The rotary position of the cut (degrees), per rotary axis in chain order.
    pub rotary_deg: Vec<Real>,
    /// The fitted plane, normal oriented like the flank's.
    pub fit: PlaneFit,
    /// Indices of the cloud points in the region.
    pub indices: Vec<usize>,
    /// How the fitted plane's uncertainty spreads over the face.
    pub design: FaceDesign,
}

/// The least-squares design of a face's plane fit, for propagating its uncertainty to any
/// point and direction: in-plane coordinates along the cut (`u`) and the tool axis (`v`)
/// relative to the centroid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceDesign {
    /// In-plane directions (cut direction, tool axis), as on the flank.
    pub basis: [UnitVector3; 2],
    /// Scatter matrix Σ q qᵀ of the used points' in-plane coordinates q (mm²).
    pub scatter: Matrix2<Real>,
    /// Points used.
    pub n: usize,
    /// Residual standard deviation, inflated for correlated residuals (mm).
    pub sigma_mm: Real,
    /// The inflation of the variance for correlated residuals (≥ 1; 1 for independent
    /// noise), from block averaging.
    pub correlation_inflation: Real,
}

impl FaceDesign {
    /// Standard uncertainty (mm) of the plane's offset at the in-plane point `at`.
    pub fn offset_sigma_at(&self, centroid: &Point3, at: &Point3) -> Real {
        let d = at - centroid;
        let q = Vector2::new(self.basis[0].dot(&d), self.basis[1].dot(&d));
        let minv = self
            .scatter
            .try_inverse()
            .unwrap_or_else(|| Matrix2::from_element(Real::INFINITY));
        self.sigma_mm * (1.0 / self.n as Real + (q.transpose() * minv * q)[0]).sqrt()
    }

    /// Standard uncertainty (rad) of the plane's slope along the cut direction.
    pub fn slope_sigma_along_cut(&self) -> Real {
        let minv = self
            .scatter
            .try_inverse()
            .unwrap_or_else(|| Matrix2::from_element(Real::INFINITY));
        self.sigma_mm * minv[(0, 0)].sqrt()
    }
}

/// Block edges (mm) over which residual correlation is looked for: from about three point
/// pitches to a fifth of a typical face.
const BLOCK_EDGES_MM: [Real; 4] = [0.5, 1.0, 2.0, 4.0];
/// Fewest points in a block for its mean to count.
const BLOCK_MIN_POINTS: usize = 4;

/// The design of a fit from its points, with the variance inflation for correlated residuals
/// found by block averaging (Flyvbjerg & Petersen): residual means over blocks of edge b vary
/// like σ²·f/n_block if the residuals are correlated over less than b; f is the largest such
/// ratio over the block sizes, and 1 for independent noise.
pub fn face_design(points: &[Point3], fit: &PlaneFit, basis: [UnitVector3; 2]) -> FaceDesign {
    let c = fit.centroid;
    let coords: Vec<(Real, Real, Real)> = points
        .iter()
        .map(|p| {
            let d = p - c;
            (
                basis[0].dot(&d),
                basis[1].dot(&d),
                fit.plane.signed_distance(p),
            )
        })
        .collect();
    let mut scatter = Matrix2::zeros();
    let mut ss = 0.0;
    for &(u, v, r) in &coords {
        scatter += Matrix2::new(u * u, u * v, u * v, v * v);
        ss += r * r;
    }
    let n = coords.len();
    let var = ss / (n.saturating_sub(3).max(1)) as Real;
    let mut inflation: Real = 1.0;
    for b in BLOCK_EDGES_MM {
        let mut blocks: std::collections::BTreeMap<(i64, i64), (usize, Real)> = Default::default();
        for &(u, v, r) in &coords {
            let e = blocks
                .entry(((u / b).floor() as i64, (v / b).floor() as i64))
                .or_default();
            e.0 += 1;
            e.1 += r;
        }
        let (mut num, mut den) = (0.0, 0usize);
        for &(k, sum) in blocks.values().filter(|(k, _)| *k >= BLOCK_MIN_POINTS) {
            let mean = sum / k as Real;
            num += k as Real * mean * mean;
            den += 1;
        }
        if den >= 8 && var > 0.0 {
            inflation = inflation.max(num / den as Real / var);
        }
    }
    FaceDesign {
        basis,
        scatter,
        n,
        sigma_mm: (var * inflation).sqrt(),
        correlation_inflation: inflation,
    }
}

/// The straight cut on the face's NC line, at constant rotary positions.
pub fn find_cut<'m>(
    moves: &'m [Move],
    spec: &FaceSpec,
    chain: &Chain,
) -> Result<&'m Move, IdentifyError> {
    let mv = moves
        .iter()
        .find(|m| m.line == spec.line)
        .ok_or_else(|| IdentifyError::NoMove {
            face: spec.name.clone(),
            line: spec.line,
        })?;
    let turns = chain
        .axes()
        .iter()
        .any(|a| a.kind == AxisKind::Rotary && mv.start.get(a.letter) != mv.end.get(a.letter));
    if mv.kind != MoveKind::Linear || turns {
        return Err(IdentifyError::NotACut {
            face: spec.name.clone(),
            line: spec.line,
        });
    }
    Ok(mv)
}

/// Indices of the points a face region selects: those passing `auto` for
/// [`FaceRegion::Auto`] (the model's expectation of the face), those in the box, or the
/// planar region grown from the seed (none if no region grows there).
pub fn region_indices(
    points: &[Point3],
    region: &FaceRegion,
    auto: impl Fn(&Point3) -> bool,
) -> Vec<usize> {
    match region {
        FaceRegion::Auto => points
            .iter()
            .enumerate()
            .filter(|(_, p)| auto(p))
            .map(|(i, _)| i)
            .collect(),
        FaceRegion::Box(b) => select_box(points, &b.min, &b.max)
            .into_iter()
            .map(|i| i as usize)
            .collect(),
        FaceRegion::Seed(seed) => {
            select_region_from_seed(points, seed, &PlaneSegmentOptions::default())
                .map(|r| r.indices.into_iter().map(|i| i as usize).collect())
                .unwrap_or_default()
        }
    }
}

/// Fewest points a face's plane is fitted to.
pub const MIN_FACE_POINTS: usize = 3;

/// A crossing of the cut stock belongs to a face when its material's outward normal is
/// within 25° of the face's outward normal (cos 25° ≈ 0.9); the crossings on a cut face lie
/// within microradians of it, those of the cut's other flank or its floor 90° or more off.
const FACING_COS: Real = 0.9;

/// Where a face is expected: the part of the cut's face (flank or floor) on the model
/// chain, clipped to the stock and shrunk by the margin, and the band around its plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceWindow {
    /// Origin of the in-plane coordinates: the tool tip at the cut's start.
    pub origin: Point3,
    /// In-plane directions: the cut direction and the tool axis (flank) or the cross-feed
    /// direction (floor).
    pub axes: [UnitVector3; 2],
    /// The face's extent along each in-plane direction (mm, from `origin`).
    pub ranges: [(Real, Real); 2],
    /// The expected plane, normal from the tool into the material.
    pub plane: Plane,
    /// Half-width of the band around the plane (mm).
    pub band_mm: Real,
}

impl FaceWindow {
    /// Whether `p` lies over the face's extent (at any distance from its plane).
    pub fn over(&self, p: &Point3) -> bool {
        let w = p - self.origin;
        (0..2).all(|k| {
            let x = self.axes[k].dot(&w);
            x >= self.ranges[k].0 && x <= self.ranges[k].1
        })
    }

    /// Whether `p` lies in the window: over the face's extent and within the band.
    pub fn contains(&self, p: &Point3) -> bool {
        self.over(p) && self.plane.signed_distance(p).abs() <= self.band_mm
    }

    /// The window in words, for messages.
    pub fn describe(&self) -> String {
        let size = |k: usize| self.ranges[k].1 - self.ranges[k].0;
        format!(
            "within {} mm of the expected plane over {:.1} × {:.1} mm",
            self.band_mm,
            size(0),
            size(1)
        )
    }
}

/// The window of a face of the straight cut `mv` on the model chain: the flank between the
/// move's ends and between the tool's flank start and its length, or the floor across the
/// tool's diameter; clipped to the stock and shrunk by the margin. Also returns the cut's
/// model flank (its frame and, for flanks, its plane).
pub fn face_window(
    spec: &FaceSpec,
    mv: &Move,
    model: &Chain,
    tool: &Tool,
    stock: &Aabb,
    opts: &FaceOptions,
) -> Result<(FaceWindow, Flank), IdentifyError> {
    let empty = || IdentifyError::EmptyRegion {
        face: spec.name.clone(),
    };
    let fl = flank(model, tool, mv, stock).ok_or_else(empty)?;
    let m = opts.margin_mm;
    let su = extent(stock, &fl.tip, &fl.u);
    let along = (su.0.max(0.0) + m, su.1.min(fl.length) - m);
    let (second, across, plane) = match spec.kind {
        FaceKind::Flank => {
            // The flank is the cylindrical part of the tool at its full radius: from the
            // tip (flat) or one radius above it (ball); a tool with no such part makes no
            // planar flank.
            let flank_start = tool.flank_start().ok_or_else(empty)?;
            let sv = extent(stock, &fl.tip, &fl.v);
            let across = (sv.0.max(flank_start) + m, sv.1.min(tool.length()) - m);
            (fl.v, across, fl.plane)
        }
        FaceKind::Floor => {
            // The bottom of a flat end mill: across the feed over the tool's diameter; its
            // normal from the tool into the material below it.
            let e2 = UnitVector3::try_new(fl.v.cross(&fl.u), tol::LENGTH_EPS).ok_or_else(empty)?;
            let mn =
                UnitVector3::new_normalize(fl.u.into_inner() * fl.u.dot(&fl.v) - fl.v.into_inner());
            let se = extent(stock, &fl.tip, &e2);
            let r = tool.radius();
            let across = (se.0.max(-r) + m, se.1.min(r) - m);
            (e2, across, Plane::through(&fl.tip, mn))
        }
    };
    if along.0 >= along.1 || across.0 >= across.1 {
        return Err(empty());
    }
    Ok((
        FaceWindow {
            origin: fl.tip,
            axes: [fl.u, second],
            ranges: [along, across],
            plane,
            band_mm: opts.band_mm,
        },
        fl,
    ))
}

/// The points of a cloud a face selects, with its cut and window.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceSelection {
    /// The face.
    pub spec: FaceSpec,
    /// The cut that made it.
    pub cut: Move,
    /// The cut's flank on the model chain.
    pub flank: Flank,
    /// Where the face is expected.
    pub window: FaceWindow,
    /// Indices of the cloud points in the face's region.
    pub indices: Vec<usize>,
}

impl FaceSelection {
    /// The face's region in words, for messages.
    pub fn describe_region(&self) -> String {
        match &self.spec.region {
            FaceRegion::Auto => self.window.describe(),
            FaceRegion::Box(b) => format!(
                "in the box [{}, {}, {}] – [{}, {}, {}]",
                b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z
            ),
            FaceRegion::Seed(p) => {
                format!("the planar region grown around [{}, {}, {}]", p.x, p.y, p.z)
            }
        }
    }
}

/// Selects the points of a face: its cut, its window on the model chain, and the cloud
/// points in its region ([`FaceRegion`]).
pub fn select_face(
    points: &[Point3],
    spec: &FaceSpec,
    moves: &[Move],
    model: &Chain,
    tool: &Tool,
    stock: &Aabb,
    opts: &FaceOptions,
) -> Result<FaceSelection, IdentifyError> {
    let mv = find_cut(moves, spec, model)?;
    let (window, fl) = face_window(spec, mv, model, tool, stock, opts)?;
    let indices = region_indices(points, &spec.region, |p| window.contains(p));
    Ok(FaceSelection {
        spec: spec.clone(),
        cut: *mv,
        flank: fl,
        window,
        indices,
    })
}

/// Checks, on the cut stock a simulated scan was made of, that the face's cut left its
/// surface inside the face's region: a face may be fitted only where its cut removed
/// material. The stock's crossings carry the NC line that cut them; those of the face's
/// line, facing like the face, must lie in its region (the window for an automatic
/// region, the box, or — for a seed — the box of the selected points grown by the band).
/// Otherwise the points found there are of another surface (the uncut stock, another
/// cut), and fitting them would give a number for a measurement that did not happen.
pub fn check_cut(
    sel: &FaceSelection,
    points: &[Point3],
    stock: &TriDexel,
) -> Result<(), IdentifyError> {
    let w = &sel.window;
    let seed_box = match &sel.spec.region {
        FaceRegion::Seed(_) if sel.indices.is_empty() => return Ok(()),
        FaceRegion::Seed(_) => {
            let grow = Vector3::repeat(w.band_mm);
            let (lo, hi) = sel.indices.iter().fold(
                (
                    Point3::from(Vector3::repeat(Real::INFINITY)),
                    Point3::from(Vector3::repeat(Real::NEG_INFINITY)),
                ),
                |(lo, hi), &i| (lo.inf(&points[i]), hi.sup(&points[i])),
            );
            Some(Aabb {
                min: lo - grow,
                max: hi + grow,
            })
        }
        _ => None,
    };
    let inside = |p: &Point3| match (&sel.spec.region, &seed_box) {
        (FaceRegion::Auto, _) => w.contains(p),
        (FaceRegion::Box(b), _) | (FaceRegion::Seed(_), Some(b)) => {
            (0..3).all(|k| p[k] >= b.min[k] && p[k] <= b.max[k])
        }
        (FaceRegion::Seed(_), None) => false,
    };
    let n = w.plane.normal.into_inner();
    let line = sel.spec.line;
    let (mut found, mut elsewhere) = (0usize, Vec::new());
    for g in stock.grids() {
        g.for_each_crossing(|p, c| {
            if c.line as usize != line || c.normal().dot(&n) > -FACING_COS {
                return;
            }
            if inside(&p) {
                found += 1;
            } else if w.over(&p) {
                elsewhere.push(w.plane.signed_distance(&p));
            }
        });
    }
    if found >= MIN_FACE_POINTS {
        return Ok(());
    }
    let region = sel.describe_region();
    let detail = if elsewhere.is_empty() {
        format!(
            "{region}: no surface of line {line} remains there; the cut missed the stock, or a \
             later cut removed what it left"
        )
    } else {
        elsewhere.sort_by(Real::total_cmp);
        let median = elsewhere[elsewhere.len() / 2];
        format!(
            "{region}: its surface there lies {median:+.3} mm from the expected plane, beyond \
             band_mm = {}",
            w.band_mm
        )
    };
    Err(IdentifyError::NotCut {
        face: sel.spec.name.clone(),
        line,
        detail,
    })
}

/// Fits the plane of a selected flank.
pub fn fit_face(
    points: &[Point3],
    sel: &FaceSelection,
    model: &Chain,
    opts: &FaceOptions,
) -> Result<Face, IdentifyError> {
    let (sel_points, fit) = fit_selection(points, sel, opts)?;
    let fl = sel.flank;
    let used = used_points(&sel_points, &fit, opts);
    let design = face_design(&used, &fit, [fl.u, fl.v]);
    let rotary_deg = model
        .axes()
        .iter()
        .filter(|a| a.kind == AxisKind::Rotary)
        .map(|a| sel.cut.start.get(a.letter))
        .collect();
    Ok(Face {
        name: sel.spec.name.clone(),
        cut: sel.cut,
        flank: fl,
        rotary_deg,
        fit,
        indices: sel.indices.clone(),
        design,
    })
}

/// The selected points and their robust plane fit, normal oriented like the window's; an
/// error if there are too few points to fit.
pub fn fit_selection(
    points: &[Point3],
    sel: &FaceSelection,
    opts: &FaceOptions,
) -> Result<(Vec<Point3>, PlaneFit), IdentifyError> {
    let sel_points: Vec<Point3> = sel.indices.iter().map(|&i| points[i]).collect();
    if sel_points.len() < MIN_FACE_POINTS {
        return Err(IdentifyError::FewPoints {
            face: sel.spec.name.clone(),
            found: sel_points.len(),
            region: sel.describe_region(),
        });
    }
    let mut fit =
        fit_plane_robust(&sel_points, &opts.robust).map_err(|source| IdentifyError::Fit {
            face: sel.spec.name.clone(),
            points: sel_points.len(),
            source,
        })?;
    fit.plane = fit.plane.oriented_towards(&sel.window.plane.normal);
    Ok((sel_points, fit))
}

/// The points a robust fit kept (within its rejection limit).
pub fn used_points(points: &[Point3], fit: &PlaneFit, opts: &FaceOptions) -> Vec<Point3> {
    points
        .iter()
        .copied()
        .filter(|p| {
            fit.plane.signed_distance(p).abs()
                <= opts.robust.k_sigma * fit.rms_mm.max(tol::LENGTH_EPS)
        })
        .collect()
}

/// Segments and fits one face (a flank) in a cloud: [`select_face`], then [`fit_face`].
pub fn extract_face(
    points: &[Point3],
    spec: &FaceSpec,
    moves: &[Move],
    model: &Chain,
    tool: &Tool,
    stock: &Aabb,
    opts: &FaceOptions,
) -> Result<Face, IdentifyError> {
    let sel = select_face(points, spec, moves, model, tool, stock, opts)?;
    fit_face(points, &sel, model, opts)
}

/// The geometry the step and tilt are measured with, fixed from the model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepFrame {
    /// Where the step is measured (midpoint of the faces' centroids).
    pub at: Point3,
    /// Direction of measurement: the first face's model normal, into the material.
    pub n: UnitVector3,
    /// The first face's cut direction.
    pub u: UnitVector3,
}

impl StepFrame {
    /// Where a plane lies in the frame: its offset along `n` on the line through `at` (mm)
    /// and its normal's component along `u` (rad, to first order its turn about the tool
    /// axis); `None` for a plane parallel to `n`. [`StepFrame::measure`] is the second
    /// plane's less the first's.
    pub fn place(&self, plane: &Plane) -> Option<(Real, Real)> {
        let p = plane.intersect_line(&self.at, &self.n)?;
        Some(((p - self.at).dot(&self.n), plane.normal.dot(&self.u)))
    }

    /// Step (mm) and tilt (rad) between two planes.
    pub fn measure(&self, first: &Plane, second: &Plane) -> Option<(Real, Real)> {
        let a = first.intersect_line(&self.at, &self.n)?;
        let b = second.intersect_line(&self.at, &self.n)?;
        let step = (b - a).dot(&self.n);
        let tilt = (second.normal.into_inner() - first.normal.into_inner()).dot(&self.u);
        Some((step, tilt))
    }
}

/// The faces' goodness of fit: each face's points against the scanner's noise
/// ([`face_rms_check`]). The step and tilt are matched exactly by the two unknowns, so the
/// faces' shapes are what can contradict the model: a face that is not one plane (two
/// chamfers, a face of another cut) leaves residuals far beyond the scanner's noise.
pub fn faces_fit(faces: &[Face], scan: &ScanNoise) -> FitCheck {
    let p_limit = REFUSE_P / faces.len().max(1) as Real;
    let parts = faces
        .iter()
        .map(|f| {
            face_rms_check(
                &format!("face '{}' (NC line {})", f.name, f.cut.line),
                f.fit.rms_mm,
                f.design.n,
                f.design.correlation_inflation,
                scan,
                p_limit,
            )
        })
        .collect();
    FitCheck::new(
        "faces' points against the scanner's range noise",
        None,
        0.0,
        parts,
    )
}

/// The step and tilt the exact chain predicts for two cuts, measured in `frame`: on each
/// cut the flank on the side `toward` points to — the side of its face's model flank, the
/// side the material is on, whatever the deviations ([`flank_towards`]; for fitted faces
/// `[(&f.cut, &f.flank.plane.normal), …]`).
pub fn predicted_step(
    chain: &Chain,
    tool: &Tool,
    cuts: [(&Move, &UnitVector3); 2],
    frame: &StepFrame,
) -> Option<(Real, Real)> {
    let [a, b] = cuts.map(|(mv, toward)| flank_towards(chain, tool, mv, toward));
    frame.measure(&a?.plane, &b?.plane)
}
