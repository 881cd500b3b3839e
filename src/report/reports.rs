//! The run report: what was simulated, measured and identified, serialised to
//! `report.json`, and the short summary the CLI prints.
//!
//! **Invariant:** the report is plain data assembled by [`crate::pipeline`]; formatting it
//! does no computation of the physics.

use crate::cutting::sweep::SweepReport;
use crate::math::Real;
use crate::metrology::scan::ViewReport;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// One fitted face.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FaceReport {
    /// Face name.
    pub name: String,
    /// NC line of its cut.
    pub line: usize,
    /// Rotary positions of the cut (degrees), per rotary axis.
    pub rotary_deg: Vec<f64>,
    /// Points used in the fit.
    pub points: usize,
    /// Points rejected as outliers.
    pub rejected: usize,
    /// Unit normal (into the material), workpiece frame.
    pub normal: [f64; 3],
    /// Plane offset: normal · x = offset (mm).
    pub offset_mm: f64,
    /// Centroid of the fitted points (mm).
    pub centroid_mm: [f64; 3],
    /// RMS of the residuals (mm).
    pub rms_mm: f64,
    /// Largest absolute residual (mm).
    pub max_abs_mm: f64,
}

/// Stock figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StockReport {
    /// Requested dexel pitch (mm).
    pub pitch_mm: f64,
    /// Rays in the three grids.
    pub rays: usize,
    /// Material segments after cutting.
    pub segments: usize,
    /// Material volume after cutting (mm³).
    pub volume_mm3: f64,
    /// Volume removed (mm³).
    pub removed_mm3: f64,
    /// Memory held by the tri-dexel (MiB).
    pub memory_mib: f64,
}

impl StockReport {
    /// The figures of a cut `stock` whose volume before cutting was `volume0` (mm³).
    pub fn of(stock: &crate::cutting::stock::TriDexel, volume0: f64) -> Self {
        Self {
            pitch_mm: stock.pitch(),
            rays: stock.grids().iter().map(|g| g.dims().0 * g.dims().1).sum(),
            segments: stock.grids().iter().map(|g| g.segment_count()).sum(),
            volume_mm3: stock.volume(),
            removed_mm3: volume0 - stock.volume(),
            memory_mib: stock.memory_bytes() as f64 / 1048576.0,
        }
    }
}

/// Surface-mesh figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MeshSummary {
    /// Vertices.
    pub vertices: usize,
    /// Triangles.
    pub triangles: usize,
    /// Euler characteristic V − E + F (2 for a part with no through-holes).
    pub euler_characteristic: i64,
    /// Volume enclosed by the mesh (mm³).
    pub volume_mm3: f64,
    /// Surface area (mm²).
    pub area_mm2: f64,
    /// Vertices added at sharp edges and corners (the rest lie on exact dexel crossings).
    pub feature_vertices: usize,
}

/// What `twinmill simulate` reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SimulationReport {
    /// Scene name.
    pub scene: String,
    /// Program file.
    pub program: String,
    /// Stock figures (removed volume).
    pub stock: StockReport,
    /// What the sweep did, with its approximation bounds.
    pub sweep: SweepReport,
    /// The surface mesh.
    pub mesh: MeshSummary,
    /// Collisions in program order (empty: none).
    pub collisions: Vec<CollisionEvent>,
    /// The deviation from the scene's design model, if it has one.
    pub deviation: Option<DeviationSummary>,
    /// Stage timings (s).
    pub timings_s: BTreeMap<String, f64>,
}

/// A collision found while sweeping (see [`crate::cutting::collide`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CollisionEvent {
    /// `rapid_through_material`, `shank_in_stock`, `holder_in_stock` or `fixture_hit`.
    pub kind: &'static str,
    /// The part that collided: `tool`, `shank` or `holder`.
    pub part: &'static str,
    /// The fixture's name (`fixture_hit` only).
    pub fixture: Option<String>,
    /// NC line of the move.
    pub line: usize,
    /// First contact point (mm, workpiece frame W).
    pub point_mm: [f64; 3],
    /// Stock: penetration depth estimate; fixture: travel after first contact (mm).
    pub depth_mm: f64,
    /// Stock: estimated overlap volume (mm³); fixtures: `None`.
    pub volume_mm3: Option<f64>,
}

