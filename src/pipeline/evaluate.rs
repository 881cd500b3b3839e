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
