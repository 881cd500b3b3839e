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
    CircularFigures, CircularOptions, Diagnosis, TraceError, evaluate as evaluate_circular,
    parse_trace,
};
use twinmill::metrology::cloud::read_cloud_file;
use twinmill::metrology::positioning::{
    PositioningFigures, evaluate as evaluate_positioning, parse_readings,
};
use twinmill::metrology::scan::Surface;
use twinmill::metrology::segment::{PlaneSegmentOptions, RansacOptions};
use twinmill::nc::{AxisLetter, Interpreter, LengthUnit, Program, write_jsonl};
use twinmill::output::{
    MeshFormat, json_bytes, ply_bytes, write_files, write_outcome, write_simulation, write_streamed,
};
use twinmill::pipeline::pages::{correct_page, design_page, identify_page, run_page, scan_page};
use twinmill::pipeline::{
    FitRequest, Selection, Shape, correct, design_scene, fit_cloud, identified_model,
    identify_scene, machine_part, run, scanner_study, simulate,
};
use twinmill::progress::Progress;
use twinmill::report::html::render_page;
use twinmill::report::pages;
use twinmill::report::{ScanFileReport, ScanReport};
use twinmill::scene::{MemoryBudget, Need, Scene, SceneError};

/// twinmill: a digital twin of machine-tool accuracy.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Keep an identification (run, identify, design, correct --model identified, measure,
    /// calibrate) whose residuals the stated noise cannot explain, instead of refusing it;
    /// its report then says so on its first line.
    #[arg(long, global = true)]
    accept_misfit: bool,
}

/// `--accept-misfit`, set once from the command line before any command runs; every
/// scene a command loads takes it.
static ACCEPT_MISFIT: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

fn accept_misfit() -> bool {
    ACCEPT_MISFIT.load(std::sync::atomic::Ordering::Relaxed)
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

/// Which study command.
#[derive(Subcommand)]
enum StudyCommand {
    /// Fix every trial's inputs: write the manifest (JSON).
    Plan {
        /// The study file (TOML).
        study: PathBuf,
        /// Number of shards.
        #[arg(long, default_value_t = 1)]
        shards: usize,
        /// The manifest to write (default: <study stem>.manifest.json beside the study).
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
    },
    /// Run one shard's trials and write its Parquet file.
    Run {
        /// The manifest.
        manifest: PathBuf,
        /// The shard (default: SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX).
        #[arg(long)]
        shard: Option<usize>,
        /// Folder of the shard files (default: the manifest's folder).
        #[arg(long, value_name = "DIR")]
        dir: Option<PathBuf>,
    },
    /// Check every shard against the manifest and summarise per parameter.
    Merge {
        /// The manifest.
        manifest: PathBuf,
        /// Folder of the shard files (default: the manifest's folder).
        #[arg(long, value_name = "DIR")]
        dir: Option<PathBuf>,
        /// Print the summary as JSON.
        #[arg(long)]
        json: bool,
        /// Also write the summary JSON here.
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
    },
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
        /// Stop as an endless loop after this many lines in a row without motion.
        #[arg(long, default_value_t = twinmill::nc::DEFAULT_MAX_IDLE_BLOCKS,
              value_parser = clap::value_parser!(u64).range(1..))]
        max_idle_blocks: u64,
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
    /// Studies of many identification trials, planned once, run in shards (a Slurm array or
    /// a Kubernetes Indexed Job), merged into a summary (docs/studies.md).
    Study {
        #[command(subcommand)]
        command: StudyCommand,
    },
    /// Hexapod (Stewart platform) scenes: inverse and forward kinematics, resolution
    /// amplification, homing, pivot accuracy (docs/hexapod.md).
    Hexapod {
        #[command(subcommand)]
        command: HexapodCommand,
    },
    /// A hexapod scene's virtual double ball bar: one circle on the deviated machine, its
    /// radial deviation trace (CSV, polar plot) and ISO 230-4 figures (docs/hexapod.md).
    Ballbar(DbbArgs),
    /// Seed 000's double-ball-bar calibration of a hexapod scene on the twin: measure,
    /// identify with what is not determined, pose errors before and after (docs/hexapod.md).
    Calibrate(CalibrateArgs),
    /// Design a hexapod's double-ball-bar calibration: choose the circles (ball positions,
    /// bar lengths and tilts, platform tilts and swing) that predict the smallest pose error
    /// after calibration, beside the fixed plan; write the plan `calibrate --plan` reads
    /// (docs/hexapod.md).
    CalibrateDesign(CalibrateDesignArgs),
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
    /// Measure the scene's machine with a virtual instrument on its deviated chain (error
    /// motions, reversals, squareness as the scene gives them): the laser interferometer's
    /// ISO 230-2 test cycle of one linear axis, or the ball bar's ISO 230-4 circles; write
    /// the readings or the trace (the file `evaluate` reads) and print its evaluation. Only
    /// the scene's machine is used: no program, stock or scanner.
    Measure(Box<MeasureArgs>),
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
        /// Also write the page (self-contained HTML: the summary, the figures, the plot as
        /// SVG) into this file.
        #[arg(long, value_name = "FILE")]
        html: Option<PathBuf>,
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
        /// Also write the page (self-contained HTML: the summary, the figures, the plot as
        /// SVG) into this file.
        #[arg(long, value_name = "FILE")]
        html: Option<PathBuf>,
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
        /// Also write the page (self-contained HTML: the summary and the figures in tables)
        /// into this file.
        #[arg(long, value_name = "FILE")]
        html: Option<PathBuf>,
    },
}

/// The virtual instruments of `measure`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Instrument {
    /// Laser interferometer: ISO 230-2's test cycle of one linear axis.
    Laser,
    /// Telescoping ball bar: ISO 230-4's circular test in a plane.
    Ballbar,
    /// Seed 003's non-contact ball sensor on the table, its master ball in the spindle:
    /// ISO 10791-6's simultaneous motion test of the rotary axes, and their location errors.
    BallSensor,
    /// A touch probe finding a calibration sphere at rotary indices, and the rotary axes'
    /// location errors.
    Probe,
}

impl Instrument {
    /// The name in messages and file names.
    fn name(self) -> &'static str {
        match self {
            Instrument::Laser => "laser",
            Instrument::Ballbar => "ballbar",
            Instrument::BallSensor => "ball-sensor",
            Instrument::Probe => "probe",
        }
    }
}

/// `twinmill measure`: the scene, the instrument, what every instrument shares, and each
/// instrument's own options (given only with that instrument).
#[derive(clap::Args)]
struct MeasureArgs {
    /// The scene file (TOML); only its machine is used.
    scene: PathBuf,
    /// The instrument.
    #[arg(long, value_enum)]
    instrument: Instrument,
    /// The readings or trace file to write (default: <scene name>-laser.csv or
    /// <scene name>-ballbar.csv in the current folder).
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Print the figures as JSON (the keys of `evaluate`) instead of the summary.
    #[arg(long)]
    json: bool,
    /// Also draw the standard's plot into this PNG file.
    #[arg(long, value_name = "FILE")]
    png: Option<PathBuf>,
    /// The page (self-contained HTML: the summary, the figures, the standard's plot as SVG,
    /// the identification; default: the readings file's name with `.html`).
    #[arg(long, value_name = "FILE")]
    html: Option<PathBuf>,
    /// Seed of the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Gaussian noise of each reading or sample, σ (µm; default 0: the twin repeats exactly).
    /// Ball sensor: the micrometers' accuracy bound ±a (µm, default 0.5, seed 003's), each
    /// shadow edge read with σ = a/√3. Probe: σ of each found axis value (µm, default 0.5).
    #[arg(long, allow_negative_numbers = true, value_name = "UM")]
    noise: Option<f64>,
    /// Laser: how far each run travels past the last target and below the first (mm,
    /// default 5). Ball bar: the feed-in and feed-out arcs (degrees, default 180).
    #[arg(long, allow_negative_numbers = true, value_name = "MM|DEG")]
    overshoot: Option<f64>,
    #[command(flatten)]
    laser: LaserArgs,
    #[command(flatten)]
    ballbar: BallbarArgs,
    #[command(flatten)]
    rotary: RotaryArgs,
}

