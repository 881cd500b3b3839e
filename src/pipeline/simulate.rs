//! `simulate`: the program cut into the scene's stock on the deviated machine with the
//! collision checks, the part's surface mesh and top view, and the deviation map against
//! the design model.

use super::{PipelineError, make_stock, sweep_failed};
use crate::cutting::collide::sweep_with_checks;
use crate::cutting::mesh::{TriMesh, mesh_stock};
use crate::math::Real;
use crate::nc::Program;
use crate::progress::Progress;
use crate::report::deviation_map::{DeviationImageOptions, deviation_map, render_deviation_map};
use crate::report::render::{encode_png, render_top_view};
use crate::report::{CollisionEvent, DeviationSummary};
use crate::report::{MeshSummary, SimulationReport, StockReport};
use crate::scene::Scene;
use std::collections::BTreeMap;
use std::time::Instant;

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
