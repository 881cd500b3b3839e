//! The deviation map: how far the cut part's surface is from a design model.
//!
//! The part's surface points are the tri-dexel's crossings (exact points of the cut surface,
//! all three grids). For each, the signed distance to the design model's surface: its
//! magnitude is the distance to the closest point of the design mesh (parry3d point
//! projection), its sign comes from the design's robust winding-number inside test
//! ([`ClosedMesh::contains`]): **positive = the part point lies outside the design = material
//! left; negative = inside = a gouge**. The report gives max, min, mean and RMS; the picture
//! is a top view (x right, y up), each point a square one point spacing wide, each pixel
//! showing the point of largest |distance| covering it (anywhere in that column of the part), in the diverging colours of [`crate::report::render`], with a colour bar labelled in µm
//! (or mm when the range reaches 1 mm).
//!
//! Accuracy: crossings lie on the cut surface to rounding, and the design mesh is exact for
//! planar designs; on a curved design its chords add up to h²κ/8 of tessellation error.
//!
//! **Invariant:** reads the stock and the design only; deterministic for any thread count
//! (fixed chunks joined in order); never touches files.

use crate::cutting::shape::ClosedMesh;
use crate::cutting::stock::TriDexel;
use crate::math::{Point3, Real, Vector3};
use crate::report::render::{RenderError, diverging_colour, draw_text, nice_ceil};
use image::{Rgb, RgbImage};
use parry3d_f64::query::PointQuery;
use rayon::prelude::*;

/// Points per parallel chunk (fixed, so results do not depend on the thread count).
const CHUNK: usize = 4096;

/// Errors of the deviation map.
#[derive(Debug, thiserror::Error)]
pub enum DeviationError {
    /// parry3d refused the design mesh.
    #[error("the design mesh cannot be used for distance queries")]
    BadDesign,
    /// The part has no surface points.
    #[error("the part has no surface points")]
    NoPoints,
}

/// A design model: a closed mesh with its distance structure.
#[derive(Clone)]
pub struct DesignModel {
    mesh: ClosedMesh,
    shape: parry3d_f64::shape::TriMesh,
}

impl std::fmt::Debug for DesignModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DesignModel")
            .field("triangles", &self.mesh.triangles().len())
            .finish()
    }
}

impl DesignModel {
    /// The design model of a closed mesh (mm, workpiece frame).
    pub fn try_new(mesh: ClosedMesh) -> Result<Self, DeviationError> {
        let shape = mesh.to_parry().ok_or(DeviationError::BadDesign)?;
        Ok(Self { mesh, shape })
    }

    /// The design's closed mesh.
    pub fn mesh(&self) -> &ClosedMesh {
        &self.mesh
    }

    /// Signed distance of `p` to the design surface (mm): positive outside (material left
    /// on a part), negative inside (a gouge).
    pub fn signed_distance(&self, p: &Point3) -> Real {
        let proj = self.shape.project_local_point(p, false);
        let d = (p - proj.point).norm();
        if self.mesh.contains(p) { -d } else { d }
    }
}

/// One surface point of the part with its deviation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeviationPoint {
    /// Position (mm, W).
    pub point: Point3,
    /// Outward normal of the part there.
    pub normal: Vector3,
    /// NC line that made the surface (0 = stock face).
    pub line: u32,
    /// Signed distance to the design (mm): + material left, − gouge.
    pub distance_mm: Real,
}

/// Summary of a deviation map (mm).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DeviationReport {
    /// Number of surface points.
    pub points: usize,
    /// Largest signed distance (most material left).
    pub max_mm: Real,
    /// Smallest signed distance (deepest gouge if negative).
    pub min_mm: Real,
    /// Mean signed distance.
    pub mean_mm: Real,
    /// Root mean square of the signed distances.
    pub rms_mm: Real,
    /// Where the maximum is (W).
    pub at_max: [Real; 3],
    /// Where the minimum is (W).
    pub at_min: [Real; 3],
    /// The NC line that made the surface where the maximum is (0: an uncut stock face).
    pub line_at_max: u32,
    /// The NC line that made the surface where the minimum is.
    pub line_at_min: u32,
}

