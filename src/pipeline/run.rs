//! `run`: the 0°/180° experiment on a scene — the part cut on the deviated machine,
//! scanned, its two faces fitted, the deviations identified, the faces' heat map drawn, what
//! the page needs kept (the cut stock, the fitted faces, the faces' map as SVG; the page
//! itself is made by [`super::pages::run_page`], so library callers that want only the
//! figures do not pay for it) — and the scanner-effects study of `scan --study`.

use super::{PipelineError, machine_part, scan_noise};
use crate::calibration::identify::{self, Face};
use crate::calibration::step;
use crate::cutting::stock::TriDexel;
use crate::math::{Point3, Real};
use crate::metrology::cloud::PointCloud;
use crate::metrology::fit::Plane;
use crate::metrology::scan::{Misregistration, StudyOptions, Surface, scan};
use crate::nc::Program;
use crate::progress::Progress;

use crate::report::pages::FittedPlane;
use crate::report::render::{HeatMapOptions, encode_png, nice_ceil, render_heat_map};
use crate::report::svg::{MapLabels, deviation_map_svg};
use crate::report::{FaceReport, Report, ScanReport, SolverReport, StockReport, StudyCase};
use crate::scene::{Need, Scene};
use std::collections::BTreeMap;
use std::time::Instant;

/// Everything a run produces.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// The report.
    pub report: Report,
    /// The scanned cloud (workpiece frame).
    pub cloud: PointCloud,
    /// The heat map of the scanned faces, PNG-encoded.
    pub heat_map_png: Vec<u8>,
    /// The cut stock.
    pub stock: TriDexel,
    /// The two fitted faces as planes over their points in the cloud.
    pub planes: Vec<FittedPlane>,
    /// The scanned faces' map (faces.png as SVG).
    pub faces_svg: String,
}

fn face_report(f: &Face, line: usize) -> FaceReport {
    let n = f.fit.plane.normal;
    FaceReport {
        name: f.name.clone(),
        line,
        rotary_deg: f.rotary_deg.clone(),
        points: f.fit.n_used,
        rejected: f.fit.n_rejected,
        normal: [n.x, n.y, n.z],
        offset_mm: f.fit.plane.offset,
        centroid_mm: [f.fit.centroid.x, f.fit.centroid.y, f.fit.centroid.z],
        rms_mm: f.fit.rms_mm,
        max_abs_mm: f.fit.max_abs_mm,
    }
}

/// A colour range (µm) that spans 99 % of the points' distances from `plane`, rounded up to
/// a 1-2-5 step: edge points beyond it saturate instead of washing out the face.
fn colour_range_um(points: &[Point3], plane: &Plane) -> Real {
    let mut d: Vec<Real> = points
        .iter()
        .map(|p| plane.signed_distance(p).abs() * 1e3)
        .collect();
    d.sort_by(Real::total_cmp);
    let p99 = d
        .get(d.len().saturating_sub(1) * 99 / 100)
        .copied()
        .unwrap_or(1.0);
    nice_ceil(p99.max(1e-3))
}

/// Segments and fits the scene's two faces in a cloud (workpiece frame). With `cut`, the
/// stock the cloud was scanned from, each face is fitted only if its cut left its surface
/// inside the face's region ([`identify::check_cut`]).
pub fn extract_faces(
    scene: &Scene,
    program: &Program,
    points: &[Point3],
    cut: Option<&TriDexel>,
) -> Result<[Face; 2], PipelineError> {
    let id_err = |source| PipelineError::Identify {
        path: scene.path.display().to_string(),
        source,
    };
    scene.require("run", &[Need::StepFaces])?;
    let select = |k: usize| {
        identify::select_face(
            points,
            &scene.faces[k],
            &program.moves,
            scene.model(),
            &scene.tool,
            &scene.stock_box,
            &scene.face_options,
        )
        .map_err(id_err)
    };
    let selected = [select(0)?, select(1)?];
    if let Some(stock) = cut {
        for sel in &selected {
            identify::check_cut(sel, points, stock).map_err(id_err)?;
        }
    }
    let fit =
        |sel| identify::fit_face(points, sel, scene.model(), &scene.face_options).map_err(id_err);
    Ok([fit(&selected[0])?, fit(&selected[1])?])
}

