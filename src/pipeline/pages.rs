//! What the commands' pages and part pictures need from a scene: the part the deviations
//! are measured from ([`reference_part`]: the design model, or the program cut on the
//! nominal machine), the cut part's display mesh with its deviations and the view that
//! shows its machined faces ([`display_part`]), `part.png` ([`part_png`]), the 3-D view of
//! a part and a cloud ([`view`]), and the page of `run`, `scan`, `identify`, `design` and
//! `correct` ([`run_page`], [`scan_page`], [`identify_page`], [`design_page`],
//! [`correct_page`]; `simulate` makes its own), and the pages of the commands whose
//! reports live here: the rotary-axis tests of `measure` ([`rotary_page`]), the hexapod's
//! ball bar ([`hexapod_ballbar_page`]) and calibration ([`calibrate_page`]).

use super::{PipelineError, make_stock, sweep_failed};
use crate::calibration::calibrate::Feature;
use crate::cutting::mesh::{TriMesh, mesh_stock};
use crate::cutting::stock::TriDexel;
use crate::cutting::sweep::{Kinematics, sweep_program};
use crate::machine::hexapod::{HexapodTwin, TableAxes};
use crate::math::{Point3, Real, UnitVector3, Vector3};
use crate::nc::Move;
use crate::progress::NoProgress;
use crate::report::deviation_map::DeviationError;
use crate::report::display::ReferenceSurface;
use crate::report::display::{self, DisplayMesh};
use crate::report::html::{Marker, View3d, render_page};
use crate::report::pages::{self as page, FittedPlane, PartGeometry, View3dParts};
use crate::report::part_view::{PartViewOptions, render_part_view};
use crate::report::render::encode_png;
use crate::report::{CorrectReport, DesignReport, IdentifyReport, ScanFileReport};
use crate::scene::Scene;

/// What a part's deviation is measured from.
pub struct Reference {
    /// The reference surface; `None` when the deviation is not computed.
    pub model: Option<ReferenceSurface>,
    /// Its name ("the nominal part", the design file) or why there is none.
    pub what: String,
}

/// The part the deviations are measured from: the scene's design model if it has one; else,
/// when the scene's machine has deviations or error motions, the same program cut on the
/// nominal machine (swept, meshed and closed like the part itself); else none, since the
/// part is then the nominal part (deviation 0 everywhere).
pub fn reference_part(scene: &Scene, moves: &[Move]) -> Result<Reference, PipelineError> {
    if let Some((path, design)) = &scene.design {
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        let m = design.mesh();
        return Ok(Reference {
            model: ReferenceSurface::new(m.vertices().to_vec(), m.triangles().to_vec()),
            what: format!("the design {name}"),
        });
    }
    let nominal = scene.chain.nominal();
    // A hexapod's nominal machine: the actual one with the nominal parameters.
    let nominal_twin = scene.hexapod.as_ref().map(|t| HexapodTwin {
        actual: t.nominal.clone(),
        table: t.table.as_ref().map(|a| TableAxes {
            nominal: a.nominal.clone(),
            actual: a.nominal.clone(),
        }),
        ..t.clone()
    });
    let perfect = match (&scene.hexapod, &nominal_twin) {
        (Some(t), Some(n)) => t == n,
        _ => scene.chain == nominal,
    };
    if perfect {
        return Ok(Reference {
            model: None,
            what: "the machine has no deviations, so the part is the nominal part (deviation 0)"
                .into(),
        });
    }
    let spath = scene.path.display().to_string();
    let mut stock = make_stock(scene)?;
    let machine = match &nominal_twin {
        Some(t) => Kinematics::Poses(t),
        None => Kinematics::Chain(&nominal),
    };
    sweep_program(
        &mut stock,
        machine,
        &scene.tool,
        moves,
        &scene.sweep,
        &NoProgress,
    )
    .map_err(|source| PipelineError::Sweep {
        location: format!("{spath}: nominal part"),
        source,
    })?;
    let (mesh, _) = mesh_stock(&stock).map_err(|source| PipelineError::Mesh {
        path: spath.clone(),
        source,
    })?;
    let model =
        ReferenceSurface::new(mesh.vertices, mesh.triangles).ok_or(PipelineError::Deviation {
            path: spath,
            source: DeviationError::BadDesign,
        })?;
    Ok(Reference {
        model: Some(model),
        what: "the nominal part".into(),
    })
}