impl CollisionEvent {
    /// The report of a collision event.
    pub fn of(e: &crate::cutting::collide::Event) -> Self {
        use crate::cutting::collide::{EventKind, Part};
        let part_name = |p: &Part| match p {
            Part::Tool => "tool",
            Part::Shank => "shank",
            Part::Holder => "holder",
        };
        let (kind, part, fixture) = match &e.kind {
            EventKind::RapidThroughMaterial => ("rapid_through_material", "tool", None),
            EventKind::NonCuttingInStock(p) => (
                if *p == Part::Holder {
                    "holder_in_stock"
                } else {
                    "shank_in_stock"
                },
                part_name(p),
                None,
            ),
            EventKind::FixtureHit { part, fixture } => {
                ("fixture_hit", part_name(part), Some(fixture.clone()))
            }
        };
        Self {
            kind,
            part,
            fixture,
            line: e.line,
            point_mm: e.point,
            depth_mm: e.depth_mm,
            volume_mm3: e.volume_mm3,
        }
    }
}

/// The cut part's deviation from a design model (signed distances of the part's surface
/// points: + material left, − gouge).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DeviationSummary {
    /// The design mesh file.
    pub design: String,
    /// Max, min, mean and RMS of the signed distances, and where the extremes are.
    #[serde(flatten)]
    pub map: crate::report::deviation_map::DeviationReport,
}

impl SimulationReport {
    /// A short text summary.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "scene         {}\nprogram       {}\nmoves         {} ({} cutting, {} rotary)\nremoved       {:.4} mm³ of {:.4} mm³\nsweep bound   {:.2e} mm (rotary envelope or sub-steps, and arc chords)\nmesh          {} triangles, {} vertices, Euler characteristic {}\n",
            self.scene,
            self.program,
            self.sweep.moves,
            self.sweep.cutting_moves,
            self.sweep.rotary_moves,
            self.stock.removed_mm3,
            self.stock.volume_mm3 + self.stock.removed_mm3,
            self.sweep.error_bound_mm,
            self.mesh.triangles,
            self.mesh.vertices,
            self.mesh.euler_characteristic,
        );
        s.push_str(&format!("collisions    {}\n", self.collisions.len()));
        for e in &self.collisions {
            s.push_str(&format!(
                "  line {:<6} {} ({}{}) at [{:.3}, {:.3}, {:.3}] mm, depth {:.3} mm\n",
                e.line,
                e.kind,
                e.part,
                e.fixture
                    .as_ref()
                    .map_or_else(String::new, |f| format!(", fixture '{f}'")),
                e.point_mm[0],
                e.point_mm[1],
                e.point_mm[2],
                e.depth_mm
            ));
        }
        if let Some(d) = &self.deviation {
            s.push_str(&format!(
                "deviation     max {:+.4} mm, min {:+.4} mm, RMS {:.4} mm over {} points from {}\n",
                d.map.max_mm, d.map.min_mm, d.map.rms_mm, d.map.points, d.design
            ));
        }
        s
    }
}

/// Scan figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScanReport {
    /// Camera rays cast.
    pub rays: usize,
    /// Points measured.
    pub points: usize,
    /// Points in the projector's shadow (not measured).
    pub shadowed: usize,
    /// Point pitch at the target distance (mm).
    pub pitch_mm: f64,
    /// Range noise σ (mm).
    pub noise_sigma_mm: f64,
    /// Noise seed.
    pub seed: u64,
    /// Per view: points, drop-outs and the registration error applied.
    pub views: Vec<ViewReport>,
}

impl ScanReport {
    /// The figures of `scan`, made with `cfg`.
    pub fn of(
        scan: &crate::metrology::scan::Scan,
        cfg: &crate::metrology::scan::ScannerConfig,
    ) -> Self {
        Self {
            rays: scan.rays,
            points: scan.cloud.points.len(),
            shadowed: scan.shadowed(),
            pitch_mm: cfg.pitch_mm,
            noise_sigma_mm: cfg.noise_sigma_mm,
            seed: cfg.seed,
            views: scan.views.clone(),
        }
    }
}

/// What `twinmill scan` writes to scan.json.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScanFileReport {
    /// Scene name.
    pub scene: String,
    /// The scan.
    pub scan: ScanReport,
    /// The scanner-effects study, if asked for.
    pub study: Vec<StudyCase>,
}

