//! `[scanner]`, the virtual scanner that measures the cut part (with the defaults of an
//! EinScan-SP class instrument), and `[study]`, the scanner-effects study.

use super::Ctx;
use super::SceneError;
use super::file::{ScannerFile, StudyFile};
use crate::math::{Real, UnitVector3, tol};
use crate::metrology::scan::{Misregistration, ScanError, ScannerConfig, StudyOptions, Turntable};
use toml::Spanned;

/// `[scanner]`: the virtual scanner, with the defaults of an EinScan-SP class instrument.
pub(super) fn scanner_config(ctx: &Ctx, s: &ScannerFile) -> Result<ScannerConfig, SceneError> {
    let fov = match &s.fov_mm {
        Some(f) => (f.get_ref()[0], f.get_ref()[1]),
        None => (200.0, 150.0),
    };
    let scanner = ScannerConfig {
        position: ctx.vec3(&s.position, "position")?.into(),
        target: ctx.vec3(&s.target, "target")?.into(),
        up: ctx.vec3(&s.up, "up")?,
        baseline_mm: ctx.opt(&s.baseline_mm, "baseline_mm", 100.0)?,
        fov_mm: fov,
        pitch_mm: ctx.opt(&s.pitch_mm, "pitch_mm", 0.185)?,
        noise_sigma_mm: ctx.opt(&s.noise_sigma_mm, "noise_sigma_mm", 0.025)?,
        noise_correlation_mm: ctx.opt(&s.noise_correlation_mm, "noise_correlation_mm", 0.0)?,
        working_range_mm: match &s.working_range_mm {
            Some(r) => (r.get_ref()[0], r.get_ref()[1]),
            None => (290.0, 480.0),
        },
        grazing_limit_deg: ctx.opt(&s.grazing_limit_deg, "grazing_limit_deg", 80.0)?,
        misregistration: match &s.misregistration {
            Some(m) => Misregistration {
                translation_sigma_mm: ctx.opt(
                    &m.translation_sigma_mm,
                    "translation_sigma_mm",
                    0.0,
                )?,
                rotation_sigma_rad: ctx.opt(&m.rotation_sigma_rad, "rotation_sigma_rad", 0.0)?,
            },
            None => Misregistration::default(),
        },
        turntable: match &s.turntable {
            Some(t) => Some(Turntable {
                axis_point: ctx.vec3(&t.axis_point, "axis_point")?.into(),
                axis: UnitVector3::try_new(ctx.vec3(&t.axis, "axis")?, tol::LENGTH_EPS)
                    .ok_or_else(|| ctx.err(t.axis.span(), "turntable axis must not be zero"))?,
                angles_deg: t.angles_deg.get_ref().clone(),
            }),
            None => None,
        },
        seed: s.seed.unwrap_or(1),
    };
    scanner.validate().map_err(|e| {
        let span = match &e {
            ScanError::BadConfig { field, .. } => match *field {
                "position" => s.position.span(),
                "target" => s.target.span(),
                "up" => s.up.span(),
                "pitch_mm" => s.pitch_mm.as_ref().map_or(s.position.span(), |v| v.span()),
                "fov_mm" => s.fov_mm.as_ref().map_or(s.position.span(), |v| v.span()),
                "noise_sigma_mm" => s
                    .noise_sigma_mm
                    .as_ref()
                    .map_or(s.position.span(), |v| v.span()),
                "noise_correlation_mm" => s
                    .noise_correlation_mm
                    .as_ref()
                    .map_or(s.position.span(), |v| v.span()),
                "working_range_mm" => s
                    .working_range_mm
                    .as_ref()
                    .map_or(s.position.span(), |v| v.span()),
                "grazing_limit_deg" => s
                    .grazing_limit_deg
                    .as_ref()
                    .map_or(s.position.span(), |v| v.span()),
                "turntable" => s
                    .turntable
                    .as_ref()
                    .map_or(s.position.span(), |t| t.angles_deg.span()),
                "misregistration" => s
                    .misregistration
                    .as_ref()
                    .and_then(|m| {
                        m.translation_sigma_mm
                            .as_ref()
                            .or(m.rotation_sigma_rad.as_ref())
                    })
                    .map_or(s.position.span(), |v| v.span()),
                _ => s.position.span(),
            },
            ScanError::TooManyRays { .. } => {
                s.pitch_mm.as_ref().map_or(s.position.span(), |v| v.span())
            }
        };
        ctx.err(span, e.to_string())
    })?;
    Ok(scanner)
}

/// `[study]`, or its defaults: 20 trials, 0.5 mm noise correlation, 0.02 mm and 5e-5 rad
/// misregistration.
pub(super) fn study_options(ctx: &Ctx, f: Option<&StudyFile>) -> Result<StudyOptions, SceneError> {
    let pick = |v: Option<&Spanned<Real>>, what: &str, default: Real| -> Result<Real, SceneError> {
        match v {
            Some(v) => {
                let x = ctx.finite(v, what)?;
                if x < 0.0 {
                    return Err(ctx.err(v.span(), format!("{what} must not be negative")));
                }
                Ok(x)
            }
            None => Ok(default),
        }
    };
    let trials = match f.and_then(|f| f.trials.as_ref()) {
        Some(t) if *t.get_ref() == 0 || *t.get_ref() > 10_000 => {
            return Err(ctx.err(t.span(), "study trials must be 1 to 10000"));
        }
        Some(t) => *t.get_ref(),
        None => 20,
    };
    Ok(StudyOptions {
        trials,
        correlation_mm: pick(
            f.and_then(|f| f.correlation_mm.as_ref()),
            "correlation_mm",
            0.5,
        )?,
        translation_sigma_mm: pick(
            f.and_then(|f| f.translation_sigma_mm.as_ref()),
            "translation_sigma_mm",
            0.02,
        )?,
        rotation_sigma_rad: pick(
            f.and_then(|f| f.rotation_sigma_rad.as_ref()),
            "rotation_sigma_rad",
            5e-5,
        )?,
    })
}