/// The rotary-axis tests' options.
#[derive(clap::Args)]
#[command(next_help_heading = "Rotary-axis tests (--instrument ball-sensor | probe)")]
struct RotaryArgs {
    /// A sweep AXIS:FROM:TO:N[+AXIS:FROM:TO][@AXIS=VALUE,…] (degrees), repeatable, e.g.
    /// C:0:330:12@A=-30 or A:-45:45:13+C:0:180 (default: the first rotary axis a full turn;
    /// each further one swept ±60°, with the first turning at −30° of it, and both together).
    #[arg(long, value_name = "SWEEP", allow_hyphen_values = true)]
    sweep: Vec<String>,
    /// The table-side point (sensor's measuring point or sphere centre) in the workpiece
    /// frame (mm; default 60,0,30).
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        value_name = "X,Y,Z"
    )]
    point: Option<Vec<f64>>,
    /// Where the sensor or sphere actually is relative to --point (mm; default 0): unknown
    /// to the controller and to the identification.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        value_name = "DX,DY,DZ"
    )]
    mounting: Option<Vec<f64>>,
    /// The spindle-side ball's (master ball's or stylus ball's) offset from the tool point,
    /// in the tool frame (mm; default 0).
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        value_name = "DX,DY,DZ"
    )]
    stylus: Option<Vec<f64>>,
    /// Ball sensor: the ball's height above the sheets of light (mm; default 1.0, inside
    /// seed 003's 0.6–1.6 mm).
    #[arg(long, allow_negative_numbers = true, value_name = "MM")]
    height: Option<f64>,
    /// Ball sensor: the width of each light band (mm; default 8).
    #[arg(long, allow_negative_numbers = true, value_name = "MM")]
    band: Option<f64>,
    /// The terms to identify, comma separated (default: every rotary axis's ISO 230-7
    /// location terms, e.g. EX0C,EY0C,EA0C,EB0C, and the table's two that no test sees).
    #[arg(long, value_delimiter = ',', num_args = 1, value_name = "TERMS")]
    identify: Option<Vec<String>>,
    /// Only measure: do not identify.
    #[arg(long, conflicts_with = "identify")]
    no_identify: bool,
}

/// The laser interferometer's options.
#[derive(clap::Args)]
#[command(next_help_heading = "Laser interferometer (--instrument laser)")]
struct LaserArgs {
    /// The linear axis measured (a letter of the machine's axes).
    #[arg(long)]
    axis: Option<String>,
    /// First target (mm).
    #[arg(long, allow_negative_numbers = true, value_name = "MM")]
    from: Option<f64>,
    /// Last target (mm).
    #[arg(long, allow_negative_numbers = true, value_name = "MM")]
    to: Option<f64>,
    /// Number of evenly spaced targets from --from to --to (default: 5 per metre, at least 5).
    #[arg(long, value_name = "N")]
    targets: Option<usize>,
    /// The targets as a list instead of --from, --to, --targets (mm, comma separated, any
    /// spacing).
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        value_name = "T1,T2,...",
        conflicts_with_all = ["from", "to", "targets"]
    )]
    target_list: Option<Vec<f64>>,
    /// Bidirectional runs (default 5, as ISO 230-2 asks; at least 2).
    #[arg(long, value_name = "N")]
    runs: Option<usize>,
    /// The retroreflector's offset from the tool point, in the tool frame (mm; default 0).
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        value_name = "DX,DY,DZ"
    )]
    abbe: Option<Vec<f64>>,
    /// Linear drift of the readings (µm per run; default 0).
    #[arg(long, allow_negative_numbers = true, value_name = "UM")]
    drift: Option<f64>,
    /// The other axes' values during the test, e.g. Y=100,Z=50 (default: the scene's home).
    #[arg(long, value_name = "AXIS=VALUE,...", allow_hyphen_values = true)]
    at: Option<String>,
}

/// The ball bar's options.
#[derive(clap::Args)]
#[command(next_help_heading = "Ball bar (--instrument ballbar)")]
struct BallbarArgs {
    /// The plane of the circle by its machine axes, first then second: XY, YZ or ZX (default
    /// XY).
    #[arg(long)]
    plane: Option<String>,
    /// The centre command, e.g. X=0,Y=0,Z=50 (default: the scene's home for every axis not
    /// given).
    #[arg(long, value_name = "AXIS=VALUE,...", allow_hyphen_values = true)]
    centre: Option<String>,
    /// The radius: the bar's nominal length (mm; default 100).
    #[arg(long, allow_negative_numbers = true, value_name = "MM")]
    radius: Option<f64>,
    /// The directions run: ccw, cw, or both (one ccw run, then one cw run; the default).
    #[arg(long, value_enum)]
    direction: Option<TurnsArg>,
    /// The programmed feed (mm/min; recorded, the twin has no servo dynamics; default 1000).
    #[arg(long, allow_negative_numbers = true, value_name = "MM_PER_MIN")]
    feed: Option<f64>,
    /// Samples per revolution (default 360).
    #[arg(long, value_name = "N")]
    points: Option<usize>,
    /// The tool ball's offset from the tool point, in the tool frame (mm; default 0).
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        value_name = "DX,DY,DZ"
    )]
    tool_ball: Option<Vec<f64>>,
    /// The centre ball's mounting offset from where the nominal machine puts the tool ball
    /// at the centre command, in the workpiece frame (mm; default 0).
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        value_name = "DX,DY,DZ"
    )]
    mount: Option<Vec<f64>>,
    /// Screw lead of the axes, for the cyclic-error terms of the evaluation (mm).
    #[arg(long, allow_negative_numbers = true, value_name = "MM")]
    pitch: Option<f64>,
}

/// `--direction` of the ball bar.
#[derive(Clone, Copy, clap::ValueEnum)]
enum TurnsArg {
    /// Counter-clockwise only.
    Ccw,
    /// Clockwise only.
    Cw,
    /// One counter-clockwise run, then one clockwise run.
    Both,
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
    let scene = match Scene::load_with(scene, &budget) {
        Err(SceneError::Hexapod { .. }) if command == "simulate" => {
            twinmill::hexapod_scene::HexapodScene::load_cut(scene, &budget).map_err(fail)?
        }
        Err(SceneError::Hexapod { path }) => {
            return Err(fail(format!(
                "{}: `{command}` does not drive a hexapod (the scene's [machine] kind is \"hexapod\"; `twinmill simulate` cuts its program, and its other commands are `twinmill hexapod ik|fk|amplification|homing|pivot`, `ballbar` and `calibrate`)",
                path.display()
            )));
        }
        r => r.map_err(fail)?,
    };
    let scene = Scene {
        accept_misfit: accept_misfit(),
        ..scene
    };
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

/// Lines of a summary after its title: `(label, text)`, the label in the figures' column.
fn labelled(lines: &[(&str, String)]) -> String {
    lines
        .iter()
        .map(|(label, text)| format!("  {label:<13} {text}\n"))
        .collect()
}

/// The ISO 230-2 figures as the CLI prints them (µm): `title`, then `extra` lines, then the
/// figures.
fn positioning_summary(title: &str, extra: &[(&str, String)], f: &PositioningFigures) -> String {
    use std::fmt::Write as _;
    let um = |x: f64| x * 1e3;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{title} ({} targets, {} runs each way)",
        f.targets.len(),
        f.runs
    );
    s.push_str(&labelled(extra));
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

/// The ISO 230-4 figures and diagnostics as the CLI prints them (µm): `title`, then `extra`
/// lines, then the figures.
fn circular_summary(title: &str, extra: &[(&str, String)], f: &CircularFigures) -> String {
    use std::fmt::Write as _;
    let um = |x: f64| x * 1e3;
    let diag = |d: &Diagnosis, scale: f64, unit: &str| match d {
        Diagnosis::Value { value, sigma } => {
            format!("{:+.3} ± {:.3} {unit}", value * scale, sigma * scale)
        }
        Diagnosis::NotDetermined { not_determined } => format!("not determined: {not_determined}"),
    };
    let mut s = String::new();
    let _ = writeln!(s, "{title} (radius {} mm)", f.radius_mm);
    s.push_str(&labelled(extra));
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
        diag(&f.squareness_urad, 1.0, "µrad")
    );
    let _ = writeln!(
        s,
        "  servo mismatch {}",
        diag(&f.servo_mismatch_urad, 1.0, "µrad")
    );
    s
}