impl ScanFileReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let sc = &self.scan;
        let _ = writeln!(
            s,
            "twinmill scan: {} — {} points from {} view(s), {} rays",
            self.scene,
            sc.points,
            sc.views.len(),
            sc.rays
        );
        for v in &sc.views {
            let _ = writeln!(
                s,
                "  view at table {:>7.2}°: {} points; dropped {} shadowed, {} grazing, {} out of range",
                v.table_deg, v.points, v.shadowed, v.grazing, v.out_of_range
            );
        }
        if !self.study.is_empty() {
            let _ = writeln!(
                s,
                "  scanner study ({} = true value {:+.4} mm):",
                self.study[0].parameter, self.study[0].truth_mm
            );
            let _ = writeln!(
                s,
                "    {:<48} {:>6} {:>11} {:>10} {:>10} {:>10}",
                "case", "trials", "mean mm", "spread µm", "worst µm", "σ rep. µm"
            );
            for c in &self.study {
                let _ = writeln!(
                    s,
                    "    {:<48} {:>6} {:>+11.5} {:>10.2} {:>10.2} {:>10.2}",
                    c.case,
                    c.trials,
                    c.mean_mm,
                    c.spread_mm * 1e3,
                    c.worst_error_mm * 1e3,
                    c.mean_reported_sigma_mm * 1e3
                );
            }
        }
        s
    }
}

/// One case of the study: the identified offset over seeded trials.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StudyCase {
    /// What the scanner does in this case.
    pub case: String,
    /// Trials run.
    pub trials: usize,
    /// The offset parameter (e.g. `dy_AY`).
    pub parameter: String,
    /// Its true (injected) value (mm).
    pub truth_mm: Real,
    /// Mean identified value (mm).
    pub mean_mm: Real,
    /// Sample standard deviation over the trials (mm); 0 for one trial.
    pub spread_mm: Real,
    /// Largest |identified − truth| (mm).
    pub worst_error_mm: Real,
    /// Mean of the uncertainty the fits report (mm): compare with `spread_mm`.
    pub mean_reported_sigma_mm: Real,
    /// Mean measured step (mm).
    pub mean_step_mm: Real,
}

/// Solver figures of the identification.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SolverReport {
    /// Method used.
    pub method: String,
    /// Singular values of the Jacobian of (step, tilt) w.r.t. the two parameters.
    pub singular_values: [f64; 2],
    /// Residual evaluations.
    pub evaluations: usize,
    /// Final residual norm.
    pub residual: f64,
}

/// The whole report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Report {
    /// Scene name.
    pub scene: String,
    /// Machine name.
    pub machine: String,
    /// The chain, workpiece to tool.
    pub chain: String,
    /// Program file.
    pub program: String,
    /// Moves in the program.
    pub moves: usize,
    /// Measured step between the faces (mm): second face minus first along the first's
    /// normal into the material, at the faces' centre. For seed 002's setup, −2·dy_AY.
    pub step_mm: f64,
    /// Standard uncertainty of the measured step (mm).
    pub step_sigma_mm: f64,
    /// The step the exact twin predicts for the injected deviations (mm).
    pub predicted_step_mm: f64,
    /// Measured relative tilt of the faces about the tool axis (rad).
    pub tilt_rad: f64,
    /// The tilt the exact twin predicts (rad).
    pub predicted_tilt_rad: f64,
    /// Deviations injected into the simulated machine (mm or rad).
    pub injected: BTreeMap<String, f64>,
    /// Deviations assumed known in the identification (mm or rad).
    pub known: BTreeMap<String, f64>,
    /// Identified deviations and combinations (mm or rad).
    pub identified: BTreeMap<String, f64>,
    /// Standard uncertainties of the identified values, from the fit residuals.
    pub uncertainty: BTreeMap<String, f64>,
    /// Deviations this experiment does not identify; held at their known values, never
    /// given an identified value.
    pub not_identified: Vec<String>,
    /// The fitted faces.
    pub faces: Vec<FaceReport>,
    /// Identification solver.
    pub solver: SolverReport,
    /// Stock.
    pub stock: StockReport,
    /// Sweep, with the bound on the rotary sub-step approximation.
    pub sweep: SweepReport,
    /// Scan.
    pub scan: ScanReport,
    /// Wall-clock seconds per stage, in pipeline order.
    pub timings_s: Vec<(String, f64)>,
}

