//! `twinmill measure`: a virtual instrument on the scene's machine — laser, ball bar (a
//! hexapod's double ball bar), ball sensor, probe — its readings written and evaluated.
//! `ballbar` is the hidden old name of the hexapod's double ball bar.

use super::{fail, numbers, print_out, write};
use std::path::PathBuf;
use std::process::ExitCode;
use twinmill::math::Vector3;
use twinmill::metrology::ballbar::Turns;
use twinmill::metrology::hexapod_dbb::DbbPlane;
use twinmill::pipeline::instrument_pages::hexapod_ballbar_page;
use twinmill::pipeline::measure::{
    BallbarOptions, DbbRequest, LaserOptions, MeasureInstrument, MeasureRequest, RotaryOptions,
    hexapod_ballbar, measure,
};
use twinmill::scene::HexapodScene;

/// The virtual instruments of `measure`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Instrument {
    /// Laser interferometer: ISO 230-2's test cycle of one linear axis.
    Laser,
    /// Telescoping ball bar: ISO 230-4's circular test in a plane (a hexapod's double ball
    /// bar).
    Ballbar,
    /// Seed 003's non-contact ball sensor on the table, its master ball in the spindle:
    /// ISO 10791-6's simultaneous motion test of the rotary axes, and their location errors.
    BallSensor,
    /// A touch probe finding a calibration sphere at rotary indices, and the rotary axes'
    /// location errors.
    Probe,
}

impl Instrument {
    /// The library's instrument.
    fn request(self) -> MeasureInstrument {
        match self {
            Instrument::Laser => MeasureInstrument::Laser,
            Instrument::Ballbar => MeasureInstrument::Ballbar,
            Instrument::BallSensor => MeasureInstrument::BallSensor,
            Instrument::Probe => MeasureInstrument::Probe,
        }
    }
}

/// Measure the machine with a virtual instrument; evaluate the readings.
///
/// Measure the scene's machine with a virtual instrument on its deviated machine (error
/// motions, reversals, squareness as the scene gives them): the laser interferometer's
/// ISO 230-2 test cycle of one linear axis, the ball bar's ISO 230-4 circles (a hexapod's
/// double ball bar), the ball sensor's or the probe's rotary-axis tests; write the readings
/// or the trace (the file `evaluate` reads) and the page, and print the evaluation. Only
/// the scene's machine is used: no program, stock or scanner.
#[derive(clap::Args)]
pub struct MeasureArgs {
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
    /// Replace the machine's deviations, error motions and reversals by an identified
    /// machine's (the file `identify --measurement … --deviations-out` writes).
    #[arg(long, value_name = "FILE")]
    deviations: Option<PathBuf>,
    /// A hexapod: run the circle with the controller on these calibrated parameters (the
    /// `[controller]` file `identify … --corrected` writes).
    #[arg(long, value_name = "FILE")]
    controller: Option<PathBuf>,
    /// Gaussian noise of each reading or sample, σ (µm; default 0: the twin repeats exactly;
    /// a hexapod's double ball bar: 0.5).
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

// The rotary-axis tests' options.
#[derive(clap::Args)]
#[command(next_help_heading = "Rotary-axis tests (--instrument ball-sensor | probe)")]
pub struct RotaryArgs {
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

// The laser interferometer's options.
#[derive(clap::Args)]
#[command(next_help_heading = "Laser interferometer (--instrument laser)")]
pub struct LaserArgs {
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
    /// A LinuxCNC compensation file (`[JOINT_n] COMP_FILE` with `COMP_FILE_TYPE = 1`, as
    /// `evaluate iso230-2 --comp` writes it) that the controller applies to the measured
    /// axis, interpolated by direction of motion as LinuxCNC's motion controller does: the
    /// readings then show the accuracy after compensation.
    #[arg(long, value_name = "FILE")]
    comp: Option<PathBuf>,
}

// The ball bar's options.
#[derive(clap::Args)]
#[command(next_help_heading = "Ball bar (--instrument ballbar)")]
pub struct BallbarArgs {
    /// The plane of the circle by its machine axes, first then second: XY, YZ or ZX (default
    /// XY).
    #[arg(long)]
    plane: Option<String>,
    /// The centre command, e.g. X=0,Y=0,Z=50 (default: the scene's home for every axis not
    /// given); a hexapod: the table ball's nominal centre X,Y,Z (mm; default the home tool
    /// point less the bar).
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
    /// Hexapod: the bar's elevation out of the plane (degrees; default 0).
    #[arg(long, allow_negative_numbers = true, value_name = "DEG")]
    tilt: Option<f64>,
    /// Hexapod: the platform's orientation during the circle (degrees; default level).
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        value_name = "A,B,C"
    )]
    orientation: Option<Vec<f64>>,
    /// Hexapod: the platform's swing along the bar while the circle runs (degrees; default 0).
    #[arg(long, allow_negative_numbers = true, value_name = "DEG")]
    swing: Option<f64>,
}

