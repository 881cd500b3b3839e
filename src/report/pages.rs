//! Each command's `report.html`: which geometry its 3-D view shows and which tables and
//! plots its page has, from the command's report and what it made ([`html::Page`](crate::report::html::Page)).
//!
//! - [`part_view3d`] / [`View3dParts`]: the display mesh coloured by deviation (with the
//!   deviations at its vertices as `_DEVIATION_UM` for picking), the scanned cloud decimated
//!   to [`display::MAX_POINTS`] and coloured by its residual from the fitted face it belongs
//!   to (points on no face grey), each fitted plane as an outline over the extent of its
//!   points, and markers with labels;
//! - [`run_page`], [`simulate_page`], [`scan_page`], [`identify_page`], [`design_page`],
//!   [`correct_page`]: the summary, the identified values with σ, what is and is not
//!   determined, the singular values (and their plot), timings, the command's other tables
//!   and plots, and the whole JSON report.
//! - The instruments' and evaluations' pages, without a 3-D view: [`positioning_page`]
//!   (ISO 230-2: figures, targets, the bidirectional plot), [`circular_page`] (ISO 230-4:
//!   figures and diagnostics per direction, the polar plot), [`ball_sensor_page`] (the
//!   sensor's window, Z error curve and ball centres), [`amplification_page`] (a hexapod's
//!   K_p and K_a maps), and [`instrument_page`] for the pages `pipeline::pages` assembles
//!   (the rotary-axis tests, the hexapod's calibration).
//!
//! **Invariant:** builds pages from reports and geometry; computes nothing but display
//! colours, extents and formatting.

use crate::calibration::calibrate::DETERMINED_FRACTION;
use crate::calibration::goodness::{FitCheck, RankMargin};
use crate::machine::hexapod_accuracy::AmplificationMap;
use crate::math::{Point3, Real, UnitVector3, Vector3};
use crate::metrology::circular::{CircularFigures, Diagnosis, Sample};
use crate::metrology::fit::Plane;
use crate::metrology::positioning::PositioningFigures;
use crate::report::display::{self, DisplayMesh};
use crate::report::glb::{GlbError, MeshData, Mode, write_glb};
use crate::report::html::{Legend, Marker, Page, Plot, Section, View3d};
use crate::report::render::diverging_colour;
use crate::report::svg::{amplification_svg, polar_svg, positioning_svg, spectrum_svg};
use crate::report::{
    CorrectReport, DesignReport, IdentifyReport, Report, ScanFileReport, SimulationReport,
};

/// The part in the view: its display mesh, the deviation of each display vertex (mm) if
/// known, and what the deviation is measured from.
#[derive(Clone, Debug)]
pub struct PartGeometry<'a> {
    /// The display mesh.
    pub mesh: &'a DisplayMesh,
    /// Deviation at each corner of each triangle (mm), + material left, NaN unknown.
    pub deviations: Option<&'a [[Real; 3]]>,
    /// What the deviation is from ("the nominal part", "design.stl") or why it is not known.
    pub reference: String,
}

/// A fitted plane in the view.
#[derive(Clone, Debug)]
pub struct FittedPlane {
    /// Name (`A0`).
    pub name: String,
    /// The plane.
    pub plane: Plane,
    /// Indices of its points in the cloud.
    pub points: Vec<usize>,
}

/// What goes into a 3-D view.
#[derive(Clone, Debug, Default)]
pub struct View3dParts<'a> {
    /// The part.
    pub part: Option<PartGeometry<'a>>,
    /// The scanned cloud (W).
    pub cloud: Option<&'a [Point3]>,
    /// Fitted planes in it.
    pub planes: Vec<FittedPlane>,
    /// Each point's residual (mm) and what it is measured from, when not from the planes
    /// (e.g. the scan's distance from the cut surface).
    pub residuals: Option<(Vec<Option<Real>>, String)>,
    /// Labelled points.
    pub markers: Vec<Marker>,
    /// View direction and up (see [`display::view_direction`]); `None`: isometric.
    pub view: Option<(UnitVector3, Vector3)>,
}

fn f32p(p: &Point3) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

fn srgb(c: image::Rgb<u8>) -> [u8; 3] {
    [c[0], c[1], c[2]]
}

/// Two in-plane unit axes of a plane.
fn plane_axes(n: &Vector3) -> (Vector3, Vector3) {
    let a = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let u = n.cross(&a).normalize();
    (u, n.cross(&u).normalize())
}