/// A cut part ready to show.
pub struct DisplayPart {
    /// Its display mesh.
    pub mesh: DisplayMesh,
    /// Deviation at each corner of each display triangle from the reference (mm), when
    /// there is one.
    pub deviations: Option<Vec<[Real; 3]>>,
    /// What the deviation is from, or why there is none.
    pub reference: String,
    /// From the part towards the eye, and the screen's up.
    pub view: (UnitVector3, Vector3),
}

/// The display mesh of `mesh` (the part cut from `scene`'s stock), its deviations from the
/// reference `reference` makes (made while the mesh is simplified) and its view: the
/// scene's `[report] view`, else the direction its machined faces face.
pub fn display_part(
    scene: &Scene,
    mesh: &TriMesh,
    reference: impl FnOnce() -> Result<Reference, PipelineError> + Send,
) -> Result<DisplayPart, PipelineError> {
    let (shown, reference) = rayon::join(
        || display::simplify(mesh, display::MAX_TRIANGLES),
        reference,
    );
    let reference = reference?;
    let deviations = reference
        .model
        .as_ref()
        .map(|m| display::deviations(&shown, m));
    let view = match scene.view {
        Some(eye) => (eye, display::view_up(&eye)),
        None => display::view_direction(&shown, &scene.stock_box),
    };
    Ok(DisplayPart {
        mesh: shown,
        deviations,
        reference: reference.what,
        view,
    })
}

/// `part.png`: the display part shaded from its view, coloured by deviation where known.
pub fn part_png(scene: &Scene, part: &DisplayPart) -> Result<Vec<u8>, PipelineError> {
    let range = part
        .deviations
        .as_deref()
        .map_or(1e-3, |d| display::area_colour_range_mm(&part.mesh, d));
    let title = match part.deviations {
        Some(_) => format!(
            "{}: cut part, deviation from {}",
            scene.name, part.reference
        ),
        None => format!("{}: cut part", scene.name),
    };
    let opts = PartViewOptions {
        title,
        width_px: 1100,
        height_px: 800,
        eye: part.view.0,
        up: part.view.1,
        range_mm: range,
        no_deviation: format!("grey: {}", part.reference),
    };
    render_part_view(&part.mesh, part.deviations.as_deref(), &opts)
        .and_then(|img| encode_png(&img))
        .map_err(|source| PipelineError::Render {
            path: scene.path.display().to_string(),
            source,
        })
}

/// The 3-D view of a part, a cloud with its fitted planes or residuals, and markers.
pub fn view(
    scene: &Scene,
    part: Option<&DisplayPart>,
    cloud: Option<&[Point3]>,
    planes: Vec<FittedPlane>,
    residuals: Option<(Vec<Option<Real>>, String)>,
    markers: Vec<Marker>,
) -> Result<View3d, PipelineError> {
    let parts = View3dParts {
        part: part.map(|p| PartGeometry {
            mesh: &p.mesh,
            deviations: p.deviations.as_deref(),
            reference: p.reference.clone(),
        }),
        cloud,
        planes,
        residuals,
        markers,
        view: part.map(|p| p.view),
    };
    page::part_view3d(&parts).map_err(|e| PipelineError::Page {
        path: scene.path.display().to_string(),
        message: e.to_string(),
    })
}

