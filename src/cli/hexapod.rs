//! `twinmill hexapod`: the analyses of a hexapod (Stewart platform) scene — kinematics,
//! resolution amplification, homing, pivot accuracy, the probe calibration.

use super::{fail, numbers, print_out, write};
use clap::Subcommand;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use twinmill::report::html::render_page;
use twinmill::report::pages;

/// A hexapod's kinematics, amplification, homing, pivot accuracy.
///
/// Hexapod (Stewart platform) scenes: inverse and forward kinematics, resolution
/// amplification, homing, pivot accuracy (docs/hexapod.md). Its double ball bar is
/// `measure --instrument ballbar`, its calibration `identify`, its circles `design`.
#[derive(clap::Args)]
pub struct HexapodArgs {
    #[command(subcommand)]
    command: HexapodCommand,
}

/// Which hexapod command.
#[derive(Subcommand)]
pub enum HexapodCommand {
    /// Inverse kinematics on the controller's parameters (what the controller computes;
    /// nominal unless calibrated): the six strut lengths of a pose.
    Ik {
        /// The hexapod scene file (TOML, [machine] kind = "hexapod").
        scene: PathBuf,
        /// The pose X,Y,Z,A,B,C (mm, degrees; R = Rz(C)·Ry(B)·Rx(A)).
        #[arg(long, allow_hyphen_values = true)]
        pose: String,
        /// Run the controller on these calibrated parameters (the `[controller]` file
        /// `identify … --corrected` writes) instead of the scene's.
        #[arg(long, value_name = "FILE")]
        controller: Option<PathBuf>,
        /// Print {"struts_mm": [...]}.
        #[arg(long)]
        json: bool,
    },
    /// Forward kinematics: the pose of commanded strut lengths (or encoder counts), by
    /// Newton–Raphson from a nearby pose: where the controller believes the tool is;
    /// --actual: where the real machine goes.
    Fk {
        /// The hexapod scene file.
        scene: PathBuf,
        /// The commanded strut lengths L1,…,L6 (mm), as the controller computes them (`ik`).
        #[arg(
            long,
            allow_hyphen_values = true,
            required_unless_present = "counts",
            conflicts_with = "counts"
        )]
        struts: Option<String>,
        /// The drives' encoder counts N1,…,N6 since homing (needs [drives]): the readings
        /// N·lead/counts_per_rev (mm) from each strut's reference length.
        #[arg(long, allow_hyphen_values = true)]
        counts: Option<String>,
        /// Start pose X,Y,Z,A,B,C (mm, degrees); default the scene's home pose.
        #[arg(long, allow_hyphen_values = true)]
        near: Option<String>,
        /// Where the actual machine (nominal plus [deviations]) goes: its struts are its own
        /// reference lengths plus the readings the controller's lengths give.
        #[arg(long)]
        actual: bool,
        /// Run the controller on these calibrated parameters (the `[controller]` file
        /// `identify … --corrected` writes) instead of the scene's.
        #[arg(long, value_name = "FILE")]
        controller: Option<PathBuf>,

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
        /// Run the controller on these calibrated parameters (the `[controller]` file
        /// `identify … --corrected` writes) instead of the scene's.
        #[arg(long, value_name = "FILE")]
        controller: Option<PathBuf>,
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
        /// Run the controller on these calibrated parameters (the `[controller]` file
        /// `identify … --corrected` writes) instead of the scene's.
        #[arg(long, value_name = "FILE")]
        controller: Option<PathBuf>,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Seed 001's calibration from gauge-block / touch-probe readings of positioning and
    /// pivot accuracy, in rounds on the corrected controller (needs [workspace]).
    ProbeCalibrate {
        /// The hexapod scene file.
        scene: PathBuf,
        /// Calibration rounds.
        #[arg(long, default_value_t = 2)]
        rounds: usize,
        /// The probe's noise σ (mm).
        #[arg(long, default_value_t = 0.0015)]
        sigma: f64,
        /// Seed of the probe's noise.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Keep a calibration whose readings the noise cannot explain.
        #[arg(long)]
        accept_misfit: bool,
        /// Start from the controller of this file (the `[controller]` file a calibration
        /// wrote), not the scene's.
        #[arg(long, value_name = "FILE")]
        controller: Option<PathBuf>,
        /// Write controller.toml (for --controller) and report.json into this folder.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Write the first round's probe readings (taken through the starting controller)
        /// into this CSV file: what `identify SCENE --readings … --probe FILE` reads.
        #[arg(long, value_name = "FILE")]
        readings_out: Option<PathBuf>,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// A pose X,Y,Z,A,B,C (mm, degrees).
fn pose_arg(text: &str, what: &str) -> Result<twinmill::machine::hexapod::Pose, String> {
    let v = numbers(text, 6, what)?;
    Ok(twinmill::machine::hexapod::Pose::from_mm_deg([
        v[0], v[1], v[2], v[3], v[4], v[5],
    ]))
}

/// A range MIN,MAX.
fn range_arg(text: &str, what: &str) -> Result<(f64, f64), String> {
    let v = numbers(text, 2, what)?;
    Ok((v[0], v[1]))
}

/// `twinmill hexapod ik | fk | amplification | homing | pivot | probe-calibrate`.
pub fn exec(a: HexapodArgs) -> ExitCode {
    match hexapod_run(a.command) {
        Ok(code) => code,
        Err(e) => fail(e),
    }
}

/// The hexapod command, or why it failed.
fn hexapod_run(command: HexapodCommand) -> Result<ExitCode, String> {
    use twinmill::machine::hexapod_accuracy::Workspace;
    use twinmill::pipeline::hexapod::{
        AmplificationRequest, hexapod_amplification, hexapod_homing, hexapod_pivot,
    };
    use twinmill::scene::HexapodScene;
    let load = |p: &Path, controller: &Option<PathBuf>| {
        let mut s = HexapodScene::load(p).map_err(|e| e.to_string())?;
        if let Some(c) = controller {
            s.apply_controller_file(c).map_err(|e| e.to_string())?;
        }
        Ok::<_, String>(s)
    };
    let json_text = |v: serde_json::Value| serde_json::to_string(&v);
    Ok(match command {
        HexapodCommand::Ik {
            scene,
            pose,
            controller,
            json,
        } => {
            let s = load(&scene, &controller)?;
            let pose = pose_arg(&pose, "pose")?;
            let l = s
                .controller
                .inverse(&pose)
                .map_err(|e| format!("{}: pose {pose}: {e}", scene.display()))?;
            print_out(
                || {
                    let mut t = format!(
                        "twinmill: hexapod ik on {} at {pose} ({})\n",
                        s.name,
                        s.controller_label()
                    );
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
            counts,
            near,
            actual,
            controller,
            json,
        } => {
            let s = load(&scene, &controller)?;
            let l: [f64; 6] = match (&struts, &counts) {
                (Some(t), _) => {
                    let v = numbers(t, 6, "struts")?;
                    [v[0], v[1], v[2], v[3], v[4], v[5]]
                }
                (None, Some(c)) => {
                    let d = s.drives.ok_or_else(|| {
                        format!(
                            "{}: --counts needs [drives] lead_mm and counts_per_rev",
                            scene.display()
                        )
                    })?;
                    let v = numbers(c, 6, "counts")?;
                    if let Some(x) = v.iter().find(|x| x.fract() != 0.0) {
                        return Err(format!("--counts are whole encoder counts, got {x}"));
                    }
                    let readings: [f64; 6] = std::array::from_fn(|i| v[i] * d.resolution_mm());
                    s.controller.lengths_of_readings(&readings)
                }
                (None, None) => return Err("fk needs --struts or --counts".into()),
            };
            let near = match near {
                Some(n) => pose_arg(&n, "near")?,
                None => s.home,
            };
            let sol = if actual {
                twinmill::machine::hexapod::reached_by_lengths(&s.controller, &s.actual, &l, &near)
            } else {
                s.controller.forward(&l, &near)
            }
            .map_err(|e| format!("{}: {e}", scene.display()))?;
            let p = sol.pose.to_mm_deg();
            print_out(
                || {
                    format!(
                        "twinmill: hexapod fk on {} ({})\n  pose        {}\n  iterations  {}, strut residual {:.1e} mm\n",
                        s.name,
                        if actual {
                            format!(
                                "where the actual machine goes, commanded by {}",
                                s.controller_label()
                            )
                        } else {
                            format!("where {} puts the tool", s.controller_label())
                        },
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
            let s = load(&scene, &None)?;
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
                write(out, o.csv.as_bytes())?;
            }
            if let Some(png) = &png {
                write(png, &o.png)?;
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
            controller,
            json,
        } => {
            let s = load(&scene, &controller)?;
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
            controller,
            json,
        } => {
            let s = load(&scene, &controller)?;
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
        HexapodCommand::ProbeCalibrate {
            scene,
            rounds,
            sigma,
            seed,
            accept_misfit,
            controller,
            out,
            readings_out,
            json,
        } => {
            use twinmill::calibration::hexapod_probe::ProbeOptions;
            let s = load(&scene, &controller)?;
            let o = twinmill::pipeline::hexapod_probe::hexapod_probe_calibrate(
                &s,
                &ProbeOptions {
                    rounds,
                    sigma_mm: sigma,
                    seed,
                    accept_misfit,
                },
            )
            .map_err(|e| e.to_string())?;
            if let Some(dir) = &out {
                let report = serde_json::to_string_pretty(&o).map_err(|e| e.to_string())?;
                twinmill::output::write_files(
                    dir,
                    &[
                        ("controller.toml", o.fragment.clone().into_bytes()),
                        ("report.json", report.into_bytes()),
                    ],
                )
                .map_err(|e| e.to_string())?;
            }
            if let Some(file) = &readings_out {
                write(file, o.readings_csv.as_bytes())?;
            }
            print_out(
                || o.summary.clone(),
                json.then(|| serde_json::to_string_pretty(&o)),
            )
        }
    })
}