impl Report {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "twinmill: {} on {} ({} moves)",
            self.scene, self.machine, self.moves
        );
        let inj: Vec<String> = self
            .injected
            .iter()
            .map(|(k, v)| format!("{k} = {v}"))
            .collect();
        let _ = writeln!(
            s,
            "  injected      {}",
            if inj.is_empty() {
                "none".into()
            } else {
                inj.join(", ")
            }
        );
        let _ = writeln!(
            s,
            "  step          {:+.4} mm ± {:.4} (predicted by the twin {:+.4} mm)",
            self.step_mm, self.step_sigma_mm, self.predicted_step_mm
        );
        for (k, v) in &self.identified {
            let u = self.uncertainty.get(k).copied().unwrap_or(f64::NAN);
            let unit = if k.starts_with('d') {
                ("mm", 1.0)
            } else {
                ("µrad", 1e6)
            };
            let _ = writeln!(
                s,
                "  identified    {k} = {:+.4} ± {:.4} {}",
                v * unit.1,
                u * unit.1,
                unit.0
            );
        }
        for f in &self.faces {
            let _ = writeln!(
                s,
                "  face {:<8} {} points, rms {:.4} mm",
                f.name, f.points, f.rms_mm
            );
        }
        let _ = writeln!(
            s,
            "  scan          {} points ({} shadowed), σ = {} mm; sweep bound on rotary moves {:.1e} mm",
            self.scan.points,
            self.scan.shadowed,
            self.scan.noise_sigma_mm,
            self.sweep.rotary_error_bound_mm
        );
        let total: f64 = self.timings_s.iter().map(|(_, t)| t).sum();
        let stages: Vec<String> = self
            .timings_s
            .iter()
            .map(|(k, t)| format!("{k} {:.3}", t))
            .collect();
        let _ = writeln!(s, "  time          {total:.3} s ({})", stages.join(", "));
        s
    }
}

fn arr(v: &crate::math::Vector3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// A fitted plane, as `twinmill fit` reports it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlaneReport {
    /// Unit normal.
    pub normal: [f64; 3],
    /// normal · x = offset (mm).
    pub offset_mm: f64,
    /// Centroid of the points used (mm).
    pub centroid_mm: [f64; 3],
    /// Points used and rejected.
    pub points: [usize; 2],
    /// RMS and largest absolute residual (mm).
    pub rms_mm: f64,
    /// Largest absolute residual (mm).
    pub max_abs_mm: f64,
    /// Standard uncertainty of the offset at the centroid (mm).
    pub offset_sigma_mm: f64,
    /// Standard uncertainties of the normal's tilt about the in-plane principal axes (rad).
    pub tilt_sigma_rad: [f64; 2],
}

impl PlaneReport {
    /// From a fit.
    pub fn of(f: &crate::metrology::fit::PlaneFit) -> Self {
        Self {
            normal: arr(&f.plane.normal),
            offset_mm: f.plane.offset,
            centroid_mm: arr(&f.centroid.coords),
            points: [f.n_used, f.n_rejected],
            rms_mm: f.rms_mm,
            max_abs_mm: f.max_abs_mm,
            offset_sigma_mm: f.offset_sigma_mm,
            tilt_sigma_rad: f.tilt_sigma_rad,
        }
    }
}

/// Distance and angle between two fitted planes, the way seed 002 reports them.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlanePair {
    /// Indices into the plane list.
    pub planes: [usize; 2],
    /// Signed distance from the first to the second along the first's normal, through the
    /// midpoint of their centroids (mm); only for planes within 10° of parallel, where a
    /// distance means something.
    pub distance_mm: Option<f64>,
    /// Angle between the normals (rad).
    pub angle_rad: f64,
}

/// A fitted sphere.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SphereReport {
    /// Centre (mm) and its standard uncertainties.
    pub centre_mm: [f64; 3],
    /// Standard uncertainties of the centre (mm).
    pub centre_sigma_mm: [f64; 3],
    /// Radius and its standard uncertainty (mm).
    pub radius_mm: [f64; 2],
    /// Points used and rejected.
    pub points: [usize; 2],
    /// RMS residual (mm).
    pub rms_mm: f64,
}

impl SphereReport {
    /// From a fit.
    pub fn of(f: &crate::metrology::fit::SphereFit) -> Self {
        Self {
            centre_mm: arr(&f.centre.coords),
            centre_sigma_mm: f.centre_sigma_mm,
            radius_mm: [f.radius, f.radius_sigma_mm],
            points: [f.n_used, f.n_rejected],
            rms_mm: f.rms_mm,
        }
    }
}

