//! `[identify]`: the faces to measure on the cut part, how points are kept for each, the
//! deviations to identify, the registration, the Monte-Carlo trials and the tolerance of the
//! model-correction loop.

use super::Ctx;
use super::SceneError;
use super::file::{FaceFile, IdentifyFile};
use crate::calibration::calibrate::Registration;
use crate::calibration::identify::{FaceKind, FaceOptions, FaceRegion, FaceSpec};
use crate::machine::chain::Chain;
use crate::math::{Aabb, Real};
use crate::metrology::fit::RobustRule;

/// Default tolerance of the model-correction loop: 0.5 µm, the accuracy the twin's faces are
/// tested to.
pub const DEFAULT_LOOP_TOLERANCE_MM: Real = 5e-4;

/// Default `[identify] margin_mm`: points kept this far inside a face's edges (mm).
const DEFAULT_MARGIN_MM: Real = 1.0;

/// Default `[identify] band_mm`: points kept within this of the expected plane (mm).
const DEFAULT_BAND_MM: Real = 2.0;

/// `[identify]`: the faces and how they are measured and identified.
pub(super) fn identify_setup(
    ctx: &Ctx,
    chain: &Chain,
    f: &IdentifyFile,
) -> Result<IdentifySetup, SceneError> {
    let faces = f.faces.get_ref();
    let general = f.parameters.is_some();
    if general && faces.is_empty() {
        return Err(ctx.err(f.faces.span(), "identify.faces is empty"));
    }
    if !general && faces.len() != 2 {
        return Err(ctx.err(
            f.faces.span(),
            format!(
                "identify.faces must list exactly two faces (cut at A = 0° and 180°), got {}",
                faces.len()
            ),
        ));
    }
    let spec = |face: &FaceFile| -> Result<FaceSpec, SceneError> {
        let region = match (&face.bbox, &face.seed) {
            (Some(_), Some(s)) => {
                return Err(ctx.err(s.span(), "a face takes a box or a seed, not both"));
            }
            (Some(b), None) => {
                let (mn, mx) = (ctx.vec3(&b.min, "box.min")?, ctx.vec3(&b.max, "box.max")?);
                if (0..3).any(|k| mx[k] <= mn[k]) {
                    return Err(ctx.err(b.max.span(), "box.max must exceed box.min on every axis"));
                }
                FaceRegion::Box(Aabb {
                    min: mn.into(),
                    max: mx.into(),
                })
            }
            (None, Some(s)) => FaceRegion::Seed(ctx.vec3(s, "seed")?.into()),
            (None, None) => FaceRegion::Auto,
        };
        let kind = match face.kind.as_ref().map(|k| (k.get_ref().as_str(), k.span())) {
            None | Some(("flank", _)) => FaceKind::Flank,
            Some(("floor", _)) => FaceKind::Floor,
            Some((other, span)) => {
                return Err(ctx.err(
                    span,
                    format!("face kind must be 'flank' or 'floor', got '{other}'"),
                ));
            }
        };
        Ok(FaceSpec {
            kind,
            name: face.name.clone(),
            line: *face.line.get_ref(),
            region,
        })
    };
    let margin = ctx.opt(&f.margin_mm, "margin_mm", DEFAULT_MARGIN_MM)?;
    let band = ctx.opt(&f.band_mm, "band_mm", DEFAULT_BAND_MM)?;
    if margin < 0.0 {
        return Err(ctx.err(
            f.margin_mm.as_ref().map_or(0..0, |m| m.span()),
            "margin_mm must not be negative",
        ));
    }
    if band <= 0.0 {
        return Err(ctx.err(
            f.band_mm.as_ref().map_or(0..0, |m| m.span()),
            "band_mm must be positive",
        ));
    }
    let mut parameters = Vec::new();
    if let Some(ps) = &f.parameters {
        // A joint deviation (`dy_AY`) or an ISO 230-7 location or squareness term (`EX0C`,
        // `EC(0X)Y`), as `[deviations]` and `known` name them; an ISO term counts once
        // under any of its names.
        let mut terms = Vec::new();
        for p in ps.get_ref() {
            let name = p.get_ref();
            if name.contains('_') {
                chain
                    .deviation_id(name)
                    .map_err(|e| ctx.err(p.span(), e.to_string()))?;
            } else {
                let term = chain
                    .iso_term_id(name)
                    .map_err(|e| ctx.err(p.span(), e.to_string()))?;
                if let Some((_, other)) = terms.iter().find(|(t, _)| *t == term) {
                    return Err(ctx.err(
                        p.span(),
                        format!("parameter '{name}' is '{other}' again (one ISO term)"),
                    ));
                }
                terms.push((term, name.clone()));
            }
            if parameters.contains(name) {
                return Err(ctx.err(p.span(), format!("parameter '{name}' given twice")));
            }
            parameters.push(name.clone());
        }
        if parameters.is_empty() {
            return Err(ctx.err(ps.span(), "identify.parameters is empty"));
        }
    }
    let registration = match f
        .registration
        .as_ref()
        .map(|r| (r.get_ref().as_str(), r.span()))
    {
        None | Some(("estimate", _)) => Registration::Estimate,
        Some(("workpiece", _)) => Registration::Workpiece,
        Some((other, span)) => {
            return Err(ctx.err(
                span,
                format!("registration must be 'estimate' or 'workpiece', got '{other}'"),
            ));
        }
    };
    let (monte_carlo_trials, monte_carlo_seed) = match &f.monte_carlo {
        Some(m) if *m.trials.get_ref() > 10_000 => {
            return Err(ctx.err(m.trials.span(), "monte_carlo.trials must be at most 10000"));
        }
        Some(m) => (*m.trials.get_ref(), m.seed.unwrap_or(1)),
        None => (0, 1),
    };
    let loop_tolerance_mm = match &f.loop_tolerance_mm {
        Some(v) => ctx.positive(v, "loop_tolerance_mm")?,
        None => DEFAULT_LOOP_TOLERANCE_MM,
    };
    Ok(IdentifySetup {
        faces: faces.iter().map(spec).collect::<Result<_, _>>()?,
        parameters,
        registration,
        monte_carlo_trials,
        monte_carlo_seed,
        loop_tolerance_mm,
        face_options: FaceOptions {
            margin_mm: margin,
            band_mm: band,
            robust: RobustRule::default(),
        },
    })
}

/// What `[identify]` sets, or its defaults when the scene has none (no faces).
pub(super) struct IdentifySetup {
    pub faces: Vec<FaceSpec>,
    pub parameters: Vec<String>,
    pub registration: Registration,
    pub monte_carlo_trials: usize,
    pub monte_carlo_seed: u64,
    pub loop_tolerance_mm: Real,
    pub face_options: FaceOptions,
}

impl IdentifySetup {
    pub(super) fn none() -> Self {
        IdentifySetup {
            faces: Vec::new(),
            parameters: Vec::new(),
            registration: Registration::Estimate,
            monte_carlo_trials: 0,
            monte_carlo_seed: 1,
            loop_tolerance_mm: DEFAULT_LOOP_TOLERANCE_MM,
            face_options: FaceOptions {
                margin_mm: DEFAULT_MARGIN_MM,
                band_mm: DEFAULT_BAND_MM,
                robust: RobustRule::default(),
            },
        }
    }
}
