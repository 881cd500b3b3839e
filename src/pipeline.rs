//! The main job: program → sweep through the deviated chain → scan → fit → identify →
//! report, on a loaded scene. Pure: it returns everything it made and writes nothing.
//!
//! **Invariant:** `run` has no side effects beyond the progress calls; the same scene and
//! program give the same outcome (except the timings) for any thread count.

use crate::cloud::PointCloud;
use crate::fit::Plane;
use crate::fit::{
    RobustRule, fit_circle, fit_circle_robust, fit_cylinder, fit_cylinder_robust, fit_plane,
    fit_plane_robust, fit_sphere, fit_sphere_robust, plane_distance_and_angle,
};
use crate::identify::{self, Face, IdentifyError};
use crate::math::Aabb;
use crate::math::{Point3, Real};
use crate::mesh::{MeshError, TriMesh, mesh_stock};
use crate::nc::Program;
use crate::progress::Progress;
use crate::render::{
    HeatMapOptions, RenderError, encode_png, nice_ceil, render_heat_map, render_top_view,
};
use crate::report::{
    CircleReport, CylinderReport, FaceReport, FitFileReport, MeshSummary, PlanePair, PlaneReport,
    Report, ScanReport, SimulationReport, SolverReport, SphereReport, StockReport, StudyCase,
};
use crate::scan::{Misregistration, ScanError, StudyOptions, Surface, scan};
use crate::scene::Scene;
use crate::segment::{
    PlaneSegmentOptions, RansacOptions, estimate_normals, ransac_cylinder, ransac_sphere,
    segment_planes, select_box, select_region_from_seed,
};
use crate::stock::{StockError, TriDexel};
use crate::sweep::{SweepError, SweepReport, sweep_program};
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

/// Makes the stock and sweeps the program through the scene's deviated chain.
pub fn machine_part(
    scene: &Scene,
    program: &Program,
    progress: &dyn Progress,
) -> Result<Part, PipelineError> {
    let spath = scene.path.display().to_string();
    let clock = Instant::now();
    let mut stock = TriDexel::new_box(scene.stock_box, scene.pitch_mm, scene.memory_budget_bytes)
        .map_err(|source| PipelineError::Stock {
        path: spath.clone(),
        source,
    })?;
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
    .map_err(|source| {
        let location = match source.line() {
            Some(line) => format!("{}:{line}", program.path.display()),
            None => format!("{spath}: [sweep]"),
        };
        PipelineError::Sweep { location, source }
    })?;
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

    let scanned = scan(&stock, &scene.scanner, progress).map_err(|source| PipelineError::Scan {
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
    let edge = 2.0 * scene.scanner.pitch_mm;
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
            point_pitch_mm: 1.5 * scene.scanner.pitch_mm,
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
        scan: ScanReport::of(&scanned, &scene.scanner),
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
    let spath = scene.path.display().to_string();
    let base = &scene.scanner;
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
    let candidates = |found: Result<Vec<u32>, crate::segment::SegmentError>| -> Result<Vec<Point3>, PipelineError> {
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
}

/// Cuts the scene's program into its stock on the deviated machine and meshes the result:
/// no scan, no identification.
pub fn simulate(
    scene: &Scene,
    program: &Program,
    progress: &dyn Progress,
) -> Result<Simulation, PipelineError> {
    let path = scene.path.display().to_string();
    let part = machine_part(scene, program, progress)?;
    let mut timings: BTreeMap<String, Real> = part.timings.iter().cloned().collect();
    let clock = Instant::now();
    let (mesh, mesh_report) = mesh_stock(&part.stock).map_err(|source| PipelineError::Mesh {
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
    let img = render_top_view(&part.stock, &title).map_err(render_err)?;
    let top_view_png = encode_png(&img).map_err(render_err)?;
    timings.insert("render".into(), clock.elapsed().as_secs_f64());
    let report = SimulationReport {
        scene: scene.name.clone(),
        program: program.path.display().to_string(),
        stock: StockReport::of(&part.stock, part.volume0),
        sweep: part.sweep,
        mesh: MeshSummary {
            vertices: mesh.vertices.len(),
            triangles: mesh.triangles.len(),
            euler_characteristic: mesh.euler_characteristic(),
            volume_mm3: mesh.signed_volume(),
            area_mm2: mesh.area(),
            feature_vertices: mesh_report.feature_vertices,
        },
        timings_s: timings,
    };
    Ok(Simulation {
        report,
        mesh,
        top_view_png,
    })
}