/// The GLB, legend and notes of a view.
pub fn part_view3d(parts: &View3dParts<'_>) -> Result<View3d, GlbError> {
    let mut meshes = Vec::new();
    let mut notes = Vec::new();
    let mut legend = None;
    let mut shown = vec!["part".to_string(), "planes".into(), "collisions".into()];
    if let Some(part) = &parts.part
        && !part.mesh.triangles.is_empty()
    {
        let m = part.mesh;
        // One GLB vertex per display vertex and deviation: corners of one face share
        // vertices, corners where faces of different deviation meet do not.
        let range = part
            .deviations
            .map_or(1e-3, |d| display::area_colour_range_mm(m, d));
        let mut ids: std::collections::HashMap<(u32, u64), u32> = Default::default();
        let (mut positions, mut colours, mut devs, mut indices) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (k, t) in m.triangles.iter().enumerate() {
            for (c, &i) in t.iter().enumerate() {
                let d = part.deviations.map_or(Real::NAN, |d| d[k][c]);
                let key = (i, if d.is_finite() { d.to_bits() } else { u64::MAX });
                let next = positions.len() as u32;
                let id = *ids.entry(key).or_insert_with(|| {
                    positions.push(f32p(&m.vertices[i as usize]));
                    colours.push(if d.is_finite() {
                        srgb(diverging_colour(d / range))
                    } else {
                        [200, 200, 200]
                    });
                    devs.push(if d.is_finite() { (d * 1e3) as f32 } else { 0.0 });
                    next
                });
                indices.push(id);
            }
        }
        let scalars = match part.deviations {
            Some(_) => {
                legend = Some(Legend {
                    title: format!("deviation from {} (+ material left)", part.reference),
                    range_mm: range,
                });
                vec![("deviation_um".to_string(), devs)]
            }
            None => {
                notes.push(format!("The part is grey: {}.", part.reference));
                Vec::new()
            }
        };
        meshes.push(MeshData {
            name: "part".into(),
            mode: Mode::Triangles,
            positions,
            colours: Some(colours),
            scalars,
            indices: Some(indices),
            material: None,
        });
        notes.push(format!(
            "Part: the cut surface simplified for display by meshoptimizer to {} of its {} triangles; every display vertex is a vertex of the cut surface and the display surface lies within {:.1e} mm of it.{}",
            m.triangles.len(),
            m.source_triangles,
            m.error_mm,
            if part.deviations.is_some() {
                " Colours: the deviation at each triangle's corners, measured along the triangle's normal, interpolated between them."
            } else {
                ""
            }
        ));
    }
    if let Some(cloud) = parts.cloud
        && !cloud.is_empty()
    {
        // Residual of each point from the plane it was fitted to, or as given.
        let (residual, from) = match &parts.residuals {
            Some((r, what)) if r.len() == cloud.len() => (r.clone(), what.clone()),
            _ => {
                let mut r: Vec<Option<Real>> = vec![None; cloud.len()];
                for f in &parts.planes {
                    for &i in &f.points {
                        if let Some(p) = cloud.get(i) {
                            r[i] = Some(f.plane.signed_distance(p));
                        }
                    }
                }
                (r, "the plane fitted to their face".to_string())
            }
        };
        let fitted: Vec<Real> = residual.iter().flatten().copied().collect();
        let range = display::colour_range_mm(&fitted);
        let keep = display::decimate(cloud.len(), display::MAX_POINTS);
        let (on, off): (Vec<usize>, Vec<usize>) =
            keep.iter().partition(|&&i| residual[i].is_some());
        if !on.is_empty() {
            meshes.push(MeshData {
                name: "cloud".into(),
                mode: Mode::Points,
                positions: on.iter().map(|&i| f32p(&cloud[i])).collect(),
                colours: Some(
                    on.iter()
                        .map(|&i| srgb(diverging_colour(residual[i].unwrap_or(0.0) / range)))
                        .collect(),
                ),
                scalars: vec![(
                    "residual_um".into(),
                    on.iter()
                        .map(|&i| (residual[i].unwrap_or(0.0) * 1e3) as f32)
                        .collect(),
                )],
                indices: None,
                material: None,
            });
        }
        if !off.is_empty() {
            meshes.push(MeshData {
                name: "cloud-other".into(),
                mode: Mode::Points,
                positions: off.iter().map(|&i| f32p(&cloud[i])).collect(),
                colours: Some(vec![[150, 150, 150]; off.len()]),
                scalars: Vec::new(),
                indices: None,
                material: None,
            });
        }
        let stride = cloud.len().div_ceil(keep.len().max(1));
        let which = if stride == 1 {
            format!("All {} scanned points", cloud.len())
        } else {
            format!(
                "{} of the {} scanned points (every {stride}th)",
                keep.len(),
                cloud.len()
            )
        };
        notes.push(format!(
            "Cloud: {which}, coloured by their distance from {from}, ±{:.1} µm full scale; points without one are grey. Shown with the 'cloud' switch.",
            range * 1e3
        ));
        if parts.part.is_none() {
            shown.push("cloud".into());
        }
        for f in &parts.planes {
            let pts: Vec<&Point3> = f.points.iter().filter_map(|&i| cloud.get(i)).collect();
            if pts.is_empty() {
                continue;
            }
            let n = f.plane.normal.into_inner();
            let (u, v) = plane_axes(&n);
            let (mut u0, mut u1, mut v0, mut v1) = (
                Real::INFINITY,
                Real::NEG_INFINITY,
                Real::INFINITY,
                Real::NEG_INFINITY,
            );
            for p in &pts {
                let (a, b) = (u.dot(&p.coords), v.dot(&p.coords));
                u0 = u0.min(a);
                u1 = u1.max(a);
                v0 = v0.min(b);
                v1 = v1.max(b);
            }
            let o = n * f.plane.offset;
            let corner = |a: Real, b: Real| f32p(&Point3::from(o + u * a + v * b));
            meshes.push(MeshData {
                name: format!("plane {}", f.name),
                mode: Mode::Lines,
                positions: vec![
                    corner(u0, v0),
                    corner(u1, v0),
                    corner(u1, v1),
                    corner(u0, v1),
                ],
                colours: None,
                scalars: Vec::new(),
                indices: Some(vec![0, 1, 1, 2, 2, 3, 3, 0]),
                material: None,
            });
        }
        if !parts.planes.is_empty() {
            notes.push(
                "Planes: the outline of each fitted plane over the extent of its points (green)."
                    .into(),
            );
        }
    }
    if meshes.is_empty() {
        return Err(GlbError::Empty("view".into()));
    }
    let glb = write_glb(&meshes, &[])?;
    let (eye, up) = parts.view.unwrap_or((
        UnitVector3::new_normalize(Vector3::new(1.0, -1.0, 1.0)),
        Vector3::z(),
    ));
    if !parts.markers.is_empty() {
        notes.push("Markers: collisions, each labelled with its NC line.".into());
    }
    Ok(View3d {
        glb,
        legend,
        markers: parts.markers.clone(),
        eye: [eye.x, eye.y, eye.z],
        up: [up.x, up.y, up.z],
        shown,
        notes,
        picture: None,
    })
}

