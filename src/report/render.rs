//! PNG heat maps of scanned faces.
//!
//! Each point is projected onto two in-plane axes (`u` to the right, `v` up) and drawn as a
//! filled square coloured by its signed distance from a nominal plane, with a diverging
//! colour map (ColorBrewer "RdBu" reversed: blue below the plane, near-white on it, red
//! above). A vertical colour bar labelled in µm sits right of the plot, a title above it
//! and the plot's mm extent below. Text uses a built-in 5×7 bitmap font drawn at 2×.
//!
//! Rendering is sequential and deterministic: points are drawn in input order and a pixel
//! covered by several points shows the last one drawn.

use crate::cutting::stock::TriDexel;
use crate::math::{Point3, Real, UnitVector3, Vector3, tol};
use crate::metrology::fit::Plane;
use image::{Rgb, RgbImage};

/// Options of a heat map. (Document units and ranges.)
///
/// * `title`: text of the title line (printable ASCII and `µ`; other characters show as
///   `?`; at most [`MAX_TITLE_CHARS`] characters are drawn).
/// * `width_px`: width of the plot area in pixels, clamped to [`MIN_WIDTH_PX`] ..=
///   [`MAX_WIDTH_PX`] (800 is a good default). The plot height follows the aspect ratio of the data extent, at most [`MAX_PLOT_HEIGHT`]
///   pixels (the width shrinks instead when the data are tall).
/// * `point_pitch_mm`: nominal spacing of the points (mm, finite; negative counts as 0);
///   each point is drawn as a square of side max(1, round(pitch / pixel size)) pixels, at most [`MAX_DOT_PX`].
/// * `range_um`: symmetric colour range ±range (µm, finite); values beyond it are clamped
///   to the end colours. `None` (or a value ≤ 0): the largest |distance| rounded up to a
///   1-2-5 step (1 µm for a perfectly flat face).
#[derive(Clone, Debug, PartialEq)]
pub struct HeatMapOptions {
    /// Title line.
    pub title: String,
    /// Plot area width (px), clamped to [`MIN_WIDTH_PX`] ..= [`MAX_WIDTH_PX`].
    pub width_px: u32,
    /// Nominal spacing of the points (mm); sets the dot size.
    pub point_pitch_mm: Real,
    /// Symmetric colour range ±range (µm); `None` (or ≤ 0) = automatic 1-2-5 step.
    pub range_um: Option<Real>,
}

/// Why a heat map could not be drawn or encoded.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// No points to draw.
    #[error("no points to draw")]
    NoPoints,
    /// A point, the plane, an axis, `point_pitch_mm` or `range_um` is not finite.
    #[error("non-finite point, plane or axis")]
    NonFinite,
    /// PNG encoding failed.
    #[error("PNG encoding failed: {0}")]
    Encode(String),
}

/// Light direction of the top view (towards the light, W frame): from the upper left, so
/// walls facing −x and +y are lit and a step reads as a bright or dark line.
const LIGHT: [Real; 3] = [-0.4, 0.4, 0.82];
/// Smallest top-view width (px): small stocks are magnified by an integer factor.
const TOP_VIEW_MIN_PX: usize = 480;

