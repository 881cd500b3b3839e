//! The standards' plots as PNG: the ISO 230-2 bidirectional positioning plot and the
//! ISO 230-4 polar plot of a circular test.
//!
//! **ISO 230-2 plot:** deviation (µm, up) against target position (mm, right); the mean
//! deviations x̄↑ (red) and x̄↓ (blue) joined target to target, with x̄ ± 2s of each direction
//! as thin lines of the same colour (the band A is measured over), and the axis figures
//! A, B, R, E, M under the title.
//!
//! **Polar plot:** each direction's trace drawn at radius `ρ₀ + k·Δr` about the centre (ccw
//! red, cw blue): the nominal circle (grey) at ρ₀ and rings one division (a 1-2-5 step in µm)
//! inside and outside, so the deviations are magnified as ball-bar software shows them; the
//! scale, G of each direction and H are written under the title.
//!
//! **Rotary-axis trace:** the ISO 10791-6 deviation trace of a motion test, X (red), Y
//! (blue) and Z (green) in µm against the sample number, the sweeps one after another with
//! a grey line between them and each sweep's axis and range under the title.
//!
//! Drawing is sequential and deterministic: the same figures give the same pixels.

use super::render::{RenderError, draw_text, nice_ceil};
use crate::math::Real;
use crate::metrology::circular::{CircularFigures, Sample, Turn};
use crate::metrology::positioning::PositioningFigures;
use crate::metrology::rotary_test::{Sample as RotarySample, SweepFigures};
use image::{Rgb, RgbImage};

const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const GREY: Rgb<u8> = Rgb([170, 170, 170]);
const LIGHT: Rgb<u8> = Rgb([225, 225, 225]);
const RED: Rgb<u8> = Rgb([0xd6, 0x27, 0x28]);
const BLUE: Rgb<u8> = Rgb([0x1f, 0x5f, 0xb4]);
const SCALE: u32 = 2;
const LINE_H: u32 = 7 * SCALE + 8;

/// A straight line from (x0, y0) to (x1, y1) in pixels, `width` px wide (1 or 2).
fn line(
    img: &mut RgbImage,
    (x0, y0): (Real, Real),
    (x1, y1): (Real, Real),
    c: Rgb<u8>,
    width: u32,
) {
    if !(x0.is_finite() && y0.is_finite() && x1.is_finite() && y1.is_finite()) {
        return;
    }
    let n = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as usize).clamp(1, 100_000);
    for i in 0..=n {
        let t = i as Real / n as Real;
        let (x, y) = (x0 + t * (x1 - x0), y0 + t * (y1 - y0));
        for dx in 0..width {
            for dy in 0..width {
                let (px, py) = (x.round() + dx as Real, y.round() + dy as Real);
                if px >= 0.0
                    && py >= 0.0
                    && let Some(p) = img.get_pixel_mut_checked(px as u32, py as u32)
                {
                    *p = c;
                }
            }
        }
    }
}

/// Writes the lines of `text` from (x, y) down.
fn text_lines(img: &mut RgbImage, x: u32, y: u32, lines: &[String], c: Rgb<u8>) {
    for (i, l) in lines.iter().enumerate() {
        draw_text(img, x, y + i as u32 * LINE_H, l, SCALE, c);
    }
}

fn um(x: Real) -> String {
    format!("{:.3}", x * 1e3)
}