/// `run`'s page: the part coloured by its deviation from the part the nominal machine cuts,
/// the cloud coloured by residual from the fitted faces, the faces' outlines, the faces' map.
pub fn run_page(
    scene: &Scene,
    program: &crate::nc::Program,
    outcome: &super::Outcome,
) -> Result<String, PipelineError> {
    let (mesh, _) = mesh_stock(&outcome.stock).map_err(|source| PipelineError::Mesh {
        path: scene.path.display().to_string(),
        source,
    })?;
    let shown = display_part(scene, &mesh, || reference_part(scene, &program.moves))?;
    let v = view(
        scene,
        Some(&shown),
        Some(&outcome.cloud.points),
        outcome.planes.clone(),
        None,
        Vec::new(),
    )?;
    let plots = vec![crate::report::html::Plot {
        caption: "The scanned faces, each point's distance from the nominal plane (faces.png as SVG, binned).".into(),
        svg: outcome.faces_svg.clone(),
    }];
    Ok(render_page(&page::run_page(
        &outcome.report,
        Some(v),
        plots,
    )))
}

/// Plane features as fitted planes over the cloud: each point belongs to the nearest
/// feature plane within four of its RMS residuals (at least 20 µm).
fn feature_planes(
    cloud: &[Point3],
    features: &[Feature],
    report: &IdentifyReport,
) -> Vec<FittedPlane> {
    let planes: Vec<(String, crate::metrology::fit::Plane, Real)> = features
        .iter()
        .filter_map(|f| match f {
            Feature::Plane(p) => {
                let rms = report
                    .features
                    .iter()
                    .find(|r| r.name == p.name)
                    .map_or(0.0, |r| r.rms_mm);
                Some((p.name.clone(), p.plane, (4.0 * rms).max(0.02)))
            }
            Feature::Ball(_) => None,
        })
        .collect();
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); planes.len()];
    for (i, p) in cloud.iter().enumerate() {
        let best = planes
            .iter()
            .enumerate()
            .map(|(k, (_, pl, band))| (k, pl.signed_distance(p).abs(), *band))
            .filter(|(_, d, band)| d <= band)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((k, _, _)) = best {
            members[k].push(i);
        }
    }
    planes
        .into_iter()
        .zip(members)
        .map(|((name, plane, _), points)| FittedPlane {
            name,
            plane,
            points,
        })
        .collect()
}

/// `identify`'s page: the cloud coloured by residual from its features' planes.
pub fn identify_page(
    scene: &Scene,
    report: &IdentifyReport,
    cloud: &[Point3],
    features: &[Feature],
) -> Result<String, PipelineError> {
    let planes = feature_planes(cloud, features, report);
    let v = view(scene, None, Some(cloud), planes, None, Vec::new())?;
    Ok(render_page(&page::identify_page(report, Some(v))))
}

/// `design`'s page: the verifying identification's cloud and planes.
pub fn design_page(
    scene: &Scene,
    report: &DesignReport,
    verified: &super::IdentifyOutcome,
) -> Result<String, PipelineError> {
    let cloud = &verified.cloud.points;
    let planes = feature_planes(cloud, &verified.features, &verified.report);
    let v = view(scene, None, Some(cloud), planes, None, Vec::new())?;
    Ok(render_page(&page::design_page(
        report,
        &verified.report,
        Some(v),
    )))
}