/// `evaluate ball-sensor`: the sensor from the options `[band_x, band_y, ball, accuracy,
/// tolerance, min_chord]` (mm), the window, and the centres of a readings file if one is given.
fn evaluate_ball_sensor(
    file: Option<&Path>,
    o: [f64; 6],
    json: bool,
    html: Option<&Path>,
) -> ExitCode {
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
    let summary = {
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
    };
    if let Some(html) = html {
        let title = match file {
            Some(f) => format!("twinmill evaluate ball-sensor: {}", f.display()),
            None => "twinmill evaluate ball-sensor".to_string(),
        };
        let page = pages::ball_sensor_page(&title, &summary, figures.clone());
        if let Err(e) = twinmill::output::write_file(html, render_page(&page).as_bytes()) {
            return fail(e);
        }
    }
    print_out(
        || summary,
        json.then(|| serde_json::to_string_pretty(&figures)),
    )
}

/// What an instrument measured, evaluated and ready to write and print.
struct Measured {
    /// The readings or trace file's text.
    text: String,
    /// The standard's plot, when `--png` asks for it.
    plot: Option<Result<image::RgbImage, twinmill::report::render::RenderError>>,
    /// The summary the CLI prints.
    summary: String,
    /// The figures as `evaluate --json` prints them.
    json: Result<String, serde_json::Error>,
    /// The page.
    html: String,
}

/// The options of each instrument, by name, and whether they were given (a new instrument
/// adds its own here, so that the others refuse them).
fn instrument_options(a: &MeasureArgs) -> Vec<(Instrument, &'static str, bool)> {
    let (l, b, r) = (&a.laser, &a.ballbar, &a.rotary);
    use Instrument::{BallSensor, Ballbar, Laser, Probe};
    vec![
        (Laser, "--axis", l.axis.is_some()),
        (Laser, "--from", l.from.is_some()),
        (Laser, "--to", l.to.is_some()),
        (Laser, "--targets", l.targets.is_some()),
        (Laser, "--target-list", l.target_list.is_some()),
        (Laser, "--runs", l.runs.is_some()),
        (Laser, "--abbe", l.abbe.is_some()),
        (Laser, "--drift", l.drift.is_some()),
        (Laser, "--at", l.at.is_some()),
        (Ballbar, "--plane", b.plane.is_some()),
        (Ballbar, "--centre", b.centre.is_some()),
        (Ballbar, "--radius", b.radius.is_some()),
        (Ballbar, "--direction", b.direction.is_some()),
        (Ballbar, "--feed", b.feed.is_some()),
        (Ballbar, "--points", b.points.is_some()),
        (Ballbar, "--tool-ball", b.tool_ball.is_some()),
        (Ballbar, "--mount", b.mount.is_some()),
        (Ballbar, "--pitch", b.pitch.is_some()),
        (BallSensor, "--height", r.height.is_some()),
        (BallSensor, "--band", r.band.is_some()),
    ]
    .into_iter()
    .chain(
        [
            ("--sweep", !r.sweep.is_empty()),
            ("--point", r.point.is_some()),
            ("--mounting", r.mounting.is_some()),
            ("--stylus", r.stylus.is_some()),
            ("--identify", r.identify.is_some()),
            ("--no-identify", r.no_identify),
        ]
        .into_iter()
        .flat_map(|(o, given)| [(BallSensor, o, given), (Probe, o, given)]),
    )
    .collect()
}

/// `twinmill measure`: refuses another instrument's options, loads the scene's machine, runs
/// the instrument on it, evaluates what it measured, writes the file (and the plot) and
/// prints the figures. Nothing is written unless everything before succeeded.
fn measure(a: MeasureArgs) -> ExitCode {
    let options = instrument_options(&a);
    if let Some((other, option, _)) = options.iter().copied().find(|(i, o, given)| {
        *given
            && *i != a.instrument
            && !options.iter().any(|(j, p, _)| j == &a.instrument && p == o)
    }) {
        return fail(format!(
            "{option} is an option of --instrument {}, not of --instrument {}",
            other.name(),
            a.instrument.name()
        ));
    }
    // Only the machine is used: the program is not read and no stock is built, so the
    // stock's memory budget does not apply.
    let budget = MemoryBudget {
        bytes: f64::INFINITY,
        source: "measure builds no stock".into(),
    };
    let scene = match Scene::load_with(&a.scene, &budget) {
        Ok(s) => Scene {
            accept_misfit: accept_misfit(),
            ..s
        },
        Err(e) => return fail(e),
    };
    if let Err(e) = scene.require("measure", &[]) {
        return fail(e);
    }
    let file = a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("{}-{}.csv", scene.name, a.instrument.name())));
    let measured = match a.instrument {
        Instrument::Laser => measure_laser(&scene, &a, &file),
        Instrument::Ballbar => measure_ballbar(&scene, &a, &file),
        Instrument::BallSensor | Instrument::Probe => measure_rotary(&scene, &a),
    };
    let m = match measured {
        Ok(m) => m,
        Err(e) => return fail(e),
    };
    let html = a
        .html
        .clone()
        .unwrap_or_else(|| file.with_extension("html"));
    if html == file {
        return fail(format!(
            "{}: the page would overwrite the readings file: give --out or --html another name",
            html.display()
        ));
    }
    let png = match (&a.png, m.plot) {
        (Some(png), Some(drawn)) => {
            match drawn.and_then(|img| twinmill::report::render::encode_png(&img)) {
                Ok(bytes) => Some((png, bytes)),
                Err(e) => return fail(format!("{}: {e}", png.display())),
            }
        }
        _ => None,
    };
    if let Err(e) = twinmill::output::write_file(&file, m.text.as_bytes()) {
        return fail(e);
    }
    if let Err(e) = twinmill::output::write_file(&html, m.html.as_bytes()) {
        return fail(e);
    }
    if let Some((png, bytes)) = png
        && let Err(e) = twinmill::output::write_file(png, &bytes)
    {
        return fail(e);
    }
    print_out(|| m.summary, a.json.then_some(m.json))
}

/// Axis values `X=1,Y=-2.5` for axes of `chain`, as the option `option` gives them.
fn axis_values(
    option: &str,
    text: &str,
    chain: &twinmill::machine::chain::Chain,
) -> Result<Vec<(AxisLetter, f64)>, String> {
    let axes: Vec<String> = chain
        .axes()
        .iter()
        .map(|a| a.letter.as_char().to_string())
        .collect();
    let mut out: Vec<(AxisLetter, f64)> = Vec::new();
    for item in text.split(',').map(str::trim) {
        let (name, value) = item
            .split_once('=')
            .map(|(n, v)| (n.trim(), v.trim()))
            .ok_or_else(|| format!("{option}: '{item}': expected AXIS=VALUE, e.g. Y=100"))?;
        let mut chars = name.chars();
        let letter = match (chars.next(), chars.next()) {
            (Some(c), None) => AxisLetter::from_char(c).filter(|l| chain.has_axis(*l)),
            _ => None,
        }
        .ok_or_else(|| {
            format!(
                "{option}: '{name}' is not an axis of this machine (axes: {})",
                axes.join(" ")
            )
        })?;
        let v: f64 = match value.parse::<f64>() {
            Ok(v) if v.is_finite() => v,
            Ok(v) => return Err(format!("{option}: {name} = {v} is not finite")),
            Err(_) => return Err(format!("{option}: {name} = '{value}' is not a number")),
        };
        if out.iter().any(|(l, _)| *l == letter) {
            return Err(format!("{option}: {name} is given twice"));
        }
        out.push((letter, v));
    }
    Ok(out)
}

/// A vector given as `DX,DY,DZ` (mm) by `option`.
fn offset3(option: &str, v: &[f64]) -> Result<twinmill::math::Vector3, String> {
    match v {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => {
            Ok(twinmill::math::Vector3::new(*x, *y, *z))
        }
        [_, _, _] => Err(format!("{option}: {v:?} must be finite numbers (mm)")),
        _ => Err(format!(
            "{option} needs three numbers DX,DY,DZ (mm), got {}",
            v.len()
        )),
    }
}