/// Renders the cut stock seen from +z: one square per z-dexel ray, coloured by the height of
/// its top crossing (dark blue at the lowest, yellow at the highest) and shaded by the
/// crossing's normal (Lambert, light from the upper left). Rays with no material are light
/// grey. A colour bar labelled in mm is drawn on the right and `title` above.
pub fn render_top_view(stock: &TriDexel, title: &str) -> Result<RgbImage, RenderError> {
    let grid = &stock.grids()[2];
    let (nu, nv) = grid.dims();
    if nu == 0 || nv == 0 {
        return Err(RenderError::NoPoints);
    }
    let top = |iu: usize, iv: usize| grid.ray(iu, iv).last().map(|s| s.hi);
    let (mut zmin, mut zmax) = (Real::INFINITY, Real::NEG_INFINITY);
    for iv in 0..nv {
        for iu in 0..nu {
            if let Some(c) = top(iu, iv) {
                if !c.t.is_finite() {
                    return Err(RenderError::NonFinite);
                }
                zmin = zmin.min(c.t);
                zmax = zmax.max(c.t);
            }
        }
    }
    if !zmin.is_finite() {
        return Err(RenderError::NoPoints);
    }
    // A flat top (one height) is drawn in the middle colour.
    let level = |z: Real| {
        if zmax - zmin > tol::LENGTH_EPS {
            (z - zmin) / (zmax - zmin)
        } else {
            0.5
        }
    };
    let k = TOP_VIEW_MIN_PX.div_ceil(nu).clamp(1, MAX_DOT_PX as usize) as u32;
    let (w, h) = (nu as u32 * k, nv as u32 * k);
    let bar_x = PLOT_X0 + w + BAR_GAP;
    let width = bar_x + BAR_W + TICK + 4 + 8 * ADVANCE + MARGIN;
    let height = PLOT_Y0 + h.max(MIN_BAR_H) + TEXT_H + 2 * MARGIN;
    let mut img = RgbImage::from_pixel(width, height, Rgb([255, 255, 255]));
    draw_text(&mut img, MARGIN, MARGIN, title, SCALE, Rgb([0, 0, 0]));
    let light = Vector3::new(LIGHT[0], LIGHT[1], LIGHT[2]).normalize();
    for iv in 0..nv {
        for iu in 0..nu {
            let colour = match top(iu, iv) {
                None => Rgb([225, 225, 225]),
                Some(c) => {
                    let shade = 0.35 + 0.65 * c.normal().dot(&light).max(0.0);
                    let Rgb(base) = height_colour(level(c.t));
                    Rgb(base.map(|b| (b as Real * shade).round().clamp(0.0, 255.0) as u8))
                }
            };
            // Image rows run down; v (y in W) runs up.
            let (x0, y0) = (PLOT_X0 + iu as u32 * k, PLOT_Y0 + (nv - 1 - iv) as u32 * k);
            for dy in 0..k {
                for dx in 0..k {
                    put(&mut img, x0 + dx, y0 + dy, colour);
                }
            }
        }
    }
    frame_rect(
        &mut img,
        PLOT_X0 - 1,
        PLOT_Y0 - 1,
        w + 2,
        h + 2,
        Rgb([0, 0, 0]),
    );
    let bar_h = h.max(MIN_BAR_H);
    for y in 0..bar_h {
        let c = height_colour(1.0 - y as Real / (bar_h - 1).max(1) as Real);
        for x in 0..BAR_W {
            put(&mut img, bar_x + x, PLOT_Y0 + y, c);
        }
    }
    frame_rect(
        &mut img,
        bar_x - 1,
        PLOT_Y0 - 1,
        BAR_W + 2,
        bar_h + 2,
        Rgb([0, 0, 0]),
    );
    for (frac, z) in [(0.0, zmax), (1.0, zmin)] {
        let y = PLOT_Y0 + (frac * (bar_h - 1) as Real) as u32;
        for t in 0..TICK {
            put(&mut img, bar_x + BAR_W + t, y, Rgb([0, 0, 0]));
        }
        let label = format!("{z:.3} mm");
        let ty = y.saturating_sub(TEXT_H / 2).min(height - TEXT_H - 1);
        draw_text(
            &mut img,
            bar_x + BAR_W + TICK + 4,
            ty,
            &label,
            SCALE,
            Rgb([0, 0, 0]),
        );
    }
    Ok(img)
}

/// A sequential colour for `x` ∈ [0, 1] (clamped): dark blue → teal → green → yellow.
pub fn height_colour(x: Real) -> Rgb<u8> {
    const STOPS: [[Real; 3]; 4] = [
        [40.0, 30.0, 110.0],
        [30.0, 140.0, 150.0],
        [90.0, 190.0, 80.0],
        [250.0, 225.0, 40.0],
    ];
    let x = if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let f = x * (STOPS.len() - 1) as Real;
    let i = (f.floor() as usize).min(STOPS.len() - 2);
    let w = f - i as Real;
    let c = |j: usize| (STOPS[i][j] * (1.0 - w) + STOPS[i + 1][j] * w).round() as u8;
    Rgb([c(0), c(1), c(2)])
}

/// Smallest plot-area width (px).
pub const MIN_WIDTH_PX: u32 = 16;
/// Largest plot-area width (px).
pub const MAX_WIDTH_PX: u32 = 8192;
/// Largest plot-area height (px).
pub const MAX_PLOT_HEIGHT: u32 = 1600;
/// Largest dot side (px).
pub const MAX_DOT_PX: u32 = 64;
/// Longest title drawn (characters).
pub const MAX_TITLE_CHARS: usize = 160;

/// Integer scale of the 5×7 font.
const SCALE: u32 = 2;
/// Horizontal advance of one character (px).
const ADVANCE: u32 = 6 * SCALE;
/// Height of a text line's glyphs (px).
const TEXT_H: u32 = 7 * SCALE;
/// Outer margin (px).
const MARGIN: u32 = 16;
/// Top of the plot area (below the title).
const PLOT_Y0: u32 = MARGIN + TEXT_H + 12;
/// Left of the plot area.
const PLOT_X0: u32 = MARGIN;
/// Gap between plot and colour bar.
const BAR_GAP: u32 = 24;
/// Colour-bar width.
const BAR_W: u32 = 24;
/// Tick length.
const TICK: u32 = 6;
/// Smallest colour-bar height.
const MIN_BAR_H: u32 = 200;
/// Offset of the colour bar's top below the plot top (room for the unit label).
const BAR_TOP: u32 = TEXT_H + 12;

