//! `identify`: general identification of the scene's `[identify] parameters` from its
//! faces, in a simulated scan or a given cloud, with the model-correction loop and
//! Monte-Carlo trials over scanner noise.

use super::{PipelineError, machine_part, scan_noise};
use crate::calibration::calibrate::{
    CalibrateError, Feature, Identification, IsoTerm, Model, PlaneFeature, Registration,
    face_rms_parts, plane_feature, predicted_plane, select_plane_face,
};
use crate::calibration::design::kind_name;
use crate::calibration::goodness::ScanNoise;
use crate::calibration::identify::check_cut;
use crate::cutting::stock::TriDexel;
use crate::machine::chain::{Chain, DeviationId};
use crate::math::{Point3, Real};
use crate::metrology::cloud::PointCloud;
use crate::metrology::scan::Surface;
use crate::nc::Program;
use crate::progress::Progress;
use crate::report::{
    EstimateReport, FeatureReport, IdentifyReport, IdentifySolverReport, LoopRound,
};
use crate::scene::{Need, Scene};
use std::collections::BTreeMap;
use std::time::Instant;

/// Everything `identify_scene` produces.
#[derive(Clone, Debug)]
pub struct IdentifyOutcome {
    /// The report.
    pub report: IdentifyReport,
    /// The cloud the features were measured in.
    pub cloud: PointCloud,
    /// The faces measured in it, as the identification used them.
    pub features: Vec<Feature>,
    /// The final identification (last loop round).
    pub identification: Identification,
    /// The twin after the loop: the model chain with the determined directions updated.
    pub twin: Chain,
}

/// Most rounds of the model-correction loop: the solve converges in one; a second confirms.
const MAX_ROUNDS: usize = 5;

/// Measures every face of the scene in `points` as a plane feature. With `cut`, the stock
/// the cloud was scanned from, a face is measured only if its cut left its surface inside
/// the face's region ([`check_cut`]); every face is checked before any is fitted.
pub fn extract_features(
    scene: &Scene,
    program: &Program,
    points: &[Point3],
    cut: Option<&TriDexel>,
) -> Result<Vec<Feature>, PipelineError> {
    let err = |source| PipelineError::Calibrate {
        path: scene.path.display().to_string(),
        source,
    };
    let selected = scene
        .faces
        .iter()
        .map(|spec| {
            select_plane_face(
                points,
                spec,
                &program.moves,
                scene.model(),
                &scene.tool,
                &scene.stock_box,
                &scene.face_options,
            )
            .map_err(err)
        })
        .collect::<Result<Vec<_>, _>>()?;
    if let Some(stock) = cut {
        for sel in &selected {
            check_cut(sel, points, stock).map_err(|e| err(e.into()))?;
        }
    }
    selected
        .iter()
        .map(|sel| {
            plane_feature(points, sel, scene.model(), &scene.tool, &scene.face_options)
                .map(Feature::Plane)
                .map_err(err)
        })
        .collect()
}

/// The scene's `[identify] parameters` on its model: the joint deviations (`dy_AY`), then
/// the ISO location and squareness terms (`EX0C`, `EC(0X)Y`), each one parameter.
fn scene_params(scene: &Scene) -> Result<(Vec<DeviationId>, Vec<IsoTerm>), PipelineError> {
    let err = |source| PipelineError::Calibrate {
        path: scene.path.display().to_string(),
        source,
    };
    if scene.parameters.is_empty() {
        return Err(err(CalibrateError::NoParameters));
    }
    let (joints, iso): (Vec<&String>, Vec<&String>) =
        scene.parameters.iter().partition(|n| n.contains('_'));
    let ids = joints
        .iter()
        .filter_map(|n| scene.model().deviation_id(n).ok())
        .collect();
    let terms = iso
        .iter()
        .filter_map(|n| IsoTerm::parse(scene.model(), n).ok())
        .collect();
    Ok((ids, terms))
}