/// A value in its natural unit: mm for offsets (`d…`, `EX0C`), µrad for angles.
fn value_text(name: &str, v: Real) -> String {
    if !super::is_angle_name(name) {
        format!("{v:+.6} mm")
    } else {
        format!("{:+.4} µrad", v * 1e6)
    }
}

fn sigma_text(name: &str, v: Real) -> String {
    if !super::is_angle_name(name) {
        format!("{v:.6} mm")
    } else {
        format!("{:.4} µrad", v * 1e6)
    }
}

fn timings(t: &[(String, Real)]) -> Section {
    let total: Real = t.iter().map(|x| x.1).sum();
    let mut rows: Vec<Vec<String>> = t
        .iter()
        .map(|(k, v)| vec![k.clone(), format!("{v:.3}")])
        .collect();
    rows.push(vec!["total".into(), format!("{total:.3}")]);
    Section {
        heading: "Timings".into(),
        intro: "Wall-clock seconds per stage (they vary with the machine and its load).".into(),
        columns: vec!["stage".into(), "s".into()],
        rows,
    }
}

/// A one-column table of `items` under `heading`, or nothing when there are none.
pub fn list_section(heading: &str, intro: &str, items: &[String]) -> Option<Section> {
    (!items.is_empty()).then(|| Section {
        heading: heading.into(),
        intro: intro.into(),
        columns: Vec::new(),
        rows: items.iter().map(|s| vec![s.clone()]).collect(),
    })
}

/// The identifiability spectrum's plot with `caption`, or nothing if it cannot be drawn.
pub fn spectrum_plot(values: &[Real], threshold: Option<Real>, caption: &str) -> Option<Plot> {
    spectrum_svg(values, threshold, "identifiability spectrum")
        .ok()
        .map(|svg| Plot {
            caption: caption.into(),
            svg,
        })
}

/// `v` as a JSON value (null if it cannot be one).
pub fn json(v: &impl serde::Serialize) -> serde_json::Value {
    serde_json::to_value(v).unwrap_or(serde_json::Value::Null)
}

/// `run`'s page.
pub fn run_page(r: &Report, view: Option<View3d>, mut plots: Vec<Plot>) -> Page {
    let mut sections = vec![Section {
        heading: "Step".into(),
        intro: "The distance from the face cut at the first index to the face cut at the second, measured from the scan and predicted by the exact twin; their relative tilt.".into(),
        columns: vec!["figure".into(), "measured".into(), "σ".into(), "predicted".into()],
        rows: vec![
            vec!["step (mm)".into(), format!("{:+.6}", r.step_mm), format!("{:.6}", r.step_sigma_mm), format!("{:+.6}", r.predicted_step_mm)],
            vec!["tilt (µrad)".into(), format!("{:+.3}", r.tilt_rad * 1e6), String::new(), format!("{:+.3}", r.predicted_tilt_rad * 1e6)],
        ],
    }];
    let mut rows = Vec::new();
    for (name, v) in &r.identified {
        let sigma = r.uncertainty.get(name).copied().unwrap_or(Real::NAN);
        let injected = name
            .split('+')
            .map(|n| r.injected.get(n).copied())
            .try_fold(0.0, |acc, x| x.map(|x| acc + x));
        rows.push(vec![
            name.clone(),
            value_text(name, *v),
            sigma_text(name, sigma),
            injected.map_or_else(|| "—".into(), |x| value_text(name, x)),
        ]);
    }
    sections.push(Section {
        heading: "Identified".into(),
        intro: "Values identified from the two faces on the exact chain, each with its standard uncertainty σ, and the value injected into the simulated machine.".into(),
        columns: vec!["deviation".into(), "value".into(), "σ".into(), "injected".into()],
        rows,
    });
    let why = r
        .why_not_identified
        .iter()
        .map(|w| {
            let mut c = w.chars();
            let first: String = c
                .next()
                .map(|f| f.to_uppercase().collect())
                .unwrap_or_default();
            format!(" {first}{}.", c.as_str())
        })
        .collect::<String>();
    sections.extend(list_section(
        "Not identified",
        &format!("This experiment does not determine these: each is held at its known value and never given an identified value.{why}"),
        &r.not_identified,
    ));
    let mut sv_rows: Vec<Vec<String>> = r
        .solver
        .singular_values
        .iter()
        .enumerate()
        .map(|(i, s)| vec![format!("{}", i + 1), format!("{s:.6e}")])
        .collect();
    sv_rows.push(vec!["rank margin".into(), r.solver.margin.describe()]);
    sv_rows.push(vec!["method".into(), r.solver.method.clone()]);
    sv_rows.push(vec!["evaluations".into(), r.solver.evaluations.to_string()]);
    sv_rows.push(vec![
        "residual".into(),
        format!("{:.3e}", r.solver.residual),
    ]);
    sections.push(Section {
        heading: "Identifiability".into(),
        intro: "Singular values of the Jacobian of (step, tilt) with respect to the two parameters: both non-zero, so both are determined.".into(),
        columns: vec!["singular value".into(), "".into()],
        rows: sv_rows,
    });
    sections.push(Section {
        heading: "Faces".into(),
        intro: "The two fitted faces.".into(),
        columns: [
            "face",
            "NC line",
            "points",
            "rejected",
            "offset (mm)",
            "rms (mm)",
            "max |r| (mm)",
        ]
        .map(String::from)
        .to_vec(),
        rows: r
            .faces
            .iter()
            .map(|f| {
                vec![
                    f.name.clone(),
                    f.line.to_string(),
                    f.points.to_string(),
                    f.rejected.to_string(),
                    format!("{:+.6}", f.offset_mm),
                    format!("{:.6}", f.rms_mm),
                    format!("{:.6}", f.max_abs_mm),
                ]
            })
            .collect(),
    });
    sections.push(fit_section(&r.fit));
    sections.push(timings(&r.timings_s));
    plots.extend(spectrum_plot(
        &r.solver.singular_values,
        None,
        "Singular values of the step-and-tilt Jacobian (not scaled like identify's: no threshold drawn).",
    ));
    Page {
        title: format!("twinmill run: {}", r.scene),
        summary: r.summary(),
        view,
        sections,
        plots,
        report: json(r),
    }
}