/// `scan`'s page: the cut part and the cloud coloured by each point's distance from the cut
/// surface (the scanner's error).
pub fn scan_page(
    scene: &Scene,
    report: &ScanFileReport,
    stock: &TriDexel,
    cloud: &[Point3],
) -> Result<String, PipelineError> {
    let spath = scene.path.display().to_string();
    let (mesh, _) = mesh_stock(stock).map_err(|source| PipelineError::Mesh {
        path: spath.clone(),
        source,
    })?;
    let shown = display_part(scene, &mesh, || {
        Ok(Reference {
            model: None,
            what: "scan shows the cut part itself".into(),
        })
    })?;
    let surface = ReferenceSurface::new(mesh.vertices, mesh.triangles);
    let residuals = surface.map(|m| {
        let keep = display::decimate(cloud.len(), display::MAX_POINTS);
        let mut r = vec![None; cloud.len()];
        let d = display::distances(&keep.iter().map(|&i| cloud[i]).collect::<Vec<_>>(), &m);
        for (k, i) in keep.into_iter().enumerate() {
            r[i] = Some(d[k]);
        }
        (r, "the cut surface (the scanner's error)".to_string())
    });
    let v = view(
        scene,
        Some(&shown),
        Some(cloud),
        Vec::new(),
        residuals,
        Vec::new(),
    )?;
    let mut v = v;
    v.shown.push("cloud".into());
    Ok(render_page(&page::scan_page(report, Some(v))))
}

/// `correct`'s page: the corrected program cut on the scene's machine, coloured by its
/// deviation from the nominal part.
pub fn correct_page(
    scene: &Scene,
    program: &crate::nc::Program,
    report: &CorrectReport,
    corrected: &[Move],
) -> Result<String, PipelineError> {
    let spath = scene.path.display().to_string();
    let mut stock = make_stock(scene)?;
    sweep_program(
        &mut stock,
        &scene.chain,
        &scene.tool,
        corrected,
        &scene.sweep,
        &NoProgress,
    )
    .map_err(sweep_failed(program, &spath))?;
    let (mesh, _) = mesh_stock(&stock).map_err(|source| PipelineError::Mesh {
        path: spath.clone(),
        source,
    })?;
    let shown = display_part(scene, &mesh, || {
        let mut r = reference_part(scene, &program.moves)?;
        if r.model.is_some() && scene.design.is_none() {
            r.what = "the nominal part (the program as given, on the nominal machine)".into();
        }
        Ok(r)
    })?;
    let v = view(scene, Some(&shown), None, Vec::new(), None, Vec::new())?;
    let mut v = v;
    v.notes.insert(
        0,
        "The corrected program cut on the scene's (deviated) machine.".into(),
    );
    Ok(render_page(&page::correct_page(report, Some(v))))
}

/// A term's value or σ in its unit: µrad for tilts, µm for offsets.
fn term_text(name: &str, v: Real, signed: bool) -> String {
    let (k, unit) = if super::is_angle_term(name) {
        (1e6, "µrad")
    } else {
        (1e3, "µm")
    };
    if signed {
        format!("{:+.4} {unit}", v * k)
    } else {
        format!("{:.4} {unit}", v * k)
    }
}

