//! The `twinmill` command line: parses arguments, calls the library, prints, picks the exit
//! code. Nothing else happens here.

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Mutex;
use twinmill::calibration::correct::write_gcode;
use twinmill::math::{Aabb, Point3};
use twinmill::metrology::ball_sensor::{self, BallSensor};
use twinmill::metrology::circular::{
    CircularFigures, CircularOptions, Diagnosis, evaluate as evaluate_circular, parse_trace,
};
use twinmill::metrology::cloud::read_cloud_file;
use twinmill::metrology::positioning::{
    PositioningFigures, evaluate as evaluate_positioning, parse_readings,
};
use twinmill::metrology::scan::Surface;
use twinmill::metrology::segment::{PlaneSegmentOptions, RansacOptions};
use twinmill::nc::{Interpreter, LengthUnit, Program, write_jsonl};
use twinmill::output::{
    MeshFormat, json_bytes, ply_bytes, write_files, write_outcome, write_simulation, write_streamed,
};
use twinmill::pipeline::pages::{correct_page, design_page, identify_page, run_page, scan_page};
use twinmill::pipeline::{
    FitRequest, Selection, Shape, correct, design_scene, fit_cloud, identified_model,
    identify_scene, machine_part, run, scanner_study, simulate,
};
use twinmill::progress::Progress;
use twinmill::report::{ScanFileReport, ScanReport};
use twinmill::scene::{MemoryBudget, Need, Scene, SceneError};

/// twinmill: a digital twin of machine-tool accuracy.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// What `run` and `scan` share.
#[derive(clap::Args)]
struct SceneArgs {
    /// The scene file (TOML).
    scene: PathBuf,
    /// Folder for outputs: run writes <out>/<scene name>/, scan <out>/<scene name>-scan/.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Print the report as JSON on stdout instead of the summary.
    #[arg(long)]
    json: bool,
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// List every problem found in the NC program, not only the first.
    #[arg(short, long)]
    verbose: bool,
    /// Memory the tri-dexel stock may use, e.g. 2G, 512M, 1.5GiB (default: half the
    /// installed memory).
    #[arg(long, value_name = "SIZE")]
    memory: Option<String>,
}

/// Which NC command.
#[derive(Subcommand)]
enum NcCommand {
    /// Interpret a program and print its machine-coordinate motion (LinuxCNC dialect).
    Motion {
        /// The NC program (.ngc).
        program: PathBuf,
        /// LinuxCNC tool table (.tbl).
        #[arg(long)]
        tool_table: Option<PathBuf>,
        /// LinuxCNC parameter file (.var).
        #[arg(long)]
        var: Option<PathBuf>,
        /// INI file: [RS274NGC] SUBROUTINE_PATH and DISABLE_FANUC_STYLE_SUB.
        #[arg(long)]
        ini: Option<PathBuf>,
        /// Block delete switch on: skip lines starting with '/'.
        #[arg(long)]
        block_delete: bool,
        /// Unit of tool-table / var-file lengths: mm (default) or inch (LinuxCNC's
        /// standalone rs274).
        #[arg(long, default_value = "mm", value_parser = ["mm", "inch"])]
        external_units: String,
        /// Do not accept Fanuc-style O1000 ... M99 subprograms and M98 calls.
        #[arg(long)]
        no_fanuc_subs: bool,
        /// Print JSON lines (the only output format for now).
        #[arg(long)]
        jsonl: bool,
        /// Also print non-motion records (tool, spindle, offsets, ...).
        #[arg(long)]
        events: bool,
    },
    /// Print the synthetic benchmark program (G1 with A words, every fifth block a G3).
    BenchProgram {
        /// Number of motion blocks (200000 makes the 6.3 MB benchmark file).
        #[arg(default_value_t = 200_000)]
        blocks: usize,
    },
}

/// Which deviations `correct` corrects for.
#[derive(Clone, Copy, clap::ValueEnum)]
enum ModelSource {
    /// The scene's injected deviations (the simulated machine itself).
    Injected,
    /// The deviations identified from the scene's simulated scan (plus the known ones).
    Identified,
}