/// `simulate`'s page.
pub fn simulate_page(r: &SimulationReport, view: Option<View3d>, plots: Vec<Plot>) -> Page {
    let mut sections = Vec::new();
    if !r.collisions.is_empty() {
        sections.push(Section {
            heading: "Collisions".into(),
            intro: "Rapids through material, shank or holder in the stock, fixtures hit: each at its NC line, with its first contact and depth.".into(),
            columns: ["NC line", "kind", "part", "fixture", "contact (mm)", "depth (mm)"].map(String::from).to_vec(),
            rows: r
                .collisions
                .iter()
                .map(|c| {
                    vec![
                        c.line.to_string(),
                        c.kind.to_string(),
                        c.part.to_string(),
                        c.fixture.clone().unwrap_or_default(),
                        format!("({:.3}, {:.3}, {:.3})", c.point_mm[0], c.point_mm[1], c.point_mm[2]),
                        format!("{:.4}", c.depth_mm),
                    ]
                })
                .collect(),
        });
    }
    if let Some(d) = &r.deviation {
        let (heading, intro) = match &d.design {
            Some(design) => (
                "Deviation from the design",
                format!(
                    "Every dexel crossing of the cut part against {design} (+ material left, − gouge)."
                ),
            ),
            None => (
                "Deviation from the nominal part",
                format!(
                    "What the part's colours show: the display surface's deviation from {} at {} triangle corners, mean and RMS over its area (+ material left, − gouge).",
                    d.reference(),
                    d.map.points
                ),
            ),
        };
        let at = |p: &[Real; 3], line: u32| {
            let by = if line == 0 {
                "stock face".to_string()
            } else {
                format!("NC line {line}")
            };
            format!("({:.3}, {:.3}, {:.3}), {by}", p[0], p[1], p[2])
        };
        sections.push(Section {
            heading: heading.into(),
            intro,
            columns: vec!["figure".into(), "mm".into(), "where".into()],
            rows: vec![
                vec![
                    "max".into(),
                    format!("{:+.6}", d.map.max_mm),
                    at(&d.map.at_max, d.map.line_at_max),
                ],
                vec![
                    "min".into(),
                    format!("{:+.6}", d.map.min_mm),
                    at(&d.map.at_min, d.map.line_at_min),
                ],
                vec![
                    "mean".into(),
                    format!("{:+.6}", d.map.mean_mm),
                    String::new(),
                ],
                vec!["rms".into(), format!("{:.6}", d.map.rms_mm), String::new()],
            ],
        });
    }
    let t: Vec<(String, Real)> = r.timings_s.iter().map(|(k, v)| (k.clone(), *v)).collect();
    sections.push(timings(&t));
    Page {
        title: format!("twinmill simulate: {}", r.scene),
        summary: r.summary(),
        view,
        sections,
        plots,
        report: json(r),
    }
}

/// `scan`'s page.
pub fn scan_page(r: &ScanFileReport, view: Option<View3d>) -> Page {
    let mut sections = Vec::new();
    if !r.study.is_empty() {
        sections.push(Section {
            heading: "Scanner study".into(),
            intro: "How the identified offset moves with each scanner effect alone and together."
                .into(),
            columns: [
                "case",
                "trials",
                "parameter",
                "truth (mm)",
                "mean (mm)",
                "spread (mm)",
                "worst error (mm)",
                "mean σ (mm)",
            ]
            .map(String::from)
            .to_vec(),
            rows: r
                .study
                .iter()
                .map(|c| {
                    vec![
                        c.case.clone(),
                        c.trials.to_string(),
                        c.parameter.clone(),
                        format!("{:+.6}", c.truth_mm),
                        format!("{:+.6}", c.mean_mm),
                        format!("{:.6}", c.spread_mm),
                        format!("{:.6}", c.worst_error_mm),
                        format!("{:.6}", c.mean_reported_sigma_mm),
                    ]
                })
                .collect(),
        });
    }
    Page {
        title: format!("twinmill scan: {}", r.scene),
        summary: r.summary(),
        view,
        sections,
        plots: Vec::new(),
        report: json(r),
    }
}

