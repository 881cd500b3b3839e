//! The report page's 2-D plots as SVG, drawn with `plotters` (SVG backend only: axes,
//! ticks, labels and series from a maintained plotting library rather than hand-placed
//! coordinates; its naive font metrics need no font files): the deviation map of a face or
//! a part ([`deviation_map_svg`]), the identifiability spectrum ([`spectrum_svg`]), and the
//! standards' plots, ISO 230-2's bidirectional positioning plot ([`positioning_svg`]) and
//! ISO 230-4's polar plot ([`polar_svg`]), ISO 10791-6's deviation trace of a rotary-axis
//! test ([`rotary_trace_svg`]) and a hexapod's resolution amplification maps
//! ([`amplification_svg`]) — the vector counterparts of [`crate::report::plots`] and
//! [`crate::report::hexapod`].
//!
//! A deviation map bins its points into at most [`MAX_CELLS`] × [`MAX_CELLS`] cells, each
//! showing the point of largest |deviation| in it (as the PNG maps do), so an SVG stays
//! small whatever the number of points.
//!
//! **Invariant:** deterministic text for the same input; non-finite input is an error,
//! never a drawing.

use crate::machine::hexapod_accuracy::AmplificationMap;
use crate::math::Real;
use crate::metrology::circular::{CircularFigures, Sample};
use crate::metrology::positioning::PositioningFigures;
use crate::metrology::rotary_test::Sample as RotarySample;
use crate::report::render::{diverging_colour, height_colour, nice_ceil};
use plotters::prelude::*;

/// Cells along the longer side of a deviation map.
pub const MAX_CELLS: usize = 120;

/// Why a plot could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum SvgError {
    /// Nothing to draw.
    #[error("no points to plot")]
    NoPoints,
    /// A value is NaN or infinite.
    #[error("non-finite value in a plot")]
    NonFinite,
    /// plotters failed.
    #[error("drawing the plot: {0}")]
    Draw(String),
}

fn draw_err(e: impl std::fmt::Display) -> SvgError {
    SvgError::Draw(e.to_string())
}

fn rgb(c: image::Rgb<u8>) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

/// Axis labels and title of a deviation map.
#[derive(Clone, Debug, PartialEq)]
pub struct MapLabels {
    /// Title.
    pub title: String,
    /// Horizontal axis (e.g. `x (mm)`).
    pub x: String,
    /// Vertical axis.
    pub y: String,
}

/// A deviation map: points `(x, y, deviation mm)` on a plane, binned (see the module docs)
/// and coloured ±`range_mm` with a colour bar in µm (mm from 1 mm).
pub fn deviation_map_svg(
    points: &[(Real, Real, Real)],
    range_mm: Real,
    labels: &MapLabels,
) -> Result<String, SvgError> {
    if points.is_empty() {
        return Err(SvgError::NoPoints);
    }
    let finite = points
        .iter()
        .all(|p| p.0.is_finite() && p.1.is_finite() && p.2.is_finite());
    if !finite || !range_mm.is_finite() || range_mm <= 0.0 {
        return Err(SvgError::NonFinite);
    }
    let (mut x0, mut x1, mut y0, mut y1) = (
        Real::INFINITY,
        Real::NEG_INFINITY,
        Real::INFINITY,
        Real::NEG_INFINITY,
    );
    for p in points {
        x0 = x0.min(p.0);
        x1 = x1.max(p.0);
        y0 = y0.min(p.1);
        y1 = y1.max(p.1);
    }
    let cell = ((x1 - x0).max(y1 - y0) / MAX_CELLS as Real).max(1e-6);
    let (nx, ny) = (
        ((x1 - x0) / cell).floor() as usize + 1,
        ((y1 - y0) / cell).floor() as usize + 1,
    );
    let mut best: Vec<Option<Real>> = vec![None; nx * ny];
    for p in points {
        let i = (((p.0 - x0) / cell) as usize).min(nx - 1);
        let j = (((p.1 - y0) / cell) as usize).min(ny - 1);
        let b = &mut best[j * nx + i];
        if b.is_none_or(|d| d.abs() < p.2.abs()) {
            *b = Some(p.2);
        }
    }
    let (unit, scale) = if range_mm >= 1.0 {
        ("mm", 1.0)
    } else {
        ("µm", 1000.0)
    };
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (760, 520)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let (left, right) = root.split_horizontally(640);
        let mut chart = ChartBuilder::on(&left)
            .caption(&labels.title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d(x0..x1 + cell, y0..y1 + cell)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(&labels.x)
            .y_desc(&labels.y)
            .draw()
            .map_err(draw_err)?;
        chart
            .draw_series(best.iter().enumerate().filter_map(|(k, b)| {
                let d = (*b)?;
                let (i, j) = ((k % nx) as Real, (k / nx) as Real);
                let (xa, ya) = (x0 + i * cell, y0 + j * cell);
                let c = rgb(diverging_colour(d / range_mm));
                Some(Rectangle::new(
                    [(xa, ya), (xa + cell, ya + cell)],
                    c.filled(),
                ))
            }))
            .map_err(draw_err)?;
        colour_bar(
            &right,
            ColourBar {
                range: (-range_mm * scale, range_mm * scale),
                steps: 64,
                margins: (50, 10),
                caption: Some(unit),
            },
            |t| diverging_colour(2.0 * t - 1.0),
        )?;
        root.present().map_err(draw_err)?;
    }
    Ok(s)
}