/// The value of the ISO term `term` in `values` (deviations by name, as a scene writes
/// them), under any of its names; zero when absent.
pub(crate) fn iso_value(chain: &Chain, values: &BTreeMap<String, Real>, term: &IsoTerm) -> Real {
    values
        .iter()
        .filter(|(n, _)| !n.contains('_'))
        .filter(|(n, _)| {
            chain
                .iso_term_id(n)
                .is_ok_and(|(a, c)| a == term.axis && c == term.component)
        })
        .map(|(_, v)| *v)
        .sum()
}

/// How far the twin's faces are from the measured ones: for each plane feature, the largest
/// distance (mm) between its predicted plane on `twin` (mapped by the registration) and the
/// measured plane, taken at the centroid and at the four corners of the face's extent (so a
/// tilt mismatch counts, not only an offset), minus what the scan's noise allows there.
/// Returns the worst distance and whether every face is within `tolerance_mm` or its noise.
///
/// The extent comes from the fit's design: the in-plane second moments are
/// `σ_off² · WᵀW` (`W` the slope whitening, `σ_off` the offset uncertainty), and a uniform
/// face of half-width `a` has variance `a²/3`. At a corner the measured plane's uncertainty
/// is `σ_off·√7` (offset plus the two slopes, each `3σ_off²` there), so a face is matched
/// when it agrees within `max(tolerance_mm, 3·√7·σ_off)`.
fn face_match(
    twin: &Chain,
    tool: &crate::cutting::tool::Tool,
    features: &[Feature],
    reg: &[Real; 6],
    tolerance_mm: Real,
) -> (Real, bool) {
    let s_from_w = crate::machine::chain::Deviation { values: *reg }.transform();
    let mut worst: Real = 0.0;
    let mut all = true;
    for f in features {
        let Feature::Plane(p) = f else {
            continue;
        };
        let Some(pl) = predicted_plane(twin, tool, p) else {
            return (Real::INFINITY, false);
        };
        let n = s_from_w.rotation * pl.normal.into_inner();
        let d = pl.offset + n.dot(&s_from_w.translation.vector);
        let moments = p.slope_whitening.transpose()
            * p.slope_whitening
            * (p.offset_sigma_mm * p.offset_sigma_mm);
        let half = [0, 1].map(|i| (3.0 * moments[(i, i)]).max(0.0).sqrt());
        let mut far: Real = 0.0;
        for (su, sv) in [
            (0.0, 0.0),
            (1.0, 1.0),
            (1.0, -1.0),
            (-1.0, 1.0),
            (-1.0, -1.0),
        ] {
            let q = p.centroid
                + p.basis[0].into_inner() * (su * half[0])
                + p.basis[1].into_inner() * (sv * half[1]);
            let q = p.plane.project(&q);
            far = far.max((n.dot(&q.coords) - d).abs());
        }
        worst = worst.max(far);
        all &= far <= tolerance_mm.max(3.0 * 7.0_f64.sqrt() * p.offset_sigma_mm);
    }
    (worst, all)
}

/// The model-correction loop on measured features: identify → update the twin → compare
/// its predicted faces with the measured ones over each face's extent (`face_match`) →
/// repeat, re-identifying from the updated twin, until every face agrees within
/// `tolerance_mm` or what its scan noise allows (a twin cannot match noise better than the
/// noise).
///
/// Each round's goodness of fit accounts for the views `scan` merged the cloud from
/// ([`crate::calibration::calibrate::feature_fit`]); the caller judges the last.
pub fn correction_loop(
    model: &Chain,
    ids: &[DeviationId],
    tool: &crate::cutting::tool::Tool,
    features: &[Feature],
    registration: Registration,
    tolerance_mm: Real,
    scan: Option<&ScanNoise>,
) -> Result<(Identification, Chain, Vec<LoopRound>, bool), CalibrateError> {
    correction_loop_terms(
        model,
        ids,
        &[],
        tool,
        features,
        registration,
        tolerance_mm,
        scan,
    )
}