/// `measure --instrument ball-sensor | probe`'s page: ISO 10791-6's deviation ranges per
/// sweep and the trace, the identified location terms with σ, what is not determined, the
/// singular values; `summary` is what the CLI prints.
pub fn rotary_page(out: &super::RotaryOutcome, summary: &str) -> String {
    use crate::report::html::{Plot, Section};
    let rep = &out.report;
    let mut sections = vec![Section {
        heading: "ISO 10791-6 deviation ranges".into(),
        intro: format!(
            "{} measurements with the {}: per sweep, the range (max − min) of each coordinate of the ball's deviation from the table-side point, and its largest distance from it (µm).",
            rep.samples, rep.instrument
        ),
        columns: [
            "sweep",
            "axis",
            "from (°)",
            "to (°)",
            "samples",
            "X",
            "Y",
            "Z",
            "max distance",
        ]
        .map(String::from)
        .to_vec(),
        rows: rep
            .sweeps
            .iter()
            .map(|f| {
                vec![
                    f.sweep.to_string(),
                    f.axis.to_string(),
                    format!("{}", f.range_deg[0]),
                    format!("{}", f.range_deg[1]),
                    f.samples.to_string(),
                    format!("{:.4}", f.deviation_range_mm[0] * 1e3),
                    format!("{:.4}", f.deviation_range_mm[1] * 1e3),
                    format!("{:.4}", f.deviation_range_mm[2] * 1e3),
                    format!("{:.4}", f.max_distance_mm * 1e3),
                ]
            })
            .collect(),
    }];
    let mut plots = Vec::new();
    match crate::report::svg::rotary_trace_svg(
        &out.samples,
        &format!("ISO 10791-6 {}: {}", rep.instrument, rep.scene),
    ) {
        Ok(svg) => plots.push(Plot {
            caption: "The deviation of the ball from the table-side point, X red, Y blue, Z green (µm), measurement by measurement.".into(),
            svg,
        }),
        Err(e) => plots.push(Plot {
            caption: format!("The deviation trace is not drawn: {e}."),
            svg: String::new(),
        }),
    }
    if let Some(id) = &rep.identification {
        let rows = |ts: &[super::TermReport]| -> Vec<Vec<String>> {
            ts.iter()
                .map(|t| {
                    vec![
                        t.name.clone(),
                        term_text(&t.name, t.value, true),
                        term_text(&t.name, t.sigma, false),
                        t.injected
                            .map_or_else(|| "—".into(), |v| term_text(&t.name, v, true)),
                    ]
                })
                .collect()
        };
        let cols = ["term", "value", "σ", "injected by the scene"]
            .map(String::from)
            .to_vec();
        sections.push(Section {
            heading: "Identified location terms".into(),
            intro: format!(
                "Solved for {}; each identified term with its standard uncertainty σ (offsets µm, tilts µrad).",
                id.terms.join(", ")
            ),
            columns: cols.clone(),
            rows: rows(&id.identified),
        });
        if !id.combinations.is_empty() {
            sections.push(Section {
                heading: "Determined combinations".into(),
                intro: "Combinations the test determines though their members are not determined alone.".into(),
                columns: cols,
                rows: rows(&id.combinations),
            });
        }
        sections.extend(page::list_section(
            "Not determined",
            "Directions the test does not determine, held at the model's values: a table-side point cannot see them.",
            &id.not_determined,
        ));
        sections.extend(page::list_section(
            "No data",
            "Terms no measurement depends on: add sweeps of their axis.",
            &id.no_data,
        ));
        let threshold = 1.0 / crate::calibration::calibrate::DETERMINED_FRACTION;
        let mut sv: Vec<Vec<String>> = id
            .singular_values
            .iter()
            .enumerate()
            .map(|(i, s)| {
                vec![
                    (i + 1).to_string(),
                    format!("{s:.6e}"),
                    if *s >= threshold {
                        "determined"
                    } else {
                        "not determined"
                    }
                    .into(),
                ]
            })
            .collect();
        sv.push(vec![
            "χ²".into(),
            format!("{:.6e}", id.chi2),
            format!("{} degrees of freedom", id.dof),
        ]);
        sections.push(Section {
            heading: "Identifiability".into(),
            intro: format!("Singular values of the Jacobian scaled by each term's realistic magnitude and whitened by the measurements' σ; a direction is determined from {threshold}."),
            columns: vec!["#".into(), "singular value".into(), "".into()],
            rows: sv,
        });
        let p = id.fixed_point_mm;
        let sp = id.fixed_point_sigma_mm;
        sections.push(Section {
            heading: "Table-side point".into(),
            intro: "Where the identification puts the sensor's measuring point or the sphere's centre (workpiece frame), estimated with the terms.".into(),
            columns: vec!["coordinate".into(), "mm".into(), "σ (mm)".into()],
            rows: ["x", "y", "z"]
                .iter()
                .enumerate()
                .map(|(k, c)| vec![(*c).into(), format!("{:+.6}", p[k]), format!("{:.3e}", sp[k])])
                .collect(),
        });
        plots.extend(page::spectrum_plot(
            &id.singular_values,
            Some(threshold),
            "Singular values of the scaled Jacobian: dark bars are determined directions, light ones are not.",
        ));
    }
    render_page(&page::instrument_page(
        format!(
            "twinmill measure --instrument {}: {}",
            rep.instrument, rep.scene
        ),
        summary.into(),
        sections,
        plots,
        page::json(rep),
    ))
}

