//! `twinmill evaluate`: measurements evaluated as a standard says — ISO 230-2 positioning
//! from a readings file, ISO 230-4 circular tests from a radial-deviation trace, seed 003's
//! ball sensor from its micrometers' readings — each returning its figures, the summary, and
//! on request the plot (PNG bytes) and the page; and the summaries `measure` shares.
//! Reads the input file; writes nothing.

use crate::math::Real;
use crate::metrology::ball_sensor::{self, BallSensor};
use crate::metrology::circular::{
    CircularFigures, CircularOptions, Diagnosis, evaluate as evaluate_circular, parse_trace,
};
use crate::metrology::positioning::{
    PositioningFigures, evaluate as evaluate_positioning, parse_readings,
};
use crate::report::html::render_page;
use crate::report::pages;
use crate::report::render::{RenderError, encode_png};
use std::path::{Path, PathBuf};

/// What an evaluation made: the summary, the figures as JSON, and what was asked for.
#[derive(Clone, Debug)]
pub struct Evaluated {
    /// The summary text.
    pub summary: String,
    /// The figures as `--json` prints them.
    pub json: String,
    /// The plot's file and its PNG bytes, when a plot was asked for.
    pub png: Option<(PathBuf, Vec<u8>)>,
    /// The page (self-contained HTML), when asked for.
    pub html: Option<String>,
}

/// Encodes a drawn plot for `png`, or says why not (naming the file).
pub fn plot_bytes(
    png: &Path,
    drawn: Result<image::RgbImage, RenderError>,
) -> Result<(PathBuf, Vec<u8>), String> {
    let bytes = drawn
        .and_then(|img| encode_png(&img))
        .map_err(|e| format!("{}: {e}", png.display()))?;
    Ok((png.to_path_buf(), bytes))
}

/// The text of a measurement file, or why it cannot be read.
fn read(file: &Path) -> Result<String, String> {
    std::fs::read_to_string(file).map_err(|e| format!("{}: cannot read: {e}", file.display()))
}

/// `evaluate iso230-2`: the positioning figures of a readings file; `png` and `html` ask
/// for the plot and the page.
pub fn iso230_2(file: &Path, png: Option<&Path>, html: bool) -> Result<Evaluated, String> {
    let text = read(file)?;
    let figures = parse_readings(&text, file)
        .and_then(|readings| evaluate_positioning(&readings, file))
        .map_err(|e| e.to_string())?;
    let plot_title = format!("ISO 230-2: {}", file.display());
    let title = format!("twinmill evaluate iso230-2: {}", file.display());
    let summary = positioning_summary(&title, &[], &figures);
    let png = png
        .map(|p| {
            plot_bytes(
                p,
                crate::report::plots::positioning_plot(&figures, &plot_title),
            )
        })
        .transpose()?;
    let html = html.then(|| {
        render_page(&pages::positioning_page(
            &title,
            &summary,
            &figures,
            &plot_title,
        ))
    });
    Ok(Evaluated {
        json: serde_json::to_string_pretty(&figures).map_err(|e| e.to_string())?,
        summary,
        png,
        html,
    })
}

/// What `evaluate iso230-2 --comp` writes: a LinuxCNC compensation table.
#[derive(Clone, Debug, PartialEq)]
pub struct CompRequest {
    /// The compensation file to write.
    pub out: PathBuf,
    /// The axis letter the table is for; `None`: the one the readings file records.
    pub axis: Option<String>,
    /// The LinuxCNC joint number; `None`: the axis's joint under trivial kinematics (X 0,
    /// Y 1, Z 2, A 3, B 4, C 5).
    pub joint: Option<u32>,
}

/// A compensation table made from readings: the file's text and the summary's lines.
#[derive(Clone, Debug, PartialEq)]
pub struct CompWritten {
    /// The file to write.
    pub out: PathBuf,
    /// Its text.
    pub text: String,
    /// What the summary says about it.
    pub summary: String,
}