/// A fitted cylinder.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CylinderReport {
    /// The axis point nearest the points' centroid (mm).
    pub axis_point_mm: [f64; 3],
    /// Its standard uncertainties (mm).
    pub axis_point_sigma_mm: [f64; 3],
    /// Unit axis direction.
    pub axis: [f64; 3],
    /// Standard uncertainties of the axis tilt (rad).
    pub axis_sigma_rad: [f64; 2],
    /// Radius and its standard uncertainty (mm).
    pub radius_mm: [f64; 2],
    /// Points used and rejected.
    pub points: [usize; 2],
    /// RMS residual (mm).
    pub rms_mm: f64,
}

impl CylinderReport {
    /// From a fit.
    pub fn of(f: &crate::metrology::fit::CylinderFit) -> Self {
        Self {
            axis_point_mm: arr(&f.axis_point.coords),
            axis_point_sigma_mm: f.axis_point_sigma_mm,
            axis: arr(&f.axis),
            axis_sigma_rad: f.axis_sigma_rad,
            radius_mm: [f.radius, f.radius_sigma_mm],
            points: [f.n_used, f.n_rejected],
            rms_mm: f.rms_mm,
        }
    }
}

/// A fitted circle in 3-D.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CircleReport {
    /// Centre (mm).
    pub centre_mm: [f64; 3],
    /// Its standard uncertainties (mm).
    pub centre_sigma_mm: [f64; 3],
    /// Unit normal of the circle's plane, and its tilt uncertainty (rad) as a fourth number.
    pub normal: [f64; 4],
    /// Radius and its standard uncertainty (mm).
    pub radius_mm: [f64; 2],
    /// Points used and rejected.
    pub points: [usize; 2],
    /// RMS residual (mm).
    pub rms_mm: f64,
}

impl CircleReport {
    /// From a fit.
    pub fn of(f: &crate::metrology::fit::CircleFit) -> Self {
        Self {
            centre_mm: arr(&f.centre.coords),
            centre_sigma_mm: f.centre_sigma_mm,
            normal: [f.normal.x, f.normal.y, f.normal.z, f.normal_sigma_rad],
            radius_mm: [f.radius, f.radius_sigma_mm],
            points: [f.n_used, f.n_rejected],
            rms_mm: f.rms_mm,
        }
    }
}

/// What `twinmill fit` reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FitFileReport {
    /// The cloud file.
    pub cloud: String,
    /// Points in the cloud.
    pub points: usize,
    /// Points selected.
    pub selected: usize,
    /// Fitted planes (largest first for segmentation).
    pub planes: Vec<PlaneReport>,
    /// Distance and angle between each pair of planes.
    pub pairs: Vec<PlanePair>,
    /// A fitted sphere.
    pub sphere: Option<SphereReport>,
    /// A fitted cylinder.
    pub cylinder: Option<CylinderReport>,
    /// A fitted circle.
    pub circle: Option<CircleReport>,
}

impl FitFileReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "twinmill fit: {} — {} points, {} selected",
            self.cloud, self.points, self.selected
        );
        for (i, p) in self.planes.iter().enumerate() {
            let n = p.normal;
            let _ = writeln!(
                s,
                "  plane {i}: n = ({:+.6}, {:+.6}, {:+.6}), offset {:+.5} ± {:.5} mm, {} points, rms {:.4} mm",
                n[0], n[1], n[2], p.offset_mm, p.offset_sigma_mm, p.points[0], p.rms_mm
            );
        }
        for p in &self.pairs {
            let (a, b) = (p.planes[0], p.planes[1]);
            let _ = match p.distance_mm {
                Some(d) => writeln!(
                    s,
                    "  planes {a}–{b}: distance {d:+.5} mm, angle {:.2} µrad",
                    p.angle_rad * 1e6
                ),
                None => writeln!(
                    s,
                    "  planes {a}–{b}: angle {:.4}°",
                    p.angle_rad.to_degrees()
                ),
            };
        }
        if let Some(c) = &self.sphere {
            let _ = writeln!(
                s,
                "  sphere: centre ({:.5}, {:.5}, {:.5}) mm, radius {:.5} ± {:.5} mm, rms {:.4} mm",
                c.centre_mm[0],
                c.centre_mm[1],
                c.centre_mm[2],
                c.radius_mm[0],
                c.radius_mm[1],
                c.rms_mm
            );
        }
        if let Some(c) = &self.cylinder {
            let _ = writeln!(
                s,
                "  cylinder: axis through ({:.5}, {:.5}, {:.5}) along ({:+.6}, {:+.6}, {:+.6}), radius {:.5} ± {:.5} mm, rms {:.4} mm",
                c.axis_point_mm[0],
                c.axis_point_mm[1],
                c.axis_point_mm[2],
                c.axis[0],
                c.axis[1],
                c.axis[2],
                c.radius_mm[0],
                c.radius_mm[1],
                c.rms_mm
            );
        }
        if let Some(c) = &self.circle {
            let _ = writeln!(
                s,
                "  circle: centre ({:.5}, {:.5}, {:.5}) mm, radius {:.5} ± {:.5} mm, rms {:.4} mm",
                c.centre_mm[0],
                c.centre_mm[1],
                c.centre_mm[2],
                c.radius_mm[0],
                c.radius_mm[1],
                c.rms_mm
            );
        }
        s
    }
}

