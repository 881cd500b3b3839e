//! `twinmill evaluate`: measurement files evaluated as a standard says (ISO 230-2, ISO 230-4,
//! seed 003's ball sensor).

use super::{fail, print_out, write};
use clap::Subcommand;
use std::path::PathBuf;
use std::process::ExitCode;
use twinmill::pipeline::evaluate::{
    BallSensorRequest, CompRequest, Evaluated, ball_sensor, comp_table, iso230_2, iso230_4,
};

/// Evaluate measurement files as a standard says (ISO 230-2, 230-4).
///
/// Evaluate measurements as a standard says: ISO 230-2 positioning accuracy from readings,
/// ISO 230-4 circular tests from a ball-bar trace, seed 003's ball sensor from its
/// micrometers' readings.
#[derive(clap::Args)]
pub struct EvaluateArgs {
    #[command(subcommand)]
    command: EvaluateCommand,
}

/// Which standard's evaluation.
#[derive(Subcommand)]
pub enum EvaluateCommand {
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
        /// Also write the LinuxCNC axis compensation file (`[JOINT_n] COMP_FILE` with
        /// `COMP_FILE_TYPE = 1`) that cancels the mean deviations at the targets: each line
        /// `nominal forward_trim reverse_trim` (mm), trims −x̄↑ and −x̄↓; the provenance
        /// follows the table as `#` lines.
        #[arg(long, value_name = "OUT")]
        comp: Option<PathBuf>,
        /// The axis the compensation is for (default: the one the readings file records).
        #[arg(long, value_name = "L", requires = "comp")]
        axis: Option<String>,
        /// The LinuxCNC joint number named in the file (default: the axis's joint under
        /// trivial kinematics, X 0, Y 1, Z 2, A 3, B 4, C 5).
        #[arg(long, value_name = "N", requires = "comp")]
        joint: Option<u32>,
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

/// Writes the plot and the page asked for, then prints the summary or the JSON.
fn written(e: Result<Evaluated, String>, html: Option<PathBuf>, json: bool) -> ExitCode {
    let e = match e {
        Ok(e) => e,
        Err(m) => return fail(m),
    };
    if let Some((png, bytes)) = &e.png
        && let Err(m) = write(png, bytes)
    {
        return fail(m);
    }
    if let (Some(path), Some(page)) = (&html, &e.html)
        && let Err(m) = write(path, page.as_bytes())
    {
        return fail(m);
    }
    print_out(|| e.summary, json.then_some(Ok(e.json)))
}

/// `twinmill evaluate iso230-2 | iso230-4 | ball-sensor`.
pub fn exec(a: EvaluateArgs) -> ExitCode {
    match a.command {
        EvaluateCommand::Iso230_2 {
            file,
            json,
            png,
            html,
            comp,
            axis,
            joint,
        } => {
            // Everything is computed before anything is written.
            let table = comp
                .map(|out| comp_table(&file, &CompRequest { out, axis, joint }))
                .transpose();
            let (table, e) = match (table, iso230_2(&file, png.as_deref(), html.is_some())) {
                (Err(m), _) | (_, Err(m)) => return fail(m),
                (Ok(t), Ok(e)) => (t, e),
            };
            let e = match table {
                Some(t) => {
                    if let Err(m) = write(&t.out, t.text.as_bytes()) {
                        return fail(m);
                    }
                    Evaluated {
                        summary: e.summary + &t.summary,
                        ..e
                    }
                }
                None => e,
            };
            written(Ok(e), html, json)
        }
        EvaluateCommand::Iso230_4 {
            file,
            radius,
            pitch,
            json,
            png,
            html,
        } => written(
            iso230_4(&file, radius, pitch, png.as_deref(), html.is_some()),
            html,
            json,
        ),
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
        } => {
            let request = BallSensorRequest {
                band_x_mm: band_x,
                band_y_mm: band_y,
                ball_mm: ball,
                accuracy_mm: accuracy * 1e-3,
                tolerance_mm: tolerance * 1e-3,
                min_chord_mm: min_chord,
            };
            written(
                ball_sensor(file.as_deref(), &request, html.is_some()),
                html,
                json,
            )
        }
    }
}