/// A colour bar's scale and layout.
struct ColourBar<'a> {
    /// The values at its bottom and top.
    range: (Real, Real),
    /// Bands drawn.
    steps: usize,
    /// Bottom and right margins (px; the top is 40).
    margins: (u32, u32),
    /// A caption above it (the unit).
    caption: Option<&'a str>,
}

/// Draws a colour bar on `area`: `bar.steps` bands from the bottom of `bar.range` to its
/// top, band k coloured by `colour` at its middle's fraction `(k + ½) / steps` of the
/// range, with five labels on the right.
fn colour_bar(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    bar: ColourBar<'_>,
    colour: impl Fn(Real) -> image::Rgb<u8>,
) -> Result<(), SvgError> {
    let (lo, hi) = bar.range;
    let mut builder = ChartBuilder::on(area);
    builder
        .margin_top(40)
        .margin_bottom(bar.margins.0)
        .margin_right(bar.margins.1)
        .right_y_label_area_size(60);
    if let Some(c) = bar.caption {
        builder.caption(c, ("sans-serif", 14));
    }
    let mut chart = builder
        .build_cartesian_2d(0.0..1.0, lo..hi)
        .map_err(draw_err)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(5)
        .draw()
        .map_err(draw_err)?;
    let n = bar.steps as Real;
    chart
        .draw_series((0..bar.steps).map(|k| {
            let k = k as Real;
            let (a, b) = (lo + (hi - lo) * k / n, lo + (hi - lo) * (k + 1.0) / n);
            Rectangle::new([(0.0, a), (1.0, b)], rgb(colour((k + 0.5) / n)).filled())
        }))
        .map_err(draw_err)?;
    Ok(())
}

/// The identifiability spectrum: the singular values, largest first, as bars on a log axis;
/// with a `threshold` of determination, a bar is dark when its direction is determined
/// (σᵢ ≥ threshold) and light when not, and the threshold is drawn as a line.
pub fn spectrum_svg(
    values: &[Real],
    threshold: Option<Real>,
    title: &str,
) -> Result<String, SvgError> {
    if values.is_empty() {
        return Err(SvgError::NoPoints);
    }
    if !values.iter().all(|v| v.is_finite() && *v >= 0.0)
        || threshold.is_some_and(|t| !(t.is_finite() && t > 0.0))
    {
        return Err(SvgError::NonFinite);
    }
    let positive = values.iter().copied().filter(|v| *v > 0.0);
    let hi = positive
        .clone()
        .chain(threshold)
        .fold(Real::MIN_POSITIVE, Real::max);
    let lo = positive.chain(threshold).fold(hi, Real::min);
    let (lo, hi) = (nice_ceil(lo) / 100.0, nice_ceil(hi) * 2.0);
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (640, 360)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let n = values.len();
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..n as Real, (lo..hi).log_scale())
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(n.min(12))
            .x_label_formatter(&|x| format!("{}", x.floor() as usize + 1))
            .x_desc("singular value, largest first")
            .y_label_formatter(&|y| format!("{y:.0e}"))
            .y_desc("singular value")
            .draw()
            .map_err(draw_err)?;
        let dark = RGBColor(0x21, 0x66, 0xac);
        let light = RGBColor(0xd1, 0xe5, 0xf0);
        chart
            .draw_series(values.iter().enumerate().map(|(i, &v)| {
                let c = if threshold.is_none_or(|t| v >= t) {
                    dark
                } else {
                    light
                };
                Rectangle::new(
                    [(i as Real + 0.15, lo), (i as Real + 0.85, v.max(lo))],
                    c.filled(),
                )
            }))
            .map_err(draw_err)?
            .label("determined")
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 10, y + 5)], dark.filled()));
        if let Some(t) = threshold {
            chart
                .draw_series([Rectangle::new([(0.0, lo), (0.0, lo)], light.filled())])
                .map_err(draw_err)?
                .label("not determined")
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 10, y + 5)], light.filled())
                });
            let red = RGBColor(0xb2, 0x18, 0x2b);
            chart
                .draw_series(LineSeries::new(
                    [(0.0, t), (n as Real, t)],
                    red.stroke_width(2),
                ))
                .map_err(draw_err)?
                .label(format!("threshold of determination {t}"))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 12, y)], red));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(s)
}

