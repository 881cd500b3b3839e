//! The main job: program → sweep through the deviated chain → scan → fit → identify →
//! report, on a loaded scene. Pure: it returns everything it made and writes nothing.
//!
//! **Invariant:** `run` has no side effects beyond the progress calls; the same scene and
//! program give the same outcome (except the timings) for any thread count.

use crate::calibration::calibrate::{
    CalibrateError, Feature, Identification, Model, PlaneFeature, Registration,
    extract_plane_feature, predicted_plane,
};
use crate::calibration::correct::{
    CorrectError, CorrectOptions, CorrectedProgram, correct_program, face_errors, part_error,
    path_error, uncorrected,
};
use crate::calibration::design::kind_name;
use crate::calibration::identify::{self, Face, IdentifyError};
use crate::cutting::collide::sweep_with_checks;
use crate::cutting::mesh::{MeshError, TriMesh, mesh_stock};
use crate::cutting::stock::{StockError, TriDexel};
use crate::cutting::sweep::{SweepError, SweepOptions, SweepReport, sweep_program};
use crate::machine::chain::{Chain, DeviationId};
use crate::math::Aabb;
use crate::math::{Point3, Real};
use crate::metrology::cloud::PointCloud;
use crate::metrology::fit::Plane;
use crate::metrology::fit::{
    RobustRule, fit_circle, fit_circle_robust, fit_cylinder, fit_cylinder_robust, fit_plane,
    fit_plane_robust, fit_sphere, fit_sphere_robust, plane_distance_and_angle,
};
use crate::metrology::scan::{Misregistration, ScanError, StudyOptions, Surface, scan};
use crate::metrology::segment::{
    PlaneSegmentOptions, RansacOptions, estimate_normals, ransac_cylinder, ransac_sphere,
    segment_planes, select_box, select_region_from_seed,
};
use crate::nc::Program;
use crate::progress::Progress;
use crate::report::deviation_map::{
    DeviationError, DeviationImageOptions, deviation_map, render_deviation_map,
};
use crate::report::render::{
    HeatMapOptions, RenderError, encode_png, nice_ceil, render_heat_map, render_top_view,
};
use crate::report::{
    CircleReport, CorrectIteration, CorrectReport, CylinderReport, FaceReport, FitFileReport,
    MeshSummary, PlanePair, PlaneReport, Report, ScanReport, SimulationReport, SolverReport,
    SphereReport, StockReport, StudyCase, UncorrectableReport,
};
use crate::report::{CollisionEvent, DeviationSummary};
use crate::report::{
    EstimateReport, FeatureReport, IdentifyReport, IdentifySolverReport, LoopRound,
};
use crate::scene::{Need, Scene, SceneError, StockShape};
use std::collections::BTreeMap;
use std::time::Instant;