/// `twinmill ballbar`'s page: the hexapod's circle as ISO 230-4 evaluates it.
pub fn hexapod_ballbar_page(scene: &str, o: &super::dbb::BallbarOutcome) -> String {
    render_page(&page::circular_page(
        &format!("twinmill ballbar: {scene}"),
        &o.summary,
        &o.samples,
        &o.figures,
        &format!("ISO 230-4: {scene}"),
        page::json(o),
    ))
}

/// `twinmill calibrate`'s page: the identified parameters with σ beside the injected
/// ones, the singular values, what the readings do not determine and why (the gauge), the
/// pose errors before and after, the working times and the trials.
pub fn calibrate_page(scene: &str, o: &super::dbb::CalibrateOutcome) -> String {
    use crate::calibration::hexapod_calibrate::RANK_TOLERANCE;
    use crate::report::html::Section;
    let c = &o.run.calibration;
    let id = &c.identifiability;
    let mut sections = vec![Section {
        heading: "Identifiability".into(),
        intro: format!(
            "{} unknowns ({} parameters{}); a direction is determined when its singular value is at least {RANK_TOLERANCE:e} of the largest.",
            id.unknowns,
            id.unknowns - id.ball_unknowns,
            if id.ball_unknowns > 0 {
                format!(" and {} table-ball coordinates", id.ball_unknowns)
            } else {
                String::new()
            }
        ),
        columns: vec!["figure".into(), "value".into()],
        rows: vec![
            vec!["rank".into(), id.rank.to_string()],
            vec![
                "parameters determined".into(),
                format!("{} of 24", id.parameters_determined),
            ],
            vec![
                "condition number (determined)".into(),
                format!("{:.6e}", id.condition_number),
            ],
            vec![
                "undetermined outside the gauge".into(),
                format!("{:.3e}", id.undetermined_outside_gauge),
            ],
            vec![
                "residual rms (µm)".into(),
                format!("{:.4}", c.residual_rms_mm * 1e3),
            ],
            vec![
                "σ of a reading (µm)".into(),
                format!("{:.4}", c.sigma_mm * 1e3),
            ],
            vec!["Gauss–Newton iterations".into(), c.iterations.to_string()],
        ],
    }];
    if id.gauge.is_empty() {
        sections.push(Section {
            heading: "Not determined".into(),
            intro: "Nothing: the plate's balls are known, so they fix the table frame and every parameter is determined.".into(),
            columns: Vec::new(),
            rows: Vec::new(),
        });
    } else {
        sections.extend(page::list_section(
            "Not determined (the gauge)",
            "The ball bar measures lengths only: moving the base frame rigidly together with the table balls changes no reading, so its six rigid motions are not determined. The base joints are reported with their rigid motion removed (best fit to nominal).",
            &id.gauge,
        ));
    }
    sections.extend(page::list_section(
        "Weakly determined",
        "Directions the readings determine with σ above a tenth of their magnitude: solved, their large σ carried into the parameters'.",
        &id.weak,
    ));
    sections.push(Section {
        heading: "Identified parameters".into(),
        intro: "Each parameter's deviation from nominal, identified with its standard uncertainty σ, beside the deviation the scene injects (in the same gauge).".into(),
        columns: ["parameter", "injected (mm)", "identified (mm)", "σ (µm)", "|identified − injected| / σ"]
            .map(String::from)
            .to_vec(),
        rows: o
            .run
            .parameters
            .iter()
            .map(|p| {
                vec![
                    p.name.clone(),
                    format!("{:+.6}", p.injected_mm),
                    format!("{:+.6}", p.identified_mm),
                    format!("{:.4}", p.sigma_mm * 1e3),
                    format!("{:.2}", (p.identified_mm - p.injected_mm).abs() / p.sigma_mm),
                ]
            })
            .collect(),
    });
    let threshold = id.singular_values.first().copied().unwrap_or(0.0) * RANK_TOLERANCE;
    sections.push(Section {
        heading: "Singular values".into(),
        intro: "Of the scaled, whitened Jacobian, largest first.".into(),
        columns: vec!["#".into(), "singular value".into(), "".into()],
        rows: id
            .singular_values
            .iter()
            .enumerate()
            .map(|(i, s)| {
                vec![
                    (i + 1).to_string(),
                    format!("{s:.6e}"),
                    if i < id.rank {
                        "determined"
                    } else {
                        "not determined"
                    }
                    .into(),
                ]
            })
            .collect(),
    });
    let mut pose = vec![
        vec![
            "largest level positioning error (mm)".into(),
            format!("{:.6}", o.run.before.position_mm),
            format!("{:.6}", o.run.after.position_mm),
        ],
        vec![
            "largest pivot error (mm)".into(),
            format!("{:.6}", o.run.before.pivot_mm),
            format!("{:.6}", o.run.after.pivot_mm),
        ],
    ];
    if let Some((rot, tr)) = o.run.table_alignment {
        pose.push(vec![
            "table calibration corrects".into(),
            format!("{rot:.2} µrad"),
            format!("{tr:.6} mm"),
        ]);
    }
    sections.push(Section {
        heading: "Before and after".into(),
        intro: "Pose errors of the machine driven by the nominal controller (before) and by the calibrated one (after).".into(),
        columns: vec!["figure".into(), "before".into(), "after".into()],
        rows: pose,
    });
    sections.push(Section {
        heading: "Working time".into(),
        intro: "Both procedures' circles, readings and time.".into(),
        columns: [
            "procedure",
            "circles",
            "readings",
            "path (mm)",
            "set-up (min)",
            "measuring (min)",
            "total (min)",
        ]
        .map(String::from)
        .to_vec(),
        rows: o
            .work
            .iter()
            .map(|w| {
                vec![
                    w.procedure.name().to_string(),
                    w.circles.to_string(),
                    w.readings.to_string(),
                    format!("{:.0}", w.path_mm),
                    format!("{:.1}", w.setup_min),
                    format!("{:.1}", w.measuring_min),
                    format!("{:.1}", w.total_min),
                ]
            })
            .collect(),
    });
    if let Some(t) = &o.trials {
        sections.push(Section {
            heading: "Trials".into(),
            intro: format!("{} seeded trials of random deviations.", t.trials),
            columns: vec!["figure".into(), "value".into()],
            rows: vec![
                vec![
                    "parameters within 3σ".into(),
                    format!("{:.1} %", 100.0 * t.within_3_sigma),
                ],
                vec![
                    "trials all within 3σ".into(),
                    format!("{:.1} %", 100.0 * t.trials_all_within_3_sigma),
                ],
                vec![
                    "worst before: position / pivot (mm)".into(),
                    format!("{:.6} / {:.6}", t.before_position_mm, t.before_pivot_mm),
                ],
                vec![
                    "worst after: position / pivot (mm)".into(),
                    format!("{:.6} / {:.6}", t.after_position_mm, t.after_pivot_mm),
                ],
            ],
        });
    }
    let plots = page::spectrum_plot(
        &id.singular_values,
        (threshold > 0.0).then_some(threshold),
        "Singular values of the calibration's Jacobian: dark bars are determined directions; the gauge's lie below the line.",
    )
    .into_iter()
    .collect();
    render_page(&page::instrument_page(
        format!("twinmill calibrate: {scene} ({})", o.procedure.name()),
        o.summary.clone(),
        sections,
        plots,
        page::json(o),
    ))
}