/// Runs the whole pipeline on `scene` with its parsed `program`.
pub fn run(
    scene: &Scene,
    program: &Program,
    progress: &dyn Progress,
) -> Result<Outcome, PipelineError> {
    scene.require("run", &[Need::Scanner, Need::StepFaces])?;
    let scanner = scene.scanner_for("run")?;
    let spath = scene.path.display().to_string();
    let mut timings = Vec::new();
    let mut clock = Instant::now();
    let mut lap = |name: &str, timings: &mut Vec<(String, Real)>| {
        timings.push((name.to_string(), clock.elapsed().as_secs_f64()));
        clock = Instant::now();
    };

    let part = machine_part(scene, program, progress)?;
    let volume0 = part.volume0;
    let (stock, sweep) = (part.stock, part.sweep);
    timings.extend(part.timings);

    let scanned = scan(&stock, scanner, progress).map_err(|source| PipelineError::Scan {
        path: spath.clone(),
        source,
    })?;
    lap("scan", &mut timings);

    let points = &scanned.cloud.points;
    let faces = extract_faces(scene, program, points, Some(&stock))?;
    // A face that is not the one plane its cut makes refuses the run.
    let mut fit = identify::faces_fit(&faces, &scan_noise(scanner, &scene.stock_box));
    fit.enforce("run", scene.accept_misfit)
        .map_err(|source| PipelineError::Misfit {
            path: spath.clone(),
            source,
        })?;
    lap("fit", &mut timings);

    let id_err = |source| PipelineError::Identify {
        path: spath.clone(),
        source,
    };
    let cuts = [&faces[0].cut, &faces[1].cut];
    let mut ident = step::identify_step(&faces, scene.model(), &scene.tool).map_err(id_err)?;
    // What the solved deviations leave of the faces' offsets and tilts (with the offset
    // alone: their relative tilt) refuses the run too, naming the face.
    ident
        .fit
        .enforce("run", scene.accept_misfit)
        .map_err(|source| PipelineError::Misfit {
            path: spath.clone(),
            source,
        })?;
    let (predicted_step, predicted_tilt) = identify::predicted_step(
        scene.chain(),
        &scene.tool,
        faces.each_ref().map(|f| (&f.cut, &f.flank.plane.normal)),
        &ident.frame,
    )
    .unwrap_or((Real::NAN, Real::NAN));
    lap("identify", &mut timings);

    // Heat map of both faces against the first face's nominal plane.
    let nominal = identify::flank(
        &scene.chain().nominal(),
        &scene.tool,
        cuts[0],
        &scene.stock_box,
    )
    .unwrap_or(faces[0].flank);
    // The whole face as scanned, step edge and occluded band included: every point within
    // the identification band of the nominal plane, strictly between the stock's faces
    // across it (whose edge strips also fall in the band).
    let band = scene.face_options.band_mm;
    let (v0, v1) = identify::extent(&scene.stock_box, &nominal.tip, &nominal.v);
    let edge = 2.0 * scanner.pitch_mm;
    let face_points: Vec<_> = points
        .iter()
        .filter(|p| {
            let v = nominal.v.dot(&(*p - nominal.tip));
            nominal.plane.signed_distance(p).abs() <= band && v > v0 + edge && v < v1 - edge
        })
        .copied()
        .collect();
    let title = format!(
        "{}: scanned faces, distance from nominal plane (step {:+.4} mm)",
        scene.name, ident.step_mm
    );
    let range_um = colour_range_um(&face_points, &nominal.plane);
    let img = render_heat_map(
        &face_points,
        &nominal.plane,
        &nominal.u,
        &nominal.v,
        &HeatMapOptions {
            title: title.clone(),
            width_px: 800,
            // Seen obliquely, points on a face lie further apart than the nominal pitch:
            // dots 1.5 pitches wide close the gaps.
            point_pitch_mm: 1.5 * scanner.pitch_mm,
            range_um: Some(range_um),
        },
    )
    .and_then(|img| encode_png(&img))
    .map_err(|source| PipelineError::Render {
        path: spath.clone(),
        source,
    })?;

    // What the page needs: the faces as planes and their map as SVG.
    let planes = faces
        .iter()
        .map(|f| FittedPlane {
            name: f.name.clone(),
            plane: f.fit.plane,
            points: f.indices.clone(),
        })
        .collect();
    let xyd: Vec<_> = face_points
        .iter()
        .map(|p| {
            (
                nominal.u.dot(&p.coords),
                nominal.v.dot(&p.coords),
                nominal.plane.signed_distance(p),
            )
        })
        .collect();
    let labels = MapLabels {
        title: title.clone(),
        x: "along the cut (mm)".into(),
        y: "along the tool axis (mm)".into(),
    };
    let faces_svg =
        deviation_map_svg(&xyd, range_um * 1e-3, &labels).map_err(|e| PipelineError::Page {
            path: spath.clone(),
            message: e.to_string(),
        })?;
    lap("render", &mut timings);

    let mut identified = BTreeMap::new();
    let mut uncertainty = BTreeMap::new();
    for (name, value, sigma) in [&ident.offset, &ident.angle_sum].into_iter().flatten() {
        identified.insert(name.clone(), *value);
        uncertainty.insert(name.clone(), *sigma);
    }
    let mut not_identified = ident.not_identified.clone();
    if ident.offset.is_none() {
        // The faces do not determine the pair: report the names, give no value.
        let names = [ident.offset_name.clone(), ident.angle_name.clone()];
        not_identified.extend(names);
    }
    let report = Report {
        warning: fit.accepted_line().or_else(|| ident.fit.accepted_line()),
        scene: scene.name.clone(),
        machine: scene.machine_name().to_string(),
        chain: scene.chain().to_string(),
        program: program.path.display().to_string(),
        moves: program.moves.len(),
        step_mm: ident.step_mm,
        step_sigma_mm: ident.step_sigma_mm,
        predicted_step_mm: predicted_step,
        tilt_rad: ident.tilt_rad,
        predicted_tilt_rad: predicted_tilt,
        injected: scene.injected().clone(),
        known: scene.known().clone(),
        identified,
        uncertainty,
        not_identified,
        why_not_identified: ident.why_not.clone(),
        faces: faces.iter().zip(&scene.faces).map(|(f, s)| face_report(f, s.line)).collect(),
        fit,
        solver: SolverReport {
            method: if ident.offset.is_some() && ident.angle_sum.is_none() {
                "the identification engine on the exact chain (the step alone: the tilt sees no angle of the joint)"
            } else {
                "the identification engine on the exact chain (the faces' offsets and tilts; step and tilt, seed 002 eq. (6)(7) to first order)"
            }
            .into(),
            singular_values: ident.singular_values,
            margin: ident.margin,
            evaluations: ident.solver.0,
            residual: ident.solver.1,
        },
        stock: StockReport::of(&stock, volume0),
        sweep,
        scan: ScanReport::of(&scanned, scanner),
        timings_s: timings,
    };
    Ok(Outcome {
        report,
        cloud: scanned.cloud,
        heat_map_png: img,
        stock,
        planes,
        faces_svg,
    })
}

