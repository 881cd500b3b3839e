//! The 0°/180° step identification on [`crate::calibration::engine`]: from two faces cut
//! 180° apart about one rotary axis ([`crate::calibration::identify`] finds and fits them),
//! the rotary joint's offset along the faces' normal and the angle sum their relative tilt
//! sees (dy_AY and gamma_AY + gamma_YX for seed 002's A axis;
//! docs/identification-and-correction.md).
//!
//! **The model.** Each face's fitted plane, placed in the step's frame (its offset along
//! the first face's model normal `n` on the line through the faces' midpoint, and its
//! normal's component along the cut direction `u`), is one block of two observations named
//! by the face and its NC line; the exact chain predicts both faces' flank planes with the
//! joint's offset and angle as the parameters, every other deviation at its known value.
//! The scan's placement the two faces share — a shift along `n` and a turn about the tool
//! axis — are nuisance unknowns, so only the step (the offsets' difference: to first order
//! −2·dy_AY, seed 002 eq. 6, 7) and the relative tilt (2·(gamma_AY + gamma_YX)) inform the
//! joint: four observations, four unknowns, matched exactly.
//!
//! **Which parameters.** The offset the step is most sensitive to and the angle the tilt is
//! most sensitive to, by central differences on the model. When no angle of the joint tilts
//! the faces apart about the tool axis — the rotary axis parallel to it, a C table under a
//! vertical spindle — the offset is solved from the step alone, every angle held and
//! reported not identified, saying why; the relative tilt is then a degree of freedom of the
//! engine's goodness of fit. The engine's identifiability report decides what is determined
//! (σ below a tenth of the realistic magnitude); nothing else is given a value, and every
//! other deviation is reported as not observable from this experiment.
//!
//! **Invariant:** reads fitted faces and the program's moves; never runs the sweep or the
//! scanner, never opens files.

use crate::calibration::calibrate::{ANGLE_MAGNITUDE_RAD, OFFSET_MAGNITUDE_MM, magnitude};
use crate::calibration::engine::{self, Block, Forward, Problem, Unknown};
use crate::calibration::goodness::{FitCheck, RankMargin};
use crate::calibration::identify::{Face, IdentifyError, StepFrame, flank_towards};
use crate::cutting::tool::Tool;
use crate::machine::chain::{AxisKind, Chain, Component, DeviationId};
use crate::math::{Point3, Real, UnitVector3, tol};
use crate::nc::Move;
use nalgebra::Vector2;

/// Outcome of the identification.
#[derive(Clone, Debug, PartialEq)]
pub struct StepIdentification {
    /// The measurement frame.
    pub frame: StepFrame,
    /// Measured step (mm): second face minus first, along the first face's normal.
    pub step_mm: Real,
    /// Its standard uncertainty from the fits (mm).
    pub step_sigma_mm: Real,
    /// Measured tilt (rad).
    pub tilt_rad: Real,
    /// Its standard uncertainty (rad).
    pub tilt_sigma_rad: Real,
    /// Name and value of the offset parameter (e.g. `dy_AY`, mm), if identifiable.
    pub offset: Option<(String, Real, Real)>,
    /// Name and value of the angle sum (e.g. `gamma_AY+gamma_YX`, rad), if identifiable.
    pub angle_sum: Option<(String, Real, Real)>,
    /// Name of the offset parameter solved for (e.g. `dy_AY`).
    pub offset_name: String,
    /// Name of the angle combination solved for (e.g. `gamma_AY+gamma_YX`).
    pub angle_name: String,
    /// Singular values (descending; 0 where fewer were solved) of the engine's whitened
    /// Jacobian of the faces' offsets and tilts, the parameters scaled by their realistic
    /// magnitudes and the scan's placement projected out: what decided the rank.
    pub singular_values: [Real; 2],
    /// How clearly the rank was decided (the engine's cut: σ a tenth of the realistic
    /// magnitude).
    pub margin: RankMargin,
    /// The engine's model evaluations, and the norm of the (step, tilt) residual at the
    /// solution (the step's alone when the tilt sees no angle).
    pub solver: (usize, Real),
    /// The engine's goodness of fit, face by face: with the offset and the angle solved it
    /// has no degree of freedom (the faces' shapes are judged by [`faces_fit`]); with the
    /// offset alone, the relative tilt the model leaves is judged against its σ.
    ///
    /// [`faces_fit`]: crate::calibration::identify::faces_fit
    pub fit: FitCheck,
    /// Deviation names this experiment does not identify (alone or separably): held at
    /// their known values (0 unless the scene gives them), never given a value.
    pub not_identified: Vec<String>,
    /// Why the offset or the angle combination was not identified, one sentence each
    /// (empty when both were).
    pub why_not: Vec<String>,
}

