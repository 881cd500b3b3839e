//! **The commands**, each a function with no side effects: it takes a loaded scene (and its
//! program, or a cloud), returns everything it made — reports, clouds, pictures, meshes,
//! corrected moves — and writes nothing ([`crate::output`] does). One module per command:
//! [`simulate()`], [`run()`] (and [`scanner_study`]), [`fit_cloud`], [`correct()`],
//! [`identify_scene`], [`design_scene`], [`rotary_test()`]; [`pages`] makes what their
//! `report.html` and `part.png` need (the reference part, the display mesh, the 3-D view),
//! [`instrument_pages`] the pages of the instrument commands; [`evaluate`] the standards'
//! evaluations of measurement files, [`measure`] the virtual instruments on a scene's machine
//! (serial or hexapod) as plain requests and outcomes, [`measurements`] the identification
//! from several instruments' files, [`hexapod_probe`] seed 001's probe calibration of a
//! hexapod;
//! this file holds what they share: the stock, the sweep of the program through the deviated
//! machine, and the errors.
//!
//! May use every stage folder and [`crate::scene`]. **Invariant:** the same scene and
//! program give the same outcome (except the timings) for any thread count.

pub mod pages;
mod simulate;
mod run;
mod fit;
mod correct;
mod identify;
mod design;
mod rotary;
pub mod hexapod;
pub mod dbb;
pub mod instrument_pages;
pub mod evaluate;
pub mod measure;
pub mod measurements;
pub mod hexapod_probe;

pub use correct::{CorrectOutcome, correct, correct_hexapod, identified_model};
pub use design::{DesignOutcome, MAX_DESIGN_ROUNDS, design_scene};
pub use fit::{FitRequest, Selection, Shape, fit_cloud};
pub use identify::{
    IdentifyOutcome, correction_loop, extract_features, identify_scene, part_faces,
};
pub use rotary::{
    LocationReport, RotaryInstrument, RotaryOutcome, RotaryReport, RotaryRequest, TermReport,
    TraceIdentification, default_setup, identify_location_files, identify_location_with,
    is_angle_term, rotary_test,
};
pub use run::{Outcome, extract_faces, run, scanner_study};
pub use simulate::{Simulation, simulate};

use crate::calibration::calibrate::CalibrateError;
use crate::calibration::correct::CorrectError;
use crate::calibration::goodness::{Misfit, ScanNoise};
use crate::calibration::identify::IdentifyError;
use crate::cutting::mesh::MeshError;
use crate::cutting::stock::{StockError, TriDexel};
use crate::cutting::sweep::{SweepError, SweepReport, sweep_program};
use crate::math::Real;
use crate::metrology::scan::{ScanError, ScannerConfig};
use crate::nc::Program;
use crate::progress::Progress;
use crate::report::deviation_map::DeviationError;
use crate::report::render::RenderError;
use crate::scene::{Scene, SceneError, StockShape};
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
    /// Test cuts could not be designed.
    #[error("{path}: design: {source}")]
    Design {
        /// Scene file.
        path: String,
        /// Why.
        source: crate::calibration::design::DesignError,
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
    /// The report page could not be made.
    #[error("{path}: report.html: {message}")]
    Page {
        /// Scene file.
        path: String,
        /// Why.
        message: String,
    },
    /// The heat map could not be drawn.
    #[error("{path}: heat map: {source}")]
    Render {
        /// Scene file.
        path: String,
        /// Why.
        source: RenderError,
    },
    /// A rotary-axis test could not be run or evaluated.
    #[error("{path}: {message}")]
    Rotary {
        /// Scene file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// The measurements cannot come from the model at the stated noise: the
    /// identification is refused ([`crate::calibration::goodness`]).
    #[error("{path}: {source}")]
    Misfit {
        /// Scene file.
        path: String,
        /// The statistic, its expected range and what is out of line.
        source: Misfit,
    },
}

/// What the scanner of `scanner` states about a cloud's points of faces within `stock`
/// (see [`face_rms_check`](crate::calibration::goodness::face_rms_check)): its range noise,
/// the views merged (the turntable's, or one), each view's registration error and the lever
/// it turns over — the farthest corner of the stock from the view's target or the
/// turntable's axis point.
pub fn scan_noise(scanner: &ScannerConfig, stock: &crate::math::Aabb) -> ScanNoise {
    let mut centres = vec![scanner.target];
    if let Some(t) = &scanner.turntable {
        centres.push(t.axis_point);
    }
    let mut lever: Real = 0.0;
    for i in 0..8 {
        let corner = crate::math::Point3::new(
            if i & 1 == 0 { stock.min.x } else { stock.max.x },
            if i & 2 == 0 { stock.min.y } else { stock.max.y },
            if i & 4 == 0 { stock.min.z } else { stock.max.z },
        );
        for c in &centres {
            lever = lever.max((corner - c).norm());
        }
    }
    ScanNoise {
        sigma_mm: scanner.noise_sigma_mm,
        views: scanner
            .turntable
            .as_ref()
            .map_or(1, |t| t.angles_deg.len().max(1)),
        translation_sigma_mm: scanner.misregistration.translation_sigma_mm,
        rotation_sigma_rad: scanner.misregistration.rotation_sigma_rad,
        lever_mm: lever,
    }
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
    let (b, h, budget) = (scene.stock_box, scene.pitch_mm, scene.memory.bytes);
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

/// The cut part's mesh as the commands write and draw it: the adaptive mesh at its default
/// tolerances (docs/cutting.md#the-part-mesh), its failure naming the scene at `path`.
pub fn part_mesh(
    stock: &TriDexel,
    path: &str,
) -> Result<
    (
        crate::cutting::mesh::TriMesh,
        crate::cutting::adaptive::AdaptiveReport,
    ),
    PipelineError,
> {
    crate::cutting::adaptive::mesh_stock_adaptive(
        stock,
        &crate::cutting::adaptive::AdaptiveOptions::default(),
    )
    .map_err(|source| PipelineError::Mesh {
        path: path.to_string(),
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
        scene.kinematics(),
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