const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const GREY: Rgb<u8> = Rgb([150, 150, 150]);

/// ColorBrewer RdBu (11 classes), reversed: index 0 is −range (dark blue), 5 is zero
/// (near-white #f7f7f7), 10 is +range (dark red).
const COLOURS: [[u8; 3]; 11] = [
    [0x05, 0x30, 0x61],
    [0x21, 0x66, 0xac],
    [0x43, 0x93, 0xc3],
    [0x92, 0xc5, 0xde],
    [0xd1, 0xe5, 0xf0],
    [0xf7, 0xf7, 0xf7],
    [0xfd, 0xdb, 0xc7],
    [0xf4, 0xa5, 0x82],
    [0xd6, 0x60, 0x4d],
    [0xb2, 0x18, 0x2b],
    [0x67, 0x00, 0x1f],
];

/// The diverging colour of `x` ∈ [−1, 1] (clamped; NaN maps to the centre colour), by
/// linear interpolation in an 11-entry table (ColorBrewer RdBu, reversed).
pub fn diverging_colour(x: Real) -> Rgb<u8> {
    let x = if x.is_nan() { 0.0 } else { x.clamp(-1.0, 1.0) };
    let pos = (x + 1.0) * 0.5 * (COLOURS.len() - 1) as Real;
    let i = (pos.floor() as usize).min(COLOURS.len() - 2);
    let f = pos - i as Real;
    let (a, b) = (COLOURS[i], COLOURS[i + 1]);
    let mix = |k: usize| (Real::from(a[k]) * (1.0 - f) + Real::from(b[k]) * f).round() as u8;
    Rgb([mix(0), mix(1), mix(2)])
}

/// Smallest value of the form {1, 2, 5}·10^k that is ≥ `x` (1 for x ≤ 0 or non-finite).
pub fn nice_ceil(x: Real) -> Real {
    if x.is_nan() || x <= 0.0 || x.is_infinite() {
        return 1.0;
    }
    let e = Real::powi(10.0, x.log10().floor() as i32);
    for m in [1.0, 2.0, 5.0, 10.0, 20.0] {
        let v = m * e;
        if v >= x * (1.0 - 1e-12) {
            return v;
        }
    }
    20.0 * e
}