/// `evaluate iso230-2 --comp`: the LinuxCNC compensation table (`COMP_FILE_TYPE = 1`) that
/// cancels the readings' mean deviations at their targets (see
/// [`crate::metrology::comp_table`]), with its provenance after the table.
pub fn comp_table(file: &Path, r: &CompRequest) -> Result<CompWritten, String> {
    use crate::metrology::comp_table::CompTable;
    use crate::metrology::table::setup_record;
    use crate::nc::AxisLetter;
    let text = read(file)?;
    let figures = parse_readings(&text, file)
        .and_then(|readings| evaluate_positioning(&readings, file))
        .map_err(|e| e.to_string())?;
    let letter = |s: &str| {
        let mut c = s.trim().chars();
        match (c.next(), c.next()) {
            (Some(c), None) => AxisLetter::from_char(c.to_ascii_uppercase()),
            _ => None,
        }
    };
    let recorded = setup_record(&text, "laser").and_then(|(line, pairs)| {
        pairs
            .iter()
            .find(|(k, _)| k == "axis")
            .map(|(_, v)| (line, v.clone()))
    });
    let axis = match (&r.axis, &recorded) {
        (Some(a), _) => {
            let l = letter(a)
                .ok_or_else(|| format!("--axis: '{a}' is not an axis letter (X Y Z A B C)"))?;
            if let Some((line, v)) = &recorded
                && letter(v) != Some(l)
            {
                return Err(format!(
                    "{}:{line}: the readings were taken on axis {v}, not on --axis {a}",
                    file.display()
                ));
            }
            l
        }
        (None, Some((line, v))) => letter(v).ok_or_else(|| {
            format!(
                "{}:{line}: axis '{v}' is not an axis letter",
                file.display()
            )
        })?,
        (None, None) => {
            return Err(format!(
                "{}: the readings record no axis: give --axis with --comp",
                file.display()
            ));
        }
    };
    let joint = r.joint.unwrap_or(axis.index() as u32);
    let table = CompTable::from_figures(&figures, file).map_err(|e| e.to_string())?;
    let out = r.out.display();
    let comments = vec![
        format!(
            "LinuxCNC axis compensation for axis {} (joint {joint}), units mm: [JOINT_{joint}] \
             COMP_FILE = {out}, COMP_FILE_TYPE = 1",
            axis.as_char()
        ),
        format!(
            "from the ISO 230-2 readings {} ({} targets, {} runs each way) by twinmill \
             evaluate iso230-2 --comp",
            file.display(),
            figures.targets.len(),
            figures.runs
        ),
        "each line: nominal (commanded position), forward trim = -(mean deviation approaching \
         in +), reverse trim = -(mean deviation approaching in -); LinuxCNC adds the trim of \
         the direction of motion to the command, interpolated between nominals"
            .to_string(),
        "these comments follow the table: LinuxCNC stops reading at the first line that is \
         not three numbers"
            .to_string(),
    ];
    let um = |x: f64| x * 1e3;
    let worst = table
        .entries()
        .iter()
        .flat_map(|e| [e.forward_trim.abs(), e.reverse_trim.abs()])
        .fold(0.0, f64::max);
    Ok(CompWritten {
        text: table.to_text(&comments),
        summary: format!(
            "  compensation  wrote {out}: {} entries for axis {} (joint {joint}), largest trim \
             {:.4} µm; [JOINT_{joint}] COMP_FILE = {out}, COMP_FILE_TYPE = 1\n",
            table.entries().len(),
            axis.as_char(),
            um(worst)
        ),
        out: r.out.clone(),
    })
}