/// `--direction` of the ball bar.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum TurnsArg {
    /// Counter-clockwise only.
    Ccw,
    /// Clockwise only.
    Cw,
    /// One counter-clockwise run, then one clockwise run.
    Both,
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
        (Laser, "--comp", l.comp.is_some()),
        (Ballbar, "--plane", b.plane.is_some()),
        (Ballbar, "--centre", b.centre.is_some()),
        (Ballbar, "--radius", b.radius.is_some()),
        (Ballbar, "--direction", b.direction.is_some()),
        (Ballbar, "--feed", b.feed.is_some()),
        (Ballbar, "--points", b.points.is_some()),
        (Ballbar, "--tool-ball", b.tool_ball.is_some()),
        (Ballbar, "--mount", b.mount.is_some()),
        (Ballbar, "--pitch", b.pitch.is_some()),
        (Ballbar, "--tilt", b.tilt.is_some()),
        (Ballbar, "--orientation", b.orientation.is_some()),
        (Ballbar, "--swing", b.swing.is_some()),
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

/// `ballbar`, the hidden old name of `measure --instrument ballbar` on a hexapod.
#[derive(clap::Args)]
pub struct DbbArgs {
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

/// `twinmill measure`: refuses another instrument's options, measures, then writes the
/// readings, the page and the plot, and prints the figures. Nothing is written unless
/// everything before succeeded.
pub fn exec(a: MeasureArgs) -> ExitCode {
    let options = instrument_options(&a);
    if let Some((other, option, _)) = options.iter().copied().find(|(i, o, given)| {
        *given
            && *i != a.instrument
            && !options.iter().any(|(j, p, _)| j == &a.instrument && p == o)
    }) {
        return fail(format!(
            "{option} is an option of --instrument {}, not of --instrument {}",
            other.request().name(),
            a.instrument.request().name()
        ));
    }
    let (l, b, r) = (a.laser, a.ballbar, a.rotary);
    let request = MeasureRequest {
        accept_misfit: super::accept_misfit(),
        deviations: a.deviations,
        controller: a.controller,
        scene: a.scene,
        instrument: a.instrument.request(),
        out: a.out,
        png: a.png,
        html: a.html,
        seed: a.seed,
        noise_um: a.noise,
        overshoot: a.overshoot,
        laser: LaserOptions {
            axis: l.axis,
            from: l.from,
            to: l.to,
            targets: l.targets,
            target_list: l.target_list,
            runs: l.runs,
            abbe: l.abbe,
            drift: l.drift,
            at: l.at,
            comp: l.comp,
        },
        ballbar: BallbarOptions {
            plane: b.plane,
            centre: b.centre,
            radius: b.radius,
            direction: b.direction.map(TurnsArg::turns),
            feed: b.feed,
            points: b.points,
            tool_ball: b.tool_ball,
            mount: b.mount,
            pitch: b.pitch,
            tilt: b.tilt,
            orientation: b.orientation,
            swing: b.swing,
        },
        rotary: RotaryOptions {
            sweep: r.sweep,
            point: r.point,
            mounting: r.mounting,
            stylus: r.stylus,
            height: r.height,
            band: r.band,
            identify: r.identify,
            no_identify: r.no_identify,
        },
    };
    let m = match measure(&request) {
        Ok(m) => m,
        Err(e) => return fail(e),
    };
    let written = write(&m.file, m.text.as_bytes())
        .and_then(|()| write(&m.html_file, m.html.as_bytes()))
        .and_then(|()| match &m.png {
            Some((png, bytes)) => write(png, bytes),
            None => Ok(()),
        });
    if let Err(e) = written {
        return fail(e);
    }
    print_out(|| m.summary, a.json.then_some(Ok(m.json)))
}

impl TurnsArg {
    /// The library's directions.
    fn turns(self) -> Turns {
        match self {
            TurnsArg::Ccw => Turns::Ccw,
            TurnsArg::Cw => Turns::Cw,
            TurnsArg::Both => Turns::Both,
        }
    }
}

/// Three numbers of `text` as a vector, if given.
fn vector(text: &Option<String>, what: &str) -> Result<Option<Vector3>, String> {
    text.as_ref()
        .map(|t| numbers(t, 3, what).map(|v| Vector3::new(v[0], v[1], v[2])))
        .transpose()
}

/// One number of `text`, if given.
fn one_number(text: &Option<String>, what: &str) -> Result<Option<f64>, String> {
    text.as_ref()
        .map(|t| numbers(t, 1, what).map(|v| v[0]))
        .transpose()
}

/// The old `ballbar` options as the library's request, checked in their old order.
fn dbb_request(a: &DbbArgs) -> Result<DbbRequest, String> {
    let radius_mm = one_number(&a.radius, "radius")?;
    let tilt_deg = one_number(&a.tilt, "tilt")?;
    let plane = match &a.plane {
        None => None,
        Some(p) => Some(
            DbbPlane::from_name(p)
                .ok_or_else(|| format!("--plane must be XY, YZ or ZX, got '{p}'"))?,
        ),
    };
    let turns = match a.direction.as_deref() {
        None | Some("both") => Turns::Both,
        Some("ccw") => Turns::Ccw,
        Some("cw") => Turns::Cw,
        Some(d) => return Err(format!("--direction must be ccw, cw or both, got '{d}'")),
    };
    let centre = vector(&a.centre, "centre")?;
    let orientation_deg = vector(&a.orientation, "orientation")?;
    let points = match &a.points {
        None => None,
        Some(p) => Some(
            p.trim()
                .parse::<usize>()
                .map_err(|_| format!("--points needs a whole number, got '{p}'"))?,
        ),
    };
    Ok(DbbRequest {
        centre,
        radius_mm,
        plane,
        tilt_deg,
        orientation_deg,
        swing_deg: one_number(&a.swing, "swing")?,
        turns: Some(turns),
        points,
        mount_mm: vector(&a.mount, "mount")?,
        noise_um: one_number(&a.noise, "noise")?,
        seed: a.seed,
    })
}

/// `twinmill ballbar` (hidden): the hexapod's double ball bar as before — only the files
/// asked for are written.
pub fn exec_ballbar(a: DbbArgs) -> ExitCode {
    let run = || -> Result<ExitCode, String> {
        let s = HexapodScene::load(&a.scene).map_err(|e| e.to_string())?;
        let o = hexapod_ballbar(&s, &dbb_request(&a)?)?;
        if let Some(out) = &a.out {
            write(out, o.csv.as_bytes())?;
        }
        if let Some(png) = &a.png {
            write(png, &o.png)?;
        }
        if let Some(html) = &a.html {
            write(html, hexapod_ballbar_page(&s.name, &o).as_bytes())?;
        }
        Ok(print_out(
            || o.summary.clone(),
            a.json.then(|| serde_json::to_string_pretty(&o)),
        ))
    };
    run().unwrap_or_else(fail)
}