#[derive(Subcommand)]
enum Command {
    /// NC program tools.
    Nc {
        #[command(subcommand)]
        command: NcCommand,
    },
    /// Simulate a scene's program on its deviated machine, scan the part, fit the faces and
    /// identify the deviations; write report.json, cloud.ply, faces.png and report.html (a
    /// self-contained page with the part in 3-D).
    Run {
        #[command(flatten)]
        args: SceneArgs,
    },
    /// Cut the scene's program into its stock on the deviated machine (no scan): write the
    /// part's surface mesh, a shaded picture of it (part.png, coloured by deviation where
    /// known), report.html (the page, with the part in 3-D) and report.json with the removed volume,
    /// the sweep's approximation bounds and the collisions (rapids through material, shank or
    /// holder in the stock, fixtures hit); with a [design] mesh, also its deviation map
    /// (deviation.png, max/min/RMS in report.json).
    Simulate {
        #[command(flatten)]
        args: SceneArgs,
        /// Mesh formats to write, comma separated: stl, obj, ply.
        #[arg(long, value_delimiter = ',', default_value = "stl", value_parser = ["stl", "obj", "ply"])]
        mesh: Vec<String>,
    },
    /// Simulate the scene's program and scan the part with the scene's scanner (all views);
    /// write cloud.ply and scan.json. With --study, also scan it again and again with each
    /// scanner effect alone and together, and report how the identified offset moves.
    Scan {
        #[command(flatten)]
        args: SceneArgs,
        /// Run the scanner-effects study with N seeded trials per case (default: the
        /// scene's [study] trials, 20 if not given).
        #[arg(long, num_args = 0..=1, default_missing_value = "0", value_name = "N")]
        study: Option<usize>,
    },
    /// Correct the scene's NC program for its machine's deviations: simulate the corrected
    /// program on the deviated machine, compare the milled faces and the tool path with the
    /// nominal ones, refine until within the accuracy; write <out>/<scene>-corrected.ngc and
    /// <out>/<scene>-correct.json.
    Correct {
        /// The scene file (TOML).
        scene: PathBuf,
        /// The deviations to correct for: the scene's injected ones, or those identified by
        /// simulating, scanning and fitting the scene first (`run`), as on a real machine.
        #[arg(long, value_enum, default_value = "injected")]
        model: ModelSource,
        /// Accuracy the corrected part must reach on the twin (mm, > 0).
        #[arg(long, default_value_t = 0.001, allow_hyphen_values = true)]
        accuracy_mm: f64,
        /// Folder for the corrected program and the report.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Print the report as JSON on stdout instead of the summary.
        #[arg(long)]
        json: bool,
        /// Worker threads (default: all cores). Results do not depend on it.
        #[arg(long)]
        threads: Option<usize>,
        /// List every problem found in the NC program, not only the first.
        #[arg(short, long)]
        verbose: bool,
        /// Memory the tri-dexel stock may use, e.g. 2G, 512M, 1.5GiB (default: half the
        /// installed memory).
        #[arg(long, value_name = "SIZE")]
        memory: Option<String>,
    },
    /// Identify the scene's `[identify] parameters` from its faces (any number, flanks and
    /// floors) in its simulated scan or in a given cloud: identifiability (singular values,
    /// what is and is not determined), values with uncertainties, the model-correction loop;
    /// write identify.json and cloud.ply.
    Identify {
        #[command(flatten)]
        args: SceneArgs,
        /// Identify from this cloud (PLY, XYZ/CSV, PTS; workpiece or scanner frame) instead
        /// of the scene's simulated scan.
        #[arg(long)]
        cloud: Option<PathBuf>,
        /// Monte-Carlo trials over scanner noise (simulated scans only; default: the
        /// scene's [identify] monte_carlo.trials).
        #[arg(long, value_name = "N")]
        monte_carlo: Option<usize>,
    },
    /// Design test cuts that make the given deviations observable on the scene's machine;
    /// write design.ngc, design.toml (a scene that cuts, scans and identifies them) and
    /// design.json.
    Design {
        #[command(flatten)]
        args: SceneArgs,
        /// Deviations to make observable, comma separated (e.g. dy_AY,gamma_YX).
        #[arg(long, value_delimiter = ',', num_args = 1, required = true)]
        params: Vec<String>,
    },
    /// Evaluate measurements as a standard says (ISO 230-2 positioning, ISO 230-4 circular
    /// tests).
    Evaluate {
        #[command(subcommand)]
        command: EvaluateCommand,
    },
    /// Fit shapes to any point cloud (PLY, XYZ/CSV, PTS): every planar face with the
    /// distance and angle between each pair (the default), or one plane, sphere, cylinder
    /// or circle, in all points, a box, or the planar region around a seed point.
    Fit {
        /// The cloud file.
        cloud: PathBuf,
        /// Every planar face (segmentation) with pairwise distances and angles.
        #[arg(long, group = "shape")]
        planes: bool,
        /// One plane through the selected points.
        #[arg(long, group = "shape")]
        plane: bool,
        /// One sphere (found by RANSAC when nothing is selected).
        #[arg(long, group = "shape")]
        sphere: bool,
        /// One cylinder (found by RANSAC on estimated normals).
        #[arg(long, group = "shape")]
        cylinder: bool,
        /// One circle in 3-D through the selected points.
        #[arg(long, group = "shape")]
        circle: bool,
        /// Use only points in this box: xmin,ymin,zmin,xmax,ymax,zmax (mm).
        #[arg(
            long = "box",
            value_name = "X0,Y0,Z0,X1,Y1,Z1",
            value_delimiter = ',',
            num_args = 1,
            conflicts_with = "seed",
            allow_hyphen_values = true
        )]
        bbox: Option<Vec<f64>>,
        /// Use the planar region grown around the point nearest to x,y,z (mm).
        #[arg(
            long,
            value_name = "X,Y,Z",
            value_delimiter = ',',
            num_args = 1,
            allow_hyphen_values = true
        )]
        seed: Option<Vec<f64>>,
        /// Reject outliers (iterative 3σ trimming) in the final fit.
        #[arg(long)]
        robust: bool,
        /// Segmentation cell edge (mm).
        #[arg(long, default_value_t = 1.0)]
        cell: f64,
        /// Largest point-to-surface distance of a member or RANSAC inlier (mm).
        #[arg(long, default_value_t = 0.1)]
        distance: f64,
        /// Print the result as JSON.
        #[arg(long)]
        json: bool,
        /// Worker threads (default: all cores). Results do not depend on it.
        #[arg(long)]
        threads: Option<usize>,
    },
}