/// The deviation of every crossing of `stock` from `design`, and its summary.
pub fn deviation_map(
    stock: &TriDexel,
    design: &DesignModel,
) -> Result<(Vec<DeviationPoint>, DeviationReport), DeviationError> {
    let mut raw = Vec::new();
    for g in stock.grids() {
        g.for_each_crossing(|p, c| raw.push((p, c.normal(), c.line)));
    }
    if raw.is_empty() {
        return Err(DeviationError::NoPoints);
    }
    let points: Vec<DeviationPoint> = raw
        .par_chunks(CHUNK)
        .flat_map_iter(|chunk| {
            chunk.iter().map(|&(point, normal, line)| DeviationPoint {
                point,
                normal,
                line,
                distance_mm: design.signed_distance(&point),
            })
        })
        .collect();
    let (mut sum, mut sum2) = (0.0, 0.0);
    let (mut imax, mut imin) = (0, 0);
    for (i, p) in points.iter().enumerate() {
        sum += p.distance_mm;
        sum2 += p.distance_mm * p.distance_mm;
        if p.distance_mm > points[imax].distance_mm {
            imax = i;
        }
        if p.distance_mm < points[imin].distance_mm {
            imin = i;
        }
    }
    let n = points.len() as Real;
    let at = |i: usize| {
        let p = points[i].point;
        [p.x, p.y, p.z]
    };
    let report = DeviationReport {
        points: points.len(),
        max_mm: points[imax].distance_mm,
        min_mm: points[imin].distance_mm,
        mean_mm: sum / n,
        rms_mm: (sum2 / n).sqrt(),
        at_max: at(imax),
        at_min: at(imin),
        line_at_max: points[imax].line,
        line_at_min: points[imin].line,
    };
    Ok((points, report))
}

/// Options of the deviation picture.
///
/// * `width_px`, `height_px`: size of the whole image (px), each clamped to
///   [`MIN_SIZE_PX`] ..= [`MAX_SIZE_PX`]; the top view keeps its aspect ratio inside.
/// * `point_pitch_mm`: spacing of the points (mm, finite; ≤ 0 draws single pixels).
/// * `range_mm`: symmetric colour range ±range (mm, finite, > 0); `None`: the largest
///   |distance| rounded up to a 1-2-5 step.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviationImageOptions {
    /// Title line (printable ASCII and µ).
    pub title: String,
    /// Image width (px).
    pub width_px: u32,
    /// Image height (px).
    pub height_px: u32,
    /// Colour range (mm); `None` = automatic.
    pub range_mm: Option<Real>,
    /// Spacing of the points (mm, e.g. the stock's largest ray spacing): each point fills a
    /// square of that side (1 to [`MAX_DOT_PX`] px).
    pub point_pitch_mm: Real,
}

/// Largest dot side (px).
pub const MAX_DOT_PX: u32 = 64;

/// Smallest image side (px).
pub const MIN_SIZE_PX: u32 = 200;
/// Largest image side (px).
pub const MAX_SIZE_PX: u32 = 8192;

const FONT_SCALE: u32 = 2;
const TEXT_H: u32 = 7 * FONT_SCALE;
const ADVANCE: u32 = 6 * FONT_SCALE;
const MARGIN: u32 = 16;
const BAR_W: u32 = 24;
/// Room right of the plot: gap, bar, tick and a 7-character label.
const LEGEND_W: u32 = 24 + BAR_W + 6 + 4 + 7 * ADVANCE;
const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);

/// Formats a tick value in the legend's unit: "0" or a signed number without trailing zeros.
fn tick_label(x: Real) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let s = format!("{:.3}", x.abs());
    let s = s.trim_end_matches('0').trim_end_matches('.');
    format!("{}{s}", if x > 0.0 { '+' } else { '-' })
}