/// [`correction_loop`] identifying the ISO location and squareness terms `iso` too, each
/// one parameter (not the joint values it composes onto), given with its value in `model`
/// (the prior: `[identify] known`, else zero). The solve takes an ISO term on top of the
/// chain's values, so each round's increment is composed onto the twin
/// ([`Chain::apply_iso_term`]) and the reported values and solution are the prior plus the
/// increments so far.
#[expect(
    clippy::too_many_arguments,
    reason = "correction_loop's arguments and the ISO terms with their priors"
)]
pub fn correction_loop_terms(
    model: &Chain,
    ids: &[DeviationId],
    iso: &[(IsoTerm, Real)],
    tool: &crate::cutting::tool::Tool,
    features: &[Feature],
    registration: Registration,
    tolerance_mm: Real,
    scan: Option<&ScanNoise>,
) -> Result<(Identification, Chain, Vec<LoopRound>, bool), CalibrateError> {
    let mut twin = model.clone();
    let mut rounds = Vec::new();
    let mut last = None;
    let mut converged = false;
    let terms: Vec<IsoTerm> = iso.iter().map(|(t, _)| t.clone()).collect();
    let mut total: Vec<Real> = iso.iter().map(|(_, v)| *v).collect();
    for round in 1..=MAX_ROUNDS {
        let m = Model {
            chain: &twin,
            ids,
            iso_terms: &terms,
            tool,
            features,
            registration,
        };
        let mut ident = crate::calibration::calibrate::identify_with(&m, scan)?;
        for (id, v) in ids.iter().zip(&ident.solution) {
            twin.set_deviation(*id, *v);
        }
        // The ISO terms' values so far: before this round (`total`) plus its increments.
        let before: Vec<Real> = ids
            .iter()
            .map(|_| 0.0)
            .chain(total.iter().copied())
            .collect();
        for (k, t) in terms.iter().enumerate() {
            let step = ident.solution[ids.len() + k];
            twin.apply_identified_term(&t.name, step)
                .map_err(|e| CalibrateError::Parameter(e.to_string()))?;
            total[k] += step;
        }
        for e in ident.parameters.iter_mut().chain(&mut ident.combinations) {
            e.value += e
                .coefficients
                .iter()
                .zip(&before)
                .map(|(c, b)| c * b)
                .sum::<Real>();
        }
        for (x, b) in ident.solution.iter_mut().zip(&before) {
            *x += b;
        }
        let (worst, matched) = face_match(&twin, tool, features, &ident.registration, tolerance_mm);
        rounds.push(LoopRound {
            round,
            worst_face_mm: worst,
            chi2: ident.solver.chi2,
        });
        last = Some(ident);
        if matched {
            converged = true;
            break;
        }
    }
    let ident = last.ok_or(CalibrateError::NoFeatures)?;
    Ok((ident, twin, rounds, converged))
}

fn feature_report(f: &Feature, residuals: [Real; 3]) -> FeatureReport {
    match f {
        Feature::Plane(p) => plane_feature_report(p, residuals),
        Feature::Ball(b) => FeatureReport {
            name: b.name.clone(),
            kind: "ball".into(),
            line: 0,
            points: 1,
            rms_mm: 0.0,
            normal: [0.0; 3],
            centroid_mm: [b.measured.x, b.measured.y, b.measured.z],
            offset_sigma_mm: b.sigma_mm[0],
            residuals,
        },
    }
}

fn plane_feature_report(p: &PlaneFeature, residuals: [Real; 3]) -> FeatureReport {
    let n = p.plane.normal;
    FeatureReport {
        name: p.name.clone(),
        kind: kind_name(p.kind).into(),
        line: p.cut.line,
        points: p.points,
        rms_mm: p.rms_mm,
        normal: [n.x, n.y, n.z],
        centroid_mm: [p.centroid.x, p.centroid.y, p.centroid.z],
        offset_sigma_mm: p.offset_sigma_mm,
        residuals,
    }
}