/// Which standard's evaluation.
#[derive(Subcommand)]
enum EvaluateCommand {
    /// ISO 230-2 positioning accuracy and repeatability of a linear axis from a readings
    /// file: CSV `target,direction,run,deviation` (mm; `+`/`-`; runs from 1) or a laser
    /// system's table `target,+run1,…,+runN,-run1,…,-runN`; a unit may follow a header name
    /// in brackets (`deviation[um]`).
    #[command(name = "iso230-2")]
    Iso230_2 {
        /// The readings file.
        file: PathBuf,
        /// Print the figures as JSON (mm): A, A_fwd, A_bwd, B, B_mean, E, E_fwd, E_bwd, M,
        /// R, R_fwd, R_bwd, runs and per target {target, mean_fwd, mean_bwd, mean, B, s_fwd,
        /// s_bwd, R_fwd, R_bwd, R}.
        #[arg(long)]
        json: bool,
        /// Also draw the standard's bidirectional plot into this PNG file.
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// ISO 230-4 circular test (ball bar) from a radial-deviation trace: CSV
    /// `direction,angle,deviation` (`ccw`/`cw`, degrees, mm; `deviation[um]`, `angle[rad]`
    /// set units): circular deviation G, radial deviation F, hysteresis H, and the
    /// diagnostics (squareness, servo mismatch, scale mismatch, reversals, straightness,
    /// cyclic error with --pitch).
    #[command(name = "iso230-4")]
    Iso230_4 {
        /// The trace file.
        file: PathBuf,
        /// Nominal radius of the circle (mm).
        #[arg(long, allow_negative_numbers = true)]
        radius: f64,
        /// Screw lead of the axes, for the cyclic-error terms (mm).
        #[arg(long, allow_negative_numbers = true)]
        pitch: Option<f64>,
        /// Print the figures as JSON.
        #[arg(long)]
        json: bool,
        /// Also draw the polar plot into this PNG file.
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// Seed 003's non-contact ball sensor: ball centres from the two micrometers' readings
    /// (CSV `Lx1,Lx2,Ly1,Ly2`, mm; `[um]` after a name sets its unit) by eq. (1)–(3), each
    /// with its Z error bound, and the Z working window for a tolerance.
    #[command(name = "ball-sensor")]
    BallSensor {
        /// The readings file; without it, only the Z error curve and the window.
        file: Option<PathBuf>,
        /// Width of micrometer B's light band L_x0 (mm).
        #[arg(long, default_value_t = 10.0)]
        band_x: f64,
        /// Width of micrometer A's light band L_y0 (mm).
        #[arg(long, default_value_t = 10.0)]
        band_y: f64,
        /// Master ball diameter (mm).
        #[arg(long, default_value_t = 4.0002)]
        ball: f64,
        /// Bound of each micrometer reading's error (µm).
        #[arg(long, default_value_t = 0.5)]
        accuracy: f64,
        /// Tolerance on Z for the working window (µm).
        #[arg(long, default_value_t = 1.0)]
        tolerance: f64,
        /// Shortest chord the micrometers measure within their accuracy (mm); 0: no limit.
        #[arg(long, default_value_t = 0.0)]
        min_chord: f64,
        /// Print the figures as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// Sets the thread count, loads the scene, checks that it has what `command` needs, and
/// loads its program.
fn prepare(
    scene: &Path,
    threads: Option<usize>,
    verbose: bool,
    memory: Option<&str>,
    command: &str,
    needs: &[Need],
) -> Result<(Scene, Program), ExitCode> {
    if let Some(n) = threads
        && let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global()
    {
        return Err(fail(e));
    }
    let budget = match memory {
        Some(m) => MemoryBudget::parse(m).map_err(fail)?,
        None => MemoryBudget::installed(),
    };
    let scene = Scene::load_with(scene, &budget).map_err(fail)?;
    scene.require(command, needs).map_err(fail)?;
    let program = match scene.load_program() {
        Ok(p) => p,
        Err(SceneError::Program(e)) if verbose => {
            let _ = write!(std::io::stderr(), "{}", e.full_report());
            return Err(fail(e));
        }
        Err(e) => return Err(fail(e)),
    };
    Ok((scene, program))
}

/// Prints `text` (or `json`) on stdout.
fn print_out(
    text: impl FnOnce() -> String,
    json: Option<Result<String, serde_json::Error>>,
) -> ExitCode {
    let mut stdout = std::io::stdout().lock();
    let printed = match json {
        Some(j) => j
            .map_err(std::io::Error::other)
            .and_then(|s| writeln!(stdout, "{s}")),
        None => write!(stdout, "{}", text()),
    };
    match printed {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fail(e),
    }
}

/// Progress bars on stderr when it is a terminal.
struct Bars {
    bar: Mutex<Option<ProgressBar>>,
    enabled: bool,
}

impl Progress for Bars {
    fn start(&self, stage: &str, total: u64) {
        if !self.enabled {
            return;
        }
        let bar = ProgressBar::new(total);
        if let Ok(style) =
            ProgressStyle::with_template("{prefix:>8} [{bar:40}] {pos}/{len} {elapsed}")
        {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_prefix(stage.to_string());
        if let Ok(mut b) = self.bar.lock() {
            *b = Some(bar);
        }
    }
    fn advance(&self, n: u64) {
        if let Ok(b) = self.bar.lock()
            && let Some(bar) = b.as_ref()
        {
            bar.inc(n);
        }
    }
    fn finish(&self) {
        if let Ok(mut b) = self.bar.lock()
            && let Some(bar) = b.take()
        {
            bar.finish_and_clear();
        }
    }
}

/// The ISO 230-2 figures as the CLI prints them (µm).
fn positioning_summary(file: &Path, f: &PositioningFigures) -> String {
    use std::fmt::Write as _;
    let um = |x: f64| x * 1e3;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "twinmill evaluate iso230-2: {} ({} targets, {} runs each way)",
        file.display(),
        f.targets.len(),
        f.runs
    );
    let _ = writeln!(
        s,
        "  accuracy      A {:.4} µm (A↑ {:.4}, A↓ {:.4})",
        um(f.a),
        um(f.a_fwd),
        um(f.a_bwd)
    );
    let _ = writeln!(
        s,
        "  repeatability R {:.4} µm (R↑ {:.4}, R↓ {:.4})",
        um(f.r),
        um(f.r_fwd),
        um(f.r_bwd)
    );
    let _ = writeln!(
        s,
        "  systematic    E {:.4} µm (E↑ {:.4}, E↓ {:.4}); mean M {:.4} µm",
        um(f.e),
        um(f.e_fwd),
        um(f.e_bwd),
        um(f.m)
    );
    let _ = writeln!(
        s,
        "  reversal      B {:.4} µm, mean B̄ {:+.4} µm",
        um(f.b),
        um(f.b_mean)
    );
    let _ = writeln!(
        s,
        "  {:>12} {:>10} {:>10} {:>10} {:>9} {:>9} {:>9}",
        "target mm", "x̄↑ µm", "x̄↓ µm", "B µm", "s↑ µm", "s↓ µm", "R µm"
    );
    for t in &f.targets {
        let _ = writeln!(
            s,
            "  {:>12.4} {:>10.4} {:>10.4} {:>+10.4} {:>9.4} {:>9.4} {:>9.4}",
            t.target,
            um(t.mean_fwd),
            um(t.mean_bwd),
            um(t.b),
            um(t.s_fwd),
            um(t.s_bwd),
            um(t.r)
        );
    }
    s
}

/// The ISO 230-4 figures and diagnostics as the CLI prints them (µm).
fn circular_summary(file: &Path, f: &CircularFigures) -> String {
    use std::fmt::Write as _;
    let um = |x: f64| x * 1e3;
    let diag = |d: &Diagnosis, scale: f64, unit: &str| match d {
        Diagnosis::Value { value, sigma } => {
            format!("{:+.3} ± {:.3} {unit}", value * scale, sigma * scale)
        }
        Diagnosis::NotDetermined { not_determined } => format!("not determined: {not_determined}"),
    };
    let mut s = String::new();
    let _ = writeln!(
        s,
        "twinmill evaluate iso230-4: {} (radius {} mm)",
        file.display(),
        f.radius_mm
    );
    for d in &f.directions {
        let _ = writeln!(
            s,
            "  {:<4} {} points over {:.0}°: G {:.3} µm, F {:+.3} / {:+.3} µm, centre ({:+.3}, {:+.3}) µm",
            format!("{:?}", d.direction).to_lowercase(),
            d.points,
            d.span_deg,
            um(d.g),
            um(d.f_max),
            um(d.f_min),
            um(d.centre_mm[0]),
            um(d.centre_mm[1])
        );
        let _ = writeln!(
            s,
            "       scale mismatch {}; reversal axis 1 {}; axis 2 {}",
            diag(&d.scale_mismatch_um_per_m, 1.0, "µm/m"),
            diag(&d.reversal_1_mm, 1e3, "µm"),
            diag(&d.reversal_2_mm, 1e3, "µm")
        );
        let _ = writeln!(
            s,
            "       straightness axis 1 {}; axis 2 {}; residual rms {:.3} µm",
            diag(&d.straightness_1_mm, 1e3, "µm"),
            diag(&d.straightness_2_mm, 1e3, "µm"),
            um(d.residual_rms_mm)
        );
    }
    if let Some(h) = f.h {
        let _ = writeln!(s, "  hysteresis H {:.3} µm", um(h));
    }
    let _ = writeln!(
        s,
        "  squareness    {}",
        diag(&f.squareness_urad, 1.0, "µm/m")
    );
    let _ = writeln!(
        s,
        "  servo mismatch {}",
        diag(&f.servo_mismatch_urad, 1.0, "µm/m")
    );
    s
}

/// `evaluate ball-sensor`: the sensor from the options `[band_x, band_y, ball, accuracy,
/// tolerance, min_chord]` (mm), the window, and the centres of a readings file if one is given.
fn evaluate_ball_sensor(file: Option<&Path>, o: [f64; 6], json: bool) -> ExitCode {
    use std::fmt::Write as _;
    let [band_x, band_y, ball, accuracy, tolerance, min_chord] = o;
    let checks = [
        ("--band-x", band_x),
        ("--band-y", band_y),
        ("--ball", ball),
        ("--accuracy", accuracy),
        ("--tolerance", tolerance),
    ];
    if let Some((name, v)) = checks.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        return fail(format!("{name} must be positive, got {v}"));
    }
    if !(min_chord.is_finite() && min_chord >= 0.0) {
        return fail(format!(
            "--min-chord must be 0 or positive, got {min_chord}"
        ));
    }
    let mut sensor = BallSensor::seed003(band_x);
    sensor.a.width_mm = band_y;
    sensor.ball_diameter_mm = ball;
    sensor.accuracy_mm = accuracy;
    sensor.min_chord_mm = min_chord;
    let centres = match file {
        Some(f) => {
            let text = match std::fs::read_to_string(f) {
                Ok(t) => t,
                Err(e) => return fail(format!("{}: cannot read: {e}", f.display())),
            };
            match ball_sensor::parse_readings(&text, f)
                .and_then(|rows| ball_sensor::centres(&sensor, &rows, f))
            {
                Ok(c) => c,
                Err(e) => return fail(e),
            }
        }
        None => Vec::new(),
    };
    let window = sensor.working_window(tolerance);
    let r = sensor.radius();
    let curve: Vec<_> = (1..=20)
        .map(|i| sensor.z_error(r * i as f64 / 20.0 * 0.95))
        .collect();
    let figures = serde_json::json!({
        "ball_diameter_mm": ball,
        "accuracy_mm": accuracy,
        "window": window,
        "z_error_curve": curve,
        "centres": centres,
    });
    print_out(
        || {
            let mut s = String::new();
            let _ = writeln!(
                s,
                "twinmill evaluate ball-sensor: ball Ø {ball} mm, micrometers ±{:.3} µm",
                accuracy * 1e3
            );
            match window {
                Some(w) => {
                    let _ = writeln!(
                        s,
                        "  working window Z {:.3} … {:.3} mm (Z error ≤ {:.3} µm)",
                        w.z_min_mm,
                        w.z_max_mm,
                        tolerance * 1e3
                    );
                }
                None => {
                    let _ = writeln!(
                        s,
                        "  no working window: no height keeps the Z error within {:.3} µm",
                        tolerance * 1e3
                    );
                }
            }
            let _ = writeln!(s, "  Z (mm)   chord short  chord long (Z error, µm)");
            for e in &curve {
                let _ = writeln!(
                    s,
                    "  {:6.3}   {:+10.3}  {:+10.3}",
                    e.z_mm,
                    e.chord_short_mm * 1e3,
                    e.chord_long_mm * 1e3
                );
            }
            for (i, c) in centres.iter().enumerate() {
                let [x, y, z] = c.centre_mm;
                let inside = window.is_some_and(|w| (w.z_min_mm..=w.z_max_mm).contains(&z));
                let _ = writeln!(
                    s,
                    "  {:>4}: X {x:+.4} Y {y:+.4} Z {z:.4} mm (±{:.3} µm{}); Z from B {:.4}",
                    i + 1,
                    c.z_error_bound_mm * 1e3,
                    if inside { "" } else { ", outside the window" },
                    c.z_from_b_mm
                );
            }
            s
        },
        json.then(|| serde_json::to_string_pretty(&figures)),
    )
}

/// Encodes a drawn plot and writes it whole to `png`, or says why not.
fn write_plot(
    png: &Path,
    drawn: Result<image::RgbImage, twinmill::report::render::RenderError>,
) -> Result<(), String> {
    let bytes = drawn
        .and_then(|img| twinmill::report::render::encode_png(&img))
        .map_err(|e| format!("{}: {e}", png.display()))?;
    twinmill::output::write_file(png, &bytes).map_err(|e| e.to_string())
}

fn fail(msg: impl std::fmt::Display) -> ExitCode {
    let _ = writeln!(std::io::stderr(), "twinmill: error: {msg}");
    ExitCode::FAILURE
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Evaluate {
            command: EvaluateCommand::Iso230_2 { file, json, png },
        } => {
            let text = match std::fs::read_to_string(&file) {
                Ok(t) => t,
                Err(e) => return fail(format!("{}: cannot read: {e}", file.display())),
            };
            let figures = match parse_readings(&text, &file)
                .and_then(|readings| evaluate_positioning(&readings, &file))
            {
                Ok(f) => f,
                Err(e) => return fail(e),
            };
            if let Some(png) = &png {
                let title = format!("ISO 230-2: {}", file.display());
                if let Err(e) = write_plot(
                    png,
                    twinmill::report::plots::positioning_plot(&figures, &title),
                ) {
                    return fail(e);
                }
            }
            print_out(
                || positioning_summary(&file, &figures),
                json.then(|| serde_json::to_string_pretty(&figures)),
            )
        }
        Command::Evaluate {
            command:
                EvaluateCommand::Iso230_4 {
                    file,
                    radius,
                    pitch,
                    json,
                    png,
                },
        } => {
            let text = match std::fs::read_to_string(&file) {
                Ok(t) => t,
                Err(e) => return fail(format!("{}: cannot read: {e}", file.display())),
            };
            let opts = CircularOptions {
                radius_mm: radius,
                pitch_mm: pitch,
            };
            let samples = match parse_trace(&text, &file) {
                Ok(s) => s,
                Err(e) => return fail(e),
            };
            let figures = match evaluate_circular(&samples, &opts, &file) {
                Ok(f) => f,
                Err(e) => return fail(e),
            };
            if let Some(png) = &png {
                let title = format!("ISO 230-4: {}", file.display());
                if let Err(e) = write_plot(
                    png,
                    twinmill::report::plots::polar_plot(&samples, &figures, &title),
                ) {
                    return fail(e);
                }
            }
            print_out(
                || circular_summary(&file, &figures),
                json.then(|| serde_json::to_string_pretty(&figures)),
            )
        }
        Command::Evaluate {
            command:
                EvaluateCommand::BallSensor {
                    file,
                    band_x,
                    band_y,
                    ball,
                    accuracy,
                    tolerance,
                    min_chord,
                    json,
                },
        } => evaluate_ball_sensor(
            file.as_deref(),
            [
                band_x,
                band_y,
                ball,
                accuracy * 1e-3,
                tolerance * 1e-3,
                min_chord,
            ],
            json,
        ),
        Command::Nc {
            command: NcCommand::BenchProgram { blocks },
        } => {
            let mut text = String::new();
            twinmill::nc::synthetic::bench_program(blocks, &mut text);
            match std::io::stdout().write_all(text.as_bytes()) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => fail(e),
            }
        }
        Command::Nc {
            command:
                NcCommand::Motion {
                    program,
                    tool_table,
                    var,
                    ini,
                    block_delete,
                    external_units,
                    no_fanuc_subs,
                    jsonl: _,
                    events,
                },
        } => {
            let unit = if external_units == "inch" {
                LengthUnit::Inch
            } else {
                LengthUnit::Mm
            };
            let mut opts = match twinmill::nc::options_from_files(
                tool_table.as_deref(),
                var.as_deref(),
                ini.as_deref(),
                unit,
            ) {
                Ok(o) => o,
                Err(e) => return fail(e),
            };
            opts.block_delete = block_delete;
            if no_fanuc_subs {
                opts.fanuc_subs = false;
            }
            let interp = match Interpreter::from_file(&program, opts) {
                Ok(i) => i,
                Err(e) => return fail(e),
            };
            let stdout = std::io::stdout();
            let mut out = std::io::BufWriter::with_capacity(1 << 16, stdout.lock());
            let r = write_jsonl(interp, events, |s| out.write_all(s.as_bytes()));
            let _ = out.flush();
            match r {
                Ok(Ok(())) => ExitCode::SUCCESS,
                Ok(Err(e)) => {
                    let _ = write!(std::io::stderr(), "{}", e.full_report());
                    ExitCode::FAILURE
                }
                Err(e) => fail(e),
            }
        }
        Command::Run {
            args:
                SceneArgs {
                    scene,
                    out,
                    json,
                    threads,
                    verbose,
                    memory,
                },
        } => {
            let (scene, program) = match prepare(
                &scene,
                threads,
                verbose,
                memory.as_deref(),
                "run",
                &[Need::Scanner, Need::StepFaces],
            ) {
                Ok(x) => x,
                Err(code) => return code,
            };
            let bars = bars(json);
            let outcome = match run(&scene, &program, &bars) {
                Ok(o) => o,
                Err(e) => return fail(e),
            };
            let dir = out.join(&scene.name);
            let html = match run_page(&scene, &program, &outcome) {
                Ok(h) => h,
                Err(e) => return fail(e),
            };
            if let Err(e) = write_outcome(&outcome, &html, &dir) {
                return fail(e);
            }
            print_out(
                || {
                    format!(
                        "{}  wrote         {}/{{report.json, cloud.ply, faces.png, report.html}}\n",
                        outcome.report.summary(),
                        dir.display()
                    )
                },
                json.then(|| serde_json::to_string_pretty(&outcome.report)),
            )
        }
        Command::Simulate {
            args:
                SceneArgs {
                    scene,
                    out,
                    json,
                    threads,
                    verbose,
                    memory,
                },
            mesh,
        } => {
            let (scene, program) =
                match prepare(&scene, threads, verbose, memory.as_deref(), "simulate", &[]) {
                    Ok(x) => x,
                    Err(code) => return code,
                };
            let formats: Vec<MeshFormat> = mesh
                .iter()
                .map(|f| match f.as_str() {
                    "obj" => MeshFormat::Obj,
                    "ply" => MeshFormat::Ply,
                    _ => MeshFormat::Stl,
                })
                .collect();
            let sim = match simulate(&scene, &program, &bars(json)) {
                Ok(s) => s,
                Err(e) => return fail(e),
            };
            let dir = out.join(format!("{}-simulate", scene.name));
            if let Err(e) = write_simulation(&sim, &formats, &dir) {
                return fail(e);
            }
            let names: Vec<&str> = ["report.json", "part.png", "report.html"]
                .into_iter()
                .chain(sim.deviation_png.as_ref().map(|_| "deviation.png"))
                .chain(formats.iter().map(|f| f.file_name()))
                .collect();
            print_out(
                || {
                    format!(
                        "{}wrote         {}/{{{}}}\n",
                        sim.report.summary(),
                        dir.display(),
                        names.join(", ")
                    )
                },
                json.then(|| serde_json::to_string_pretty(&sim.report)),
            )
        }
        Command::Scan {
            args:
                SceneArgs {
                    scene,
                    out,
                    json,
                    threads,
                    verbose,
                    memory,
                },
            study,
        } => {
            let (scan_command, scan_needs): (&str, &[Need]) = match study {
                Some(_) => ("scan --study", &[Need::Scanner, Need::StepFaces]),
                None => ("scan", &[Need::Scanner]),
            };
            let (scene, program) = match prepare(
                &scene,
                threads,
                verbose,
                memory.as_deref(),
                scan_command,
                scan_needs,
            ) {
                Ok(x) => x,
                Err(code) => return code,
            };
            let bars = bars(json);
            let part = match machine_part(&scene, &program, &bars) {
                Ok(p) => p,
                Err(e) => return fail(e),
            };
            // One surface index for the scan and every scan of the study.
            let surface = Surface::new(&part.stock);
            let scanner = match scene.scanner_for(scan_command) {
                Ok(s) => s,
                Err(e) => return fail(e),
            };
            let scanned = match surface.scan(scanner, &bars) {
                Ok(s) => s,
                Err(e) => return fail(format!("{}: [scanner]: {e}", scene.path.display())),
            };
            let cases = match study {
                None => Vec::new(),
                Some(n) => {
                    let mut opts = scene.study;
                    if n > 0 {
                        opts.trials = n;
                    }
                    match scanner_study(&scene, &program, &part.stock, &surface, &opts) {
                        Ok(c) => c,
                        Err(e) => return fail(e),
                    }
                }
            };
            let report = ScanFileReport {
                scene: scene.name.clone(),
                scan: ScanReport::of(&scanned, scanner),
                study: cases,
            };
            let dir = out.join(format!("{}-scan", scene.name));
            let html = match scan_page(&scene, &report, &part.stock, &scanned.cloud.points) {
                Ok(h) => h,
                Err(e) => return fail(e),
            };
            let files = write_report_and_cloud(&dir, "scan.json", &report, &scanned.cloud, html);
            if let Err(e) = files {
                return fail(e);
            }
            print_out(
                || {
                    format!(
                        "{}  wrote         {}/{{scan.json, cloud.ply, report.html}}\n",
                        report.summary(),
                        dir.display()
                    )
                },
                json.then(|| serde_json::to_string_pretty(&report)),
            )
        }
        Command::Correct {
            scene,
            model,
            accuracy_mm,
            out,
            json,
            threads,
            verbose,
            memory,
        } => {
            if !(accuracy_mm.is_finite() && accuracy_mm > 0.0) {
                return fail(format!(
                    "--accuracy-mm must be a positive number of mm, got {accuracy_mm}"
                ));
            }
            let (correct_command, correct_needs): (&str, &[Need]) = match model {
                ModelSource::Injected => ("correct", &[]),
                ModelSource::Identified => (
                    "correct --model identified",
                    &[Need::Scanner, Need::StepFaces],
                ),
            };
            let (scene, program) = match prepare(
                &scene,
                threads,
                verbose,
                memory.as_deref(),
                correct_command,
                correct_needs,
            ) {
                Ok(x) => x,
                Err(code) => return code,
            };
            let bars = bars(json);
            let chain = match model {
                ModelSource::Injected => scene.chain.clone(),
                ModelSource::Identified => {
                    match run(&scene, &program, &bars)
                        .and_then(|o| identified_model(&scene, &o.report))
                    {
                        Ok(c) => c,
                        Err(e) => return fail(e),
                    }
                }
            };
            let outcome = match correct(&scene, &program, &chain, accuracy_mm, &bars) {
                Ok(o) => o,
                Err(e) => return fail(e),
            };
            let report = &outcome.report;
            let ngc = report.corrected_program.clone();
            let json_name = format!("{}-correct.json", scene.name);
            let html_name = format!("{}-correct.html", scene.name);
            let html = match correct_page(&scene, &program, report, &outcome.corrected.moves) {
                Ok(h) => h,
                Err(e) => return fail(e),
            };
            let report_bytes = match json_bytes(report, &out.join(&json_name)) {
                Ok(b) => b,
                Err(e) => return fail(e),
            };
            let files: Vec<twinmill::output::StreamedFile> = vec![
                (
                    ngc.clone(),
                    Box::new(|w: &mut dyn Write| {
                        write_gcode(&outcome.corrected, &outcome.header, w)
                    }),
                ),
                (
                    json_name.clone(),
                    Box::new(move |w: &mut dyn Write| w.write_all(&report_bytes)),
                ),
                (
                    html_name.clone(),
                    Box::new(move |w: &mut dyn Write| w.write_all(html.as_bytes())),
                ),
            ];
            if let Err(e) = write_streamed(&out, files) {
                return fail(e);
            }
            let code = print_out(
                || {
                    format!(
                        "{}  wrote         {}/{{{ngc}, {json_name}, {html_name}}}\n",
                        report.summary(),
                        out.display()
                    )
                },
                json.then(|| serde_json::to_string_pretty(report)),
            );
            if code == ExitCode::SUCCESS && !report.met {
                // Written and reported, but the twin predicts the accuracy is not met.
                let _ = writeln!(
                    std::io::stderr(),
                    "twinmill: accuracy {accuracy_mm} mm not met: {}",
                    report.status
                );
                return ExitCode::from(2);
            }
            code
        }
        Command::Identify {
            args:
                SceneArgs {
                    scene,
                    out,
                    json,
                    threads,
                    verbose,
                    memory,
                },
            cloud,
            monte_carlo,
        } => {
            // A simulated scan needs the scanner; a given cloud does not.
            let identify_needs: &[Need] = match cloud {
                Some(_) => &[Need::Parameters],
                None => &[Need::Parameters, Need::Scanner],
            };
            let (scene, program) = match prepare(
                &scene,
                threads,
                verbose,
                memory.as_deref(),
                "identify",
                identify_needs,
            ) {
                Ok(x) => x,
                Err(code) => return code,
            };
            let given = match &cloud {
                Some(path) => match read_cloud_file(path) {
                    Ok(c) => Some((c, path.display().to_string())),
                    Err(e) => return fail(e),
                },
                None => None,
            };
            let bars = bars(json);
            let outcome = match identify_scene(
                &scene,
                &program,
                given.as_ref().map(|(c, s)| (c, s.as_str())),
                monte_carlo,
                &bars,
            ) {
                Ok(o) => o,
                Err(e) => return fail(e),
            };
            let dir = out.join(format!("{}-identify", scene.name));
            let html = match identify_page(
                &scene,
                &outcome.report,
                &outcome.cloud.points,
                &outcome.features,
            ) {
                Ok(h) => h,
                Err(e) => return fail(e),
            };
            let files = write_report_and_cloud(
                &dir,
                "identify.json",
                &outcome.report,
                &outcome.cloud,
                html,
            );
            if let Err(e) = files {
                return fail(e);
            }
            let code = print_out(
                || {
                    format!(
                        "{}  wrote         {}/{{identify.json, cloud.ply, report.html}}\n",
                        outcome.report.summary(),
                        dir.display()
                    )
                },
                json.then(|| serde_json::to_string_pretty(&outcome.report)),
            );
            if code == ExitCode::SUCCESS && !outcome.report.converged {
                // Written and reported, but the twin does not reproduce the measured faces.
                let worst = outcome
                    .report
                    .rounds
                    .last()
                    .map_or(f64::NAN, |r| r.worst_face_mm);
                let _ = writeln!(
                    std::io::stderr(),
                    "twinmill: the model-correction loop did not converge: after {} rounds the \
                     twin's faces still differ from the measured ones by up to {worst:.4} mm \
                     (deviations outside the identified set, or the wrong faces)",
                    outcome.report.rounds.len()
                );
                return ExitCode::from(2);
            }
            code
        }
        Command::Design {
            args:
                SceneArgs {
                    scene,
                    out,
                    json,
                    threads,
                    verbose,
                    memory,
                },
            params,
        } => {
            let (scene, _) = match prepare(
                &scene,
                threads,
                verbose,
                memory.as_deref(),
                "design",
                &[Need::Scanner],
            ) {
                Ok(x) => x,
                Err(code) => return code,
            };
            let mut ids = Vec::new();
            for p in &params {
                match scene.model.deviation_id(p) {
                    Ok(id) => ids.push(id),
                    Err(e) => return fail(format!("--params: {e}")),
                }
            }
            let name = format!("{}-design", scene.name);
            let outcome = match design_scene(&scene, &params, &ids, &name, &bars(json)) {
                Ok(o) => o,
                Err(e) => return fail(e),
            };
            let report = &outcome.report;
            let dir = out.join(&name);
            let html = match design_page(&scene, report, &outcome.verified) {
                Ok(h) => h,
                Err(e) => return fail(e),
            };
            let files = json_bytes(report, &dir.join("design.json"))
                .map(|j| {
                    vec![
                        ("design.json", j),
                        ("design.ngc", outcome.design.program.clone().into_bytes()),
                        ("design.toml", outcome.scene_toml.clone().into_bytes()),
                        ("report.html", html.into_bytes()),
                    ]
                })
                .and_then(|files| write_files(&dir, &files));
            if let Err(e) = files {
                return fail(e);
            }
            print_out(
                || {
                    format!(
                        "{}  wrote         {}/{{design.ngc, design.toml, design.json, report.html}}\n",
                        report.summary(),
                        dir.display()
                    )
                },
                json.then(|| serde_json::to_string_pretty(report)),
            )
        }
        Command::Fit {
            cloud,
            planes: _,
            plane,
            sphere,
            cylinder,
            circle,
            bbox,
            seed,
            robust,
            cell,
            distance,
            json,
            threads,
        } => {
            if let Some(n) = threads
                && let Err(e) = rayon::ThreadPoolBuilder::new()
                    .num_threads(n.max(1))
                    .build_global()
            {
                return fail(e);
            }
            let selection = match (bbox, seed) {
                (Some(b), _) if b.len() != 6 => {
                    return fail("--box needs six numbers: x0,y0,z0,x1,y1,z1");
                }
                (Some(b), _) => {
                    match (finite_point(&b[..3], "box"), finite_point(&b[3..], "box")) {
                        (Ok(min), Ok(max)) if (0..3).all(|k| min[k] < max[k]) => {
                            Selection::Box(Aabb { min, max })
                        }
                        (Err(e), _) | (_, Err(e)) => return fail(e),
                        _ => return fail("--box: each min must be below its max"),
                    }
                }
                (None, Some(p)) => match finite_point(&p, "seed") {
                    Ok(p) => Selection::Seed(p),
                    Err(e) => return fail(e),
                },
                (None, None) => Selection::All,
            };
            let shape = if plane {
                Shape::Plane
            } else if sphere {
                Shape::Sphere
            } else if cylinder {
                Shape::Cylinder
            } else if circle {
                Shape::Circle
            } else {
                Shape::Planes
            };
            let points = match read_cloud_file(&cloud) {
                Ok(c) => c,
                Err(e) => return fail(e),
            };
            let request = FitRequest {
                shape,
                selection,
                robust,
                segment: PlaneSegmentOptions {
                    cell_mm: cell,
                    max_distance_mm: distance,
                    ..PlaneSegmentOptions::default()
                },
                ransac: RansacOptions {
                    distance_mm: distance,
                    iterations: 2000,
                    seed: 1,
                    min_inliers: 10,
                },
                normal_neighbours: 12,
            };
            let report = match fit_cloud(&points, &request, &cloud.display().to_string()) {
                Ok(r) => r,
                Err(e) => return fail(e),
            };
            print_out(
                || report.summary(),
                json.then(|| serde_json::to_string_pretty(&report)),
            )
        }
    }
}

fn finite_point(v: &[f64], what: &str) -> Result<Point3, String> {
    match v {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Point3::new(*x, *y, *z)),
        _ => Err(format!("--{what} needs finite numbers")),
    }
}

fn bars(json: bool) -> Bars {
    Bars {
        bar: Mutex::new(None),
        enabled: !json && std::io::stderr().is_terminal(),
    }
}

/// Writes a JSON report, the point cloud (`cloud.ply`) and the page (`report.html`) into
/// `dir`, all or nothing.
fn write_report_and_cloud(
    dir: &Path,
    report_name: &str,
    report: &impl serde::Serialize,
    cloud: &twinmill::metrology::cloud::PointCloud,
    html: String,
) -> Result<PathBuf, twinmill::output::OutputError> {
    let files = vec![
        (report_name, json_bytes(report, &dir.join(report_name))?),
        ("cloud.ply", ply_bytes(cloud, &dir.join("cloud.ply"))?),
        ("report.html", html.into_bytes()),
    ];
    write_files(dir, &files)
}