/// The step model on [`crate::calibration::engine`]: each face's plane as the exact chain
/// puts it, measured in the frame (its offset along `n` on the line through `at`, and its
/// normal's component along `u`), with the rotary joint's solved deviations set to the
/// unknowns; every other deviation at its known value. The two nuisance unknowns are the
/// scan's placement the faces share — a shift along `n` and a turn about the tool axis,
/// added to both faces alike — so only the step and the relative tilt inform the joint.
struct StepForward<'a> {
    model: &'a Chain,
    /// The solved deviations (the offset, then the angle when the tilt sees one).
    ids: Vec<DeviationId>,
    cuts: [&'a Move; 2],
    /// The faces' model normals: which flank of each cut is its face, on any chain.
    toward: [UnitVector3; 2],
    tool: &'a Tool,
    frame: StepFrame,
}

impl Forward for StepForward<'_> {
    fn predict(&self, x: &[Real]) -> Result<Vec<Real>, String> {
        let mut chain = self.model.clone();
        for (id, v) in self.ids.iter().zip(x) {
            chain.set_deviation(*id, *v);
        }
        let (shift, turn) = (x[self.ids.len()], x[self.ids.len() + 1]);
        let mut out = Vec::with_capacity(4);
        for k in 0..2 {
            let f = flank_towards(&chain, self.tool, self.cuts[k], &self.toward[k])
                .ok_or("the model faces are degenerate")?;
            let (offset, slope) = self
                .frame
                .place(&f.plane)
                .ok_or("a model face is parallel to the direction of measurement")?;
            out.extend([offset + shift, slope + turn]);
        }
        Ok(out)
    }
}

/// A face's offset and slope uncertainties below these are the rounding of an exact
/// simulation (a scan without noise), not a measurement: floored there so that the
/// engine's whitening stays finite (1 pm and 1 nrad, far below anything measured).
const FACE_SIGMA_FLOOR: Real = tol::LENGTH_EPS;

/// Relative size below which the faces' relative tilt counts as seeing no angle of the
/// joint, against the step's sensitivity to the offset (both in their own units per unit
/// deviation): a rotary axis parallel to the tool axis turns both faces alike.
pub const IDENTIFIABLE_RATIO: Real = 1e-8;