/// The part's points: the given cloud, or the scene's program cut on its machine and
/// scanned by its scanner; with the source's name, and for a simulated scan its surface and
/// cut stock.
#[allow(clippy::type_complexity)]
fn scanned_part(
    scene: &Scene,
    program: &Program,
    cloud: Option<(&PointCloud, &str)>,
    progress: &dyn Progress,
) -> Result<(PointCloud, String, Option<Surface>, Option<TriDexel>), PipelineError> {
    Ok(match cloud {
        Some((c, src)) => (c.clone(), src.to_string(), None, None),
        None => {
            let scanner = scene.scanner_for("identify")?;
            let part = machine_part(scene, program, progress)?;
            let surface = Surface::new(&part.stock);
            let scanned =
                surface
                    .scan(scanner, progress)
                    .map_err(|source| PipelineError::Scan {
                        path: scene.path.display().to_string(),
                        source,
                    })?;
            (
                scanned.cloud,
                "simulated scan".to_string(),
                Some(surface),
                Some(part.stock),
            )
        }
    })
}

/// The faces of the part the scene's program cuts, as plane features: from `cloud` (a
/// measured part) or the scene's simulated scan; with the source's name.
pub fn part_faces(
    scene: &Scene,
    program: &Program,
    cloud: Option<(&PointCloud, &str)>,
    progress: &dyn Progress,
) -> Result<(Vec<Feature>, String), PipelineError> {
    let (cloud, source, _, stock) = scanned_part(scene, program, cloud, progress)?;
    let features = extract_features(scene, program, &cloud.points, stock.as_ref())?;
    Ok((features, source))
}

