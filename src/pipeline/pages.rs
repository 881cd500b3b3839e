//! What the commands' pages and part pictures need from a scene: the part the deviations
//! are measured from ([`reference_part`]: the design model, or the program cut on the
//! nominal machine), the cut part's display mesh with its deviations and the view that
//! shows its machined faces ([`display_part`]), `part.png` ([`part_png`]), the 3-D view of
//! a part and a cloud ([`view`]), and the page of `run`, `scan`, `identify`, `design` and
//! `correct` ([`run_page`], [`scan_page`], [`identify_page`], [`design_page`],
//! [`correct_page`]; `simulate` makes its own). The instruments' pages (the rotary-axis
//! tests of `measure`, the hexapod's ball bar and calibration) are in
//! [`super::instrument_pages`].

use super::{PipelineError, make_stock, sweep_failed};
use crate::calibration::calibrate::Feature;
use crate::cutting::mesh::TriMesh;
use crate::cutting::nominal::{NominalMachine, NominalPath, NominalStock};
use crate::cutting::stock::TriDexel;
use crate::cutting::sweep::sweep_program;
use crate::machine::hexapod::{HexapodTwin, TableAxes};
use crate::machine::{PoseError, PoseSource};
use crate::math::Isometry3;
use crate::math::{Point3, Real, UnitVector3, Vector3};
use crate::nc::Move;
use crate::nc::{AxisLetter, AxisValues};
use crate::progress::NoProgress;
use crate::report::display::{self, DisplayMesh};
use crate::report::display::{ReferenceModel, ReferenceSurface};
use crate::report::html::{Marker, View3d, render_page};
use crate::report::pages::{self as page, FittedPlane, PartGeometry, View3dParts};
use crate::report::part_view::{PartViewOptions, render_part_view};
use crate::report::render::encode_png;
use crate::report::{CorrectReport, DesignReport, IdentifyReport, ScanFileReport};
use crate::scene::{Machine, Scene, StockShape};

/// What a part's deviation is measured from.
pub struct Reference {
    /// The reference (the design's surface, or the nominal part's tri-dexel); `None` when
    /// the deviation is not computed.
    pub model: Option<ReferenceModel>,
    /// Its name ("the nominal part", the design file) or why there is none.
    pub what: String,
}

/// The part the deviations are measured from: the scene's design model if it has one; else,
/// when the scene's machine has deviations or error motions, the same program on the
/// nominal machine (read as the nominal part's distance near the cut part,
/// [`NominalPath`], not swept); else none, since the part is then the nominal part
/// (deviation 0 everywhere).
pub fn reference_part(scene: &Scene, moves: &[Move]) -> Result<Reference, PipelineError> {
    if let Some((path, design)) = &scene.design {
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        let m = design.mesh();
        return Ok(Reference {
            model: ReferenceSurface::new(m.vertices().to_vec(), m.triangles().to_vec())
                .map(ReferenceModel::Surface),
            what: format!("the design {name}"),
        });
    }
    let machine = match &scene.machine {
        Machine::Hexapod(h) => {
            let n = nominal_hexapod(&h.twin);
            (h.twin != n).then(|| NominalMachine::Poses(Box::new(Commanded(n))))
        }
        Machine::Serial(m) => {
            let nominal = scene.chain().nominal();
            (m.chain != nominal).then_some(NominalMachine::Chain(nominal))
        }
    };
    let Some(machine) = machine else {
        return Ok(Reference {
            model: None,
            what: "the machine has no deviations, so the part is the nominal part (deviation 0)"
                .into(),
        });
    };
    let b = scene.stock_box;
    let stock = match &scene.stock_shape {
        StockShape::Box => Some(NominalStock::boxed(b)),
        StockShape::Cylinder(c) => Some(NominalStock::cylinder(b, *c)),
        StockShape::Mesh { mesh, .. } => NominalStock::mesh(b, mesh),
    };
    let Some(stock) = stock else {
        return Ok(Reference {
            model: None,
            what: "the stock's mesh cannot be read as a signed distance".into(),
        });
    };
    Ok(Reference {
        model: Some(ReferenceModel::Path(NominalPath::new(
            &scene.tool,
            machine,
            stock,
            moves,
            scene.sweep.rotary_step_bound_mm,
        ))),
        what: "the nominal part".into(),
    })
}

/// A nominal hexapod read pose by pose: its controller and its build are the design, so the
/// tool is where the controller commands it (`FK(IK(command))` is the command; the forward
/// kinematics' iterations are skipped).
struct Commanded(HexapodTwin);

impl PoseSource for Commanded {
    fn has_axis(&self, axis: AxisLetter) -> bool {
        self.0.has_axis(axis)
    }

    fn w_from_t(&self, q: &AxisValues) -> Result<Isometry3, PoseError> {
        Ok(self.0.commanded(q))
    }

    fn commanded(&self, q: &AxisValues) -> Isometry3 {
        self.0.commanded(q)
    }

    fn is_translation(&self, start: &AxisValues, end: &AxisValues) -> bool {
        self.0.is_translation(start, end)
    }
}

/// A hexapod's nominal machine: the actual one with the nominal parameters.
fn nominal_hexapod(t: &HexapodTwin) -> HexapodTwin {
    HexapodTwin {
        actual: t.nominal.clone(),
        controller: t.nominal.clone(),
        table: t.table.as_ref().map(|a| TableAxes {
            nominal: a.nominal.clone(),
            actual: a.nominal.clone(),
        }),
        ..t.clone()
    }
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
/// reference `reference` makes (made once the mesh is simplified) and its view: the
/// scene's `[report] view`, else the direction its machined faces face.
pub fn display_part(
    scene: &Scene,
    mesh: &TriMesh,
    cut: &TriDexel,
    reference: impl FnOnce() -> Result<Reference, PipelineError>,
) -> Result<DisplayPart, PipelineError> {
    // The simplifier's working memory and the reference's are never held at once.
    let shown = display::simplify(mesh, display::MAX_TRIANGLES);
    let reference = reference()?;
    let deviations = reference.model.as_ref().map(|m| m.deviations(&shown, cut));
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
    let (mesh, _) = super::part_mesh(&outcome.stock, &scene.path.display().to_string())?;
    let shown = display_part(scene, &mesh, &outcome.stock, || {
        reference_part(scene, &program.moves)
    })?;
    let mut v = view(
        scene,
        Some(&shown),
        Some(&outcome.cloud.points),
        outcome.planes.clone(),
        None,
        Vec::new(),
    )?;
    v.picture = Some(part_png(scene, &shown)?);
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
    let (mesh, _) = super::part_mesh(stock, &spath)?;
    let shown = display_part(scene, &mesh, stock, || {
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
    v.picture = Some(part_png(scene, &shown)?);
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
        scene.kinematics(),
        &scene.tool,
        corrected,
        &scene.sweep,
        &NoProgress,
    )
    .map_err(sweep_failed(program, &spath))?;
    let (mesh, _) = super::part_mesh(&stock, &spath)?;
    let shown = display_part(scene, &mesh, &stock, || {
        let mut r = reference_part(scene, &program.moves)?;
        if r.model.is_some() && scene.design.is_none() {
            r.what = "the nominal part (the program as given, on the nominal machine)".into();
        }
        Ok(r)
    })?;
    let v = view(scene, Some(&shown), None, Vec::new(), None, Vec::new())?;
    let mut v = v;
    v.picture = Some(part_png(scene, &shown)?);
    v.notes.insert(
        0,
        "The corrected program cut on the scene's (deviated) machine.".into(),
    );
    Ok(render_page(&page::correct_page(report, Some(v))))
}