/// The identification tables of `identify` (and of `design`'s verification).
fn identification_sections(r: &IdentifyReport) -> Vec<Section> {
    let est_rows = |es: &[crate::report::EstimateReport]| -> Vec<Vec<String>> {
        es.iter()
            .map(|e| {
                vec![
                    e.name.clone(),
                    format!("{:+.6e}", e.value),
                    format!("{:.3e}", e.sigma),
                    e.monte_carlo_spread
                        .map_or_else(|| "—".into(), |m| format!("{m:.3e}")),
                    e.injected
                        .map_or_else(|| "—".into(), |i| super::deviation_value(&e.name, i)),
                ]
            })
            .collect()
    };
    let cols = [
        "deviation",
        "value (mm or rad)",
        "σ",
        "Monte-Carlo spread",
        "injected",
    ]
    .map(String::from)
    .to_vec();
    let mut out = vec![Section {
        heading: "Identified".into(),
        intro: "Parameters identified on their own, each with its standard uncertainty σ.".into(),
        columns: cols.clone(),
        rows: est_rows(&r.identified),
    }];
    if !r.combinations.is_empty() {
        out.push(Section {
            heading: "Determined combinations".into(),
            intro:
                "Combinations the features determine though their members are not determined alone."
                    .into(),
            columns: cols,
            rows: est_rows(&r.combinations),
        });
    }
    out.extend(list_section(
        "Not determined",
        "Directions the features do not determine: held at their known values, never valued.",
        &r.not_determined,
    ));
    if !r.borderline.is_empty() {
        out.push(Section {
            heading: "Borderline".into(),
            intro: "Directions near the threshold of determination: another scan may decide them the other way.".into(),
            columns: vec!["direction".into(), "singular value".into()],
            rows: r.borderline.iter().map(|(n, s)| vec![n.clone(), format!("{s:.4}")]).collect(),
        });
    }
    out.extend(list_section(
        "Not identified",
        "Parameters without an identified value of their own.",
        &r.not_identified,
    ));
    out.extend(list_section(
        "No data",
        "Parameters no feature depends on at all.",
        &r.no_data,
    ));
    out.extend(list_section(
        "Absorbed by the registration",
        "What the scan's registration absorbs.",
        &r.registration_absorbs,
    ));
    let threshold = 1.0 / DETERMINED_FRACTION;
    let mut rows = singular_value_rows(&r.singular_values, threshold);
    rows.push(vec![
        "condition".into(),
        format!("{:.6e}", r.condition_number),
        String::new(),
    ]);
    rows.push(vec![
        "condition (determined)".into(),
        format!("{:.6e}", r.condition_number_determined),
        String::new(),
    ]);
    rows.push(margin_row(&r.margin));
    out.push(Section {
        heading: "Identifiability".into(),
        intro: format!("Singular values of the Jacobian scaled by each parameter's realistic magnitude (registration projected out); a direction is determined from {threshold}."),
        columns: vec!["#".into(), "singular value".into(), "".into()],
        rows,
    });
    out.push(Section {
        heading: "Solver and model-correction loop".into(),
        intro: format!(
            "{} evaluations, {}, χ² {:.6e} → {:.6e} ({} dof); loop {}.",
            r.solver.evaluations,
            r.solver.termination,
            r.solver.chi2_start,
            r.solver.chi2,
            r.solver.dof,
            if r.converged {
                "within tolerance"
            } else {
                "NOT within tolerance"
            }
        ),
        columns: vec!["round".into(), "worst face (mm)".into(), "χ²".into()],
        rows: r
            .rounds
            .iter()
            .map(|l| {
                vec![
                    l.round.to_string(),
                    format!("{:.6e}", l.worst_face_mm),
                    format!("{:.6e}", l.chi2),
                ]
            })
            .collect(),
    });
    out.push(fit_section(&r.fit));
    out.push(Section {
        heading: "Features".into(),
        intro: "The measured faces.".into(),
        columns: [
            "feature",
            "kind",
            "NC line",
            "points",
            "rms (mm)",
            "offset σ (mm)",
        ]
        .map(String::from)
        .to_vec(),
        rows: r
            .features
            .iter()
            .map(|f| {
                vec![
                    f.name.clone(),
                    f.kind.clone(),
                    f.line.to_string(),
                    f.points.to_string(),
                    format!("{:.6}", f.rms_mm),
                    format!("{:.3e}", f.offset_sigma_mm),
                ]
            })
            .collect(),
    });
    out
}

/// `identify`'s page.
pub fn identify_page(r: &IdentifyReport, view: Option<View3d>) -> Page {
    let mut sections = identification_sections(r);
    sections.push(timings(&r.timings_s));
    let plots = spectrum_plot(
        &r.singular_values,
        Some(1.0 / DETERMINED_FRACTION),
        "Singular values of the scaled Jacobian: dark bars are determined directions, light ones are not.",
    )
    .into_iter()
    .collect();
    Page {
        title: format!("twinmill identify: {}", r.scene),
        summary: r.summary(),
        view,
        sections,
        plots,
        report: json(r),
    }
}

/// `design`'s page, with the identification that verified the design.
pub fn design_page(r: &DesignReport, verified: &IdentifyReport, view: Option<View3d>) -> Page {
    let mut sections = vec![Section {
        heading: "Designed cuts".into(),
        intro: r.verified.clone(),
        columns: vec!["cut".into(), "rotary index (°)".into(), "NC line".into()],
        rows: r
            .cuts
            .iter()
            .map(|(n, a, l)| vec![n.clone(), format!("{a:.1}"), l.to_string()])
            .collect(),
    }];
    sections.push(Section {
        heading: "Relative uncertainty".into(),
        intro: "σ of each identified parameter on the designed scene's simulated scan, over its realistic magnitude.".into(),
        columns: vec!["parameter".into(), "σ / magnitude".into()],
        rows: r.relative_sigma.iter().map(|(n, s)| vec![n.clone(), format!("{s:.4e}")]).collect(),
    });
    sections.extend(identification_sections(verified));
    sections.extend(list_section("Notes", "", &r.notes));
    let plots = spectrum_plot(
        &r.singular_values,
        Some(1.0 / DETERMINED_FRACTION),
        "Singular values on the designed scene's simulated scan: dark bars are determined directions.",
    )
    .into_iter()
    .collect();
    let report = serde_json::json!({ "design": json(r), "verification": json(verified) });
    Page {
        title: format!("twinmill design: {}", r.scene),
        summary: r.summary(),
        view,
        sections,
        plots,
        report,
    }
}