/// `measure --instrument ball-sensor | probe`: the rotary-axis test, its ISO 10791-6
/// figures, and the location errors identified from it.
fn measure_rotary(scene: &Scene, a: &MeasureArgs) -> Result<Measured, String> {
    use std::fmt::Write as _;
    use twinmill::metrology::ball_sensor::BallSensor;
    use twinmill::metrology::rotary_test::Sweep;
    use twinmill::pipeline::{RotaryInstrument, RotaryRequest, default_setup, rotary_test};
    let r = &a.rotary;
    if a.overshoot.is_some() {
        return Err(format!(
            "--overshoot is not an option of --instrument {}",
            a.instrument.name()
        ));
    }
    let sweeps = r
        .sweep
        .iter()
        .map(|t| Sweep::parse(t).map_err(|e| format!("--{e}")))
        .collect::<Result<Vec<_>, _>>()?;
    let mut setup = default_setup(a.seed);
    if let Some(v) = &r.point {
        setup.point_w = offset3("--point", v)?.into();
    }
    if let Some(v) = &r.mounting {
        setup.mounting_mm = offset3("--mounting", v)?;
    }
    if let Some(v) = &r.stylus {
        setup.tool_offset = offset3("--stylus", v)?;
    }
    let noise_um = a.noise.unwrap_or(0.5);
    if !(noise_um.is_finite() && noise_um > 0.0) {
        return Err(format!(
            "--noise: must be a positive number of µm, got {noise_um}"
        ));
    }
    let instrument = match a.instrument {
        Instrument::Probe => RotaryInstrument::Probe {
            sigma_mm: noise_um * 1e-3,
        },
        _ => {
            let band = r.band.unwrap_or(8.0);
            if !(band.is_finite() && band >= 6.0) {
                return Err(format!(
                    "--band: the light band must be at least the 6 mm measuring range, got {band}"
                ));
            }
            let mut sensor = BallSensor::seed003(band);
            sensor.accuracy_mm = noise_um * 1e-3;
            RotaryInstrument::BallSensor {
                sensor,
                height_mm: r.height.unwrap_or(1.0),
            }
        }
    };
    let req = RotaryRequest {
        instrument,
        sweeps,
        setup,
        identify: if r.no_identify {
            None
        } else {
            Some(r.identify.clone().unwrap_or_default())
        },
    };
    let out = rotary_test(scene, &req).map_err(|e| e.to_string())?;
    let rep = &out.report;
    let plot = a.png.as_ref().map(|_| {
        twinmill::report::plots::rotary_trace_plot(
            &out.samples,
            &rep.sweeps,
            &format!("ISO 10791-6 {} - {}", rep.instrument, rep.scene),
        )
    });
    let mut s = String::new();
    if let Some(w) = &rep.warning {
        let _ = writeln!(s, "{w}");
    }
    let _ = writeln!(s, "scene         {}", rep.scene);
    let _ = writeln!(
        s,
        "instrument    {} ({} measurements)",
        rep.instrument, rep.samples
    );
    if matches!(a.instrument, Instrument::BallSensor) {
        let _ = writeln!(s, "ISO 10791-6   deviation ranges of the ball (µm):");
        for f in &rep.sweeps {
            let _ = writeln!(
                s,
                "  sweep {}: {} {} … {}°  X {:.3}  Y {:.3}  Z {:.3}  (max distance {:.3})",
                f.sweep,
                f.axis,
                f.range_deg[0],
                f.range_deg[1],
                f.deviation_range_mm[0] * 1e3,
                f.deviation_range_mm[1] * 1e3,
                f.deviation_range_mm[2] * 1e3,
                f.max_distance_mm * 1e3
            );
        }
    }
    if let Some(id) = &rep.identification {
        let _ = writeln!(
            s,
            "identified    location errors (offsets µm, tilts µrad; ± one standard uncertainty):"
        );
        let show = |t: &twinmill::pipeline::TermReport| {
            let k = if twinmill::pipeline::is_angle_term(&t.name) {
                1e6
            } else {
                1e3
            };
            let inj = t.injected.map_or(String::new(), |v| {
                format!("   (scene injects {:+.3})", v * k)
            });
            format!(
                "  {:<24} {:+10.3} ± {:.3}{inj}",
                t.name,
                t.value * k,
                t.sigma * k
            )
        };
        for t in id.identified.iter().chain(&id.combinations) {
            let _ = writeln!(s, "{}", show(t));
        }
        if !id.not_determined.is_empty() {
            let _ = writeln!(
                s,
                "not determined {} (held at the model's values; a table-side point cannot see them)",
                id.not_determined.join(", ")
            );
        }
        if !id.no_data.is_empty() {
            let _ = writeln!(
                s,
                "no data       {} (no measurement depends on them: add sweeps of their axis)",
                id.no_data.join(", ")
            );
        }
        let _ = writeln!(
            s,
            "fit           {}; the point at ({:.4}, {:.4}, {:.4}) mm",
            id.fit.describe(),
            id.fixed_point_mm[0],
            id.fixed_point_mm[1],
            id.fixed_point_mm[2]
        );
        let _ = writeln!(s, "rank          {}", id.margin.describe());
    }
    Ok(Measured {
        text: out.trace_csv.clone(),
        plot,
        html: twinmill::pipeline::instrument_pages::rotary_page(&out, &s),
        summary: s,
        json: serde_json::to_string_pretty(rep),
    })
}

/// `measure --instrument laser`.
fn measure_laser(scene: &Scene, a: &MeasureArgs, file: &Path) -> Result<Measured, String> {
    use twinmill::metrology::interferometer::{self, LaserError, LaserSetup, Targets};
    let l = &a.laser;
    let chain = &scene.chain;
    let linear: Vec<String> = chain
        .axes()
        .iter()
        .filter(|x| x.kind == twinmill::machine::chain::AxisKind::Linear)
        .map(|x| x.letter.as_char().to_string())
        .collect();
    let name = l.axis.as_deref().ok_or_else(|| {
        format!(
            "--instrument laser needs --axis (a linear axis of the machine: {})",
            linear.join(" ")
        )
    })?;
    let mut chars = name.trim().chars();
    let axis = match (chars.next(), chars.next()) {
        (Some(c), None) => AxisLetter::from_char(c),
        _ => None,
    }
    .ok_or_else(|| {
        format!(
            "--axis: '{name}' is not an axis letter (the machine's linear axes: {})",
            linear.join(" ")
        )
    })?;
    let targets = match (&l.target_list, l.from, l.to) {
        (Some(list), _, _) => Targets::List(list.clone()),
        (None, Some(from), Some(to)) => {
            // ISO 230-2: at least 5 targets per metre of travel, and 5 in all.
            let length = (to - from).abs();
            let count = l.targets.unwrap_or(if length.is_finite() {
                ((length / 1000.0 * 5.0).ceil() as usize).max(5)
            } else {
                5
            });
            Targets::Even {
                start_mm: from,
                end_mm: to,
                count,
            }
        }
        _ => {
            return Err(
                "--instrument laser needs --from and --to (the first and last target, \
                        mm), or --target-list"
                    .into(),
            );
        }
    };
    let mut held = scene.home;
    if let Some(at) = &l.at {
        for (letter, v) in axis_values("--at", at, chain)? {
            if letter == axis {
                return Err(format!(
                    "--at: {} is the measured axis (--from and --to give its targets)",
                    letter.as_char()
                ));
            }
            held.set(letter, v);
        }
    }
    let mut setup = LaserSetup::new(axis, targets, held);
    setup.runs = l.runs.unwrap_or(setup.runs);
    setup.overshoot_mm = a.overshoot.unwrap_or(setup.overshoot_mm);
    if let Some(v) = &l.abbe {
        setup.abbe_offset_mm = offset3("--abbe", v)?;
    }
    setup.noise_um = a.noise.unwrap_or(0.0);
    setup.drift_um_per_run = l.drift.unwrap_or(0.0);
    setup.seed = a.seed;
    let m = interferometer::measure(chain, &setup).map_err(|e| match e {
        LaserError::Axis(m) => format!("--axis {}: {m}", axis.as_char()),
        LaserError::Setup { name, message } => format!("--{name}: {message}"),
    })?;
    let figures = evaluate_positioning(&m.readings, file).map_err(|e| e.to_string())?;
    let described = setup.describe(chain);
    let u = m.beam;
    let mut comments = vec![
        format!(
            "twinmill measure {} --instrument laser ({})",
            scene.path.display(),
            scene.machine_name
        ),
        described.clone(),
        format!(
            "beam along ({:?}, {:?}, {:?}) in the workpiece frame",
            u.x, u.y, u.z
        ),
        "deviation = position reached - target (mm), along the axis's commanded direction"
            .to_string(),
    ];
    comments.extend(m.notes.iter().map(|n| format!("note: {n}")));
    let title = format!(
        "twinmill measure: {} laser on {}",
        scene.path.display(),
        axis.as_char()
    );
    let mut extra = vec![("set-up", described)];
    extra.extend(m.notes.iter().map(|n| ("note", n.clone())));
    extra.push(("wrote", file.display().to_string()));
    let plot_title = format!("ISO 230-2: {} {}", scene.name, axis.as_char());
    let summary = positioning_summary(&title, &extra, &figures);
    Ok(Measured {
        text: m.csv(&comments),
        plot: a
            .png
            .as_ref()
            .map(|_| twinmill::report::plots::positioning_plot(&figures, &plot_title)),
        html: render_page(&pages::positioning_page(
            &title,
            &summary,
            &figures,
            &plot_title,
        )),
        summary,
        json: serde_json::to_string_pretty(&figures),
    })
}