/// General identification of the scene's `[identify] parameters` from its faces: in the
/// scene's simulated scan, or in `cloud` (a real scan, `source` naming it); with the
/// model-correction loop, and Monte-Carlo trials over scanner noise (simulated scans only;
/// `monte_carlo` overrides the scene's trial count).
pub fn identify_scene(
    scene: &Scene,
    program: &Program,
    cloud: Option<(&PointCloud, &str)>,
    monte_carlo: Option<usize>,
    progress: &dyn Progress,
) -> Result<IdentifyOutcome, PipelineError> {
    let spath = scene.path.display().to_string();
    let cal = |source| PipelineError::Calibrate {
        path: spath.clone(),
        source,
    };
    // A simulated scan (and Monte Carlo over its noise) needs the scanner; a cloud does not.
    match cloud {
        Some(_) => scene.require("identify", &[Need::Parameters])?,
        None => scene.require("identify", &[Need::Parameters, Need::Scanner])?,
    }
    let (ids, terms) = scene_params(scene)?;
    let iso: Vec<(IsoTerm, Real)> = terms
        .iter()
        .map(|t| (t.clone(), iso_value(scene.model(), scene.known(), t)))
        .collect();
    let mut timings = Vec::new();
    let mut clock = Instant::now();
    let mut lap = |name: &str, timings: &mut Vec<(String, Real)>| {
        timings.push((name.to_string(), clock.elapsed().as_secs_f64()));
        clock = Instant::now();
    };
    let (cloud, source, surface, stock) = scanned_part(scene, program, cloud, progress)?;
    lap("scan", &mut timings);
    let features = extract_features(scene, program, &cloud.points, stock.as_ref())?;
    lap("fit", &mut timings);
    // The scanner's account of its points: stated by the scene's [scanner] (for a given
    // cloud too, if the scene has one); without it the faces are judged against each other
    // only, at their fits' own σ.
    let noise = scene
        .scanner
        .as_ref()
        .map(|s| scan_noise(s, &scene.stock_box));
    let (mut ident, twin, rounds, converged) = correction_loop_terms(
        scene.model(),
        &ids,
        &iso,
        &scene.tool,
        &features,
        scene.registration,
        scene.loop_tolerance_mm,
        noise.as_ref(),
    )
    .map_err(cal)?;
    if let Some(n) = &noise {
        ident.fit.add_parts(face_rms_parts(&features, n));
    }
    ident
        .fit
        .enforce("identify", scene.accept_misfit)
        .map_err(|source| PipelineError::Misfit {
            path: spath.clone(),
            source,
        })?;
    lap("identify", &mut timings);
    // Monte Carlo over scanner noise: rescan with other seeds, identify from the model.
    let trials = monte_carlo.unwrap_or(scene.monte_carlo_trials);
    let mut samples: BTreeMap<String, Vec<Real>> = BTreeMap::new();
    let mut mc_trials = 0;
    if let (Some(surface), Some(scanner)) = (&surface, &scene.scanner) {
        for k in 0..trials {
            let mut cfg = scanner.clone();
            cfg.seed = scene.monte_carlo_seed.wrapping_add(k as u64);
            let scanned = surface
                .scan(&cfg, &crate::progress::NoProgress)
                .map_err(|source| PipelineError::Scan {
                    path: spath.clone(),
                    source,
                })?;
            let f = extract_features(scene, program, &scanned.cloud.points, None)?;
            let m = Model {
                chain: scene.model(),
                ids: &ids,
                iso_terms: &terms,
                tool: &scene.tool,
                features: &f,
                registration: scene.registration,
            };
            let r = crate::calibration::calibrate::identify(&m).map_err(cal)?;
            // Values of the main run's quantities (same coefficients) in this trial.
            // ISO terms solve on top of the model's prior values.
            let prior = ids.iter().map(|_| 0.0).chain(iso.iter().map(|(_, v)| *v));
            let x: Vec<Real> = r.solution.iter().zip(prior).map(|(x, p)| x + p).collect();
            for e in ident.parameters.iter().chain(&ident.combinations) {
                let v: Real = e.coefficients.iter().zip(&x).map(|(c, x)| c * x).sum();
                samples.entry(e.name.clone()).or_default().push(v);
            }
            mc_trials += 1;
        }
        lap("monte carlo", &mut timings);
    }
    // The truth of an ISO term is what the scene injects under its names (0 if none); a
    // scene that injects joint values on the joints the term composes onto gives none.
    let truth: Vec<Option<Real>> = ids
        .iter()
        .map(|id| Some(scene.chain().deviation(*id)))
        .chain(terms.iter().map(|t| {
            let named = scene.injected().keys().any(|n| {
                !n.contains('_')
                    && scene
                        .chain()
                        .iso_term_id(n)
                        .is_ok_and(|(a, c)| a == t.axis && c == t.component)
            });
            let on_joints = scene.injected().keys().any(|n| {
                n.contains('_')
                    && scene
                        .chain()
                        .deviation_id(n)
                        .is_ok_and(|id| id.joint == t.axis || id.joint + 1 == t.axis)
            });
            (named || !on_joints).then(|| iso_value(scene.chain(), scene.injected(), t))
        }))
        .collect();
    let simulated = surface.is_some();
    let estimate = |e: &crate::calibration::calibrate::Estimate| EstimateReport {
        name: e.name.clone(),
        value: e.value,
        sigma: e.sigma,
        monte_carlo_spread: samples.get(&e.name).filter(|v| v.len() > 1).map(|v| {
            let n = v.len() as Real;
            let mean = v.iter().sum::<Real>() / n;
            (v.iter().map(|x| (x - mean).powi(2)).sum::<Real>() / (n - 1.0)).sqrt()
        }),
        injected: simulated
            .then(|| {
                e.coefficients
                    .iter()
                    .zip(&truth)
                    .filter(|(c, _)| **c != 0.0)
                    .map(|(c, t)| t.map(|t| c * t))
                    .sum::<Option<Real>>()
            })
            .flatten(),
        coefficients: e.coefficients.clone(),
    };
    let id = &ident.identifiability;
    let report = IdentifyReport {
        warning: ident.fit.accepted_line(),
        scene: scene.name.clone(),
        chain: scene.chain().to_string(),
        cloud: source,
        registration: match scene.registration {
            Registration::Estimate => "estimate",
            Registration::Workpiece => "workpiece",
        }
        .into(),
        parameters: scene.parameters.clone(),
        features: features
            .iter()
            .zip(&ident.residuals)
            .map(|(f, (_, r))| feature_report(f, *r))
            .collect(),
        singular_values: id.singular_values.clone(),
        margin: id.margin,
        condition_number: id.condition_number,
        condition_number_determined: id.condition_number_determined,
        identified: ident.parameters.iter().map(estimate).collect(),
        combinations: ident.combinations.iter().map(estimate).collect(),
        not_determined: id
            .undetermined_combinations
            .iter()
            .map(|c| c.name.clone())
            .collect(),
        borderline: id
            .borderline
            .iter()
            .map(|(c, sv)| (c.name.clone(), *sv))
            .collect(),
        not_identified: id.not_identified.clone(),
        no_data: id.no_data.clone(),
        registration_absorbs: id.registration_absorbs.clone(),
        registration_estimate: ident.registration,
        solver: IdentifySolverReport {
            evaluations: ident.solver.evaluations,
            termination: ident.solver.termination.clone(),
            chi2_start: ident.solver.chi2_start,
            chi2: ident.solver.chi2,
            dof: ident.solver.dof,
        },
        fit: ident.fit.clone(),
        rounds,
        converged,
        monte_carlo_trials: mc_trials,
        timings_s: timings,
    };
    Ok(IdentifyOutcome {
        report,
        cloud,
        features,
        identification: ident,
        twin,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::calibrate::synthetic_plane_feature;
    use crate::calibration::identify::{FaceKind, FaceRegion, FaceSpec};
    use crate::cutting::tool::{Tool, ToolKind};
    use crate::math::{Aabb, UnitVector3};
    use crate::metrology::fit::Plane;
    use crate::nc::{AxisLetter, AxisValues, Move, MoveKind};

    #[test]
    fn a_face_tilted_about_its_centroid_is_not_matched() {
        // A measured flank turned by θ about its centroid agrees with the twin at the
        // centroid and differs by h·sinθ·cosθ at the corners, h = √3·σ_off/σ_slope the
        // half-width the fit's design implies.
        let chain = crate::machine::chain::mdx50_for_tests();
        let tool = Tool::try_new(ToolKind::Flat, 6.0, 25.0).expect("valid");
        let q = |x| {
            AxisValues::default()
                .with(AxisLetter::X, x)
                .with(AxisLetter::Y, -3.0)
                .with(AxisLetter::Z, 5.0)
        };
        let mv = Move {
            kind: MoveKind::Linear,
            start: q(-30.0),
            end: q(30.0),
            feed_mm_per_min: Some(600.0),
            line: 7,
        };
        let spec = FaceSpec {
            name: "flank".into(),
            line: 7,
            region: FaceRegion::Auto,
            kind: FaceKind::Flank,
        };
        let stock = Aabb {
            min: Point3::new(-20.0, -24.0, -10.0),
            max: Point3::new(20.0, 8.0, 10.0),
        };
        let (sigma_off, sigma_slope) = (1e-5, 1e-6);
        let mut f = synthetic_plane_feature(
            &spec,
            &mv,
            &chain,
            &chain,
            &tool,
            &stock,
            sigma_off,
            [sigma_slope; 2],
            (0.0, 0.0),
        )
        .expect("a flank");
        let features = |f: &PlaneFeature| vec![Feature::Plane(f.clone())];
        let (worst, matched) = face_match(&chain, &tool, &features(&f), &[0.0; 6], 1e-4);
        assert!(matched && worst < 1e-12, "the exact face: {worst}");
        let theta: Real = 1e-4;
        let (n, b0, b1) = (
            f.plane.normal.into_inner(),
            f.basis[0].into_inner(),
            f.basis[1].into_inner(),
        );
        let turned = n * theta.cos() + b1.cross(&n) * theta.sin();
        assert!(
            (b0.dot(&turned)).abs() > 0.9 * theta.sin(),
            "turned along b0"
        );
        f.plane = Plane::through(&f.centroid, UnitVector3::new_normalize(turned));
        let (worst, matched) = face_match(&chain, &tool, &features(&f), &[0.0; 6], 1e-4);
        let h = 3.0_f64.sqrt() * sigma_off / sigma_slope;
        let want = h * theta.sin() * theta.cos();
        assert!(
            (worst - want).abs() < 1e-9,
            "corner distance {worst}, expected {want}"
        );
        assert!(!matched, "a {want} mm corner mismatch is beyond 0.1 µm");
    }
}