/// Identifies the rotary axis's offset and the angle sum from two faces cut 180° apart.
pub fn identify_step(
    faces: &[Face; 2],
    model: &Chain,
    tool: &Tool,
) -> Result<StepIdentification, IdentifyError> {
    let [f0, f1] = faces;
    // The rotary axis whose position differs by 180° between the cuts.
    let rotaries: Vec<(usize, char)> = model
        .axes()
        .iter()
        .enumerate()
        .filter(|(_, a)| a.kind == AxisKind::Rotary)
        .map(|(j, a)| (j, a.letter.as_char()))
        .collect();
    let mut turned = Vec::new();
    for (k, &(joint, letter)) in rotaries.iter().enumerate() {
        let diff = (f1.rotary_deg[k] - f0.rotary_deg[k]).rem_euclid(360.0);
        if (diff - 180.0).abs() < tol::ANGLE_DEG {
            turned.push((joint, letter));
        } else if diff.abs() > tol::ANGLE_DEG && (diff - 360.0).abs() > tol::ANGLE_DEG {
            return Err(IdentifyError::NotAStepPair(format!(
                "axis {letter} differs by {diff}° between '{}' and '{}'",
                f0.name, f1.name
            )));
        }
    }
    let [(joint, _)] = turned[..] else {
        return Err(IdentifyError::NotAStepPair(format!(
            "{} rotary axes differ by 180° between '{}' and '{}'",
            turned.len(),
            f0.name,
            f1.name
        )));
    };
    let frame = StepFrame {
        at: Point3::from((f0.fit.centroid.coords + f1.fit.centroid.coords) / 2.0),
        n: f0.flank.plane.normal,
        u: f0.flank.u,
    };
    let (step, tilt) = frame.measure(&f0.fit.plane, &f1.fit.plane).ok_or_else(|| {
        IdentifyError::NotAStepPair("the fitted faces are perpendicular to each other".into())
    })?;
    // Uncertainties at the point of measurement, not at each face's centroid: the faces'
    // tilts act over the lever arm from their centroids to `at`.
    let step_sigma = f0
        .design
        .offset_sigma_at(&f0.fit.centroid, &frame.at)
        .hypot(f1.design.offset_sigma_at(&f1.fit.centroid, &frame.at));
    let tilt_sigma = f0
        .design
        .slope_sigma_along_cut()
        .hypot(f1.design.slope_sigma_along_cut());
    let cuts = [&f0.cut, &f1.cut];
    let toward = [f0.flank.plane.normal, f1.flank.plane.normal];
    // The parameters: of the rotary axis's joint, the offset the step sees most (its line's
    // offset along the faces' normal: dy_AY for seed 002) and the angle the faces' relative
    // tilt about the tool axis sees most (gamma_AY), by central differences on the model.
    let slope = |component: Component| -> Option<Vector2<Real>> {
        let id = DeviationId { joint, component };
        let h = if component.is_angle() { 1e-6 } else { 1e-4 };
        let at = |d: Real| {
            let mut chain = model.clone();
            chain.set_deviation(id, model.deviation(id) + d);
            let [a, b] = [0, 1].map(|k| flank_towards(&chain, tool, cuts[k], &toward[k]));
            frame.measure(&a?.plane, &b?.plane)
        };
        let (p, m) = (at(h)?, at(-h)?);
        Some(Vector2::new(p.0 - m.0, p.1 - m.1) / (2.0 * h))
    };
    let degenerate = || IdentifyError::NotAStepPair("the model faces are degenerate".into());
    let pick = |components: [Component; 3], k: usize| {
        let mut best = (components[0], Vector2::<Real>::zeros());
        for c in components {
            let j = slope(c).ok_or_else(degenerate)?;
            if j[k].abs() > best.1[k].abs() {
                best = (c, j);
            }
        }
        Ok::<_, IdentifyError>(best)
    };
    let (offset_c, j_offset) = pick([Component::Dx, Component::Dy, Component::Dz], 0)?;
    let (angle_c, j_angle) = pick([Component::Alpha, Component::Beta, Component::Gamma], 1)?;
    let ids = [
        DeviationId {
            joint,
            component: offset_c,
        },
        DeviationId {
            joint,
            component: angle_c,
        },
    ];
    // No angle of the joint turns the faces apart about the tool axis (the rotary axis is
    // parallel to it: a C table under a vertical spindle): the tilt carries no information
    // on the joint, and the offset is found from the step alone.
    let no_angle = j_angle[1].abs() <= IDENTIFIABLE_RATIO * j_offset[0].abs();
    let joint_next = model.joint_name(joint + 1).to_string();
    let offset_name = model.deviation_name(ids[0]);
    let angle_name = if joint + 1 < model.axes().len() {
        format!(
            "{}+{}_{joint_next}",
            model.deviation_name(ids[1]),
            angle_c.prefix()
        )
    } else {
        model.deviation_name(ids[1])
    };
    let mut observed = vec![offset_name.clone()];
    if !no_angle {
        observed.push(model.deviation_name(ids[1]));
        if joint + 1 < model.axes().len() {
            observed.push(format!("{}_{joint_next}", angle_c.prefix()));
        }
    }
    let not_identified = model
        .deviation_names()
        .into_iter()
        .filter(|n| !observed.contains(n))
        .collect();
    let axis = model.axes()[joint].letter.as_char();
    // The engine's problem: the joint's solved deviations from their known values, the
    // scan's shared placement as nuisance, one block a face.
    let solved: Vec<DeviationId> = if no_angle { vec![ids[0]] } else { ids.to_vec() };
    let forward = StepForward {
        model,
        ids: solved.clone(),
        cuts,
        toward,
        tool,
        frame,
    };
    let parameters = solved
        .iter()
        .map(|&id| Unknown {
            name: model.deviation_name(id),
            start: model.deviation(id),
            magnitude: magnitude(id),
        })
        .collect();
    let nuisance = vec![
        Unknown {
            name: "the scan's shift along the faces' normal".into(),
            start: 0.0,
            magnitude: OFFSET_MAGNITUDE_MM,
        },
        Unknown {
            name: "the scan's turn about the tool axis".into(),
            start: 0.0,
            magnitude: ANGLE_MAGNITUDE_RAD,
        },
    ];
    // Uncertainties at the point of measurement, as the step's and the tilt's.
    let blocks = faces
        .iter()
        .map(|f| {
            let (offset, slope) = frame.place(&f.fit.plane).ok_or_else(|| {
                IdentifyError::NotAStepPair(format!(
                    "face '{}' is parallel to the direction of measurement",
                    f.name
                ))
            })?;
            Ok(Block {
                name: format!("face '{}' (NC line {})", f.name, f.cut.line),
                values: vec![offset, slope],
                sigma: vec![
                    f.design
                        .offset_sigma_at(&f.fit.centroid, &frame.at)
                        .max(FACE_SIGMA_FLOOR),
                    f.design.slope_sigma_along_cut().max(FACE_SIGMA_FLOOR),
                ],
            })
        })
        .collect::<Result<Vec<_>, IdentifyError>>()?;
    let measured: Vec<Real> = blocks.iter().flat_map(|b| b.values.clone()).collect();
    let problem = Problem {
        parameters,
        nuisance,
        blocks,
        forward: &forward,
        statistic: "faces' offsets and tilts in the step's frame".into(),
    };
    let outcome = engine::solve(&problem).map_err(|e| IdentifyError::Solve(e.to_string()))?;
    let ident = &outcome.identifiability;
    let estimate = |name: &str| outcome.parameters.iter().find(|e| e.name == name);
    let angle_next = if joint + 1 < model.axes().len() {
        model.deviation(DeviationId {
            joint: joint + 1,
            component: angle_c,
        })
    } else {
        0.0
    };
    let offset = estimate(&offset_name).map(|e| (offset_name.clone(), e.value, e.sigma));
    let angle_sum = if no_angle {
        None
    } else {
        estimate(&model.deviation_name(ids[1]))
            .map(|e| (angle_name.clone(), e.value + angle_next, e.sigma))
    };
    let sv = &ident.singular_values;
    let singular_values = [0, 1].map(|k| sv.get(k).copied().unwrap_or(0.0));
    let svs = sv
        .iter()
        .map(|s| format!("{s:.3e}"))
        .collect::<Vec<_>>()
        .join(", ");
    let mut why_not = Vec::new();
    if no_angle {
        why_not.push(format!(
            "no angle of joint {} turns the faces apart about the tool axis (the {axis} axis is parallel to it, so a rotation about it turns both faces alike): their relative tilt determines none, and {offset_name} is found from the step alone, every angle held at its known value",
            model.joint_name(joint)
        ));
    }
    let missing: Vec<&String> = [
        (&offset_name, offset.is_none()),
        (&angle_name, !no_angle && angle_sum.is_none()),
    ]
    .into_iter()
    .filter_map(|(n, m)| m.then_some(n))
    .collect();
    match missing[..] {
        [] => {}
        [a, b] if ident.rank == 1 => why_not.push(format!(
            "the step and the faces' relative tilt depend on {a} and {b} only together (singular values {svs}): neither is determined"
        )),
        _ => {
            for n in &missing {
                why_not.push(format!(
                    "the step and the faces' relative tilt do not determine {n} to a tenth of its realistic size (singular values {svs}): held at its known value"
                ));
            }
        }
    }
    // The (step, tilt) residual at the solution: the faces' residuals' differences (the
    // scan's placement cancels).
    let x: Vec<Real> = outcome
        .solution
        .iter()
        .chain(&outcome.nuisance)
        .copied()
        .collect();
    let residual = forward
        .predict(&x)
        .map(|p| {
            let r: Vec<Real> = p.iter().zip(&measured).map(|(p, m)| p - m).collect();
            let (step_r, tilt_r) = (r[2] - r[0], r[3] - r[1]);
            if no_angle {
                step_r.abs()
            } else {
                step_r.hypot(tilt_r)
            }
        })
        .unwrap_or(Real::NAN);
    Ok(StepIdentification {
        frame,
        step_mm: step,
        step_sigma_mm: step_sigma,
        tilt_rad: tilt,
        tilt_sigma_rad: tilt_sigma,
        offset,
        angle_sum,
        offset_name,
        angle_name,
        singular_values,
        margin: ident.margin,
        solver: (outcome.evaluations, residual),
        fit: outcome.fit,
        not_identified,
        why_not,
    })
}