/// Scans the machined part again and again, each effect of the scanner model alone and
/// all together, and reports how the identified offset moves: the answer to "how much of
/// my result is the scanner?".
///
/// `surface` is the machined part of `scene` and `program` (`stock`), prepared for scanning
/// once by the caller (see [`machine_part`] and [`Surface::new`]); the faces are measured
/// only if their cuts left them in the stock ([`identify::check_cut`]).
pub fn scanner_study(
    scene: &Scene,
    program: &Program,
    stock: &TriDexel,
    surface: &Surface,
    opts: &StudyOptions,
) -> Result<Vec<StudyCase>, PipelineError> {
    scene.require("scan --study", &[Need::Scanner, Need::StepFaces])?;
    let base = scene.scanner_for("scan --study")?;
    let spath = scene.path.display().to_string();
    let sigma = base.noise_sigma_mm;
    let variant = |noise: Real, corr: Real, t: Real, r: Real| {
        let mut c = base.clone();
        c.noise_sigma_mm = noise;
        c.noise_correlation_mm = corr;
        c.misregistration = Misregistration {
            translation_sigma_mm: t,
            rotation_sigma_rad: r,
        };
        c
    };
    let (corr, t, r) = (
        opts.correlation_mm,
        opts.translation_sigma_mm,
        opts.rotation_sigma_rad,
    );
    let cases = [
        (
            "ideal: no noise, exact registration".to_string(),
            variant(0.0, 0.0, 0.0, 0.0),
            1,
        ),
        (
            format!("white noise σ {sigma} mm"),
            variant(sigma, 0.0, 0.0, 0.0),
            opts.trials,
        ),
        (
            format!("correlated noise σ {sigma} mm, ℓ {corr} mm"),
            variant(sigma, corr, 0.0, 0.0),
            opts.trials,
        ),
        (
            format!("misregistration {t} mm, {r} rad per view"),
            variant(0.0, 0.0, t, r),
            opts.trials,
        ),
        (
            "all: correlated noise and misregistration".to_string(),
            variant(sigma, corr, t, r),
            opts.trials,
        ),
        (
            "as the scene configures the scanner".to_string(),
            base.clone(),
            opts.trials,
        ),
    ];
    let scan_err = |source| PipelineError::Scan {
        path: spath.clone(),
        source,
    };
    let id_err = |source| PipelineError::Identify {
        path: spath.clone(),
        source,
    };
    let mut out = Vec::new();
    for (case, cfg, trials) in cases {
        let mut values = Vec::new();
        let mut sigmas = Vec::new();
        let mut steps = Vec::new();
        let mut name = String::new();
        for k in 0..trials.max(1) {
            let mut c = cfg.clone();
            c.seed = base.seed.wrapping_add(k as u64);
            let scanned = surface
                .scan(&c, &crate::progress::NoProgress)
                .map_err(scan_err)?;
            // The cut stock is the same for every trial: checked on the first.
            let first = out.is_empty() && k == 0;
            let faces = extract_faces(
                scene,
                program,
                &scanned.cloud.points,
                first.then_some(stock),
            )?;
            let ident = step::identify_step(&faces, scene.model(), &scene.tool).map_err(id_err)?;
            if let Some((n, v, s)) = &ident.offset {
                name.clone_from(n);
                values.push(*v);
                sigmas.push(*s);
            }
            steps.push(ident.step_mm);
        }
        let truth = scene
            .chain()
            .deviation_id(&name)
            .map(|id| scene.chain().deviation(id))
            .unwrap_or(Real::NAN);
        let n = values.len().max(1) as Real;
        let mean = values.iter().sum::<Real>() / n;
        let spread = if values.len() > 1 {
            (values.iter().map(|v| (v - mean).powi(2)).sum::<Real>() / (n - 1.0)).sqrt()
        } else {
            0.0
        };
        out.push(StudyCase {
            case,
            trials: values.len(),
            parameter: name,
            truth_mm: truth,
            mean_mm: mean,
            spread_mm: spread,
            worst_error_mm: values
                .iter()
                .map(|v| (v - truth).abs())
                .fold(0.0, Real::max),
            mean_reported_sigma_mm: sigmas.iter().sum::<Real>() / n,
            mean_step_mm: steps.iter().sum::<Real>() / steps.len().max(1) as Real,
        });
    }
    Ok(out)
}