/// The ISO 230-2 bidirectional plot of `f` (see the module documentation).
pub fn positioning_plot(f: &PositioningFigures, title: &str) -> Result<RgbImage, RenderError> {
    if f.targets.is_empty() {
        return Err(RenderError::NoPoints);
    }
    let (w, h) = (900u32, 620u32);
    let header = vec![
        title.chars().take(70).collect::<String>(),
        format!(
            "A {} \u{b5}m  B {} \u{b5}m  R {} \u{b5}m  E {} \u{b5}m  M {} \u{b5}m",
            um(f.a),
            um(f.b),
            um(f.r),
            um(f.e),
            um(f.m)
        ),
        format!(
            "red: approach +, blue: approach -; thin: mean +/- 2s; {} runs",
            f.runs
        ),
    ];
    let top = 16 + header.len() as u32 * LINE_H + 8;
    let (left, right, bottom) = (110u32, w - 30, h - 50);
    let mut img = RgbImage::from_pixel(w, h, WHITE);
    text_lines(&mut img, 16, 16, &header, BLACK);
    // Extents.
    let (mut lo, mut hi) = (Real::INFINITY, Real::NEG_INFINITY);
    for t in &f.targets {
        for v in [
            t.mean_fwd + 2.0 * t.s_fwd,
            t.mean_fwd - 2.0 * t.s_fwd,
            t.mean_bwd + 2.0 * t.s_bwd,
            t.mean_bwd - 2.0 * t.s_bwd,
        ] {
            if !v.is_finite() {
                return Err(RenderError::NonFinite);
            }
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    let x_lo = f.targets[0].target;
    let x_hi = f.targets[f.targets.len() - 1].target;
    let span_x = (x_hi - x_lo).max(1e-9);
    let step = nice_ceil(((hi - lo) * 1e3 / 6.0).max(1e-6)); // µm per grid line
    let (y_lo, y_hi) = (
        (lo * 1e3 / step).floor() * step,
        (hi * 1e3 / step).ceil() * step,
    );
    let y_hi = if y_hi <= y_lo { y_lo + step } else { y_hi };
    let px = |x: Real| left as Real + (x - x_lo) / span_x * (right - left) as Real;
    let py =
        |v_mm: Real| bottom as Real - (v_mm * 1e3 - y_lo) / (y_hi - y_lo) * (bottom - top) as Real;
    // Grid and labels.
    let mut g = y_lo;
    while g <= y_hi + 1e-9 * step {
        let y = py(g * 1e-3);
        line(&mut img, (left as Real, y), (right as Real, y), LIGHT, 1);
        let label = format!("{g:+.3}");
        draw_text(
            &mut img,
            10,
            (y as u32).saturating_sub(7),
            &label,
            SCALE,
            BLACK,
        );
        g += step;
    }
    line(
        &mut img,
        (left as Real, top as Real),
        (left as Real, bottom as Real),
        BLACK,
        1,
    );
    line(
        &mut img,
        (left as Real, bottom as Real),
        (right as Real, bottom as Real),
        BLACK,
        1,
    );
    draw_text(&mut img, left + 8, top + 4, "\u{b5}m", SCALE, BLACK);
    for t in [x_lo, x_hi] {
        let label = format!("{t} mm");
        let x = (px(t) as u32).saturating_sub(if t == x_hi {
            6 * SCALE * label.len() as u32
        } else {
            0
        });
        draw_text(&mut img, x, bottom + 10, &label, SCALE, BLACK);
    }
    // Curves: ±2s thin, means thick.
    for (c, get) in [
        (
            RED,
            (|t: &crate::metrology::positioning::TargetFigures| (t.mean_fwd, t.s_fwd))
                as fn(&_) -> (Real, Real),
        ),
        (BLUE, |t| (t.mean_bwd, t.s_bwd)),
    ] {
        for k in [-2.0, 2.0, 0.0] {
            let width = if k == 0.0 { 2 } else { 1 };
            for pair in f.targets.windows(2) {
                let (a, b) = (get(&pair[0]), get(&pair[1]));
                line(
                    &mut img,
                    (px(pair[0].target), py(a.0 + k * a.1)),
                    (px(pair[1].target), py(b.0 + k * b.1)),
                    c,
                    width,
                );
            }
            if f.targets.len() == 1 {
                let a = get(&f.targets[0]);
                let x = px(f.targets[0].target);
                line(
                    &mut img,
                    (x - 4.0, py(a.0 + k * a.1)),
                    (x + 4.0, py(a.0 + k * a.1)),
                    c,
                    width,
                );
            }
        }
        for t in &f.targets {
            let (m, _) = get(t);
            let (x, y) = (px(t.target), py(m));
            line(&mut img, (x - 3.0, y - 3.0), (x + 3.0, y + 3.0), c, 1);
            line(&mut img, (x - 3.0, y + 3.0), (x + 3.0, y - 3.0), c, 1);
        }
    }
    Ok(img)
}

/// The ISO 230-4 polar plot of a trace `samples` evaluated as `f` (see the module
/// documentation).
pub fn polar_plot(
    samples: &[Sample],
    f: &CircularFigures,
    title: &str,
) -> Result<RgbImage, RenderError> {
    if samples.is_empty() {
        return Err(RenderError::NoPoints);
    }
    if samples
        .iter()
        .any(|s| !(s.angle_rad.is_finite() && s.deviation_mm.is_finite()))
    {
        return Err(RenderError::NonFinite);
    }
    let size = 720u32;
    let peak = samples
        .iter()
        .map(|s| s.deviation_mm.abs())
        .fold(0.0, Real::max)
        * 1e3;
    // One division: a 1-2-5 step of at least a third of the largest deviation.
    let div = nice_ceil((peak / 2.0).max(1e-4));
    let mut header = vec![
        title.chars().take(55).collect::<String>(),
        format!("radius {} mm; scale {} \u{b5}m/div", f.radius_mm, div),
    ];
    let g: Vec<String> = f
        .directions
        .iter()
        .map(|d| {
            format!(
                "{} G {} \u{b5}m",
                if d.direction == Turn::Ccw {
                    "ccw (red)"
                } else {
                    "cw (blue)"
                },
                um(d.g)
            )
        })
        .collect();
    let mut last = g.join("  ");
    if let Some(h) = f.h {
        last.push_str(&format!("  H {} \u{b5}m", um(h)));
    }
    header.push(last);
    let top = 16 + header.len() as u32 * LINE_H + 8;
    let (w, h) = (size, size + top);
    let mut img = RgbImage::from_pixel(w, h, WHITE);
    text_lines(&mut img, 16, 16, &header, BLACK);
    let (cx, cy) = (w as Real / 2.0, top as Real + size as Real / 2.0);
    let rho0 = size as Real * 0.30;
    let k = rho0 * 0.25 / div; // px per µm: one division is a quarter of ρ₀
    let at = |t: Real, d_um: Real| {
        let r = rho0 + k * d_um;
        (cx + r * t.cos(), cy - r * t.sin())
    };
    // Rings at −2 … +2 divisions, the nominal one darker; spokes every 45°.
    for ring in -2..=2 {
        let colour = if ring == 0 { GREY } else { LIGHT };
        let mut prev = at(0.0, ring as Real * div);
        for i in 1..=360 {
            let p = at((i as Real).to_radians(), ring as Real * div);
            line(&mut img, prev, p, colour, 1);
            prev = p;
        }
    }
    for s in 0..8 {
        let t = s as Real * std::f64::consts::FRAC_PI_4;
        line(&mut img, at(t, -2.0 * div), at(t, 2.0 * div), LIGHT, 1);
    }
    for (turn, c) in [(Turn::Ccw, RED), (Turn::Cw, BLUE)] {
        let mut pts: Vec<(Real, Real)> = samples
            .iter()
            .filter(|s| s.turn == turn)
            .map(|s| (s.angle_rad, s.deviation_mm * 1e3))
            .collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        // Close a full circle across 0°.
        if let (Some(&first), Some(&last)) = (pts.first(), pts.last())
            && first.0 + std::f64::consts::TAU - last.0 <= 10f64.to_radians()
        {
            pts.push((first.0 + std::f64::consts::TAU, first.1));
        }
        for pair in pts.windows(2) {
            // Do not join across a gap of more than 10° (a partial arc).
            if pair[1].0 - pair[0].0 > 10f64.to_radians() {
                continue;
            }
            line(
                &mut img,
                at(pair[0].0, pair[0].1),
                at(pair[1].0, pair[1].1),
                c,
                2,
            );
        }
    }
    draw_text(
        &mut img,
        (cx + rho0 + 2.0 * k * div + 6.0) as u32,
        cy as u32 - 7,
        "X",
        SCALE,
        BLACK,
    );
    draw_text(
        &mut img,
        cx as u32 - 5,
        (cy - rho0 - 2.0 * k * div - 22.0).max(0.0) as u32,
        "Y",
        SCALE,
        BLACK,
    );
    Ok(img)
}

const GREEN: Rgb<u8> = Rgb([0x2c, 0xa0, 0x2c]);

/// The deviation trace of a rotary-axis motion test (see the module documentation).
pub fn rotary_trace_plot(
    samples: &[RotarySample],
    sweeps: &[SweepFigures],
    title: &str,
) -> Result<RgbImage, RenderError> {
    if samples.is_empty() {
        return Err(RenderError::NoPoints);
    }
    let (w, h) = (900u32, 560u32);
    let mut header = vec![title.chars().take(70).collect::<String>()];
    header.push("red: X, blue: Y, green: Z deviation of the ball (\u{b5}m)".to_string());
    for f in sweeps.iter().take(6) {
        header.push(format!(
            "sweep {}: {} {} .. {} deg, ranges X {} Y {} Z {} \u{b5}m",
            f.sweep,
            f.axis,
            f.range_deg[0],
            f.range_deg[1],
            um(f.deviation_range_mm[0]),
            um(f.deviation_range_mm[1]),
            um(f.deviation_range_mm[2])
        ));
    }
    let top = 16 + header.len() as u32 * LINE_H + 8;
    let (left, right, bottom) = (110u32, w - 30, h - 40);
    let mut img = RgbImage::from_pixel(w, h, WHITE);
    text_lines(&mut img, 16, 16, &header, BLACK);
    let (mut lo, mut hi) = (Real::INFINITY, Real::NEG_INFINITY);
    for s in samples {
        for v in s.deviation_mm {
            if !v.is_finite() {
                return Err(RenderError::NonFinite);
            }
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    let step = nice_ceil(((hi - lo) * 1e3 / 6.0).max(1e-6));
    let (y_lo, y_hi) = (
        (lo * 1e3 / step).floor() * step,
        (hi * 1e3 / step).ceil() * step,
    );
    let y_hi = if y_hi <= y_lo { y_lo + step } else { y_hi };
    let n = samples.len().max(2) - 1;
    let px = |i: usize| left as Real + i as Real / n as Real * (right - left) as Real;
    let py =
        |v_mm: Real| bottom as Real - (v_mm * 1e3 - y_lo) / (y_hi - y_lo) * (bottom - top) as Real;
    let mut g = y_lo;
    while g <= y_hi + 1e-9 * step {
        let y = py(g * 1e-3);
        line(&mut img, (left as Real, y), (right as Real, y), LIGHT, 1);
        draw_text(
            &mut img,
            10,
            (y as u32).saturating_sub(7),
            &format!("{g:+.3}"),
            SCALE,
            BLACK,
        );
        g += step;
    }
    for (i, pair) in samples.windows(2).enumerate() {
        if pair[0].sweep != pair[1].sweep {
            let x = 0.5 * (px(i) + px(i + 1));
            line(&mut img, (x, top as Real), (x, bottom as Real), GREY, 1);
        }
    }
    line(
        &mut img,
        (left as Real, top as Real),
        (left as Real, bottom as Real),
        BLACK,
        1,
    );
    line(
        &mut img,
        (left as Real, bottom as Real),
        (right as Real, bottom as Real),
        BLACK,
        1,
    );
    draw_text(&mut img, left + 8, top + 4, "\u{b5}m", SCALE, BLACK);
    for (c, k) in [(RED, 0), (BLUE, 1), (GREEN, 2)] {
        for (i, pair) in samples.windows(2).enumerate() {
            if pair[0].sweep == pair[1].sweep {
                line(
                    &mut img,
                    (px(i), py(pair[0].deviation_mm[k])),
                    (px(i + 1), py(pair[1].deviation_mm[k])),
                    c,
                    2,
                );
            }
        }
        for (i, s) in samples.iter().enumerate() {
            let (x, y) = (px(i), py(s.deviation_mm[k]));
            line(&mut img, (x - 2.0, y), (x + 2.0, y), c, 1);
        }
    }
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrology::circular::{CircularOptions, evaluate};
    use crate::metrology::positioning::{Direction, Reading, evaluate as eval_pos};
    use std::path::Path;

    fn count(img: &RgbImage, c: Rgb<u8>) -> usize {
        img.pixels().filter(|p| **p == c).count()
    }

    #[test]
    fn positioning_plot_draws_both_directions_where_their_means_are() {
        // Forward runs 2 µm above backward runs everywhere.
        let mut r = Vec::new();
        for i in 0..5 {
            for run in 1..=5u32 {
                for (d, off) in [(Direction::Forward, 1e-3), (Direction::Backward, -1e-3)] {
                    r.push(Reading {
                        target_mm: 10.0 * i as Real,
                        direction: d,
                        run,
                        deviation_mm: off + 1e-4 * run as Real,
                    });
                }
            }
        }
        let f = eval_pos(&r, Path::new("t")).expect("complete");
        let img = positioning_plot(&f, "X axis").expect("draws");
        assert!(count(&img, RED) > 500 && count(&img, BLUE) > 500);
        // Red (above) has its mean line higher in the picture than blue.
        let mean_row = |c: Rgb<u8>| {
            let (mut sum, mut n) = (0u64, 0u64);
            for (_, y, p) in img.enumerate_pixels() {
                if *p == c {
                    sum += y as u64;
                    n += 1;
                }
            }
            sum as Real / n as Real
        };
        assert!(mean_row(RED) < mean_row(BLUE));
        let again = positioning_plot(&f, "X axis").expect("draws");
        assert_eq!(img.as_raw(), again.as_raw(), "deterministic");
    }

    #[test]
    fn polar_plot_puts_a_bulge_where_the_trace_has_it() {
        // +5 µm bulge around 0° (east) in ccw only, otherwise round.
        let s = crate::metrology::circular::bulge_trace();
        let opts = CircularOptions {
            radius_mm: 100.0,
            pitch_mm: None,
        };
        let f = evaluate(&s, &opts, Path::new("t")).expect("evaluates");
        let img = polar_plot(&s, &f, "XY").expect("draws");
        // On the row through the centre, east of it, the red trace lies outside the blue.
        let cy = img.height() - 360;
        let row: Vec<(u32, Rgb<u8>)> = (img.width() / 2..img.width())
            .map(|x| (x, *img.get_pixel(x, cy)))
            .collect();
        let last = |c: Rgb<u8>| row.iter().filter(|(_, p)| *p == c).map(|(x, _)| *x).max();
        assert!(last(RED).expect("red east") > last(BLUE).expect("blue east") + 5);
        assert!(polar_plot(&[], &f, "").is_err());
    }
}