/// `evaluate iso230-4`: the circular test's figures of a trace for a circle of `radius_mm`
/// (and the screw lead `pitch_mm` for the cyclic terms).
pub fn iso230_4(
    file: &Path,
    radius_mm: Real,
    pitch_mm: Option<Real>,
    png: Option<&Path>,
    html: bool,
) -> Result<Evaluated, String> {
    let text = read(file)?;
    let opts = CircularOptions {
        radius_mm,
        pitch_mm,
    };
    let samples = parse_trace(&text, file).map_err(|e| e.to_string())?;
    let figures = evaluate_circular(&samples, &opts, file).map_err(|e| e.to_string())?;
    let plot_title = format!("ISO 230-4: {}", file.display());
    let title = format!("twinmill evaluate iso230-4: {}", file.display());
    let summary = circular_summary(&title, &[], &figures);
    let png = png
        .map(|p| {
            plot_bytes(
                p,
                crate::report::plots::polar_plot(&samples, &figures, &plot_title),
            )
        })
        .transpose()?;
    let html = html.then(|| {
        render_page(&pages::circular_page(
            &title,
            &summary,
            &samples,
            &figures,
            &plot_title,
            pages::json(&figures),
        ))
    });
    Ok(Evaluated {
        json: serde_json::to_string_pretty(&figures).map_err(|e| e.to_string())?,
        summary,
        png,
        html,
    })
}

/// The ball sensor of `evaluate ball-sensor` (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BallSensorRequest {
    /// Width of micrometer B's light band L_x0.
    pub band_x_mm: Real,
    /// Width of micrometer A's light band L_y0.
    pub band_y_mm: Real,
    /// Master ball diameter.
    pub ball_mm: Real,
    /// Bound of each micrometer reading's error.
    pub accuracy_mm: Real,
    /// Tolerance on Z for the working window.
    pub tolerance_mm: Real,
    /// Shortest chord the micrometers measure within their accuracy; 0: no limit.
    pub min_chord_mm: Real,
}

/// `evaluate ball-sensor`: the sensor of `r`, the window, and the centres of a readings
/// file if one is given; `html` asks for the page.
pub fn ball_sensor(
    file: Option<&Path>,
    r: &BallSensorRequest,
    html: bool,
) -> Result<Evaluated, String> {
    use std::fmt::Write as _;
    let BallSensorRequest {
        band_x_mm: band_x,
        band_y_mm: band_y,
        ball_mm: ball,
        accuracy_mm: accuracy,
        tolerance_mm: tolerance,
        min_chord_mm: min_chord,
    } = *r;
    let checks = [
        ("--band-x", band_x),
        ("--band-y", band_y),
        ("--ball", ball),
        ("--accuracy", accuracy),
        ("--tolerance", tolerance),
    ];
    if let Some((name, v)) = checks.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        return Err(format!("{name} must be positive, got {v}"));
    }
    if !(min_chord.is_finite() && min_chord >= 0.0) {
        return Err(format!(
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
            let text = read(f)?;
            ball_sensor::parse_readings(&text, f)
                .and_then(|rows| ball_sensor::centres(&sensor, &rows, f))
                .map_err(|e| e.to_string())?
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
    let html = html.then(|| {
        let title = match file {
            Some(f) => format!("twinmill evaluate ball-sensor: {}", f.display()),
            None => "twinmill evaluate ball-sensor".to_string(),
        };
        render_page(&pages::ball_sensor_page(&title, &summary, figures.clone()))
    });
    Ok(Evaluated {
        json: serde_json::to_string_pretty(&figures).map_err(|e| e.to_string())?,
        summary,
        png: None,
        html,
    })
}

/// Lines of a summary after its title: `(label, text)`, the label in the figures' column.
fn labelled(lines: &[(&str, String)]) -> String {
    lines
        .iter()
        .map(|(label, text)| format!("  {label:<13} {text}\n"))
        .collect()
}

/// The ISO 230-2 figures as the summaries print them (µm): `title`, then `extra` lines, then the
/// figures.
pub fn positioning_summary(
    title: &str,
    extra: &[(&str, String)],
    f: &PositioningFigures,
) -> String {
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

/// The ISO 230-4 figures and diagnostics as the summaries print them (µm): `title`, then `extra`
/// lines, then the figures.
pub fn circular_summary(title: &str, extra: &[(&str, String)], f: &CircularFigures) -> String {
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