/// `correct`'s page.
pub fn correct_page(r: &CorrectReport, view: Option<View3d>) -> Page {
    let sections = vec![
        Section {
            heading: "Passes".into(),
            intro: format!(
                "{} (accuracy {} mm: {}).",
                r.status,
                r.accuracy_mm,
                if r.met { "met" } else { "NOT met" }
            ),
            columns: vec![
                "pass".into(),
                "blocks".into(),
                "predicted error (mm)".into(),
            ],
            rows: r
                .iterations
                .iter()
                .map(|i| {
                    vec![
                        i.iteration.to_string(),
                        i.blocks.to_string(),
                        i.predicted_error_mm
                            .map_or_else(|| "— (no face measured)".into(), |e| format!("{e:.6e}")),
                    ]
                })
                .collect(),
        },
        Section {
            heading: "Uncorrectable".into(),
            intro: "What each deviation alone leaves after correction: no axis command removes it."
                .into(),
            columns: vec![
                "deviation".into(),
                "value".into(),
                "rms residual (mm)".into(),
                "max residual (mm)".into(),
            ],
            rows: r
                .uncorrectable
                .iter()
                .map(|u| {
                    vec![
                        u.deviation.clone(),
                        format!("{:+.6e}", u.value),
                        format!("{:.6e}", u.residual_rms_mm),
                        format!("{:.6e}", u.residual_max_mm),
                    ]
                })
                .collect(),
        },
        timings(&r.timings_s),
    ];
    Page {
        title: format!("twinmill correct: {}", r.scene),
        summary: r.summary(),
        view,
        sections,
        plots: Vec::new(),
        report: json(r),
    }
}

/// A page without a 3-D view: an instrument's or an evaluation's.
pub fn instrument_page(
    title: String,
    summary: String,
    sections: Vec<Section>,
    plots: Vec<Plot>,
    report: serde_json::Value,
) -> Page {
    Page {
        title,
        summary,
        view: None,
        sections,
        plots,
        report,
    }
}

/// A plot, or a sentence saying why it is missing (a caption without a drawing).
fn plot_or_note(drawn: Result<String, crate::report::svg::SvgError>, caption: &str) -> Plot {
    match drawn {
        Ok(svg) => Plot {
            caption: caption.into(),
            svg,
        },
        Err(e) => Plot {
            caption: format!("{caption} — not drawn: {e}."),
            svg: String::new(),
        },
    }
}

fn um(x: Real) -> String {
    format!("{:.4}", x * 1e3)
}

/// ISO 230-2's page: `summary` (what the CLI prints), the figures and each target's
/// statistics in µm, the bidirectional plot titled `plot_title`, and `f` as JSON.
pub fn positioning_page(
    title: &str,
    summary: &str,
    f: &PositioningFigures,
    plot_title: &str,
) -> Page {
    let figures = [
        ("A", "accuracy, bidirectional", f.a),
        ("A↑", "accuracy, forward", f.a_fwd),
        ("A↓", "accuracy, backward", f.a_bwd),
        ("R", "repeatability, bidirectional", f.r),
        ("R↑", "repeatability, forward", f.r_fwd),
        ("R↓", "repeatability, backward", f.r_bwd),
        ("E", "systematic deviation, bidirectional", f.e),
        ("E↑", "systematic deviation, forward", f.e_fwd),
        ("E↓", "systematic deviation, backward", f.e_bwd),
        ("M", "mean bidirectional positional deviation", f.m),
        ("B", "largest reversal value", f.b),
        ("B̄", "mean reversal value", f.b_mean),
    ];
    let sections = vec![
        Section {
            heading: "ISO 230-2 figures".into(),
            intro: format!(
                "{} targets, {} runs in each direction.",
                f.targets.len(),
                f.runs
            ),
            columns: vec!["figure".into(), "meaning".into(), "µm".into()],
            rows: figures
                .iter()
                .map(|(k, what, v)| vec![(*k).into(), (*what).into(), um(*v)])
                .collect(),
        },
        Section {
            heading: "Targets".into(),
            intro: "Each target's mean deviations x̄, reversal value B, standard deviations s and repeatabilities R (µm).".into(),
            columns: [
                "target (mm)", "x̄↑", "x̄↓", "x̄", "B", "s↑", "s↓", "R↑", "R↓", "R",
            ]
            .map(String::from)
            .to_vec(),
            rows: f
                .targets
                .iter()
                .map(|t| {
                    vec![
                        format!("{:.4}", t.target),
                        um(t.mean_fwd),
                        um(t.mean_bwd),
                        um(t.mean),
                        um(t.b),
                        um(t.s_fwd),
                        um(t.s_bwd),
                        um(t.r_fwd),
                        um(t.r_bwd),
                        um(t.r),
                    ]
                })
                .collect(),
        },
    ];
    let plots = vec![plot_or_note(
        positioning_svg(f, plot_title),
        "ISO 230-2's bidirectional plot: the mean positional deviations of each direction and their ±2s bands.",
    )];
    instrument_page(title.into(), summary.into(), sections, plots, json(f))
}