/// Renders the top view of `points` coloured by signed distance (see the module docs).
pub fn render_deviation_map(
    points: &[DeviationPoint],
    opts: &DeviationImageOptions,
) -> Result<RgbImage, RenderError> {
    if points.is_empty() {
        return Err(RenderError::NoPoints);
    }
    let finite = points
        .iter()
        .all(|p| p.point.coords.iter().all(|c| c.is_finite()) && p.distance_mm.is_finite());
    if !finite || opts.range_mm.is_some_and(|r| !r.is_finite()) || !opts.point_pitch_mm.is_finite()
    {
        return Err(RenderError::NonFinite);
    }
    let (w, h) = (
        opts.width_px.clamp(MIN_SIZE_PX, MAX_SIZE_PX),
        opts.height_px.clamp(MIN_SIZE_PX, MAX_SIZE_PX),
    );
    let dmax = points
        .iter()
        .map(|p| p.distance_mm.abs())
        .fold(0.0, Real::max);
    let range_mm = match opts.range_mm {
        Some(r) if r > 0.0 => r,
        _ => nice_ceil(dmax * 1000.0) / 1000.0,
    };
    let (unit, scale) = if range_mm >= 1.0 {
        ("mm", 1.0)
    } else {
        ("\u{b5}m", 1000.0)
    };
    let (mut x0, mut x1, mut y0, mut y1) = (
        Real::INFINITY,
        Real::NEG_INFINITY,
        Real::INFINITY,
        Real::NEG_INFINITY,
    );
    for p in points {
        x0 = x0.min(p.point.x);
        x1 = x1.max(p.point.x);
        y0 = y0.min(p.point.y);
        y1 = y1.max(p.point.y);
    }
    // Plot box: below the title, above the footer, left of the legend.
    let top = MARGIN + TEXT_H + 12;
    let avail_w = w - 2 * MARGIN - LEGEND_W;
    let avail_h = h - top - (12 + TEXT_H + MARGIN);
    let span = |a: Real, b: Real| (b - a).max(Real::MIN_POSITIVE);
    let mm_per_px =
        (span(x0, x1) / Real::from(avail_w - 1)).max(span(y0, y1) / Real::from(avail_h - 1));
    let plot_w = ((x1 - x0) / mm_per_px).round() as u32 + 1;
    let plot_h = ((y1 - y0) / mm_per_px).round() as u32 + 1;
    let mut img = RgbImage::from_pixel(w, h, WHITE);
    // Per pixel, the point of largest |distance| (ties: the earlier point).
    let mut best: Vec<Option<usize>> = vec![None; (plot_w * plot_h) as usize];
    let dot = ((opts.point_pitch_mm.max(0.0) / mm_per_px).round() as u32).clamp(1, MAX_DOT_PX);
    for (i, p) in points.iter().enumerate() {
        let ix = (((p.point.x - x0) / mm_per_px).round() as u32).min(plot_w - 1);
        let iy = (((y1 - p.point.y) / mm_per_px).round() as u32).min(plot_h - 1);
        let (xa, ya) = (
            ix.saturating_sub((dot - 1) / 2),
            iy.saturating_sub((dot - 1) / 2),
        );
        for y in ya..(ya + dot).min(plot_h) {
            for x in xa..(xa + dot).min(plot_w) {
                let cell = &mut best[(y * plot_w + x) as usize];
                if cell.is_none_or(|j| points[j].distance_mm.abs() < p.distance_mm.abs()) {
                    *cell = Some(i);
                }
            }
        }
    }
    for (k, b) in best.iter().enumerate() {
        if let Some(i) = b {
            let (ix, iy) = (k as u32 % plot_w, k as u32 / plot_w);
            img.put_pixel(
                MARGIN + ix,
                top + iy,
                diverging_colour(points[*i].distance_mm / range_mm),
            );
        }
    }
    // Colour bar: +range at the top.
    let bar_x = MARGIN + avail_w + 24;
    let bar_y = top + TEXT_H + 8;
    let bar_h = avail_h - TEXT_H - 8 - TEXT_H / 2;
    for y in 0..bar_h {
        let f = 1.0 - 2.0 * Real::from(y) / Real::from(bar_h - 1);
        for x in 0..BAR_W {
            img.put_pixel(bar_x + x, bar_y + y, diverging_colour(f));
        }
    }
    for f in [-1.0, -0.5, 0.0, 0.5, 1.0] {
        let y = bar_y + ((1.0 - f) * 0.5 * Real::from(bar_h - 1)).round() as u32;
        for x in 0..6 {
            img.put_pixel(bar_x + BAR_W + x, y, BLACK);
        }
        let label = tick_label(f * range_mm * scale);
        draw_text(
            &mut img,
            bar_x + BAR_W + 10,
            y.saturating_sub(TEXT_H / 2),
            &label,
            FONT_SCALE,
            BLACK,
        );
    }
    draw_text(&mut img, bar_x, top, unit, FONT_SCALE, BLACK);
    draw_text(&mut img, MARGIN, MARGIN, &opts.title, FONT_SCALE, BLACK);
    let footer = format!(
        "top view  x {x0:.1}..{x1:.1} mm  y {y0:.1}..{y1:.1} mm  n={}",
        points.len()
    );
    draw_text(
        &mut img,
        MARGIN,
        h - MARGIN - TEXT_H,
        &footer,
        FONT_SCALE,
        BLACK,
    );
    Ok(img)
}
