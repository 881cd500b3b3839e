//! What the `twinmill hexapod` commands tell the user: the amplification map as CSV and as a
//! PNG of two heat maps over the workspace's x–y grid (K_p and K_a, each cell the largest
//! value over the z levels and orientations sampled there, grey where no pose is reachable),
//! and the summary text of the amplification, homing and pivot commands.
//!
//! **Invariant:** formats and draws what the machine stage computed; no physics, no files.

use crate::machine::hexapod::Amplification;
use crate::machine::hexapod_accuracy::{
    AmplificationMap, LevelPositioning, PivotReport, Range, ResolutionBudget, SWITCH_BAND,
    StrutHoming, WrongIndex,
};
use crate::math::Real;
use crate::report::render::{RenderError, draw_text, height_colour};
use image::{Rgb, RgbImage};
use std::fmt::Write as _;

/// The map as CSV: one row per pose, `x,y,z,a,b,c,K_p,K_a,reachable` (mm, degrees, mm/mm,
/// °/mm; empty factors where the pose is unreachable).
pub fn amplification_csv(map: &AmplificationMap) -> String {
    let mut s = String::from(
        "x [mm],y [mm],z [mm],a [deg],b [deg],c [deg],K_p [mm/mm],K_a [deg/mm],reachable\n",
    );
    for m in &map.samples {
        let p = m.pose;
        let _ = write!(s, "{},{},{},{},{},{},", p[0], p[1], p[2], p[3], p[4], p[5]);
        let _ = match &m.factors {
            Some(f) => writeln!(
                s,
                "{:.6},{:.6},true",
                f.position_mm_per_mm, f.angle_deg_per_mm
            ),
            None => writeln!(s, ",,false"),
        };
    }
    s
}

const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const GREY: Rgb<u8> = Rgb([190, 190, 190]);
const MARGIN: u32 = 16;
const TEXT_H: u32 = 14;
const ADVANCE: u32 = 12;
const BAR_H: u32 = 16;

/// The two heat maps (K_p left, K_a right) over the x–y grid, y up.
pub fn amplification_png(map: &AmplificationMap, title: &str) -> Result<RgbImage, RenderError> {
    let [nx, ny, _] = map.steps;
    if map.samples.is_empty() || nx == 0 || ny == 0 {
        return Err(RenderError::NoPoints);
    }
    // Largest value per (x, y) cell over z and orientations.
    let mut cells = vec![[None::<Real>; 2]; nx * ny];
    for (k, s) in map.samples.iter().enumerate() {
        let c = k % (nx * ny);
        if let Some(f) = s.factors {
            for (slot, v) in cells[c]
                .iter_mut()
                .zip([f.position_mm_per_mm, f.angle_deg_per_mm])
            {
                if !v.is_finite() {
                    return Err(RenderError::NonFinite);
                }
                *slot = Some(slot.map_or(v, |o: Real| o.max(v)));
            }
        }
    }
    let cell = (360 / nx.max(ny) as u32).clamp(4, 48);
    let (pw, ph) = (nx as u32 * cell, ny as u32 * cell);
    let panel_w = pw.max(26 * ADVANCE);
    let plot_y = MARGIN + 2 * (TEXT_H + 6);
    let width = 3 * MARGIN + 2 * panel_w;
    let height = plot_y + ph + 8 + BAR_H + 6 + TEXT_H + MARGIN;
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    let title: String = title.chars().take(100).collect();
    draw_text(&mut img, MARGIN, MARGIN, &title, 2, BLACK);
    let ws = &map.workspace;
    let sub = format!(
        "x {}..{} mm, y {}..{} mm (max over z {}..{} mm, tilt +/-{} deg)",
        ws.x_mm.0, ws.x_mm.1, ws.y_mm.0, ws.y_mm.1, ws.z_mm.0, ws.z_mm.1, ws.tilt_deg
    );
    draw_text(&mut img, MARGIN, MARGIN + TEXT_H + 6, &sub, 1, BLACK);
    for (panel, (label, unit)) in [("K_p", "mm/mm"), ("K_a", "deg/mm")]
        .into_iter()
        .enumerate()
    {
        let x0 = MARGIN + panel as u32 * (panel_w + MARGIN);
        let values: Vec<Real> = cells.iter().filter_map(|c| c[panel]).collect();
        let range = Range::of(values.iter().copied());
        let (lo, hi) = range.map_or((0.0, 1.0), |r| (r.min, r.max));
        let span = if hi > lo { hi - lo } else { 1.0 };
        for j in 0..ny {
            for i in 0..nx {
                let colour =
                    cells[j * nx + i][panel].map_or(GREY, |v| height_colour((v - lo) / span));
                let (cx, cy) = (x0 + i as u32 * cell, plot_y + (ny - 1 - j) as u32 * cell);
                for y in cy..cy + cell {
                    for x in cx..cx + cell {
                        img.put_pixel(x, y, colour);
                    }
                }
            }
        }
        // Colour bar below the panel, low to high, with its ends labelled.
        let by = plot_y + ph + 8;
        for x in 0..pw {
            let c = height_colour(Real::from(x) / Real::from(pw.max(2) - 1));
            for y in by..by + BAR_H {
                img.put_pixel(x0 + x, y, c);
            }
        }
        let text = match range {
            Some(_) => format!("{label} {lo:.3}..{hi:.3} {unit}"),
            None => format!("{label}: no reachable pose"),
        };
        draw_text(&mut img, x0, by + BAR_H + 6, &text, 1, BLACK);
    }
    Ok(img)
}

