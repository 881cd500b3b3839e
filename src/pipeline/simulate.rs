//! `simulate`: the program cut into the scene's stock on the deviated machine with the
//! collision checks, the part's surface mesh, its picture and page coloured by deviation
//! (from the design model, or from the part the nominal machine cuts) with the figures
//! behind the colours, and the deviation map against the design model.

use super::pages::{DisplayPart, display_part, part_png, reference_part, view};
use super::{PipelineError, make_stock, sweep_failed};
use crate::cutting::adaptive::AdaptiveReport;
use crate::cutting::collide::{CollisionReport, sweep_with_checks};
use crate::cutting::mesh::TriMesh;
use crate::cutting::stock::TriDexel;
use crate::cutting::sweep::{Kinematics, sweep_program};
use crate::math::Real;
use crate::nc::Program;
use crate::progress::Progress;
use crate::report::deviation_map::{
    DeviationImageOptions, DeviationReport, deviation_map, render_deviation_map,
};
use crate::report::display::surface_deviation;
use crate::report::html::{Marker, Plot, render_page};
use crate::report::render::encode_png;
use crate::report::svg::{MapLabels, deviation_map_svg};
use crate::report::{CollisionEvent, DeviationSummary};
use crate::report::{MeshSummary, SimulationReport, StockReport};
use crate::scene::{Machine, Scene};
use std::collections::BTreeMap;
use std::time::Instant;

/// Everything `simulate` produces.
#[derive(Clone, Debug)]
pub struct Simulation {
    /// The report.
    pub report: SimulationReport,
    /// The cut stock's surface (workpiece frame, mm).
    pub mesh: TriMesh,
    /// PNG of the part, shaded from a direction that shows its machined faces, coloured by
    /// deviation where known.
    pub part_png: Vec<u8>,
    /// The page (`report.html`).
    pub html: String,
    /// PNG of the deviation map against the scene's design model, if it has one.
    pub deviation_png: Option<Vec<u8>>,
}

/// The NC line that made the cut part's surface nearest to `p` (a point inside a face of the
/// display surface): that of the nearest dexel crossing (0 for an uncut stock face, or a
/// part without crossings).
fn nearest_line(stock: &crate::cutting::stock::TriDexel, p: &crate::math::Point3) -> u32 {
    let mut best = (Real::INFINITY, 0);
    for g in stock.grids() {
        g.for_each_crossing(|q, c| {
            let d = (q - p).norm_squared();
            if d < best.0 {
                best = (d, c.line);
            }
        });
    }
    best.1
}

/// Size of the deviation picture (px).
const DEVIATION_IMAGE_PX: (u32, u32) = (1200, 900);

/// Cuts the scene's program into its stock on the deviated machine, reporting collisions
/// (rapids through material, shank or holder in the stock, anything touching a fixture),
/// meshes the result and, when the scene has a design model, maps the part's deviation
/// from it: no scan, no identification.
///
/// Runs on a thread of rayon's pool (the caller's, when it is one), as the work it hands
/// out does: glibc keeps a heap for each thread, so the buffers of every stage come from
/// the heaps holding what the sweep and the mesher freed, not from the calling thread's
/// own (the ball side cut's peak 98 MiB instead of 110 MiB; the same output).
pub fn simulate(
    scene: &Scene,
    program: &Program,
    progress: &dyn Progress,
) -> Result<Simulation, PipelineError> {
    rayon::scope(|_| simulate_here(scene, program, progress))
}