/// A diagnostic as text: value ± σ in `unit` (scaled by `k`), or why it is not determined.
fn diagnosis(d: &Diagnosis, k: Real, unit: &str) -> String {
    match d {
        Diagnosis::Value { value, sigma } => {
            format!("{:+.4} ± {:.4} {unit}", value * k, sigma * k)
        }
        Diagnosis::NotDetermined { not_determined } => {
            format!("not determined: {not_determined}")
        }
    }
}

/// The ISO 230-4 tables of `f`: each direction's figures and diagnostics, and what both
/// directions give together.
pub fn circular_sections(f: &CircularFigures) -> Vec<Section> {
    let mut out = Vec::new();
    let dirs: Vec<String> = f
        .directions
        .iter()
        .map(|d| format!("{:?}", d.direction).to_lowercase())
        .collect();
    let mut columns = vec!["figure".to_string()];
    columns.extend(dirs.iter().cloned());
    let row = |name: &str, g: &dyn Fn(&crate::metrology::circular::DirectionFigures) -> String| {
        let mut r = vec![name.to_string()];
        r.extend(f.directions.iter().map(g));
        r
    };
    out.push(Section {
        heading: "ISO 230-4 figures".into(),
        intro: format!(
            "Nominal radius {} mm. G about the least-squares centre, F about the centre ball (µm).",
            f.radius_mm
        ),
        columns: columns.clone(),
        rows: vec![
            row("points", &|d| d.points.to_string()),
            row("span (°)", &|d| format!("{:.1}", d.span_deg)),
            row("circular deviation G (µm)", &|d| um(d.g)),
            row("radial deviation F max (µm)", &|d| {
                format!("{:+.4}", d.f_max * 1e3)
            }),
            row("radial deviation F min (µm)", &|d| {
                format!("{:+.4}", d.f_min * 1e3)
            }),
            row("centre, axis 1 (µm)", &|d| {
                format!("{:+.4}", d.centre_mm[0] * 1e3)
            }),
            row("centre, axis 2 (µm)", &|d| {
                format!("{:+.4}", d.centre_mm[1] * 1e3)
            }),
            row("radius − nominal (µm)", &|d| {
                format!("{:+.4}", d.radius_deviation_mm * 1e3)
            }),
            row("residual rms (µm)", &|d| um(d.residual_rms_mm)),
        ],
    });
    out.push(Section {
        heading: "Diagnostics".into(),
        intro: "Each term fitted to the trace with its standard uncertainty from the residuals, or why the trace cannot determine it.".into(),
        columns,
        rows: vec![
            row("scale mismatch", &|d| diagnosis(&d.scale_mismatch_um_per_m, 1.0, "µm/m")),
            row("sin 2θ term (squareness + servo)", &|d| diagnosis(&d.sin2_term_urad, 1.0, "µrad")),
            row("reversal, axis 1", &|d| diagnosis(&d.reversal_1_mm, 1e3, "µm")),
            row("reversal, axis 2", &|d| diagnosis(&d.reversal_2_mm, 1e3, "µm")),
            row("straightness, axis 1", &|d| diagnosis(&d.straightness_1_mm, 1e3, "µm")),
            row("straightness, axis 2", &|d| diagnosis(&d.straightness_2_mm, 1e3, "µm")),
            row("cyclic error, axis 1", &|d| diagnosis(&d.cyclic_1_mm, 1e3, "µm")),
            row("cyclic error, axis 2", &|d| diagnosis(&d.cyclic_2_mm, 1e3, "µm")),
        ],
    });
    let mut both = vec![
        vec![
            "squareness".into(),
            diagnosis(&f.squareness_urad, 1.0, "µrad"),
        ],
        vec![
            "servo mismatch".into(),
            diagnosis(&f.servo_mismatch_urad, 1.0, "µrad"),
        ],
    ];
    if let Some(h) = f.h {
        both.insert(0, vec!["hysteresis H".into(), format!("{} µm", um(h))]);
    }
    out.push(Section {
        heading: "Both directions".into(),
        intro: "What the two directions give together (with one direction, squareness is not separable from servo mismatch).".into(),
        columns: vec!["figure".into(), "value".into()],
        rows: both,
    });
    out
}

/// ISO 230-4's page: `summary`, the figures and diagnostics, the polar plot of `samples`
/// titled `plot_title`, and `report` (the JSON the command prints).
pub fn circular_page(
    title: &str,
    summary: &str,
    samples: &[Sample],
    f: &CircularFigures,
    plot_title: &str,
    report: serde_json::Value,
) -> Page {
    let plots = vec![plot_or_note(
        polar_svg(samples, f, plot_title),
        "ISO 230-4's polar plot: the radial deviation of each direction, magnified about the nominal circle (black); grey circles ±2 divisions.",
    )];
    instrument_page(
        title.into(),
        summary.into(),
        circular_sections(f),
        plots,
        report,
    )
}