fn range_text(r: Option<Range>, unit: &str) -> String {
    r.map_or("no reachable pose".into(), |r| {
        format!("{:.3} – {:.3} {unit}", r.min, r.max)
    })
}

/// The summary of `twinmill hexapod amplification`.
pub fn amplification_summary(
    scene: &str,
    map: &AmplificationMap,
    worst: Option<&Amplification>,
    budget: Option<&ResolutionBudget>,
    required: (Real, Real),
    drive_resolution_mm: Option<Real>,
) -> String {
    let mut s = format!(
        "twinmill: hexapod amplification on {scene}, nominal machine (the scene's [deviations] not used; {} poses, {} unreachable)\n",
        map.samples.len(),
        map.unreachable
    );
    let _ = writeln!(
        s,
        "  level         K_p {}, K_a {}",
        range_text(map.position_level, "mm/mm"),
        range_text(map.angle_level, "°/mm")
    );
    let _ = writeln!(
        s,
        "  tilted ±{}°  K_p {}, K_a {}",
        map.workspace.tilt_deg,
        range_text(map.position_tilted, "mm/mm"),
        range_text(map.angle_tilted, "°/mm")
    );
    if let (Some(w), Some(b)) = (worst, budget) {
        let _ = writeln!(
            s,
            "  general       K_p = {:.3} mm/mm, K_a = {:.3} °/mm (the largest values)",
            w.position_mm_per_mm, w.angle_deg_per_mm
        );
        let _ = writeln!(
            s,
            "  struts need   {:.6} mm for {} mm, {:.6} mm for {}°: resolution ≤ {:.6} mm",
            b.for_position_mm, required.0, b.for_angle_mm, required.1, b.required_mm
        );
        if let Some(d) = drive_resolution_mm {
            let _ = writeln!(
                s,
                "  drives        {:.6} mm per count: {} (output {:.6} mm, {:.6}°)",
                d,
                if d <= b.required_mm {
                    "enough"
                } else {
                    "NOT enough"
                },
                w.position_mm_per_mm * d,
                w.angle_deg_per_mm * d
            );
        }
    }
    s
}

/// The summary of `twinmill hexapod homing`.
pub fn homing_summary(
    scene: &str,
    lead_mm: Real,
    sigma_mm: Real,
    struts: &[StrutHoming],
    effects: &[WrongIndex],
) -> String {
    let mut s = format!(
        "twinmill: hexapod homing on {scene} (lead T = {lead_mm} mm, switch trip σ = {sigma_mm} mm)\n"
    );
    let _ = writeln!(
        s,
        "  strut   S (mm)   S/T    in {}–{}·T   margin (mm)   P(wrong index)",
        SWITCH_BAND.0, SWITCH_BAND.1
    );
    for h in struts {
        let _ = writeln!(
            s,
            "  {:>5}   {:>6.3}   {:>4.2}   {:<11}   {:>11.3}   {:.2e}",
            h.strut,
            h.switch_to_index_mm,
            h.fraction,
            if h.in_band { "yes" } else { "NO" },
            h.margin_mm,
            h.wrong_index_probability
        );
    }
    let _ = writeln!(s, "  a wrong index (one lead off) at the pose:");
    for e in effects {
        let _ = match (&e.position_error_mm, &e.angle_error_deg) {
            (Some(p), Some(a)) => writeln!(
                s,
                "    strut {} {:+}T: tool point off by {:.3} mm ({:+.3}, {:+.3}, {:+.3}), angles ({:+.3}, {:+.3}, {:+.3})°",
                e.strut,
                e.index_offset,
                e.position_error_norm_mm.unwrap_or(Real::NAN),
                p[0],
                p[1],
                p[2],
                a[0],
                a[1],
                a[2]
            ),
            _ => writeln!(
                s,
                "    strut {} {:+}T: no pose ({})",
                e.strut,
                e.index_offset,
                e.failure.as_deref().unwrap_or("")
            ),
        };
    }
    s
}

/// The summary of `twinmill hexapod pivot`.
pub fn pivot_summary(scene: &str, r: &PivotReport, level: Option<&LevelPositioning>) -> String {
    let p = r.point_mm;
    let mut s = format!(
        "twinmill: hexapod pivot on {scene} at ({}, {}, {}) mm, a and b over ±{}° ({} orientations)\n",
        p[0],
        p[1],
        p[2],
        r.tilt_deg,
        r.samples.len()
    );
    let _ = writeln!(
        s,
        "  pivot error   {:.4} mm (largest travel of the tip from where it is with the tool level)",
        r.pivot_error_mm
    );
    let _ = writeln!(
        s,
        "  tip error     {:.4} mm (largest distance from the commanded point)",
        r.max_deviation_mm
    );
    if let Some(l) = level {
        let at = l.at_mm;
        let _ = writeln!(
            s,
            "  level moves   {:.4} mm largest positioning error over {} workspace points (at {}, {}, {} mm; {} outside the workspace skipped)",
            l.max_error_mm, l.measured, at[0], at[1], at[2], l.skipped
        );
    }
    s
}