/// One pass of the correction loop: the program simulated on the machine and measured.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CorrectIteration {
    /// 0 for the program as given, then 1, 2, … for each correction.
    pub iteration: usize,
    /// The subdivision tolerance used (mm); `None` for the program as given.
    pub path_tolerance_mm: Option<f64>,
    /// Blocks simulated.
    pub blocks: usize,
    /// Tool path on the simulated machine against the nominal path.
    pub path: crate::calibration::correct::PathError,
    /// The milled faces against the nominal faces.
    pub faces: crate::calibration::correct::FaceCheck,
    /// Every cut surface of the part against the nominal part (the program as given swept
    /// on the nominal machine), ray by ray.
    pub part: crate::calibration::correct::PartError,
    /// The predicted machining error: the largest distance of a milled-face crossing from
    /// its nominal face (mm); `None` (null) when no face was measured — the scene names no
    /// faces (`[identify]`), or they are too far off to find.
    pub predicted_error_mm: Option<f64>,
    /// What the sweep did.
    pub sweep: SweepReport,
}

/// The residual one deviation alone leaves after correction.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct UncorrectableReport {
    /// Deviation name.
    pub deviation: String,
    /// Its value in the model corrected for (mm or rad).
    pub value: f64,
    /// Largest RMS residual over the flute it alone leaves (mm).
    pub residual_rms_mm: f64,
    /// Largest residual at the flute's tip or end (mm).
    pub residual_max_mm: f64,
}

/// What `twinmill correct` writes to `<scene>-correct.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CorrectReport {
    /// Scene name.
    pub scene: String,
    /// Source program file.
    pub program: String,
    /// The corrected program's file name.
    pub corrected_program: String,
    /// Deviations corrected for (the model; mm or rad), non-zero ones.
    pub corrected_for: BTreeMap<String, f64>,
    /// Deviations of the simulated machine (mm or rad).
    pub simulated: BTreeMap<String, f64>,
    /// The accuracy asked for (mm).
    pub accuracy_mm: f64,
    /// Whether the last iteration's faces and path are within the accuracy.
    pub met: bool,
    /// How the loop ended, in words.
    pub status: String,
    /// Every pass, the program as given first.
    pub iterations: Vec<CorrectIteration>,
    /// The final correction's figures.
    pub correction: crate::calibration::correct::CorrectionSummary,
    /// Each non-zero deviation alone: the residual no axis command can remove.
    pub uncorrectable: Vec<UncorrectableReport>,
    /// Per source move of the final correction.
    pub moves: Vec<crate::calibration::correct::MoveCorrection>,
    /// Seconds per stage.
    pub timings_s: Vec<(String, f64)>,
}