/// `evaluate ball-sensor`'s page: the summary (the window, the Z error curve and the
/// centres as the CLI prints them) and `figures` (its JSON) in tables.
pub fn ball_sensor_page(title: &str, summary: &str, figures: serde_json::Value) -> Page {
    let f =
        |v: &serde_json::Value, k: &str| v[k].as_f64().map_or("—".into(), |x| format!("{x:.4}"));
    let mut sections = Vec::new();
    if let Some(curve) = figures["z_error_curve"].as_array() {
        sections.push(Section {
            heading: "Z error".into(),
            intro: "The bound of the Z error at each height of the ball above the sheets of light, for the short and the long chord (mm).".into(),
            columns: vec!["Z (mm)".into(), "short chord".into(), "long chord".into()],
            rows: curve
                .iter()
                .map(|e| vec![f(e, "z_mm"), f(e, "chord_short_mm"), f(e, "chord_long_mm")])
                .collect(),
        });
    }
    if let Some(c) = figures["centres"].as_array().filter(|c| !c.is_empty()) {
        sections.push(Section {
            heading: "Ball centres".into(),
            intro: "Each reading's ball centre (mm) by the sensor's equations, with the bound of its Z error and Z from micrometer B alone.".into(),
            columns: ["#", "X", "Y", "Z", "Z error bound", "Z from B"].map(String::from).to_vec(),
            rows: c
                .iter()
                .enumerate()
                .map(|(i, c)| {
                    let p = |k: usize| c["centre_mm"][k].as_f64().map_or("—".into(), |x| format!("{x:+.4}"));
                    vec![
                        (i + 1).to_string(),
                        p(0),
                        p(1),
                        p(2),
                        f(c, "z_error_bound_mm"),
                        f(c, "z_from_b_mm"),
                    ]
                })
                .collect(),
        });
    }
    instrument_page(title.into(), summary.into(), sections, Vec::new(), figures)
}

/// `hexapod amplification`'s page: `summary`, the ranges of K_p and K_a, the maps, and
/// `report` (the JSON the command prints).
pub fn amplification_page(
    title: &str,
    summary: &str,
    map: &AmplificationMap,
    report: serde_json::Value,
) -> Page {
    let range = |r: Option<crate::machine::hexapod_accuracy::Range>| {
        r.map_or(("—".to_string(), "no reachable pose".to_string()), |r| {
            (format!("{:.4}", r.min), format!("{:.4}", r.max))
        })
    };
    let rows = [
        ("K_p level (mm/mm)", map.position_level),
        ("K_a level (°/mm)", map.angle_level),
        ("K_p tilted (mm/mm)", map.position_tilted),
        ("K_a tilted (°/mm)", map.angle_tilted),
    ]
    .into_iter()
    .map(|(n, r)| {
        let (lo, hi) = range(r);
        vec![n.to_string(), lo, hi]
    })
    .collect();
    let sections = vec![Section {
        heading: "Amplification factors".into(),
        intro: format!(
            "The nominal machine (its design parameters; the scene's [deviations] are not used), over {} poses ({} × {} × {} positions and the tilts); {} outside the workspace.",
            map.samples.len(),
            map.steps[0],
            map.steps[1],
            map.steps[2],
            map.unreachable
        ),
        columns: vec!["factor".into(), "min".into(), "max".into()],
        rows,
    }];
    let plots = vec![plot_or_note(
        amplification_svg(map, "resolution amplification"),
        "K_p and K_a over the x–y grid: each cell the largest over z and the orientations; grey where no pose is reachable.",
    )];
    instrument_page(title.into(), summary.into(), sections, plots, report)
}

/// The goodness-of-fit table: the whole χ² with its limit and probability, then each part
/// (file, circle, face) with its statistic, what the stated noise leads one to expect, the
/// limit and whether it is out of line.
pub fn fit_section(fit: &FitCheck) -> Section {
    let mut rows = Vec::new();
    if let Some(c) = fit.chi2 {
        rows.push(vec![
            "whole fit".into(),
            "χ²".into(),
            format!("{c:.6e}"),
            format!("{} dof", fit.dof),
            fit.limit.map_or_else(|| "—".into(), |l| format!("{l:.6e}")),
            fit.p_value
                .map_or_else(|| "—".into(), |p| format!("{p:.3e}")),
            if fit
                .p_value
                .is_some_and(|p| p < crate::calibration::goodness::REFUSE_P)
            {
                "out of line".into()
            } else {
                "fits".into()
            },
        ]);
    }
    for p in &fit.parts {
        let rms = p.kind == "rms";
        rows.push(vec![
            p.name.clone(),
            if rms { "RMS (mm)" } else { "χ² left out" }.into(),
            if rms {
                format!("{:.6}", p.value)
            } else {
                format!("{:.6e}", p.value)
            },
            if rms {
                format!("σ {:.6}", p.expected)
            } else {
                format!("{} dof", p.expected)
            },
            if rms {
                format!("{:.6}", p.limit)
            } else {
                format!("{:.6e}", p.limit)
            },
            format!("{:.3e}", p.p_value),
            if p.out_of_line { "out of line" } else { "fits" }.into(),
        ]);
    }
    let verdict = if fit.fits {
        "The data fit the model at the stated noise."
    } else if fit.misfit_accepted {
        "MISFIT ACCEPTED on request (--accept-misfit): the data do not fit the model at the stated noise, and every figure on this page stands on that model."
    } else {
        "The data do not fit the model at the stated noise."
    };
    Section {
        heading: "Goodness of fit".into(),
        intro: format!(
            "{verdict} Whole: {}. A fit is refused when the probability of its χ² (or of one part's, left out, at 1e-6 over the parts) is below 1e-6.",
            fit.describe()
        ),
        columns: ["part", "statistic", "value", "expected", "limit", "p", ""]
            .map(String::from)
            .to_vec(),
        rows,
    }
}

/// The rank margin's row for an identifiability table: the gap between the last kept and
/// the first dropped singular value.
pub fn margin_row(m: &RankMargin) -> Vec<String> {
    vec![
        "rank margin".into(),
        format!("×{:.3e}", m.ratio),
        m.describe(),
    ]
}

/// The identifiability table's rows: each singular value (1-based index, value) and whether
/// its direction is determined (at least `threshold`).
pub fn singular_value_rows(values: &[Real], threshold: Real) -> Vec<Vec<String>> {
    values
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
        .collect()
}