/// [`simulate`] on the calling thread.
fn simulate_here(
    scene: &Scene,
    program: &Program,
    progress: &dyn Progress,
) -> Result<Simulation, PipelineError> {
    let mut timings: BTreeMap<String, Real> = BTreeMap::new();
    let clock = Instant::now();
    let mut stock = make_stock(scene)?;
    let volume0 = stock.volume();
    timings.insert("stock".into(), clock.elapsed().as_secs_f64());
    let (checked, [sweep_time, mesh_time], mesh, mesh_report) =
        cut_part(scene, program, progress, &mut stock)?;
    timings.insert("sweep".into(), sweep_time);
    timings.insert("mesh".into(), mesh_time);
    let clock = Instant::now();
    // The display part, with the part the deviations are measured from (the design model,
    // or the program on the nominal machine read near the cut part's surface: no second
    // sweep) made once the display mesh is, and timed on its own.
    let mut reference_time = 0.0;
    let shown = display_part(scene, &mesh, &stock, || {
        let clock = Instant::now();
        let reference = reference_part(scene, &program.moves);
        reference_time = clock.elapsed().as_secs_f64();
        reference
    })?;
    let display_time = clock.elapsed().as_secs_f64() - reference_time;
    let collisions: Vec<CollisionEvent> = checked.events.iter().map(CollisionEvent::of).collect();
    let markers = collisions
        .iter()
        .map(|c| Marker {
            position: c.point_mm,
            label: format!("line {}: {}", c.line, c.kind.replace('_', " ")),
        })
        .collect();
    // What is read off the display part, the stock and the mesh, made side by side (each
    // only reads them): the picture, the page's 3-D view, the deviation figures, and the
    // stock's and the mesh's figures. Each task is timed on its own, so the timings of
    // `render` (the display part and the picture), `page` and `deviation` may overlap.
    let ((png, view3d), (deviation, (stock_report, mesh_summary))) = rayon::join(
        || {
            rayon::join(
                || timed(|| part_png(scene, &shown)),
                || timed(|| view(scene, Some(&shown), None, Vec::new(), None, markers)),
            )
        },
        || {
            rayon::join(
                || deviation_of(scene, &stock, &shown),
                || {
                    (
                        StockReport::of(&stock, volume0),
                        mesh_summary(&mesh, &mesh_report),
                    )
                },
            )
        },
    );
    let (part_png, png_time) = png?;
    let (mut view3d, view_time) = view3d?;
    let (deviation, deviation_png, plots, deviation_time) = deviation?;
    // The stock's last read is done: freed before the page is built, whose buffers may
    // then reuse its memory.
    drop(stock);
    timings.insert("reference".into(), reference_time);
    timings.insert("render".into(), display_time + png_time);
    if let Some(t) = deviation_time {
        timings.insert("deviation".into(), t);
    }
    timings.insert("page".into(), view_time);
    view3d.picture = Some(part_png.clone());
    let report = SimulationReport {
        scene: scene.name.clone(),
        program: program.path.display().to_string(),
        stock: stock_report,
        sweep: checked.sweep,
        mesh: mesh_summary,
        collisions,
        deviation,
        timings_s: timings,
    };
    let html = render_page(&crate::report::pages::simulate_page(
        &report,
        Some(view3d),
        plots,
    ));
    Ok(Simulation {
        report,
        mesh,
        part_png,
        html,
        deviation_png,
    })
}

/// What `f` gives, with the seconds it took.
fn timed<T>(f: impl FnOnce() -> Result<T, PipelineError>) -> Result<(T, Real), PipelineError> {
    let clock = Instant::now();
    f().map(|x| (x, clock.elapsed().as_secs_f64()))
}

/// The part's deviation figures: from the scene's design model when it has one (the
/// deviation map, its picture and its plot, with the seconds they took), else the figures
/// behind the display part's colours (its deviations from the nominal part).
#[allow(clippy::type_complexity)]
fn deviation_of(
    scene: &Scene,
    stock: &TriDexel,
    shown: &DisplayPart,
) -> Result<
    (
        Option<DeviationSummary>,
        Option<Vec<u8>>,
        Vec<Plot>,
        Option<Real>,
    ),
    PipelineError,