impl CorrectReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "twinmill correct: {} ({}) for accuracy {} mm",
            self.scene, self.program, self.accuracy_mm
        );
        for (k, v) in &self.corrected_for {
            let _ = writeln!(s, "  corrected for {k} = {v}");
        }
        for it in &self.iterations {
            let label = if it.iteration == 0 {
                "as given ".to_string()
            } else {
                format!("pass {:<4}", it.iteration)
            };
            let step = it
                .faces
                .step_mm
                .map_or(String::new(), |x| format!(", step {:+.4} µm", x * 1e3));
            let faces = match it.predicted_error_mm {
                Some(e) => format!("faces max {:.4} µm{step}", e * 1e3),
                None => "faces not measured".to_string(),
            };
            let _ = writeln!(
                s,
                "  {label} {faces}; path max {:.4} µm, rms {:.4} µm; whole part max {:.4} µm ({} blocks)",
                it.path.max_mm * 1e3,
                it.path.rms_mm * 1e3,
                it.part.max_mm * 1e3,
                it.blocks
            );
        }
        let c = &self.correction;
        let _ = writeln!(
            s,
            "  residual      {:.4} µm RMS over the flute, {:.4} µm at a flute end (uncorrectable); {} moves subdivided",
            c.residual_rms_mm * 1e3,
            c.residual_max_mm * 1e3,
            c.subdivided_moves
        );
        for u in self
            .uncorrectable
            .iter()
            .filter(|u| u.residual_max_mm > crate::math::tol::LENGTH_EPS)
        {
            let _ = writeln!(
                s,
                "  {:<13} alone leaves {:.4} µm RMS (cannot be corrected with these axes)",
                u.deviation,
                u.residual_rms_mm * 1e3
            );
        }
        let _ = writeln!(s, "  status        {}", self.status);
        let total: f64 = self.timings_s.iter().map(|t| t.1).sum();
        let parts: Vec<String> = self
            .timings_s
            .iter()
            .map(|(n, t)| format!("{n} {t:.3}"))
            .collect();
        let _ = writeln!(s, "  time          {total:.3} s ({})", parts.join(", "));
        s
    }
}

/// One measured feature in an identification report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FeatureReport {
    /// Face name.
    pub name: String,
    /// `flank` or `floor`.
    pub kind: String,
    /// NC line of its cut.
    pub line: usize,
    /// Points used in the fit.
    pub points: usize,
    /// RMS residual of the fit (mm).
    pub rms_mm: f64,
    /// Measured unit normal (into the material), scan frame.
    pub normal: [f64; 3],
    /// Measured centroid (mm).
    pub centroid_mm: [f64; 3],
    /// Standard uncertainty of the offset at the centroid (mm).
    pub offset_sigma_mm: f64,
    /// Whitened residuals after the solve: offset, two slopes (in standard uncertainties).
    pub residuals: [f64; 3],
}

/// One identified quantity.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EstimateReport {
    /// Parameter or combination name.
    pub name: String,
    /// Identified value (mm or rad).
    pub value: f64,
    /// Standard uncertainty from the features' residual-based uncertainties.
    pub sigma: f64,
    /// Sample standard deviation over the Monte-Carlo trials, if run.
    pub monte_carlo_spread: Option<f64>,
    /// The value the scene injected (simulated scans only).
    pub injected: Option<f64>,
    /// Coefficients over `parameters`.
    pub coefficients: Vec<f64>,
}

/// One round of the model-correction loop.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LoopRound {
    /// Round number from 1.
    pub round: usize,
    /// Largest distance between a predicted and a measured face over the face's extent
    /// (centroid and corners, mm), after updating the twin in this round.
    pub worst_face_mm: f64,
    /// Weighted sum of squared residuals.
    pub chi2: f64,
}

/// What `twinmill identify` reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IdentifyReport {
    /// Scene name.
    pub scene: String,
    /// The chain.
    pub chain: String,
    /// Where the cloud came from (the simulated scan or a file).
    pub cloud: String,
    /// Registration handling (`estimate` or `workpiece`).
    pub registration: String,
    /// Parameters asked for.
    pub parameters: Vec<String>,
    /// The features.
    pub features: Vec<FeatureReport>,
    /// Singular values of the scaled Jacobian (registration projected out).
    pub singular_values: Vec<f64>,
    /// Condition number (infinite: some direction not seen at all).
    pub condition_number: f64,
    /// Condition number within the determined subspace.
    pub condition_number_determined: f64,
    /// Parameters identified on their own.
    pub identified: Vec<EstimateReport>,
    /// Determined combinations.
    pub combinations: Vec<EstimateReport>,
    /// Directions not determined (named); held at their known values, never valued.
    pub not_determined: Vec<String>,
    /// Parameters without an identified value of their own.
    pub not_identified: Vec<String>,
    /// Parameters no feature depends on at all.
    pub no_data: Vec<String>,
    /// What the registration absorbs.
    pub registration_absorbs: Vec<String>,
    /// The estimated registration (dx, dy, dz mm; alpha, beta, gamma rad).
    pub registration_estimate: [f64; 6],
    /// Solver: evaluations, termination, χ² before and after, degrees of freedom.
    pub solver: IdentifySolverReport,
    /// The model-correction loop.
    pub rounds: Vec<LoopRound>,
    /// Whether the loop met its tolerance.
    pub converged: bool,
    /// Monte-Carlo trials run.
    pub monte_carlo_trials: usize,
    /// Seconds per stage.
    pub timings_s: Vec<(String, f64)>,
}