/// Renders the heat map of `points`' signed distances from `plane` (see the module docs).
///
/// `u`, `v`: in-plane unit axes for the image's right and up directions.
pub fn render_heat_map(
    points: &[Point3],
    plane: &Plane,
    u: &UnitVector3,
    v: &UnitVector3,
    opts: &HeatMapOptions,
) -> Result<RgbImage, RenderError> {
    if points.is_empty() {
        return Err(RenderError::NoPoints);
    }
    if !opts.point_pitch_mm.is_finite() || opts.range_um.is_some_and(|r| !r.is_finite()) {
        return Err(RenderError::NonFinite);
    }
    let width_px = opts.width_px.clamp(MIN_WIDTH_PX, MAX_WIDTH_PX);
    let pitch = opts.point_pitch_mm.max(0.0);
    let finite = |x: &[Real]| x.iter().all(|c| c.is_finite());
    if !finite(plane.normal.as_slice())
        || !plane.offset.is_finite()
        || !finite(u.as_slice())
        || !finite(v.as_slice())
    {
        return Err(RenderError::NonFinite);
    }

    // Project and measure.
    let mut proj: Vec<(Real, Real, Real)> = Vec::with_capacity(points.len());
    let (mut umin, mut umax, mut vmin, mut vmax) = (
        Real::INFINITY,
        Real::NEG_INFINITY,
        Real::INFINITY,
        Real::NEG_INFINITY,
    );
    let mut dmax: Real = 0.0;
    for p in points {
        let (pu, pv, d) = (
            u.dot(&p.coords),
            v.dot(&p.coords),
            plane.signed_distance(p) * 1000.0,
        );
        if !(pu.is_finite() && pv.is_finite() && d.is_finite()) {
            return Err(RenderError::NonFinite);
        }
        umin = umin.min(pu);
        umax = umax.max(pu);
        vmin = vmin.min(pv);
        vmax = vmax.max(pv);
        dmax = dmax.max(d.abs());
        proj.push((pu, pv, d));
    }
    let range = match opts.range_um {
        Some(r) if r > 0.0 => r,
        _ => nice_ceil(dmax),
    };

    // Plot geometry: mm per pixel `s`, plot size, dot size.
    let (uspan, vspan) = (umax - umin, vmax - vmin);
    let mut s = (uspan / Real::from(width_px - 1)).max(vspan / Real::from(MAX_PLOT_HEIGHT - 1));
    if !(s > 0.0 && s.is_finite()) {
        s = if pitch > 0.0 { pitch } else { 1.0 };
    }
    let px = |len: Real| (len / s).round().clamp(0.0, 1e6) as u32;
    let plot_w = (px(uspan) + 1).clamp(1, width_px);
    let plot_h = (px(vspan) + 1).clamp(1, MAX_PLOT_HEIGHT);
    let dot = px(pitch).clamp(1, MAX_DOT_PX);

    // Texts.
    let title: String = opts.title.chars().take(MAX_TITLE_CHARS).collect();
    let footer = format!(
        "u {umin:.2}..{umax:.2} mm  v {vmin:.2}..{vmax:.2} mm  n={}",
        points.len()
    );
    let ticks: Vec<(Real, String)> = [-1.0, -0.5, 0.0, 0.5, 1.0]
        .iter()
        .map(|&f| (f, tick_label(f * range)))
        .collect();
    let label_chars = ticks.iter().map(|(_, t)| t.len()).max().unwrap_or(1) as u32;

    // Layout.
    let bar_x = PLOT_X0 + plot_w + BAR_GAP;
    let bar_y = PLOT_Y0 + BAR_TOP;
    let bar_h = plot_h.saturating_sub(BAR_TOP + TEXT_H).max(MIN_BAR_H);
    let content_h = plot_h.max(BAR_TOP + bar_h + TEXT_H);
    let right = bar_x + BAR_W + TICK + 4 + label_chars.max(2) * ADVANCE + MARGIN;
    let text_w = |t: &str| t.chars().count() as u32 * ADVANCE;
    let width = right
        .max(2 * MARGIN + text_w(&title))
        .max(2 * MARGIN + text_w(&footer));
    let footer_y = PLOT_Y0 + content_h + 12;
    let height = footer_y + TEXT_H + MARGIN;
    let mut img = RgbImage::from_pixel(width, height, WHITE);

    // Points, in input order (the last one drawn wins a pixel).
    let half = (dot - 1) / 2;
    for &(pu, pv, d) in &proj {
        let ix = px(pu - umin).min(plot_w - 1);
        let iy = px(vmax - pv).min(plot_h - 1);
        let colour = diverging_colour(d / range);
        let x0 = ix.saturating_sub(half);
        let y0 = iy.saturating_sub(half);
        let x1 = (ix - half.min(ix) + dot).min(plot_w);
        let y1 = (iy - half.min(iy) + dot).min(plot_h);
        for y in y0..y1 {
            for x in x0..x1 {
                put(&mut img, PLOT_X0 + x, PLOT_Y0 + y, colour);
            }
        }
    }
    frame_rect(&mut img, PLOT_X0, PLOT_Y0, plot_w, plot_h, GREY);

    // Colour bar: +range at the top.
    for y in 0..bar_h {
        let f = 1.0 - 2.0 * Real::from(y) / Real::from(bar_h - 1);
        let c = diverging_colour(f);
        for x in 0..BAR_W {
            put(&mut img, bar_x + x, bar_y + y, c);
        }
    }
    frame_rect(&mut img, bar_x, bar_y, BAR_W, bar_h, BLACK);
    for (f, label) in &ticks {
        let y = bar_y + ((1.0 - f) * 0.5 * Real::from(bar_h - 1)).round() as u32;
        for x in 0..TICK {
            put(&mut img, bar_x + BAR_W + x, y, BLACK);
        }
        draw_text(
            &mut img,
            bar_x + BAR_W + TICK + 4,
            y.saturating_sub(TEXT_H / 2),
            label,
            SCALE,
            BLACK,
        );
    }
    draw_text(&mut img, bar_x, PLOT_Y0, "\u{b5}m", SCALE, BLACK);

    draw_text(&mut img, MARGIN, MARGIN, &title, SCALE, BLACK);
    draw_text(&mut img, MARGIN, footer_y, &footer, SCALE, BLACK);
    Ok(img)
}

/// Formats a tick value in µm: "0", or a signed number without trailing zeros ("+500",
/// "-0.25").
fn tick_label(x: Real) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let sign = if x > 0.0 { '+' } else { '-' };
    let a = x.abs();
    let body = if !(1e-3..1e6).contains(&a) {
        format!("{a:.3e}")
    } else {
        let s = format!("{a:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    };
    format!("{sign}{body}")
}

/// Encodes `img` as PNG.
pub fn encode_png(img: &image::RgbImage) -> Result<Vec<u8>, RenderError> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| RenderError::Encode(e.to_string()))?;
    Ok(out.into_inner())
}

/// Sets a pixel if it lies inside the image.
fn put(img: &mut RgbImage, x: u32, y: u32, c: Rgb<u8>) {
    if let Some(p) = img.get_pixel_mut_checked(x, y) {
        *p = c;
    }
}