/// `measure --instrument ballbar`.
fn measure_ballbar(scene: &Scene, a: &MeasureArgs, file: &Path) -> Result<Measured, String> {
    use twinmill::metrology::ballbar::{self, BallBarError, BallBarSetup, Plane, Turns};
    let b = &a.ballbar;
    let chain = &scene.chain;
    let plane = match &b.plane {
        None => Plane::Xy,
        Some(p) => {
            Plane::from_name(p).ok_or_else(|| format!("--plane: '{p}': expected XY, YZ or ZX"))?
        }
    };
    let mut centre = scene.home;
    if let Some(c) = &b.centre {
        for (letter, v) in axis_values("--centre", c, chain)? {
            centre.set(letter, v);
        }
    }
    if let Some(p) = b.pitch
        && !(p.is_finite() && p > 0.0)
    {
        return Err(format!("--pitch: must be a positive lead (mm), got {p}"));
    }
    let mut setup = BallBarSetup::new(plane, centre, b.radius.unwrap_or(100.0));
    setup.turns = match b.direction {
        None | Some(TurnsArg::Both) => Turns::Both,
        Some(TurnsArg::Ccw) => Turns::Ccw,
        Some(TurnsArg::Cw) => Turns::Cw,
    };
    setup.feed_mm_per_min = b.feed.unwrap_or(setup.feed_mm_per_min);
    setup.points = b.points.unwrap_or(setup.points);
    setup.overshoot_deg = a.overshoot.unwrap_or(setup.overshoot_deg);
    if let Some(v) = &b.tool_ball {
        setup.tool_ball_mm = offset3("--tool-ball", v)?;
    }
    if let Some(v) = &b.mount {
        setup.mount_offset_mm = offset3("--mount", v)?;
    }
    setup.noise_um = a.noise.unwrap_or(0.0);
    setup.seed = a.seed;
    let m = ballbar::measure(chain, &setup).map_err(|e| match e {
        BallBarError::Plane { plane, message } => format!("--plane {plane}: {message}"),
        BallBarError::Setup { name, message } => {
            format!("--{}: {message}", name.replace('_', "-"))
        }
    })?;
    let opts = CircularOptions {
        radius_mm: setup.radius_mm,
        pitch_mm: b.pitch,
    };
    let figures = evaluate_circular(&m.samples, &opts, file).map_err(|e| match e {
        TraceError::Unusable { message, .. } => {
            format!("the measured trace cannot be evaluated (ISO 230-4): {message}")
        }
        other => other.to_string(),
    })?;
    let described = setup.describe(chain);
    let c = m.centre_ball;
    let comments = vec![
        format!(
            "twinmill measure {} --instrument ballbar ({})",
            scene.path.display(),
            scene.machine_name
        ),
        described.clone(),
        format!(
            "centre ball at ({:?}, {:?}, {:?}) in the workpiece frame",
            c.x, c.y, c.z
        ),
        format!(
            "deviation = bar length - {} mm; angle from {} towards {}; evaluate with \
             --radius {}",
            setup.radius_mm,
            plane.axes().0.as_char(),
            plane.axes().1.as_char(),
            setup.radius_mm
        ),
    ];
    let title = format!(
        "twinmill measure: {} ball bar in {}",
        scene.path.display(),
        plane.name()
    );
    let extra = vec![("set-up", described), ("wrote", file.display().to_string())];
    let plot_title = format!("ISO 230-4: {} {}", scene.name, plane.name());
    let summary = circular_summary(&title, &extra, &figures);
    Ok(Measured {
        text: m.csv(&comments),
        plot: a
            .png
            .as_ref()
            .map(|_| twinmill::report::plots::polar_plot(&m.samples, &figures, &plot_title)),
        html: render_page(&pages::circular_page(
            &title,
            &summary,
            &m.samples,
            &figures,
            &plot_title,
            pages::json(&figures),
        )),
        summary,
        json: serde_json::to_string_pretty(&figures),
    })
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

/// `twinmill study plan | run | merge`.
fn study_command(command: StudyCommand) -> ExitCode {
    use twinmill::study;
    let folder = |manifest: &Path, dir: Option<PathBuf>| {
        dir.unwrap_or_else(|| {
            manifest
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_else(|| PathBuf::from("."))
        })
    };
    match command {
        StudyCommand::Plan {
            study: file,
            shards,
            out,
        } => {
            let m = match study::plan(&file, shards) {
                Ok(m) => m,
                Err(e) => return fail(e),
            };
            let out = out.unwrap_or_else(|| {
                let stem = file
                    .file_stem()
                    .map_or("study".into(), |s| s.to_string_lossy());
                file.with_file_name(format!("{stem}.manifest.json"))
            });
            let bytes = match serde_json::to_vec_pretty(&m) {
                Ok(b) => b,
                Err(e) => return fail(e),
            };
            if let Err(e) = twinmill::output::write_file(&out, &bytes) {
                return fail(e);
            }
            let line = format!(
                "planned {} trials in {} shards: {} (study {})\n",
                m.trials.len(),
                m.shards,
                out.display(),
                m.id
            );
            print_out(|| line, None)
        }
        StudyCommand::Run {
            manifest,
            shard,
            dir,
        } => {
            let m = match study::read_manifest(&manifest) {
                Ok(m) => m,
                Err(e) => return fail(e),
            };
            let i = match study::shard_index(shard) {
                Ok(i) => i,
                Err(e) => return fail(e),
            };
            let rows = match study::run_shard(&m, i) {
                Ok(r) => r,
                Err(e) => return fail(e),
            };
            let bytes = match study::shard_parquet(&m, &rows) {
                Ok(b) => b,
                Err(e) => return fail(e),
            };
            let path = folder(&manifest, dir).join(study::shard_file_name(i, m.shards));
            if let Err(e) = twinmill::output::write_file(&path, &bytes) {
                return fail(e);
            }
            let failed = rows.iter().filter(|r| r.error.is_some()).count();
            let line = format!(
                "shard {i}: {} trials ({failed} failed) in {:.1} s → {}\n",
                rows.len(),
                rows.iter().map(|r| r.seconds).sum::<f64>(),
                path.display()
            );
            print_out(|| line, None)
        }
        StudyCommand::Merge {
            manifest,
            dir,
            json,
            out,
        } => {
            let m = match study::read_manifest(&manifest) {
                Ok(m) => m,
                Err(e) => return fail(e),
            };
            let (summary, _) = match study::merge(&m, &folder(&manifest, dir)) {
                Ok(s) => s,
                Err(e) => return fail(e),
            };
            let text = match serde_json::to_string_pretty(&summary) {
                Ok(t) => t,
                Err(e) => return fail(e),
            };
            if let Some(out) = out
                && let Err(e) = twinmill::output::write_file(&out, text.as_bytes())
            {
                return fail(e);
            }
            print_out(
                || {
                    use std::fmt::Write as _;
                    let mut s = String::new();
                    let _ = writeln!(
                        s,
                        "study {}: {} trials in {} shards, {} failed; {:.1} s of trial work",
                        summary.study,
                        summary.trials,
                        summary.shards,
                        summary.failed,
                        summary.trial_seconds
                    );
                    let _ = writeln!(
                        s,
                        "  {:<22} {:>10} {:>12} {:>12} {:>12} {:>9}",
                        "parameter", "determined", "bias", "spread", "mean σ", "±3σ"
                    );
                    for p in &summary.parameters {
                        let _ = writeln!(
                            s,
                            "  {:<22} {:>9.0}% {:>12.3e} {:>12.3e} {:>12.3e} {:>8.1}%",
                            p.name,
                            100.0 * p.determined_fraction,
                            p.bias,
                            p.spread,
                            p.mean_sigma,
                            100.0 * p.coverage_3sigma
                        );
                    }
                    for f in &summary.failures {
                        let _ = writeln!(s, "  failed: {f}");
                    }
                    s
                },
                json.then_some(Ok(text.clone())),
            )
        }
    }
}

/// Prints `twinmill: error: MESSAGE` on one line (a line break inside the message, from a
/// file's text or a library's, is printed as a space) and returns the failure exit code.
fn fail(msg: impl std::fmt::Display) -> ExitCode {
    let msg: String = msg
        .to_string()
        .trim_end()
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    let _ = writeln!(std::io::stderr(), "twinmill: error: {msg}");
    ExitCode::FAILURE
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    ACCEPT_MISFIT.store(cli.accept_misfit, std::sync::atomic::Ordering::Relaxed);
    match cli.command {
        Command::Hexapod { command } => hexapod_command(command),
        Command::Study { command } => study_command(command),
        Command::Ballbar(a) => dbb_command(dbb_ballbar(a)),
        Command::Calibrate(a) => dbb_command(dbb_calibrate(a)),
        Command::CalibrateDesign(a) => dbb_command(dbb_calibrate_design(a)),
        Command::Evaluate {
            command:
                EvaluateCommand::Iso230_2 {
                    file,
                    json,
                    png,
                    html,
                },
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
            let plot_title = format!("ISO 230-2: {}", file.display());
            let title = format!("twinmill evaluate iso230-2: {}", file.display());
            let summary = positioning_summary(&title, &[], &figures);
            if let Some(png) = &png
                && let Err(e) = write_plot(
                    png,
                    twinmill::report::plots::positioning_plot(&figures, &plot_title),
                )
            {
                return fail(e);
            }
            if let Some(html) = &html {
                let page = pages::positioning_page(&title, &summary, &figures, &plot_title);
                if let Err(e) = twinmill::output::write_file(html, render_page(&page).as_bytes()) {
                    return fail(e);
                }
            }
            print_out(
                || summary,
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
                    html,
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
            let plot_title = format!("ISO 230-4: {}", file.display());
            let title = format!("twinmill evaluate iso230-4: {}", file.display());
            let summary = circular_summary(&title, &[], &figures);
            if let Some(png) = &png
                && let Err(e) = write_plot(
                    png,
                    twinmill::report::plots::polar_plot(&samples, &figures, &plot_title),
                )
            {
                return fail(e);
            }
            if let Some(html) = &html {
                let page = pages::circular_page(
                    &title,
                    &summary,
                    &samples,
                    &figures,
                    &plot_title,
                    pages::json(&figures),
                );
                if let Err(e) = twinmill::output::write_file(html, render_page(&page).as_bytes()) {
                    return fail(e);
                }
            }
            print_out(
                || summary,
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
                    html,
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
            html.as_deref(),
        ),
        Command::Measure(args) => measure(*args),
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
                    max_idle_blocks,
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
            opts.max_idle_blocks = max_idle_blocks;
            if no_fanuc_subs {
                opts.fanuc_subs = false;
            }
            let interp = match Interpreter::from_file(&program, opts) {
                Ok(i) => i,
                Err(e) => return fail(e),
            };
            let stdout = std::io::stdout();
            let mut out = std::io::BufWriter::with_capacity(1 << 16, stdout.lock());
            let r = write_jsonl(interp, events, |s| out.write_all(s));
            let _ = out.flush();
            match r {
                Ok(Ok(())) => ExitCode::SUCCESS,
                Ok(Err(e)) => fail(e),
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
            let (chain, warning) = match model {
                ModelSource::Injected => (scene.chain.clone(), None),
                ModelSource::Identified => {
                    match run(&scene, &program, &bars).and_then(|o| {
                        identified_model(&scene, &o.report).map(|c| (c, o.report.warning))
                    }) {
                        Ok(c) => c,
                        Err(e) => return fail(e),
                    }
                }
            };
            let mut outcome = match correct(&scene, &program, &chain, accuracy_mm, &bars) {
                Ok(o) => o,
                Err(e) => return fail(e),
            };
            outcome.report.warning = warning;
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

// ---------------------------------------------------------------------------------------
// `twinmill hexapod …`

/// Which hexapod command.
#[derive(Subcommand)]
enum HexapodCommand {
    /// Inverse kinematics on the nominal machine (what the controller computes): the six
    /// strut lengths of a pose.
    Ik {
        /// The hexapod scene file (TOML, [machine] kind = "hexapod").
        scene: PathBuf,
        /// The pose X,Y,Z,A,B,C (mm, degrees; R = Rz(C)·Ry(B)·Rx(A)).
        #[arg(long, allow_hyphen_values = true)]
        pose: String,
        /// Print {"struts_mm": [...]}.
        #[arg(long)]
        json: bool,
    },
    /// Forward kinematics: the pose of six strut lengths, by Newton–Raphson from a nearby
    /// pose (nominal machine; --actual: the machine with the scene's deviations).
    Fk {
        /// The hexapod scene file.
        scene: PathBuf,
        /// The strut lengths L1,…,L6 (mm).
        #[arg(long, allow_hyphen_values = true)]
        struts: String,
        /// Start pose X,Y,Z,A,B,C (mm, degrees); default the scene's home pose.
        #[arg(long, allow_hyphen_values = true)]
        near: Option<String>,
        /// Solve on the actual machine (nominal plus [deviations]).
        #[arg(long)]
        actual: bool,
        /// Print {"pose": [x, y, z, a, b, c]}.
        #[arg(long)]
        json: bool,
    },
    /// Resolution amplification factors K_p (mm/mm) and K_a (°/mm) over the workspace and
    /// tilt range (seed 001), and the strut resolution a required output resolution needs.
    Amplification {
        /// The hexapod scene file.
        scene: PathBuf,
        /// Write every pose's factors to this CSV file.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Draw the K_p and K_a maps into this PNG file.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Write the page (self-contained HTML: the summary, the factors' ranges, the maps
        /// as SVG) into this file.
        #[arg(long, value_name = "FILE")]
        html: Option<PathBuf>,
        /// x range MIN,MAX (mm); with --y and --z, instead of the scene's [workspace].
        #[arg(long, allow_hyphen_values = true)]
        x: Option<String>,
        /// y range MIN,MAX (mm).
        #[arg(long, allow_hyphen_values = true)]
        y: Option<String>,
        /// z range MIN,MAX (mm).
        #[arg(long, allow_hyphen_values = true)]
        z: Option<String>,
        /// Tilt of a and b (degrees); default the scene's workspace tilt_deg.
        #[arg(long)]
        tilt: Option<f64>,
        /// Grid points along x and y.
        #[arg(long, default_value_t = 21)]
        steps: usize,
        /// Grid points along z.
        #[arg(long, default_value_t = 3)]
        z_steps: usize,
        /// Required position resolution of the tool (mm).
        #[arg(long, default_value_t = 0.001)]
        resolution_mm: f64,
        /// Required angle resolution of the tool (degrees).
        #[arg(long, default_value_t = 0.001)]
        resolution_deg: f64,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Homing check (seed 001): the switch-to-index distance S of each strut against
    /// (0.3–0.7)·T, the chance of latching the wrong index, and what a wrong index does to
    /// the pose.
    Homing {
        /// The hexapod scene file (needs [drives] and [homing]).
        scene: PathBuf,
        /// The pose X,Y,Z,A,B,C where the wrong index is evaluated; default home.
        #[arg(long, allow_hyphen_values = true)]
        pose: Option<String>,
        /// Standard deviation of the switch's trip point (mm); default the scene's.
        #[arg(long)]
        sigma: Option<f64>,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Pivot accuracy (seed 001): the tool tip's travel while a and b swing about a point,
    /// on the machine with the scene's deviations driven by the nominal kinematics.
    Pivot {
        /// The hexapod scene file.
        scene: PathBuf,
        /// The pivot point X,Y,Z (mm); default the home position.
        #[arg(long, allow_hyphen_values = true)]
        point: Option<String>,
        /// The largest |a| and |b| (degrees).
        #[arg(long, default_value_t = 15.0)]
        tilt: f64,
        /// Orientations per angle (steps × steps in all).
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// `n` finite comma-separated numbers.
fn numbers(text: &str, n: usize, what: &str) -> Result<Vec<f64>, String> {
    let v: Result<Vec<f64>, _> = text.split(',').map(|t| t.trim().parse::<f64>()).collect();
    match v {
        Ok(v) if v.len() == n && v.iter().all(|x| x.is_finite()) => Ok(v),
        _ => Err(format!(
            "--{what} needs {n} finite comma-separated numbers, got '{text}'"
        )),
    }
}

fn pose_arg(text: &str, what: &str) -> Result<twinmill::machine::hexapod::Pose, String> {
    let v = numbers(text, 6, what)?;
    Ok(twinmill::machine::hexapod::Pose::from_mm_deg([
        v[0], v[1], v[2], v[3], v[4], v[5],
    ]))
}

fn range_arg(text: &str, what: &str) -> Result<(f64, f64), String> {
    let v = numbers(text, 2, what)?;
    Ok((v[0], v[1]))
}

fn hexapod_command(command: HexapodCommand) -> ExitCode {
    match hexapod_run(command) {
        Ok(code) => code,
        Err(e) => fail(e),
    }
}

fn hexapod_run(command: HexapodCommand) -> Result<ExitCode, String> {
    use twinmill::hexapod_scene::HexapodScene;
    use twinmill::machine::hexapod_accuracy::Workspace;
    use twinmill::pipeline::hexapod::{
        AmplificationRequest, hexapod_amplification, hexapod_homing, hexapod_pivot,
    };
    let load = |p: &Path| HexapodScene::load(p).map_err(|e| e.to_string());
    let json_text = |v: serde_json::Value| serde_json::to_string(&v);
    Ok(match command {
        HexapodCommand::Ik { scene, pose, json } => {
            let s = load(&scene)?;
            let pose = pose_arg(&pose, "pose")?;
            let l = s
                .nominal
                .inverse(&pose)
                .map_err(|e| format!("{}: pose {pose}: {e}", scene.display()))?;
            print_out(
                || {
                    let mut t = format!("twinmill: hexapod ik on {} at {pose}\n", s.name);
                    for (i, x) in l.iter().enumerate() {
                        t += &format!("  strut {}   {x:.6} mm\n", i + 1);
                    }
                    t
                },
                json.then(|| json_text(serde_json::json!({ "struts_mm": l }))),
            )
        }
        HexapodCommand::Fk {
            scene,
            struts,
            near,
            actual,
            json,
        } => {
            let s = load(&scene)?;
            let v = numbers(&struts, 6, "struts")?;
            let l = [v[0], v[1], v[2], v[3], v[4], v[5]];
            let near = match near {
                Some(n) => pose_arg(&n, "near")?,
                None => s.home,
            };
            let machine = if actual { &s.actual } else { &s.nominal };
            let sol = machine
                .forward(&l, &near)
                .map_err(|e| format!("{}: {e}", scene.display()))?;
            let p = sol.pose.to_mm_deg();
            print_out(
                || {
                    format!(
                        "twinmill: hexapod fk on {} ({} machine)\n  pose        {}\n  iterations  {}, strut residual {:.1e} mm\n",
                        s.name,
                        if actual { "actual" } else { "nominal" },
                        sol.pose,
                        sol.iterations,
                        sol.residual_mm
                    )
                },
                json.then(|| json_text(serde_json::json!({ "pose": p }))),
            )
        }
        HexapodCommand::Amplification {
            scene,
            out,
            png,
            html,
            x,
            y,
            z,
            tilt,
            steps,
            z_steps,
            resolution_mm,
            resolution_deg,
            json,
        } => {
            let s = load(&scene)?;
            let workspace = match (x, y, z) {
                (None, None, None) => s.workspace.map(|mut w| {
                    if let Some(t) = tilt {
                        w.tilt_deg = t;
                    }
                    w
                }),
                (Some(x), Some(y), Some(z)) => Some(Workspace {
                    x_mm: range_arg(&x, "x")?,
                    y_mm: range_arg(&y, "y")?,
                    z_mm: range_arg(&z, "z")?,
                    tilt_deg: tilt.or(s.workspace.map(|w| w.tilt_deg)).unwrap_or(0.0),
                }),
                _ => return Err("--x, --y and --z go together".into()),
            };
            let o = hexapod_amplification(
                &s,
                &AmplificationRequest {
                    workspace,
                    steps: [steps, steps, z_steps],
                    position_resolution_mm: resolution_mm,
                    angle_resolution_deg: resolution_deg,
                },
            )
            .map_err(|e| e.to_string())?;
            if let Some(out) = &out {
                twinmill::output::write_file(out, o.csv.as_bytes()).map_err(|e| e.to_string())?;
            }
            if let Some(png) = &png {
                twinmill::output::write_file(png, &o.png).map_err(|e| e.to_string())?;
            }
            if let Some(html) = &html {
                let page = pages::amplification_page(
                    &format!("twinmill hexapod amplification: {}", s.name),
                    &o.summary,
                    &o.map,
                    pages::json(&o),
                );
                twinmill::output::write_file(html, render_page(&page).as_bytes())
                    .map_err(|e| e.to_string())?;
            }
            print_out(
                || o.summary.clone(),
                json.then(|| serde_json::to_string_pretty(&o)),
            )
        }
        HexapodCommand::Homing {
            scene,
            pose,
            sigma,
            json,
        } => {
            let s = load(&scene)?;
            let pose = pose.map(|p| pose_arg(&p, "pose")).transpose()?;
            let o = hexapod_homing(&s, pose, sigma).map_err(|e| e.to_string())?;
            print_out(
                || o.summary.clone(),
                json.then(|| serde_json::to_string_pretty(&o)),
            )
        }
        HexapodCommand::Pivot {
            scene,
            point,
            tilt,
            steps,
            json,
        } => {
            let s = load(&scene)?;
            let point = match point {
                Some(p) => {
                    let v = numbers(&p, 3, "point")?;
                    Some(twinmill::math::Vector3::new(v[0], v[1], v[2]))
                }
                None => None,
            };
            let o = hexapod_pivot(&s, point, tilt, steps, 5).map_err(|e| e.to_string())?;
            print_out(
                || o.summary.clone(),
                json.then(|| serde_json::to_string_pretty(&o)),
            )
        }
    })
}

#[derive(clap::Args)]
struct DbbArgs {
    /// The hexapod scene file.
    scene: PathBuf,
    /// The table ball's nominal centre X,Y,Z (mm); default the home tool point less the bar.
    #[arg(long, allow_hyphen_values = true)]
    centre: Option<String>,
    /// The bar length R (mm); default 100.
    #[arg(long, allow_hyphen_values = true)]
    radius: Option<String>,
    /// The plane: XY, YZ or ZX; default XY.
    #[arg(long)]
    plane: Option<String>,
    /// The bar's elevation out of the plane (degrees); default 0.
    #[arg(long, allow_hyphen_values = true)]
    tilt: Option<String>,
    /// The platform's orientation A,B,C during the circle (degrees); default level.
    #[arg(long, allow_hyphen_values = true)]
    orientation: Option<String>,
    /// The platform's swing along the bar while the circle runs (degrees); default 0.
    #[arg(long, allow_hyphen_values = true)]
    swing: Option<String>,
    /// ccw, cw or both; default both.
    #[arg(long)]
    direction: Option<String>,
    /// Samples per revolution; default 360.
    #[arg(long, allow_hyphen_values = true)]
    points: Option<String>,
    /// The table ball's mounting error X,Y,Z (mm); default 0.
    #[arg(long, allow_hyphen_values = true)]
    mount: Option<String>,
    /// Length noise σ (µm); default 0.5.
    #[arg(long, allow_hyphen_values = true)]
    noise: Option<String>,
    /// Noise seed; default 1.
    #[arg(long)]
    seed: Option<u64>,
    /// Write the trace (direction,angle,deviation CSV) here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Draw the polar plot into this PNG file.
    #[arg(long)]
    png: Option<PathBuf>,
    /// Write the page (self-contained HTML: the summary, the ISO 230-4 figures and
    /// diagnostics, the polar plot as SVG) into this file.
    #[arg(long, value_name = "FILE")]
    html: Option<PathBuf>,
    /// Print the figures as JSON.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct CalibrateArgs {
    /// The hexapod scene file (needs [workspace]).
    scene: PathBuf,
    /// jig-free (15 circles, 18 parameters) or ball-plate (7 circles, 24); default
    /// ball-plate.
    #[arg(long)]
    procedure: Option<String>,
    /// Also run this many seeded trials of random deviations (joints ±0.5 mm, struts
    /// ±0.2 mm).
    #[arg(long, default_value_t = 0)]
    trials: usize,
    /// Measure these circles instead of the procedure's fixed ones (a plan file written by
    /// `calibrate-design`).
    #[arg(long)]
    plan: Option<PathBuf>,
    /// Print the outcome as JSON.
    #[arg(long)]
    json: bool,
    /// Write the page (self-contained HTML: the identified parameters with σ, the singular
    /// values, what is not determined and why, the pose errors before and after) into this
    /// file.
    #[arg(long, value_name = "FILE")]
    html: Option<PathBuf>,
    /// Identify from bar readings measured on the machine instead of measuring on the twin:
    /// one trace file per circle of the plan (`--plan`, or the procedure's fixed one), in
    /// its order, in the format `twinmill ballbar --out` writes.
    #[arg(long, value_name = "FILE,…", value_delimiter = ',')]
    readings: Vec<PathBuf>,
    /// With `--readings`: write the corrected parameters (a `[deviations]` fragment of the
    /// scene) into this file.
    #[arg(long, value_name = "FILE")]
    corrected: Option<PathBuf>,
}

#[derive(clap::Args)]
struct CalibrateDesignArgs {
    /// The hexapod scene file (needs [workspace]).
    scene: PathBuf,
    /// jig-free or ball-plate; default ball-plate.
    #[arg(long)]
    procedure: Option<String>,
    /// Circles to select (1–60); default the fixed plan's count (15 jig-free, 7 ball plate).
    #[arg(long)]
    circles: Option<usize>,
    /// Write the plan (TOML) here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the outcome as JSON.
    #[arg(long)]
    json: bool,
}

fn dbb_command(r: Result<ExitCode, String>) -> ExitCode {
    r.unwrap_or_else(fail)
}

fn one_number(text: &Option<String>, what: &str, default: f64) -> Result<f64, String> {
    match text {
        None => Ok(default),
        Some(t) => Ok(numbers(t, 1, what)?[0]),
    }
}

fn dbb_ballbar(a: DbbArgs) -> Result<ExitCode, String> {
    use twinmill::hexapod_scene::HexapodScene;
    use twinmill::math::Vector3;
    use twinmill::metrology::ballbar::Turns;
    use twinmill::metrology::hexapod_dbb::{DbbCircle, DbbInstrument, DbbPlane};
    let s = HexapodScene::load(&a.scene).map_err(|e| e.to_string())?;
    let radius = one_number(&a.radius, "radius", 100.0)?;
    let tilt = one_number(&a.tilt, "tilt", 0.0)?;
    let plane = match &a.plane {
        None => DbbPlane::XY,
        Some(p) => DbbPlane::from_name(p)
            .ok_or_else(|| format!("--plane must be XY, YZ or ZX, got '{p}'"))?,
    };
    let turns = match a.direction.as_deref() {
        None | Some("both") => Turns::Both,
        Some("ccw") => Turns::Ccw,
        Some("cw") => Turns::Cw,
        Some(d) => return Err(format!("--direction must be ccw, cw or both, got '{d}'")),
    };
    let v3 = |t: &Option<String>, what: &str, d: Vector3| -> Result<Vector3, String> {
        match t {
            None => Ok(d),
            Some(t) => {
                let v = numbers(t, 3, what)?;
                Ok(Vector3::new(v[0], v[1], v[2]))
            }
        }
    };
    let (e1, _, n) = plane.basis();
    let _ = e1;
    let lift = radius * tilt.to_radians().sin();
    let centre = v3(&a.centre, "centre", s.home.position - lift * n)?;
    let o = v3(&a.orientation, "orientation", Vector3::zeros())?;
    let points = match &a.points {
        None => 360,
        Some(p) => p
            .trim()
            .parse::<usize>()
            .map_err(|_| format!("--points needs a whole number, got '{p}'"))?,
    };
    let noise_um = one_number(&a.noise, "noise", 0.5)?;
    let circle = DbbCircle {
        centre_mm: centre,
        radius_mm: radius,
        plane,
        tilt_deg: tilt,
        orientation_deg: [o.x, o.y, o.z],
        swing_deg: one_number(&a.swing, "swing", 0.0)?,
        turns,
        points,
    };
    let instrument = DbbInstrument {
        mount_mm: v3(&a.mount, "mount", Vector3::zeros())?,
        noise_sigma_mm: noise_um * 1e-3,
        seed: a.seed.unwrap_or(1),
        stream: 0,
    };
    let o =
        twinmill::pipeline::dbb::ballbar(&s, &circle, &instrument).map_err(|e| e.to_string())?;
    if let Some(out) = &a.out {
        twinmill::output::write_file(out, o.csv.as_bytes()).map_err(|e| e.to_string())?;
    }
    if let Some(png) = &a.png {
        twinmill::output::write_file(png, &o.png).map_err(|e| e.to_string())?;
    }
    if let Some(html) = &a.html {
        let page = twinmill::pipeline::instrument_pages::hexapod_ballbar_page(&s.name, &o);
        twinmill::output::write_file(html, page.as_bytes()).map_err(|e| e.to_string())?;
    }
    Ok(print_out(
        || o.summary.clone(),
        a.json.then(|| serde_json::to_string_pretty(&o)),
    ))
}

fn dbb_calibrate(a: CalibrateArgs) -> Result<ExitCode, String> {
    use twinmill::hexapod_scene::HexapodScene;
    let procedure = procedure_arg(a.procedure.as_deref())?;
    let s = HexapodScene {
        accept_misfit: accept_misfit(),
        ..HexapodScene::load(&a.scene).map_err(|e| e.to_string())?
    };
    let plan = match &a.plan {
        None => None,
        Some(p) => Some(twinmill::pipeline::dbb::load_plan(p).map_err(|e| e.to_string())?),
    };
    let procedure = match (&plan, a.procedure.is_some()) {
        (Some(p), false) => p.procedure,
        _ => procedure,
    };
    if a.corrected.is_some() && a.readings.is_empty() {
        return Err(
            "--corrected needs --readings (the parameters identified from measured circles)".into(),
        );
    }
    if !a.readings.is_empty() {
        if a.trials > 0 {
            return Err("--trials runs on the twin; it cannot go with --readings".into());
        }
        if a.html.is_some() {
            return Err("--html is for calibrations on the twin; with --readings the summary, --json and --corrected say it all".into());
        }
        let mut files = Vec::with_capacity(a.readings.len());
        for p in &a.readings {
            let text = twinmill::scene::read_text(p).map_err(|e| e.to_string())?;
            files.push((p.clone(), text));
        }
        let o = twinmill::pipeline::dbb::calibrate_measured(&s, procedure, plan, &files)
            .map_err(|e| e.to_string())?;
        if let Some(out) = &a.corrected {
            twinmill::output::write_file(out, o.fragment.as_bytes()).map_err(|e| e.to_string())?;
        }
        return Ok(print_out(
            || o.summary.clone(),
            a.json.then(|| serde_json::to_string_pretty(&o)),
        ));
    }
    let o = twinmill::pipeline::dbb::calibrate_scene(&s, procedure, plan, a.trials)
        .map_err(|e| e.to_string())?;
    if let Some(html) = &a.html {
        let page = twinmill::pipeline::instrument_pages::calibrate_page(&s.name, &o);
        twinmill::output::write_file(html, page.as_bytes()).map_err(|e| e.to_string())?;
    }
    Ok(print_out(
        || o.summary.clone(),
        a.json.then(|| serde_json::to_string_pretty(&o)),
    ))
}

/// `--procedure`: jig-free or ball-plate (default).
fn procedure_arg(
    name: Option<&str>,
) -> Result<twinmill::calibration::hexapod_calibrate::Procedure, String> {
    use twinmill::calibration::hexapod_calibrate::Procedure;
    match name {
        None => Ok(Procedure::BallPlate),
        Some(p) => Procedure::from_name(p)
            .ok_or_else(|| format!("--procedure must be jig-free or ball-plate, got '{p}'")),
    }
}

fn dbb_calibrate_design(a: CalibrateDesignArgs) -> Result<ExitCode, String> {
    use twinmill::calibration::hexapod_calibrate::Procedure;
    use twinmill::hexapod_scene::HexapodScene;
    let procedure = procedure_arg(a.procedure.as_deref())?;
    let circles = a.circles.unwrap_or(match procedure {
        Procedure::JigFree => 15,
        Procedure::BallPlate => 7,
    });
    let s = HexapodScene::load(&a.scene).map_err(|e| e.to_string())?;
    let o = twinmill::pipeline::dbb::calibration_design(&s, procedure, circles)
        .map_err(|e| e.to_string())?;
    if let Some(out) = &a.out {
        twinmill::output::write_file(out, o.plan_toml.as_bytes()).map_err(|e| e.to_string())?;
    }
    Ok(print_out(
        || o.summary.clone(),
        a.json.then(|| serde_json::to_string_pretty(&o)),
    ))
}