/// The solver's account in an identification report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IdentifySolverReport {
    /// Residual evaluations.
    pub evaluations: usize,
    /// Why it stopped.
    pub termination: String,
    /// χ² at the start.
    pub chi2_start: f64,
    /// χ² at the end.
    pub chi2: f64,
    /// Degrees of freedom.
    pub dof: usize,
}

impl IdentifyReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "twinmill identify: {} — {} faces, registration {}, cloud {}",
            self.scene,
            self.features.len(),
            self.registration,
            self.cloud
        );
        let fmt = |e: &EstimateReport| {
            let unit = if e.name.starts_with('d') { "mm" } else { "rad" };
            let mut t = format!("{:+.6e} ± {:.2e} {unit}", e.value, e.sigma);
            if let Some(m) = e.monte_carlo_spread {
                let _ = write!(t, " (MC spread {m:.2e})");
            }
            if let Some(i) = e.injected {
                let _ = write!(t, " [injected {i:+.6e}]");
            }
            t
        };
        for e in &self.identified {
            let _ = writeln!(s, "  identified    {:<28} {}", e.name, fmt(e));
        }
        for e in &self.combinations {
            let _ = writeln!(s, "  combination   {:<28} {}", e.name, fmt(e));
        }
        for n in &self.not_determined {
            let _ = writeln!(s, "  not determined {n}");
        }
        if !self.no_data.is_empty() {
            let _ = writeln!(s, "  no data       {}", self.no_data.join(", "));
        }
        let _ = writeln!(
            s,
            "  jacobian      condition {:.3e} (determined subspace {:.3e}); singular values {}",
            self.condition_number,
            self.condition_number_determined,
            self.singular_values
                .iter()
                .map(|v| format!("{v:.3e}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
        let _ = writeln!(
            s,
            "  solver        {} evaluations, {}, χ² {:.3e} → {:.3e} ({} dof)",
            self.solver.evaluations,
            self.solver.termination,
            self.solver.chi2_start,
            self.solver.chi2,
            self.solver.dof
        );
        if let Some(last) = self.rounds.last() {
            let _ = writeln!(
                s,
                "  loop          {} round(s), worst face {:.2e} mm: {}",
                self.rounds.len(),
                last.worst_face_mm,
                if self.converged {
                    "within tolerance"
                } else {
                    "NOT within tolerance"
                }
            );
        }
        s
    }
}

/// What `twinmill design` reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DesignReport {
    /// Scene the design is for.
    pub scene: String,
    /// Parameters asked for.
    pub parameters: Vec<String>,
    /// Cuts: name, rotary index (degrees), NC line of the cut.
    pub cuts: Vec<(String, f64, usize)>,
    /// Faces to measure: name and kind.
    pub faces: Vec<(String, String)>,
    /// Singular values of the scaled Jacobian expected with the scene's scanner noise.
    pub singular_values: Vec<f64>,
    /// Condition number.
    pub condition_number: f64,
    /// Parameters the design identifies on their own.
    pub identified: Vec<String>,
    /// Further determined combinations.
    pub determined_combinations: Vec<String>,
    /// Directions the design does not determine.
    pub not_determined: Vec<String>,
    /// Expected standard uncertainty of each identified parameter over its realistic
    /// magnitude (0.5 mm, 5e-4 rad).
    pub relative_sigma: Vec<(String, f64)>,
    /// Candidate evaluations made.
    pub evaluated: usize,
    /// Why the weak directions are weak (the tip-height lever of the Z-squareness and
    /// spindle-tilt pairs).
    pub notes: Vec<String>,
}

impl DesignReport {
    /// The short human summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "twinmill design: {} — {} cuts, {} faces ({} candidates evaluated)",
            self.scene,
            self.cuts.len(),
            self.faces.len(),
            self.evaluated
        );
        for (name, a, line) in &self.cuts {
            let _ = writeln!(s, "  cut           {name:<16} A = {a:>5.1}°  line {line}");
        }
        let _ = writeln!(s, "  identified    {}", self.identified.join(", "));
        for c in &self.determined_combinations {
            let _ = writeln!(s, "  combination   {c}");
        }
        for c in &self.not_determined {
            let _ = writeln!(s, "  not determined {c}");
        }
        let _ = writeln!(s, "  condition     {:.3e}", self.condition_number);
        for n in &self.notes {
            let _ = writeln!(s, "  lever         {n}");
        }
        s
    }
}