/// Draws a 1-px rectangle just outside the `w × h` area at (x, y).
fn frame_rect(img: &mut RgbImage, x: u32, y: u32, w: u32, h: u32, c: Rgb<u8>) {
    let (xl, yt) = (x.saturating_sub(1), y.saturating_sub(1));
    for i in xl..=x + w {
        put(img, i, yt, c);
        put(img, i, y + h, c);
    }
    for j in yt..=y + h {
        put(img, xl, j, c);
        put(img, x + w, j, c);
    }
}

/// Draws `text` with its top-left corner at (x, y) in the built-in 5×7 font at integer
/// `scale` (advance 6·scale px per character; pixels outside the image are clipped).
pub fn draw_text(img: &mut RgbImage, x: u32, y: u32, text: &str, scale: u32, colour: Rgb<u8>) {
    let scale = scale.max(1);
    for (k, ch) in text.chars().enumerate() {
        let gx = x.saturating_add((k as u32).saturating_mul(6 * scale));
        for (col, bits) in glyph(ch).iter().enumerate() {
            for row in 0..7u32 {
                if bits & (1 << row) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        put(
                            img,
                            gx.saturating_add(col as u32 * scale + dx),
                            y.saturating_add(row * scale + dy),
                            colour,
                        );
                    }
                }
            }
        }
    }
}

/// The 5×7 glyph of `c` as five column bytes, left to right; bit 0 is the top row, bit 6
/// the bottom. ASCII 32–126 and `µ`; anything else is `?`.
pub fn glyph(c: char) -> [u8; 5] {
    match c {
        '\u{b5}' => [0x7E, 0x20, 0x20, 0x10, 0x3E],
        ' '..='~' => FONT[c as usize - 32],
        _ => FONT['?' as usize - 32],
    }
}