> {
    let path = scene.path.display().to_string();
    let render_err = |source| PipelineError::Render {
        path: path.clone(),
        source,
    };
    let mut plots = Vec::new();
    let mut deviation_time = None;
    let (deviation, deviation_png) = match &scene.design {
        Some((design_path, design)) => {
            let clock = Instant::now();
            let (points, summary) =
                deviation_map(stock, design).map_err(|source| PipelineError::Deviation {
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
            let range = crate::report::display::colour_range_mm(
                &points.iter().map(|p| p.distance_mm).collect::<Vec<_>>(),
            );
            let xyd: Vec<_> = points
                .iter()
                .map(|p| (p.point.x, p.point.y, p.distance_mm))
                .collect();
            let labels = MapLabels {
                title: opts.title.clone(),
                x: "x (mm)".into(),
                y: "y (mm)".into(),
            };
            let svg = deviation_map_svg(&xyd, range, &labels).map_err(|e| PipelineError::Page {
                path: path.clone(),
                message: e.to_string(),
            })?;
            plots.push(Plot {
                caption: "Deviation map, top view: each cell shows the crossing of largest |deviation| in its column of the part.".into(),
                svg,
            });
            deviation_time = Some(clock.elapsed().as_secs_f64());
            (
                Some(DeviationSummary {
                    from: "design",
                    design: Some(design_path.display().to_string()),
                    map: summary,
                }),
                Some(png),
            )
        }
        // Without a design, the numbers behind the colours: the display's deviations from
        // the nominal part.
        None => (
            shown
                .deviations
                .as_deref()
                .and_then(|d| surface_deviation(&shown.mesh, d))
                .map(|d| DeviationSummary {
                    from: "nominal part",
                    design: None,
                    map: DeviationReport {
                        points: d.corners,
                        max_mm: d.max.value_mm,
                        min_mm: d.min.value_mm,
                        mean_mm: d.mean_mm,
                        rms_mm: d.rms_mm,
                        at_max: d.max.corner.coords.into(),
                        at_min: d.min.corner.coords.into(),
                        line_at_max: nearest_line(stock, &d.max.centroid),
                        line_at_min: nearest_line(stock, &d.min.centroid),
                    },
                }),
            None,
        ),
    };
    Ok((deviation, deviation_png, plots, deviation_time))
}

/// The surface mesh's figures, with the adaptive mesher's report.
fn mesh_summary(mesh: &TriMesh, r: &AdaptiveReport) -> MeshSummary {
    MeshSummary {
        vertices: mesh.vertices.len(),
        triangles: mesh.triangles.len(),
        euler_characteristic: mesh.euler_characteristic(),
        volume_mm3: mesh.signed_volume(),
        area_mm2: mesh.area(),
        feature_vertices: r.feature_vertices,
        bound_mm: r.bound_mm,
        max_plane_residual_mm: r.max_plane_residual_mm,
        planar_regions: r.planar_leaves,
        edge_regions: r.edge_leaves,
        fine_cells: r.fine_cells,
    }
}

/// The program cut into `stock` on the scene's deviated machine (with the collision checks
/// on a chain), the seconds of the sweep and the mesh, and the cut part's surface mesh.
fn cut_part(
    scene: &Scene,
    program: &Program,
    progress: &dyn Progress,
    stock: &mut TriDexel,
) -> Result<(CollisionReport, [Real; 2], TriMesh, AdaptiveReport), PipelineError> {
    let path = scene.path.display().to_string();
    let clock = Instant::now();
    // A hexapod scene has no holder or fixtures (refused on loading): its sweep runs
    // without the collision checks, which drive a chain.
    let checked = match &scene.machine {
        Machine::Hexapod(h) => {
            let sweep = sweep_program(
                stock,
                Kinematics::Poses(&h.twin),
                &scene.tool,
                &program.moves,
                &scene.sweep,
                progress,
            )
            .map_err(sweep_failed(program, &path))?;
            CollisionReport {
                events: Vec::new(),
                moves: sweep.moves,
                sweep,
                check_error_bound_mm: 0.0,
            }
        }
        Machine::Serial(m) => sweep_with_checks(
            stock,
            &m.chain,
            &scene.tool,
            scene.holder.as_ref(),
            &scene.fixtures,
            &program.moves,
            &scene.sweep,
            progress,
        )
        .map_err(sweep_failed(program, &path))?,
    };
    let sweep_time = clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    let (mesh, mesh_report) = super::part_mesh(stock, &path)?;
    let mesh_time = clock.elapsed().as_secs_f64();
    Ok((checked, [sweep_time, mesh_time], mesh, mesh_report))
}