/// Errors of a run (the scene and program are already valid).
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The stock could not be made.
    #[error("{path}: [stock]: {source}")]
    Stock {
        /// Scene file.
        path: String,
        /// Why.
        source: StockError,
    },
    /// The sweep failed.
    #[error("{location}: {source}")]
    Sweep {
        /// Program file and line (`file:line`), or the scene file.
        location: String,
        /// Why.
        source: SweepError,
    },
    /// The scan failed.
    #[error("{path}: [scanner]: {source}")]
    Scan {
        /// Scene file.
        path: String,
        /// Why.
        source: ScanError,
    },
    /// Faces could not be found or identified.
    #[error("{path}: [identify]: {source}")]
    Identify {
        /// Scene file.
        path: String,
        /// Why.
        source: IdentifyError,
    },
    /// A cloud could not be measured (no shape found, a fit failed).
    #[error("{path}: {message}")]
    Measure {
        /// The cloud file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// The cut stock could not be meshed.
    #[error("{path}: surface mesh: {source}")]
    Mesh {
        /// Scene file.
        path: String,
        /// Why.
        source: MeshError,
    },
    /// The program could not be corrected, or the corrected part not measured.
    #[error("{location}: {source}")]
    Correct {
        /// Program file and line (`file:line`), or the scene file.
        location: String,
        /// Why.
        source: CorrectError,
    },
    /// General identification failed (faces, data, solver).
    #[error("{path}: [identify]: {source}")]
    Calibrate {
        /// Scene file.
        path: String,
        /// Why.
        source: CalibrateError,
    },
    /// The deviation map against the design model failed.
    #[error("{path}: [design]: {source}")]
    Deviation {
        /// Scene file.
        path: String,
        /// Why.
        source: DeviationError,
    },
    /// The scene lacks a section the command needs.
    #[error("{0}")]
    Scene(#[from] SceneError),
    /// The heat map could not be drawn.
    #[error("{path}: heat map: {source}")]
    Render {
        /// Scene file.
        path: String,
        /// Why.
        source: RenderError,
    },
}

/// Everything a run produces.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// The report.
    pub report: Report,
    /// The scanned cloud (workpiece frame).
    pub cloud: PointCloud,
    /// The heat map of the scanned faces, PNG-encoded.
    pub heat_map_png: Vec<u8>,
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

/// The part as the deviated machine cuts it.
pub struct Part {
    /// The cut stock.
    pub stock: TriDexel,
    /// Its volume before cutting (mm³).
    pub volume0: Real,
    /// What the sweep did.
    pub sweep: SweepReport,
    /// Seconds for "stock" and "sweep".
    pub timings: Vec<(String, Real)>,
}

/// The scene's stock before cutting: its box, cylinder or mesh on the grids of
/// [`Scene::stock_box`] at the scene's pitch (refused before allocating if over the memory
/// budget).
pub fn make_stock(scene: &Scene) -> Result<TriDexel, PipelineError> {
    let (b, h, budget) = (scene.stock_box, scene.pitch_mm, scene.memory_budget_bytes);
    match &scene.stock_shape {
        StockShape::Box => TriDexel::new_box(b, h, budget),
        StockShape::Cylinder(c) => TriDexel::from_solid(b, h, budget, c),
        StockShape::Mesh { mesh, .. } => TriDexel::from_solid(b, h, budget, mesh.as_ref()),
    }
    .map_err(|source| PipelineError::Stock {
        path: scene.path.display().to_string(),
        source,
    })
}

/// Makes the stock and sweeps the program through the scene's deviated chain.
pub fn machine_part(
    scene: &Scene,
    program: &Program,
    progress: &dyn Progress,
) -> Result<Part, PipelineError> {
    let spath = scene.path.display().to_string();
    let clock = Instant::now();
    let mut stock = make_stock(scene)?;
    let volume0 = stock.volume();
    let t_stock = clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    let sweep = sweep_program(
        &mut stock,
        &scene.chain,
        &scene.tool,
        &program.moves,
        &scene.sweep,
        progress,
    )
    .map_err(sweep_failed(program, &spath))?;
    let timings = vec![
        ("stock".to_string(), t_stock),
        ("sweep".to_string(), clock.elapsed().as_secs_f64()),
    ];
    Ok(Part {
        stock,
        volume0,
        sweep,
        timings,
    })
}

/// Segments and fits the scene's two faces in a cloud (workpiece frame).
pub fn extract_faces(
    scene: &Scene,
    program: &Program,
    points: &[Point3],
) -> Result<[Face; 2], PipelineError> {
    let id_err = |source| PipelineError::Identify {
        path: scene.path.display().to_string(),
        source,
    };
    scene.require("run", &[Need::StepFaces])?;
    let face = |k: usize| {
        identify::extract_face(
            points,
            &scene.faces[k],
            &program.moves,
            &scene.model,
            &scene.tool,
            &scene.stock_box,
            &scene.face_options,
        )
        .map_err(id_err)
    };
    Ok([face(0)?, face(1)?])
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
    let faces = extract_faces(scene, program, points)?;
    lap("fit", &mut timings);

    let id_err = |source| PipelineError::Identify {
        path: spath.clone(),
        source,
    };
    let cuts = [&faces[0].cut, &faces[1].cut];
    let ident = identify::identify_step(&faces, &scene.model, &scene.tool, &scene.stock_box)
        .map_err(id_err)?;
    let (predicted_step, predicted_tilt) = identify::predicted_step(
        &scene.chain,
        &scene.tool,
        cuts,
        &scene.stock_box,
        &ident.frame,
    )
    .unwrap_or((Real::NAN, Real::NAN));
    lap("identify", &mut timings);

    // Heat map of both faces against the first face's nominal plane.
    let nominal = identify::flank(
        &scene.chain.nominal(),
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
    let img = render_heat_map(
        &face_points,
        &nominal.plane,
        &nominal.u,
        &nominal.v,
        &HeatMapOptions {
            title,
            width_px: 800,
            // Seen obliquely, points on a face lie further apart than the nominal pitch:
            // dots 1.5 pitches wide close the gaps.
            point_pitch_mm: 1.5 * scanner.pitch_mm,
            range_um: Some(colour_range_um(&face_points, &nominal.plane)),
        },
    )
    .and_then(|img| encode_png(&img))
    .map_err(|source| PipelineError::Render {
        path: spath.clone(),
        source,
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
        scene: scene.name.clone(),
        machine: scene.machine_name.clone(),
        chain: scene.chain.to_string(),
        program: program.path.display().to_string(),
        moves: program.moves.len(),
        step_mm: ident.step_mm,
        step_sigma_mm: ident.step_sigma_mm,
        predicted_step_mm: predicted_step,
        tilt_rad: ident.tilt_rad,
        predicted_tilt_rad: predicted_tilt,
        injected: scene.injected.clone(),
        known: scene.known.clone(),
        identified,
        uncertainty,
        not_identified,
        faces: faces.iter().zip(&scene.faces).map(|(f, s)| face_report(f, s.line)).collect(),
        solver: SolverReport {
            method: "Levenberg-Marquardt on the exact chain (step, tilt), seed 002 eq. (6)(7) to first order".into(),
            singular_values: ident.singular_values,
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
    })
}

/// Scans the machined part again and again, each effect of the scanner model alone and
/// all together, and reports how the identified offset moves: the answer to "how much of
/// my result is the scanner?".
///
/// `surface` is the machined part of `scene` and `program`, prepared for scanning once by
/// the caller (see [`machine_part`] and [`Surface::new`]).
pub fn scanner_study(
    scene: &Scene,
    program: &Program,
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
            let faces = extract_faces(scene, program, &scanned.cloud.points)?;
            let ident =
                identify::identify_step(&faces, &scene.model, &scene.tool, &scene.stock_box)
                    .map_err(id_err)?;
            if let Some((n, v, s)) = &ident.offset {
                name.clone_from(n);
                values.push(*v);
                sigmas.push(*s);
            }
            steps.push(ident.step_mm);
        }
        let truth = scene
            .chain
            .deviation_id(&name)
            .map(|id| scene.chain.deviation(id))
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

/// Which shape [`fit_cloud`] looks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// Every planar face (segmentation), with the distance and angle between each pair.
    Planes,
    /// One plane through the selection.
    Plane,
    /// One sphere.
    Sphere,
    /// One cylinder.
    Cylinder,
    /// One circle in 3-D.
    Circle,
}

/// Which points [`fit_cloud`] uses.
#[derive(Clone, Debug, PartialEq)]
pub enum Selection {
    /// All of them.
    All,
    /// Those inside a box.
    Box(Aabb),
    /// The planar region grown from the point nearest this one.
    Seed(Point3),
}

/// A request to [`fit_cloud`].
#[derive(Clone, Debug, PartialEq)]
pub struct FitRequest {
    /// The shape.
    pub shape: Shape,
    /// The points.
    pub selection: Selection,
    /// Outlier rejection (σ trimming) on the final least-squares fit.
    pub robust: bool,
    /// Segmentation settings (planes, seed regions).
    pub segment: PlaneSegmentOptions,
    /// RANSAC settings (a sphere or cylinder in an unselected cloud).
    pub ransac: RansacOptions,
    /// Neighbours for normal estimation (cylinders).
    pub normal_neighbours: usize,
}

/// Planes closer than this to parallel (rad, 10°) get a distance as well as an angle.
const PARALLEL_RAD: Real = 0.1745;

/// Fits shapes to any cloud — the library behind `twinmill fit`.
pub fn fit_cloud(
    cloud: &PointCloud,
    req: &FitRequest,
    source: &str,
) -> Result<FitFileReport, PipelineError> {
    let err = |message: String| PipelineError::Measure {
        path: source.to_string(),
        message,
    };
    let pts = &cloud.points;
    let selected: Vec<Point3> = match &req.selection {
        Selection::All => pts.clone(),
        Selection::Box(b) => select_box(pts, &b.min, &b.max)
            .iter()
            .map(|&i| pts[i as usize])
            .collect(),
        Selection::Seed(p) => select_region_from_seed(pts, p, &req.segment)
            .map_err(|e| err(e.to_string()))?
            .indices
            .iter()
            .map(|&i| pts[i as usize])
            .collect(),
    };
    let rule = RobustRule::default();
    let mut report = FitFileReport {
        cloud: source.to_string(),
        points: pts.len(),
        selected: selected.len(),
        planes: Vec::new(),
        pairs: Vec::new(),
        sphere: None,
        cylinder: None,
        circle: None,
    };
    // RANSAC first on an unselected cloud: the shape is somewhere in it.
    let candidates = |found: Result<Vec<u32>, crate::metrology::segment::SegmentError>| -> Result<Vec<Point3>, PipelineError> {
        let idx = found.map_err(|e| err(e.to_string()))?;
        Ok(idx.iter().map(|&i| selected[i as usize]).collect())
    };
    match req.shape {
        Shape::Planes => {
            let segs = segment_planes(&selected, &req.segment).map_err(|e| err(e.to_string()))?;
            report.planes = segs.iter().map(|s| PlaneReport::of(&s.fit)).collect();
            for (i, a) in segs.iter().enumerate() {
                for (j, b) in segs.iter().enumerate().skip(i + 1) {
                    let at = Point3::from((a.fit.centroid.coords + b.fit.centroid.coords) / 2.0);
                    if let Some((distance_mm, angle_rad)) =
                        plane_distance_and_angle(&a.fit.plane, &b.fit.plane, &at)
                    {
                        report.pairs.push(PlanePair {
                            planes: [i, j],
                            distance_mm: (angle_rad < PARALLEL_RAD).then_some(distance_mm),
                            angle_rad,
                        });
                    }
                }
            }
        }
        Shape::Plane => {
            let fit = if req.robust {
                fit_plane_robust(&selected, &rule)
            } else {
                fit_plane(&selected)
            };
            report.planes = vec![PlaneReport::of(&fit.map_err(|e| err(e.to_string()))?)];
        }
        Shape::Sphere => {
            let pts = match req.selection {
                Selection::All => {
                    candidates(ransac_sphere(&selected, &req.ransac).map(|m| m.inliers))?
                }
                _ => selected.clone(),
            };
            let fit = if req.robust {
                fit_sphere_robust(&pts, &rule)
            } else {
                fit_sphere(&pts)
            };
            report.sphere = Some(SphereReport::of(&fit.map_err(|e| err(e.to_string()))?));
        }
        Shape::Cylinder => {
            let normals = estimate_normals(&selected, req.normal_neighbours, None)
                .map_err(|e| err(e.to_string()))?;
            let found = ransac_cylinder(&selected, &normals, &req.ransac)
                .map_err(|e| err(e.to_string()))?;
            let axis = found.model.axis;
            let pts = candidates(Ok(found.inliers))?;
            let fit = if req.robust {
                fit_cylinder_robust(&pts, Some(axis), &rule)
            } else {
                fit_cylinder(&pts, Some(axis))
            };
            report.cylinder = Some(CylinderReport::of(&fit.map_err(|e| err(e.to_string()))?));
        }
        Shape::Circle => {
            let fit = if req.robust {
                fit_circle_robust(&selected, &rule)
            } else {
                fit_circle(&selected)
            };
            report.circle = Some(CircleReport::of(&fit.map_err(|e| err(e.to_string()))?));
        }
    }
    Ok(report)
}

/// Everything `simulate` produces.
#[derive(Clone, Debug)]
pub struct Simulation {
    /// The report.
    pub report: SimulationReport,
    /// The cut stock's surface (workpiece frame, mm).
    pub mesh: TriMesh,
    /// PNG of the part seen from +z.
    pub top_view_png: Vec<u8>,
    /// PNG of the deviation map against the scene's design model, if it has one.
    pub deviation_png: Option<Vec<u8>>,
}

/// Size of the deviation picture (px).
const DEVIATION_IMAGE_PX: (u32, u32) = (1200, 900);

/// Cuts the scene's program into its stock on the deviated machine, reporting collisions
/// (rapids through material, shank or holder in the stock, anything touching a fixture),
/// meshes the result and, when the scene has a design model, maps the part's deviation
/// from it: no scan, no identification.
pub fn simulate(
    scene: &Scene,
    program: &Program,
    progress: &dyn Progress,
) -> Result<Simulation, PipelineError> {
    let path = scene.path.display().to_string();
    let mut timings: BTreeMap<String, Real> = BTreeMap::new();
    let clock = Instant::now();
    let mut stock = make_stock(scene)?;
    let volume0 = stock.volume();
    timings.insert("stock".into(), clock.elapsed().as_secs_f64());
    let clock = Instant::now();
    let checked = sweep_with_checks(
        &mut stock,
        &scene.chain,
        &scene.tool,
        scene.holder.as_ref(),
        &scene.fixtures,
        &program.moves,
        &scene.sweep,
        progress,
    )
    .map_err(sweep_failed(program, &path))?;
    timings.insert("sweep".into(), clock.elapsed().as_secs_f64());
    let clock = Instant::now();
    let (mesh, mesh_report) = mesh_stock(&stock).map_err(|source| PipelineError::Mesh {
        path: path.clone(),
        source,
    })?;
    timings.insert("mesh".into(), clock.elapsed().as_secs_f64());
    let clock = Instant::now();
    let render_err = |source| PipelineError::Render {
        path: path.clone(),
        source,
    };
    let title = format!("{}: cut part seen from +z", scene.name);
    let img = render_top_view(&stock, &title).map_err(render_err)?;
    let top_view_png = encode_png(&img).map_err(render_err)?;
    timings.insert("render".into(), clock.elapsed().as_secs_f64());
    let (deviation, deviation_png) = match &scene.design {
        Some((design_path, design)) => {
            let clock = Instant::now();
            let (points, summary) =
                deviation_map(&stock, design).map_err(|source| PipelineError::Deviation {
                    path: path.clone(),
                    source,
                })?;
            let opts = DeviationImageOptions {
                title: format!(
                    "{}: deviation from {} (+ material left, - gouge)",
                    scene.name,
                    design_path
                        .file_name()
                        .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
                ),
                width_px: DEVIATION_IMAGE_PX.0,
                height_px: DEVIATION_IMAGE_PX.1,
                range_mm: None,
                point_pitch_mm: stock.max_spacing(),
            };
            let img = render_deviation_map(&points, &opts).map_err(render_err)?;
            let png = encode_png(&img).map_err(render_err)?;
            timings.insert("deviation".into(), clock.elapsed().as_secs_f64());
            (
                Some(DeviationSummary {
                    design: design_path.display().to_string(),
                    map: summary,
                }),
                Some(png),
            )
        }
        None => (None, None),
    };
    let report = SimulationReport {
        scene: scene.name.clone(),
        program: program.path.display().to_string(),
        stock: StockReport::of(&stock, volume0),
        sweep: checked.sweep,
        mesh: MeshSummary {
            vertices: mesh.vertices.len(),
            triangles: mesh.triangles.len(),
            euler_characteristic: mesh.euler_characteristic(),
            volume_mm3: mesh.signed_volume(),
            area_mm2: mesh.area(),
            feature_vertices: mesh_report.feature_vertices,
        },
        collisions: checked.events.iter().map(CollisionEvent::of).collect(),
        deviation,
        timings_s: timings,
    };
    Ok(Simulation {
        report,
        mesh,
        top_view_png,
        deviation_png,
    })
}
/// Largest number of correction passes: each refines the subdivision fourfold; exact
/// kinematic inversion meets any reachable accuracy in the first or second.
const MAX_CORRECT_PASSES: usize = 4;
/// The verification sweep's rotary sub-step bound, as a fraction of the accuracy: its own
/// approximation must not eat the error budget.
const SWEEP_BOUND_FRACTION: Real = 0.1;

/// What `correct` produces.
#[derive(Clone, Debug)]
pub struct CorrectOutcome {
    /// The report.
    pub report: CorrectReport,
    /// The final corrected program.
    pub corrected: CorrectedProgram,
    /// Comment lines for the head of the emitted program.
    pub header: Vec<String>,
}

fn nonzero_deviations(chain: &Chain) -> BTreeMap<String, Real> {
    chain
        .deviation_names()
        .into_iter()
        .filter_map(|n| {
            let v = chain.deviation(chain.deviation_id(&n).ok()?);
            (v != 0.0).then_some((n, v))
        })
        .collect()
}

/// The correction loop of seed 002 Fig. 1 on a scene: correct `program` for the deviated
/// chain `model` (the scene's injected deviations, or identified ones), simulate the
/// corrected program on the scene's machine (`scene.chain`), measure the milled faces and the
/// tool path against the nominal ones, and refine the subdivision until both are within
/// `accuracy_mm` — or report what stays out and why. Pass 0 is the program as given.
pub fn correct(
    scene: &Scene,
    program: &Program,
    model: &Chain,
    accuracy_mm: Real,
    progress: &dyn Progress,
) -> Result<CorrectOutcome, PipelineError> {
    let spath = scene.path.display().to_string();
    let cerr = |source: CorrectError| {
        let location = match source.line() {
            Some(line) => format!("{}:{line}", program.path.display()),
            None => spath.clone(),
        };
        PipelineError::Correct { location, source }
    };
    if !(accuracy_mm.is_finite() && accuracy_mm > 0.0) {
        return Err(cerr(CorrectError::BadAccuracy(accuracy_mm)));
    }
    let start = program.moves.first().map_or(scene.home, |m| m.start);
    let nominal = scene.chain.nominal();
    let mut timings: Vec<(String, Real)> = Vec::new();
    let mut sweep_scene = scene.clone();
    sweep_scene.sweep = SweepOptions {
        rotary_step_bound_mm: scene
            .sweep
            .rotary_step_bound_mm
            .min(accuracy_mm * SWEEP_BOUND_FRACTION),
    };
    // The nominal part: the program as given on the nominal machine.
    let nominal_part = {
        let mut nominal_scene = sweep_scene.clone();
        nominal_scene.chain = nominal.clone();
        machine_part(&nominal_scene, program, progress)?
    };
    timings.extend(
        nominal_part
            .timings
            .iter()
            .map(|(n, t)| (format!("{n} nominal"), *t)),
    );
    // Simulate and measure one program on the scene's machine.
    let measure = |iteration: usize,
                   tol: Option<Real>,
                   cp: &CorrectedProgram,
                   timings: &mut Vec<(String, Real)>|
     -> Result<CorrectIteration, PipelineError> {
        let as_program = Program {
            path: program.path.clone(),
            moves: cp.moves.clone(),
            axes_used: cp.axes.clone(),
            ended_by: program.ended_by,
        };
        let part = machine_part(&sweep_scene, &as_program, progress)?;
        timings.extend(
            part.timings
                .iter()
                .map(|(n, t)| (format!("{n} {iteration}"), *t)),
        );
        let clock = Instant::now();
        let faces = face_errors(
            &part.stock,
            &nominal,
            &scene.tool,
            &program.moves,
            &scene.faces,
            &scene.stock_box,
            &scene.face_options,
        )
        .map_err(cerr)?;
        let path = path_error(&scene.chain, &scene.tool, program, cp);
        let whole = part_error(&part.stock, &nominal_part.stock);
        timings.push((
            format!("measure {iteration}"),
            clock.elapsed().as_secs_f64(),
        ));
        Ok(CorrectIteration {
            iteration,
            path_tolerance_mm: tol,
            blocks: cp.blocks.len(),
            path,
            part: whole,
            predicted_error_mm: faces.max_abs_mm(),
            faces,
            sweep: part.sweep,
        })
    };

    let mut opts = CorrectOptions::for_accuracy(accuracy_mm);
    let clock = Instant::now();
    let mut next = Some(correct_program(model, &scene.tool, program, &start, &opts).map_err(cerr)?);
    timings.push(("correct 1".into(), clock.elapsed().as_secs_f64()));
    // Pass 0, the program as given. Its faces may be too far off to find: then no figure.
    let given = uncorrected(&scene.chain, program, &start).map_err(cerr)?;
    let mut iterations = vec![match measure(0, None, &given, &mut timings) {
        Ok(it) => it,
        Err(PipelineError::Correct {
            source: CorrectError::Face { .. },
            ..
        }) => CorrectIteration {
            iteration: 0,
            path_tolerance_mm: None,
            blocks: given.blocks.len(),
            path: path_error(&scene.chain, &scene.tool, program, &given),
            part: crate::calibration::correct::PartError::default(),
            faces: crate::calibration::correct::FaceCheck {
                faces: Vec::new(),
                step_mm: None,
            },
            predicted_error_mm: None,
            sweep: SweepReport::default(),
        },
        Err(e) => return Err(e),
    }];
    let mut status = String::new();
    let mut met = false;
    let mut last = None;
    for pass in 1..=MAX_CORRECT_PASSES {
        let cp = match next.take() {
            Some(cp) => cp,
            None => {
                let clock = Instant::now();
                let cp =
                    correct_program(model, &scene.tool, program, &start, &opts).map_err(cerr)?;
                timings.push((format!("correct {pass}"), clock.elapsed().as_secs_f64()));
                cp
            }
        };
        let it = measure(pass, Some(opts.path_tolerance_mm), &cp, &mut timings)?;
        let residual = cp.summary.residual_max_mm;
        // The same path on the model corrected for: what the correction itself leaves.
        let on_model = path_error(model, &scene.tool, program, &cp).max_mm - residual;
        let it_has_faces = it.predicted_error_mm.is_some();
        let faces_ok = it.predicted_error_mm.is_none_or(|e| e <= accuracy_mm);
        let path_ok = it.path.max_mm <= accuracy_mm;
        // Path error beyond what no command can remove: subdivision, rounding, the model.
        let correctable = it.path.max_mm - residual;
        iterations.push(it);
        last = Some(cp);
        if faces_ok && path_ok {
            met = true;
            let what = if it_has_faces {
                "faces and path"
            } else {
                "path (no faces named)"
            };
            status = format!("met in {pass} pass(es): {what} within {accuracy_mm} mm");
            break;
        }
        if correctable <= accuracy_mm && faces_ok {
            let faces = if it_has_faces {
                format!("faces within {accuracy_mm} mm; ")
            } else {
                String::new()
            };
            status = format!(
                "{faces}the path is off by up to {residual:.6} mm at the flute's ends \
                 because of deviations these axes cannot correct (see uncorrectable)"
            );
            break;
        }
        if correctable <= accuracy_mm {
            status = format!(
                "the faces are off by up to {:.6} mm although the path is within reach; \
                 the model corrected for differs from the simulated machine, or deviations these \
                 axes cannot correct reach the faces (see uncorrectable)",
                iterations
                    .last()
                    .and_then(|i| i.predicted_error_mm)
                    .unwrap_or(Real::NAN)
            );
            break;
        }
        if on_model <= accuracy_mm {
            // Finer sub-moves cannot remove what they did not cause.
            status = format!(
                "the path is off by {correctable:.6} mm beyond the uncorrectable residual \
                 on the simulated machine but only {on_model:.6} mm on the model corrected for: \
                 the model differs from the simulated machine"
            );
            break;
        }
        opts.path_tolerance_mm /= 4.0;
        status = format!(
            "after {pass} pass(es) the path is still off by {correctable:.6} mm beyond the residual"
        );
    }
    let corrected = last.unwrap_or(given);
    // Each deviation alone: what no axis command removes.
    let clock = Instant::now();
    let mut uncorrectable = Vec::new();
    for (name, value) in nonzero_deviations(model) {
        let mut alone = model.nominal();
        if let Ok(id) = alone.deviation_id(&name) {
            alone.set_deviation(id, value);
        }
        let cp = correct_program(
            &alone,
            &scene.tool,
            program,
            &start,
            &CorrectOptions::for_accuracy(accuracy_mm),
        )
        .map_err(cerr)?;
        uncorrectable.push(UncorrectableReport {
            deviation: name,
            value,
            residual_rms_mm: cp.summary.residual_rms_mm,
            residual_max_mm: cp.summary.residual_max_mm,
        });
    }
    timings.push(("uncorrectable".into(), clock.elapsed().as_secs_f64()));
    let corrected_for = nonzero_deviations(model);
    let file = format!("{}-corrected.ngc", scene.name);
    let fin = iterations.last().cloned();
    let mut header = vec![
        format!(
            "twinmill correct: {} corrected for the machine of scene {}",
            program.path.display(),
            scene.name
        ),
        format!(
            "deviations corrected for, mm and rad: {}",
            if corrected_for.is_empty() {
                "none".to_string()
            } else {
                corrected_for
                    .iter()
                    .map(|(k, v)| format!("{k} = {v}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        ),
    ];
    if let Some(f) = &fin {
        let faces = match f.predicted_error_mm {
            Some(e) => format!("faces within {e:.6} mm, "),
            None => String::new(),
        };
        header.push(format!(
            "predicted on the twin: {faces}path within {:.6} mm, accuracy asked {} mm",
            f.path.max_mm, accuracy_mm
        ));
    }
    header.push("each block names its source line, subdivided moves also their part k/n".into());
    let report = CorrectReport {
        scene: scene.name.clone(),
        program: program.path.display().to_string(),
        corrected_program: file,
        corrected_for,
        simulated: scene.injected.clone(),
        accuracy_mm,
        met,
        status,
        iterations,
        correction: corrected.summary,
        uncorrectable,
        moves: corrected.per_move.clone(),
        timings_s: timings,
    };
    Ok(CorrectOutcome {
        report,
        corrected,
        header,
    })
}

/// The model to correct for from a run's identification: the scene's identification model
/// (nominal plus known deviations) with the identified values set. A combination such as
/// `gamma_AY+gamma_YX` sets its first deviation so that the sum is the identified value,
/// the others staying at their known values. Errors if nothing was identified.
pub fn identified_model(scene: &Scene, report: &Report) -> Result<Chain, PipelineError> {
    let err = |message: String| PipelineError::Measure {
        path: scene.path.display().to_string(),
        message,
    };
    if report.identified.is_empty() {
        return Err(err(format!(
            "no deviation was identified from the scan (not identifiable: {})",
            report.not_identified.join(", ")
        )));
    }
    let mut model = scene.model.clone();
    for (name, value) in &report.identified {
        let mut parts = name.split('+');
        let first = parts.next().unwrap_or_default();
        let mut rest = 0.0;
        for other in parts {
            let id = model.deviation_id(other).map_err(|e| err(e.to_string()))?;
            rest += model.deviation(id);
        }
        let id = model.deviation_id(first).map_err(|e| err(e.to_string()))?;
        model.set_deviation(id, value - rest);
    }
    Ok(model)
}

// ---------------------------------------------------------------------------------------
// General identification: `twinmill identify`.

/// Everything `identify_scene` produces.
#[derive(Clone, Debug)]
pub struct IdentifyOutcome {
    /// The report.
    pub report: IdentifyReport,
    /// The cloud the features were measured in.
    pub cloud: PointCloud,
    /// The final identification (last loop round).
    pub identification: Identification,
    /// The twin after the loop: the model chain with the determined directions updated.
    pub twin: Chain,
}

/// Most rounds of the model-correction loop: the solve converges in one; a second confirms.
const MAX_ROUNDS: usize = 5;

/// Measures every face of the scene in `points` as a plane feature.
pub fn extract_features(
    scene: &Scene,
    program: &Program,
    points: &[Point3],
) -> Result<Vec<Feature>, PipelineError> {
    scene
        .faces
        .iter()
        .map(|spec| {
            extract_plane_feature(
                points,
                spec,
                &program.moves,
                &scene.model,
                &scene.tool,
                &scene.stock_box,
                &scene.face_options,
            )
            .map(Feature::Plane)
            .map_err(|source| PipelineError::Calibrate {
                path: scene.path.display().to_string(),
                source,
            })
        })
        .collect()
}

/// A sweep error located at the program line it names, or at the scene's `[sweep]`.
fn sweep_failed<'a>(
    program: &'a Program,
    scene_path: &'a str,
) -> impl Fn(SweepError) -> PipelineError + 'a {
    move |source| {
        let location = match source.line() {
            Some(line) => format!("{}:{line}", program.path.display()),
            None => format!("{scene_path}: [sweep]"),
        };
        PipelineError::Sweep { location, source }
    }
}

fn scene_ids(scene: &Scene) -> Result<Vec<DeviationId>, PipelineError> {
    let err = |source| PipelineError::Calibrate {
        path: scene.path.display().to_string(),
        source,
    };
    if scene.parameters.is_empty() {
        return Err(err(CalibrateError::NoParameters));
    }
    Ok(scene
        .parameters
        .iter()
        .filter_map(|n| scene.model.deviation_id(n).ok())
        .collect())
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
        let Feature::Plane(p) = f;
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
/// its predicted faces with the measured ones over each face's extent ([`face_match`]) →
/// repeat, re-identifying from the updated twin, until every face agrees within
/// `tolerance_mm` or what its scan noise allows (a twin cannot match noise better than the
/// noise).
pub fn correction_loop(
    model: &Chain,
    ids: &[DeviationId],
    tool: &crate::cutting::tool::Tool,
    features: &[Feature],
    registration: Registration,
    tolerance_mm: Real,
) -> Result<(Identification, Chain, Vec<LoopRound>, bool), CalibrateError> {
    let mut twin = model.clone();
    let mut rounds = Vec::new();
    let mut last = None;
    let mut converged = false;
    for round in 1..=MAX_ROUNDS {
        let m = Model {
            chain: &twin,
            ids,
            tool,
            features,
            registration,
        };
        let ident = crate::calibration::calibrate::identify(&m)?;
        for (id, v) in ids.iter().zip(&ident.solution) {
            twin.set_deviation(*id, *v);
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
    let ids = scene_ids(scene)?;
    let mut timings = Vec::new();
    let mut clock = Instant::now();
    let mut lap = |name: &str, timings: &mut Vec<(String, Real)>| {
        timings.push((name.to_string(), clock.elapsed().as_secs_f64()));
        clock = Instant::now();
    };
    let (cloud, source, surface) = match cloud {
        Some((c, src)) => (c.clone(), src.to_string(), None),
        None => {
            let scanner = scene.scanner_for("identify")?;
            let part = machine_part(scene, program, progress)?;
            let surface = Surface::new(&part.stock);
            let scanned =
                surface
                    .scan(scanner, progress)
                    .map_err(|source| PipelineError::Scan {
                        path: spath.clone(),
                        source,
                    })?;
            (scanned.cloud, "simulated scan".to_string(), Some(surface))
        }
    };
    lap("scan", &mut timings);
    let features = extract_features(scene, program, &cloud.points)?;
    lap("fit", &mut timings);
    let (ident, twin, rounds, converged) = correction_loop(
        &scene.model,
        &ids,
        &scene.tool,
        &features,
        scene.registration,
        scene.loop_tolerance_mm,
    )
    .map_err(cal)?;
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
            let f = extract_features(scene, program, &scanned.cloud.points)?;
            let m = Model {
                chain: &scene.model,
                ids: &ids,
                tool: &scene.tool,
                features: &f,
                registration: scene.registration,
            };
            let r = crate::calibration::calibrate::identify(&m).map_err(cal)?;
            // Values of the main run's quantities (same coefficients) in this trial.
            for e in ident.parameters.iter().chain(&ident.combinations) {
                let v: Real = e
                    .coefficients
                    .iter()
                    .zip(&r.solution)
                    .map(|(c, x)| c * x)
                    .sum();
                samples.entry(e.name.clone()).or_default().push(v);
            }
            mc_trials += 1;
        }
        lap("monte carlo", &mut timings);
    }
    let truth: Vec<Real> = ids.iter().map(|id| scene.chain.deviation(*id)).collect();
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
        injected: simulated.then(|| e.coefficients.iter().zip(&truth).map(|(c, t)| c * t).sum()),
        coefficients: e.coefficients.clone(),
    };
    let id = &ident.identifiability;
    let report = IdentifyReport {
        scene: scene.name.clone(),
        chain: scene.chain.to_string(),
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
        condition_number: id.condition_number,
        condition_number_determined: id.condition_number_determined,
        identified: ident.parameters.iter().map(estimate).collect(),
        combinations: ident.combinations.iter().map(estimate).collect(),
        not_determined: id
            .undetermined_combinations
            .iter()
            .map(|c| c.name.clone())
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
        rounds,
        converged,
        monte_carlo_trials: mc_trials,
        timings_s: timings,
    };
    Ok(IdentifyOutcome {
        report,
        cloud,
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
    use crate::math::UnitVector3;
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