/// Classic 5×7 font, ASCII 32 (space) to 126 (`~`), five column bytes per glyph.
#[rustfmt::skip]
const FONT: [[u8; 5]; 95] = [
    [0x00, 0x00, 0x00, 0x00, 0x00], // ' '
    [0x00, 0x00, 0x5F, 0x00, 0x00], // !
    [0x00, 0x07, 0x00, 0x07, 0x00], // "
    [0x14, 0x7F, 0x14, 0x7F, 0x14], // #
    [0x24, 0x2A, 0x7F, 0x2A, 0x12], // $
    [0x23, 0x13, 0x08, 0x64, 0x62], // %
    [0x36, 0x49, 0x55, 0x22, 0x50], // &
    [0x00, 0x05, 0x03, 0x00, 0x00], // '
    [0x00, 0x1C, 0x22, 0x41, 0x00], // (
    [0x00, 0x41, 0x22, 0x1C, 0x00], // )
    [0x08, 0x2A, 0x1C, 0x2A, 0x08], // *
    [0x08, 0x08, 0x3E, 0x08, 0x08], // +
    [0x00, 0x50, 0x30, 0x00, 0x00], // ,
    [0x08, 0x08, 0x08, 0x08, 0x08], // -
    [0x00, 0x60, 0x60, 0x00, 0x00], // .
    [0x20, 0x10, 0x08, 0x04, 0x02], // /
    [0x3E, 0x51, 0x49, 0x45, 0x3E], // 0
    [0x00, 0x42, 0x7F, 0x40, 0x00], // 1
    [0x42, 0x61, 0x51, 0x49, 0x46], // 2
    [0x21, 0x41, 0x45, 0x4B, 0x31], // 3
    [0x18, 0x14, 0x12, 0x7F, 0x10], // 4
    [0x27, 0x45, 0x45, 0x45, 0x39], // 5
    [0x3C, 0x4A, 0x49, 0x49, 0x30], // 6
    [0x01, 0x71, 0x09, 0x05, 0x03], // 7
    [0x36, 0x49, 0x49, 0x49, 0x36], // 8
    [0x06, 0x49, 0x49, 0x29, 0x1E], // 9
    [0x00, 0x36, 0x36, 0x00, 0x00], // :
    [0x00, 0x56, 0x36, 0x00, 0x00], // ;
    [0x08, 0x14, 0x22, 0x41, 0x00], // <
    [0x14, 0x14, 0x14, 0x14, 0x14], // =
    [0x00, 0x41, 0x22, 0x14, 0x08], // >
    [0x02, 0x01, 0x51, 0x09, 0x06], // ?
    [0x32, 0x49, 0x79, 0x41, 0x3E], // @
    [0x7E, 0x11, 0x11, 0x11, 0x7E], // A
    [0x7F, 0x49, 0x49, 0x49, 0x36], // B
    [0x3E, 0x41, 0x41, 0x41, 0x22], // C
    [0x7F, 0x41, 0x41, 0x22, 0x1C], // D
    [0x7F, 0x49, 0x49, 0x49, 0x41], // E
    [0x7F, 0x09, 0x09, 0x09, 0x01], // F
    [0x3E, 0x41, 0x49, 0x49, 0x7A], // G
    [0x7F, 0x08, 0x08, 0x08, 0x7F], // H
    [0x00, 0x41, 0x7F, 0x41, 0x00], // I
    [0x20, 0x40, 0x41, 0x3F, 0x01], // J
    [0x7F, 0x08, 0x14, 0x22, 0x41], // K
    [0x7F, 0x40, 0x40, 0x40, 0x40], // L
    [0x7F, 0x02, 0x0C, 0x02, 0x7F], // M
    [0x7F, 0x04, 0x08, 0x10, 0x7F], // N
    [0x3E, 0x41, 0x41, 0x41, 0x3E], // O
    [0x7F, 0x09, 0x09, 0x09, 0x06], // P
    [0x3E, 0x41, 0x51, 0x21, 0x5E], // Q
    [0x7F, 0x09, 0x19, 0x29, 0x46], // R
    [0x46, 0x49, 0x49, 0x49, 0x31], // S
    [0x01, 0x01, 0x7F, 0x01, 0x01], // T
    [0x3F, 0x40, 0x40, 0x40, 0x3F], // U
    [0x1F, 0x20, 0x40, 0x20, 0x1F], // V
    [0x3F, 0x40, 0x38, 0x40, 0x3F], // W
    [0x63, 0x14, 0x08, 0x14, 0x63], // X
    [0x07, 0x08, 0x70, 0x08, 0x07], // Y
    [0x61, 0x51, 0x49, 0x45, 0x43], // Z
    [0x00, 0x7F, 0x41, 0x41, 0x00], // [
    [0x02, 0x04, 0x08, 0x10, 0x20], // backslash
    [0x00, 0x41, 0x41, 0x7F, 0x00], // ]
    [0x04, 0x02, 0x01, 0x02, 0x04], // ^
    [0x40, 0x40, 0x40, 0x40, 0x40], // _
    [0x00, 0x01, 0x02, 0x04, 0x00], // `
    [0x20, 0x54, 0x54, 0x54, 0x78], // a
    [0x7F, 0x48, 0x44, 0x44, 0x38], // b
    [0x38, 0x44, 0x44, 0x44, 0x20], // c
    [0x38, 0x44, 0x44, 0x48, 0x7F], // d
    [0x38, 0x54, 0x54, 0x54, 0x18], // e
    [0x08, 0x7E, 0x09, 0x01, 0x02], // f
    [0x0C, 0x52, 0x52, 0x52, 0x3E], // g
    [0x7F, 0x08, 0x04, 0x04, 0x78], // h
    [0x00, 0x44, 0x7D, 0x40, 0x00], // i
    [0x20, 0x40, 0x44, 0x3D, 0x00], // j
    [0x7F, 0x10, 0x28, 0x44, 0x00], // k
    [0x00, 0x41, 0x7F, 0x40, 0x00], // l
    [0x7C, 0x04, 0x18, 0x04, 0x78], // m
    [0x7C, 0x08, 0x04, 0x04, 0x78], // n
    [0x38, 0x44, 0x44, 0x44, 0x38], // o
    [0x7C, 0x14, 0x14, 0x14, 0x08], // p
    [0x08, 0x14, 0x14, 0x18, 0x7C], // q
    [0x7C, 0x08, 0x04, 0x04, 0x08], // r
    [0x48, 0x54, 0x54, 0x54, 0x20], // s
    [0x04, 0x3F, 0x44, 0x40, 0x20], // t
    [0x3C, 0x40, 0x40, 0x20, 0x7C], // u
    [0x1C, 0x20, 0x40, 0x20, 0x1C], // v
    [0x3C, 0x40, 0x30, 0x40, 0x3C], // w
    [0x44, 0x28, 0x10, 0x28, 0x44], // x
    [0x0C, 0x50, 0x50, 0x50, 0x3C], // y
    [0x44, 0x64, 0x54, 0x4C, 0x44], // z
    [0x00, 0x08, 0x36, 0x41, 0x00], // {
    [0x00, 0x00, 0x7F, 0x00, 0x00], // |
    [0x00, 0x41, 0x36, 0x08, 0x00], // }
    [0x08, 0x04, 0x08, 0x10, 0x08], // ~
];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Vector3;

    fn step_face() -> Vec<Point3> {
        // 40 × 20 mm at 0.5 mm pitch: +1 mm on the left half, 0 on the right.
        let mut pts = Vec::new();
        for i in 0..=80 {
            for j in 0..=40 {
                let x = i as Real * 0.5;
                let y = j as Real * 0.5;
                let z = if x < 20.0 { 1.0 } else { 0.0 };
                pts.push(Point3::new(x, y, 5.0 + z));
            }
        }
        pts
    }

    fn opts(range_um: Option<Real>) -> HeatMapOptions {
        HeatMapOptions {
            title: "Step test: face A (z) +1 mm left".into(),
            width_px: 400,
            point_pitch_mm: 0.5,
            range_um,
        }
    }

    fn z_plane() -> Plane {
        Plane {
            normal: Vector3::z_axis(),
            offset: 5.0,
        }
    }

    /// The step face rendered against z = 5, x right, y up.
    fn render_step(range_um: Option<Real>) -> RgbImage {
        render_heat_map(
            &step_face(),
            &z_plane(),
            &Vector3::x_axis(),
            &Vector3::y_axis(),
            &opts(range_um),
        )
        .expect("render")
    }

    #[test]
    fn step_renders_red_left_white_right() {
        let img = render_step(None);
        // Plot is 400 × 201 px (0.1 mm per px).
        let (w, h) = img.dimensions();
        assert!(w >= PLOT_X0 + 400 + BAR_GAP + BAR_W && h >= PLOT_Y0 + 201);
        for &(fx, fy) in &[(0.1, 0.5), (0.25, 0.1), (0.4, 0.9)] {
            let p = img.get_pixel(PLOT_X0 + (fx * 400.0) as u32, PLOT_Y0 + (fy * 200.0) as u32);
            let [r, g, b] = p.0;
            assert!(r > 80 && r > g + 60 && r > b + 50, "left {p:?}");
        }
        for &(fx, fy) in &[(0.6, 0.5), (0.75, 0.1), (0.9, 0.9)] {
            let p = img.get_pixel(PLOT_X0 + (fx * 400.0) as u32, PLOT_Y0 + (fy * 200.0) as u32);
            assert!(p.0.iter().all(|&c| c >= 235), "right {p:?}");
        }
        // Colour bar: red at the top, blue at the bottom.
        let bx = PLOT_X0 + 400 + BAR_GAP + BAR_W / 2;
        let top = img.get_pixel(bx, PLOT_Y0 + BAR_TOP + 1).0;
        let bottom = img.get_pixel(bx, PLOT_Y0 + BAR_TOP + MIN_BAR_H - 2).0;
        assert!(top[0] > top[2] + 50 && bottom[2] > bottom[0] + 50);
        // Title text drawn in black in the top margin.
        let dark = (0..w)
            .flat_map(|x| (MARGIN..MARGIN + TEXT_H).map(move |y| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0 == [0, 0, 0])
            .count();
        assert!(dark > 100);
    }

    #[test]
    fn explicit_range_clamps_and_scales() {
        let img = render_step(Some(2000.0));
        // +1000 µm of ±2000 is half-way to the end colour: lighter than the end colour.
        let p = img.get_pixel(PLOT_X0 + 40, PLOT_Y0 + 100).0;
        assert_eq!(Rgb(p), diverging_colour(0.5));
        assert!(p[0] > 200 && p[0] > p[2] + 50);
    }

    #[test]
    fn png_round_trip() {
        let img = render_step(None);
        let png = encode_png(&img).expect("encode");
        assert!(png.starts_with(&[0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A]));
        let back = image::load_from_memory(&png).expect("decode").to_rgb8();
        assert_eq!(back.dimensions(), img.dimensions());
        assert_eq!(back, img);
    }

    #[test]
    fn bad_inputs() {
        let (u, v) = (Vector3::x_axis(), Vector3::y_axis());
        assert!(matches!(
            render_heat_map(&[], &z_plane(), &u, &v, &opts(None)),
            Err(RenderError::NoPoints)
        ));
        let mut pts = step_face();
        pts[7].x = Real::NAN;
        assert!(matches!(
            render_heat_map(&pts, &z_plane(), &u, &v, &opts(None)),
            Err(RenderError::NonFinite)
        ));
        assert!(matches!(
            render_heat_map(&step_face(), &z_plane(), &u, &v, &opts(Some(Real::NAN))),
            Err(RenderError::NonFinite)
        ));
        // Out-of-range options are clamped or fall back to automatic.
        let auto = render_heat_map(&step_face(), &z_plane(), &u, &v, &opts(None)).expect("auto");
        let neg = render_heat_map(&step_face(), &z_plane(), &u, &v, &opts(Some(-1.0)));
        assert_eq!(neg.expect("negative range"), auto);
        let mut o = opts(None);
        o.width_px = 0;
        o.point_pitch_mm = -3.0;
        let img = render_heat_map(&step_face(), &z_plane(), &u, &v, &o).expect("narrow");
        assert!(img.width() >= MIN_WIDTH_PX);
        // Degenerate extents still render.
        let one = [Point3::new(1.0, 2.0, 5.0)];
        let img = render_heat_map(&one, &z_plane(), &u, &v, &opts(None)).expect("one point");
        assert!(img.width() > 0 && img.height() <= PLOT_Y0 + MAX_PLOT_HEIGHT + 100);
        let tall: Vec<Point3> = (0..1000)
            .map(|i| Point3::new(0.0, i as Real, 5.0 + 1e-3 * i as Real))
            .collect();
        let img = render_heat_map(&tall, &z_plane(), &u, &v, &opts(None)).expect("tall");
        assert!(img.height() <= PLOT_Y0 + MAX_PLOT_HEIGHT + 100);
    }

    #[test]
    fn top_view_colours_a_pocket_by_depth() {
        use crate::cutting::stock::{Cutter, RayCut, TriDexel};
        use crate::math::{Aabb, Vector3};
        // A 4 × 4 mm square pocket 1 mm deep in the middle of a 10 × 10 × 5 box.
        struct Pocket;
        impl Cutter for Pocket {
            fn bounds(&self) -> Aabb {
                Aabb {
                    min: Point3::new(3.0, 3.0, 4.0),
                    max: Point3::new(7.0, 7.0, 6.0),
                }
            }
            fn ray_cut(&self, o: &Point3, axis: usize) -> Option<RayCut> {
                let b = self.bounds();
                let inside = (0..3)
                    .filter(|&k| k != axis)
                    .all(|k| o[k] > b.min[k] && o[k] < b.max[k]);
                inside.then(|| {
                    let mut n = Vector3::zeros();
                    n[axis] = 1.0;
                    RayCut {
                        t_in: b.min[axis],
                        t_out: b.max[axis],
                        n_in: n,
                        n_out: -n,
                    }
                })
            }
        }
        let bx = Aabb {
            min: Point3::new(0.0, 0.0, 0.0),
            max: Point3::new(10.0, 10.0, 5.0),
        };
        let mut stock = TriDexel::new_box(bx, 0.5, 1e9).expect("fits");
        assert!(stock.remove(&Pocket, 7));
        let img = render_top_view(&stock, "pocket").expect("renders");
        let (nu, nv) = stock.grids()[2].dims();
        let k = TOP_VIEW_MIN_PX.div_ceil(nu) as u32;
        assert!(img.width() >= PLOT_X0 + nu as u32 * k && img.height() >= PLOT_Y0 + nv as u32 * k);
        // Pixel at the centre of a ray's square (iu, iv).
        let px = |iu: usize, iv: usize| {
            *img.get_pixel(
                PLOT_X0 + iu as u32 * k + k / 2,
                PLOT_Y0 + (nv - 1 - iv) as u32 * k + k / 2,
            )
        };
        // The pocket floor (z = 4) is the lowest height: the first colour, full light from
        // the +z normal's share; the top (z = 5) the last.
        let light = Vector3::new(LIGHT[0], LIGHT[1], LIGHT[2]).normalize();
        let shade = 0.35 + 0.65 * light.z;
        let expect = |x: Real| {
            Rgb(height_colour(x)
                .0
                .map(|b| (b as Real * shade).round() as u8))
        };
        assert_eq!(px(nu / 2, nv / 2), expect(0.0));
        assert_eq!(px(1, 1), expect(1.0));
    }

    #[test]
    fn font_glyphs() {
        assert!(glyph('0').iter().any(|&c| c != 0));
        assert!(glyph(' ').iter().all(|&c| c == 0));
        assert_eq!(glyph('\u{2603}'), glyph('?'));
        for c in ' '..='~' {
            let g = glyph(c);
            assert!(g.iter().all(|&col| col < 0x80), "{c}");
            assert_eq!(g.iter().all(|&col| col == 0), c == ' ', "{c}");
        }
        let mut img = RgbImage::from_pixel(20, 20, WHITE);
        draw_text(&mut img, 0, 0, "1", 2, BLACK);
        // '1' has its full-height stem in column 2 (pixels 4–5 at 2×).
        assert!((0..14).all(|y| img.get_pixel(4, y).0 == [0, 0, 0]));
        draw_text(&mut img, 15, 15, "WWW", 2, BLACK); // clipped, no panic
    }

    #[test]
    fn tick_labels_and_steps() {
        assert_eq!(tick_label(500.0), "+500");
        assert_eq!(tick_label(-250.0), "-250");
        assert_eq!(tick_label(0.0), "0");
        assert_eq!(tick_label(0.25), "+0.25");
        assert_eq!(tick_label(-1e-5), "-1.000e-5");
        assert_eq!(nice_ceil(730.0), 1000.0);
        assert_eq!(nice_ceil(1000.0), 1000.0);
        assert_eq!(nice_ceil(3.1), 5.0);
        assert_eq!(nice_ceil(0.0), 1.0);
        assert_eq!(nice_ceil(0.15), 0.2);
    }
}