/// ISO 230-2's bidirectional plot as SVG: the mean positional deviations x̄↑ and x̄↓ and the
/// bands x̄ ± 2s of each direction against the target positions (µm).
pub fn positioning_svg(f: &PositioningFigures, title: &str) -> Result<String, SvgError> {
    if f.targets.is_empty() {
        return Err(SvgError::NoPoints);
    }
    let um = 1e3;
    let series = |g: &dyn Fn(&crate::metrology::positioning::TargetFigures) -> Real| {
        f.targets
            .iter()
            .map(|t| (t.target, g(t) * um))
            .collect::<Vec<_>>()
    };
    type Curve = (Vec<(Real, Real)>, RGBColor, &'static str);
    let curves: [Curve; 6] = [
        (series(&|t| t.mean_fwd), RGBColor(0xb2, 0x18, 0x2b), "x̄↑"),
        (series(&|t| t.mean_bwd), RGBColor(0x21, 0x66, 0xac), "x̄↓"),
        (
            series(&|t| t.mean_fwd + 2.0 * t.s_fwd),
            RGBColor(0xf4, 0xa5, 0x82),
            "x̄↑ ± 2s↑",
        ),
        (
            series(&|t| t.mean_fwd - 2.0 * t.s_fwd),
            RGBColor(0xf4, 0xa5, 0x82),
            "",
        ),
        (
            series(&|t| t.mean_bwd + 2.0 * t.s_bwd),
            RGBColor(0x92, 0xc5, 0xde),
            "x̄↓ ± 2s↓",
        ),
        (
            series(&|t| t.mean_bwd - 2.0 * t.s_bwd),
            RGBColor(0x92, 0xc5, 0xde),
            "",
        ),
    ];
    let all = curves.iter().flat_map(|c| c.0.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (
        Real::INFINITY,
        Real::NEG_INFINITY,
        Real::INFINITY,
        Real::NEG_INFINITY,
    );
    for &(x, y) in all {
        if !(x.is_finite() && y.is_finite()) {
            return Err(SvgError::NonFinite);
        }
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    let pad = ((y1 - y0) * 0.1).max(0.1);
    let xpad = ((x1 - x0) * 0.02).max(1e-3);
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (720, 440)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x0 - xpad..x1 + xpad, y0 - pad..y1 + pad)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc("target position (mm)")
            .y_desc("positional deviation (µm)")
            .draw()
            .map_err(draw_err)?;
        for (pts, colour, name) in &curves {
            let drawn = chart
                .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
                .map_err(draw_err)?;
            if !name.is_empty() {
                let c = *colour;
                drawn
                    .label(*name)
                    .legend(move |(x, y)| PathElement::new([(x, y), (x + 12, y)], c));
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(s)
}

/// ISO 230-4's polar plot as SVG: each direction's trace magnified about the nominal circle
/// (the deviation range spread over the plot's outer third), with the nominal circle.
pub fn polar_svg(samples: &[Sample], f: &CircularFigures, title: &str) -> Result<String, SvgError> {
    if samples.is_empty() {
        return Err(SvgError::NoPoints);
    }
    if !samples
        .iter()
        .all(|s| s.angle_rad.is_finite() && s.deviation_mm.is_finite())
    {
        return Err(SvgError::NonFinite);
    }
    let dmax = samples
        .iter()
        .map(|s| s.deviation_mm.abs())
        .fold(0.0, Real::max);
    let per_div_um = nice_ceil((dmax * 1e3 / 2.0).max(1e-3));
    // Radius 1 is the nominal circle; ±2 divisions span ±0.4.
    let k = 0.2 / (per_div_um * 1e-3);
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (560, 600)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(20)
            .build_cartesian_2d(-1.5..1.5, -1.5..1.5)
            .map_err(draw_err)?;
        let circle = |r: Real| {
            (0..=360).map(move |i| {
                let a = (i as Real).to_radians();
                (r * a.cos(), r * a.sin())
            })
        };
        for (r, c) in [
            (1.0, BLACK),
            (0.8, RGBColor(180, 180, 180)),
            (1.2, RGBColor(180, 180, 180)),
        ] {
            chart
                .draw_series(LineSeries::new(circle(r), c))
                .map_err(draw_err)?;
        }
        let dirs = [
            (
                crate::metrology::circular::Turn::Ccw,
                RGBColor(0xb2, 0x18, 0x2b),
                "ccw",
            ),
            (
                crate::metrology::circular::Turn::Cw,
                RGBColor(0x21, 0x66, 0xac),
                "cw",
            ),
        ];
        for (dir, colour, name) in dirs {
            let pts: Vec<(Real, Real)> = samples
                .iter()
                .filter(|s| s.turn == dir)
                .map(|s| {
                    let r = 1.0 + k * s.deviation_mm;
                    (r * s.angle_rad.cos(), r * s.angle_rad.sin())
                })
                .collect();
            if pts.is_empty() {
                continue;
            }
            chart
                .draw_series(LineSeries::new(pts, colour.stroke_width(2)))
                .map_err(draw_err)?
                .label(name)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 12, y)], colour));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(draw_err)?;
        let g = f
            .directions
            .iter()
            .map(|d| format!("G {:.2} µm", d.g * 1e3))
            .collect::<Vec<_>>()
            .join(", ");
        root.draw(&Text::new(
            format!(
                "radius {} mm, {per_div_um} µm per division; {g}",
                f.radius_mm
            ),
            (20, 575),
            ("sans-serif", 13),
        ))
        .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(s)
}

/// ISO 10791-6's deviation trace of a rotary-axis test as SVG: the X, Y and Z deviation of
/// the ball (µm) against the measurement's number, one line per sweep and coordinate,
/// sweeps separated by grey lines (the counterpart of
/// [`crate::report::plots::rotary_trace_plot`]).
pub fn rotary_trace_svg(samples: &[RotarySample], title: &str) -> Result<String, SvgError> {
    if samples.is_empty() {
        return Err(SvgError::NoPoints);
    }
    let (mut lo, mut hi) = (Real::INFINITY, Real::NEG_INFINITY);
    for s in samples {
        for v in s.deviation_mm {
            if !v.is_finite() {
                return Err(SvgError::NonFinite);
            }
            lo = lo.min(v * 1e3);
            hi = hi.max(v * 1e3);
        }
    }
    let pad = ((hi - lo) * 0.08).max(0.05);
    let n = samples.len() as Real;
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (760, 440)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..(n - 1.0).max(1.0), lo - pad..hi + pad)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc("measurement (in the order taken; grey lines separate the sweeps)")
            .y_desc("deviation of the ball (µm)")
            .draw()
            .map_err(draw_err)?;
        let grey = RGBColor(150, 150, 150);
        for (i, pair) in samples.windows(2).enumerate() {
            if pair[0].sweep != pair[1].sweep {
                let x = i as Real + 0.5;
                chart
                    .draw_series(LineSeries::new([(x, lo - pad), (x, hi + pad)], grey))
                    .map_err(draw_err)?;
            }
        }
        let colours = [
            (RGBColor(0xb2, 0x18, 0x2b), "X"),
            (RGBColor(0x21, 0x66, 0xac), "Y"),
            (RGBColor(0x2c, 0xa0, 0x2c), "Z"),
        ];
        for (k, (colour, name)) in colours.into_iter().enumerate() {
            let mut start = 0;
            let mut first = true;
            while start < samples.len() {
                let sweep = samples[start].sweep;
                let end = samples[start..]
                    .iter()
                    .position(|x| x.sweep != sweep)
                    .map_or(samples.len(), |p| start + p);
                let pts: Vec<(Real, Real)> = (start..end)
                    .map(|i| (i as Real, samples[i].deviation_mm[k] * 1e3))
                    .collect();
                let drawn = chart
                    .draw_series(LineSeries::new(pts, colour.stroke_width(2)))
                    .map_err(draw_err)?;
                if first {
                    drawn
                        .label(name)
                        .legend(move |(x, y)| PathElement::new([(x, y), (x + 12, y)], colour));
                    first = false;
                }
                start = end;
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(s)
}

/// A hexapod's resolution amplification maps as SVG: K_p (mm/mm) and K_a (°/mm) over the
/// x–y grid, each cell the largest value over z and the orientations, grey where no pose
/// is reachable, with a colour bar each (the counterpart of
/// [`crate::report::hexapod::amplification_png`]).
pub fn amplification_svg(map: &AmplificationMap, title: &str) -> Result<String, SvgError> {
    let [nx, ny, _] = map.steps;
    if map.samples.is_empty() || nx == 0 || ny == 0 {
        return Err(SvgError::NoPoints);
    }
    let mut cells = vec![[None::<Real>; 2]; nx * ny];
    for (k, smp) in map.samples.iter().enumerate() {
        if let Some(f) = smp.factors {
            for (slot, v) in cells[k % (nx * ny)]
                .iter_mut()
                .zip([f.position_mm_per_mm, f.angle_deg_per_mm])
            {
                if !v.is_finite() {
                    return Err(SvgError::NonFinite);
                }
                *slot = Some(slot.map_or(v, |o: Real| o.max(v)));
            }
        }
    }
    let ws = &map.workspace;
    let (x0, x1, y0, y1) = (ws.x_mm.0, ws.x_mm.1, ws.y_mm.0, ws.y_mm.1);
    let dx = if nx > 1 {
        (x1 - x0) / (nx - 1) as Real
    } else {
        1.0
    };
    let dy = if ny > 1 {
        (y1 - y0) / (ny - 1) as Real
    } else {
        1.0
    };
    if !(dx.is_finite() && dy.is_finite()) || dx <= 0.0 || dy <= 0.0 {
        return Err(SvgError::NonFinite);
    }
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (900, 480)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let root = root.titled(title, ("sans-serif", 16)).map_err(draw_err)?;
        let panels = root.split_evenly((1, 2));
        for (panel, (area, (label, unit))) in panels
            .iter()
            .zip([("K_p", "mm/mm"), ("K_a", "°/mm")])
            .enumerate()
        {
            let values: Vec<Real> = cells.iter().filter_map(|c| c[panel]).collect();
            let lo = values.iter().copied().fold(Real::INFINITY, Real::min);
            let hi = values.iter().copied().fold(Real::NEG_INFINITY, Real::max);
            let (lo, hi) = if values.is_empty() {
                (0.0, 1.0)
            } else {
                (lo, hi)
            };
            let span = if hi > lo { hi - lo } else { 1.0 };
            let (map_area, bar_area) = area.split_horizontally(area.dim_in_pixel().0 - 90);
            let caption = if values.is_empty() {
                format!("{label}: no reachable pose")
            } else {
                format!("{label} ({unit}), largest over z and tilt")
            };
            let mut chart = ChartBuilder::on(&map_area)
                .caption(caption, ("sans-serif", 14))
                .margin(8)
                .x_label_area_size(36)
                .y_label_area_size(50)
                .build_cartesian_2d(x0 - dx / 2.0..x1 + dx / 2.0, y0 - dy / 2.0..y1 + dy / 2.0)
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("x (mm)")
                .y_desc("y (mm)")
                .draw()
                .map_err(draw_err)?;
            chart
                .draw_series(cells.iter().enumerate().map(|(k, c)| {
                    let (i, j) = ((k % nx) as Real, (k / nx) as Real);
                    let (cx, cy) = (x0 + i * dx, y0 + j * dy);
                    let colour = c[panel].map_or(RGBColor(190, 190, 190), |v| {
                        rgb(height_colour((v - lo) / span))
                    });
                    Rectangle::new(
                        [
                            (cx - dx / 2.0, cy - dy / 2.0),
                            (cx + dx / 2.0, cy + dy / 2.0),
                        ],
                        colour.filled(),
                    )
                }))
                .map_err(draw_err)?;
            colour_bar(
                &bar_area,
                ColourBar {
                    range: (lo, lo + span),
                    steps: 48,
                    margins: (44, 8),
                    caption: None,
                },
                height_colour,
            )?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_deviation_map_is_binned_and_coloured() {
        let pts: Vec<(Real, Real, Real)> = (0..20_000)
            .map(|k| {
                let (x, y) = ((k % 200) as Real * 0.2, (k / 200) as Real * 0.2);
                (x, y, if y < 10.0 { 0.5 } else { -0.5 })
            })
            .collect();
        let labels = MapLabels {
            title: "faces".into(),
            x: "x (mm)".into(),
            y: "z (mm)".into(),
        };
        let s = deviation_map_svg(&pts, 0.5, &labels).unwrap();
        assert!(s.starts_with("<svg"));
        // Both end colours appear; the cells are far fewer than the points.
        assert!(s.contains("#67001F") || s.contains("#67001f"), "dark red");
        assert!(s.contains("#053061"), "dark blue");
        assert!(s.matches("<rect").count() < 121 * 121 + 100);
        assert_eq!(s, deviation_map_svg(&pts, 0.5, &labels).unwrap());
        assert!(matches!(
            deviation_map_svg(&[(0.0, Real::NAN, 0.0)], 0.5, &labels),
            Err(SvgError::NonFinite)
        ));
        assert!(matches!(
            deviation_map_svg(&[], 0.5, &labels),
            Err(SvgError::NoPoints)
        ));
    }

    /// The points of every polyline of more than two points drawn in `colour` (plotters
    /// writes `stroke="#RRGGBB"`; the legend's two-point samples are left out).
    fn polylines(svg: &str, colour: &str) -> Vec<(f64, f64)> {
        svg.split("<polyline")
            .skip(1)
            .filter(|e| e.to_uppercase().contains(&format!("STROKE=\"{colour}\"")))
            .filter_map(|e| e.split("points=\"").nth(1)?.split('"').next())
            .map(|pts| {
                pts.split_whitespace()
                    .filter_map(|xy| {
                        let (x, y) = xy.split_once(',')?;
                        Some((x.parse().ok()?, y.parse().ok()?))
                    })
                    .collect::<Vec<(f64, f64)>>()
            })
            .filter(|line| line.len() > 2)
            .flatten()
            .collect()
    }

    #[test]
    fn the_positioning_svg_draws_forward_above_backward() {
        use crate::metrology::positioning::{Direction, Reading, evaluate};
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
        let f = evaluate(&r, std::path::Path::new("t")).expect("complete");
        let s = positioning_svg(&f, "X axis").expect("draws");
        let (red, blue) = (polylines(&s, "#B2182B"), polylines(&s, "#2166AC"));
        assert!(red.len() >= 5 && blue.len() >= 5);
        let mean_y = |v: &[(f64, f64)]| v.iter().map(|p| p.1).sum::<f64>() / v.len() as f64;
        // SVG y runs down: the forward mean (2 µm higher) is drawn above the backward one.
        assert!(mean_y(&red) < mean_y(&blue));
        assert_eq!(s, positioning_svg(&f, "X axis").unwrap());
    }

    #[test]
    fn the_polar_svg_puts_a_bulge_where_the_trace_has_it() {
        use crate::metrology::circular::{CircularOptions, evaluate};
        let s = crate::metrology::circular::bulge_trace();
        let opts = CircularOptions {
            radius_mm: 100.0,
            pitch_mm: None,
        };
        let f = evaluate(&s, &opts, std::path::Path::new("t")).expect("evaluates");
        let svg = polar_svg(&s, &f, "XY").expect("draws");
        // East of the centre the ccw trace (red) reaches further out than the cw one.
        let east = |v: &[(f64, f64)]| v.iter().map(|p| p.0).fold(f64::MIN, f64::max);
        let (red, blue) = (polylines(&svg, "#B2182B"), polylines(&svg, "#2166AC"));
        assert!(
            east(&red) > east(&blue) + 5.0,
            "{} vs {}",
            east(&red),
            east(&blue)
        );
        assert!(polar_svg(&[], &f, "XY").is_err());
    }

    #[test]
    fn the_rotary_trace_draws_each_coordinate_where_its_values_are() {
        // Two sweeps: X rises 0 → 10 µm, Y stays 0, Z stays −5 µm.
        let s: Vec<RotarySample> = (0..20)
            .map(|i| RotarySample {
                sweep: 1 + i / 10,
                axis: 'C',
                angle_deg: (i % 10) as Real * 30.0,
                q: Default::default(),
                deviation_mm: [i as Real * 10e-3 / 19.0, 0.0, -5e-3],
                sigma_mm: [1e-4; 3],
            })
            .collect();
        let svg = rotary_trace_svg(&s, "trace").expect("draws");
        let (x, y, z) = (
            polylines(&svg, "#B2182B"),
            polylines(&svg, "#2166AC"),
            polylines(&svg, "#2CA02C"),
        );
        // One line per sweep and coordinate: 10 points each.
        assert_eq!((x.len(), y.len(), z.len()), (20, 20, 20));
        let mean_y = |v: &[(f64, f64)]| v.iter().map(|p| p.1).sum::<f64>() / v.len() as f64;
        // SVG y runs down: Z (−5 µm) below Y (0), X's last point (10 µm) above its first.
        assert!(mean_y(&z) > mean_y(&y) + 10.0);
        assert!(x[19].1 < x[0].1 - 50.0, "{:?} {:?}", x[0], x[19]);
        assert_eq!(svg, rotary_trace_svg(&s, "trace").unwrap());
        assert!(rotary_trace_svg(&[], "t").is_err());
    }

    #[test]
    fn the_amplification_maps_grey_the_unreachable_cells() {
        use crate::machine::hexapod::Amplification;
        use crate::machine::hexapod_accuracy::{MapSample, Workspace};
        let samples: Vec<MapSample> = (0..6)
            .map(|k| MapSample {
                pose: [k as Real, 0.0, 0.0, 0.0, 0.0, 0.0],
                factors: (k != 5).then_some(Amplification {
                    position_mm_per_mm: 1.0 + k as Real,
                    angle_deg_per_mm: 0.5,
                }),
                unreachable: (k == 5).then(|| "stroke".to_string()),
            })
            .collect();
        let map = AmplificationMap {
            workspace: Workspace {
                x_mm: (0.0, 20.0),
                y_mm: (0.0, 10.0),
                z_mm: (0.0, 0.0),
                tilt_deg: 0.0,
            },
            steps: [3, 2, 1],
            samples,
            position_level: None,
            angle_level: None,
            position_tilted: None,
            angle_tilted: None,
            unreachable: 1,
        };
        let svg = amplification_svg(&map, "K").expect("draws");
        // The unreachable cell is grey in both maps; the K_p map's ends are the height
        // colours of 0 and 1.
        assert_eq!(
            svg.to_uppercase().matches("FILL=\"#BEBEBE\"").count(),
            2,
            "grey cells"
        );
        for end in [height_colour(0.0), height_colour(1.0)] {
            let hex = format!("#{:02X}{:02X}{:02X}", end[0], end[1], end[2]);
            assert!(svg.to_uppercase().contains(&hex), "{hex}");
        }
        let mut bad = map.clone();
        bad.samples.clear();
        assert!(amplification_svg(&bad, "K").is_err());
    }

    #[test]
    fn the_spectrum_marks_what_is_determined() {
        let s = spectrum_svg(&[200.0, 40.0, 1e-3], Some(10.0), "spectrum").unwrap();
        assert!(s.contains("#2166AC") || s.contains("#2166ac"));
        assert!(s.contains("#D1E5F0") || s.contains("#d1e5f0"));
        assert!(s.contains("determined"));
        assert!(s.contains("not determined"));
        assert!(spectrum_svg(&[Real::NAN], None, "x").is_err());
        assert!(spectrum_svg(&[1.0], Some(0.0), "x").is_err());
    }
}
