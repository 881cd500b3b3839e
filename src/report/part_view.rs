//! `part.png`: the cut part as a shaded picture from a direction that shows its machined
//! faces, coloured by deviation where it is known.
//!
//! An orthographic view of a [`DisplayMesh`] along `eye` (from the part towards the viewer,
//! see [`crate::report::display::view_direction`]), rasterised with a depth buffer: each
//! visible triangle is lit by its own flat normal (Lambert, a light over the viewer's
//! shoulder, plus ambient), its colour interpolated between its corners' deviations in the
//! diverging colours of [`crate::report::render`] with a colour bar (µm, or mm from 1 mm),
//! or light grey where no deviation is known. A title above, the view and the display
//! mesh's size and error below.
//!
//! **Invariant:** sequential and deterministic: triangles are drawn in order, a pixel takes
//! the nearest triangle (ties: the earlier one).

use crate::math::{Real, UnitVector3, Vector3};
use crate::report::display::DisplayMesh;
use crate::report::render::{RenderError, diverging_colour, draw_text};
use image::{Rgb, RgbImage};

/// Options of the part picture.
#[derive(Clone, Debug, PartialEq)]
pub struct PartViewOptions {
    /// Title line (printable ASCII and µ).
    pub title: String,
    /// Image size (px), each side clamped to 200 ..= 4096.
    pub width_px: u32,
    /// Image height (px).
    pub height_px: u32,
    /// From the part towards the viewer.
    pub eye: UnitVector3,
    /// The screen's up (projected; must not be parallel to `eye`).
    pub up: Vector3,
    /// Symmetric colour range ±range (mm, > 0) when deviations are given.
    pub range_mm: Real,
    /// Said below the picture when no deviations are given (why not).
    pub no_deviation: String,
}

const SCALE: u32 = 2;
const TEXT_H: u32 = 7 * SCALE;
const ADVANCE: u32 = 6 * SCALE;
const MARGIN: u32 = 16;
const BAR_W: u32 = 24;
const LEGEND_W: u32 = 24 + BAR_W + 10 + 8 * ADVANCE;
const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const GREY: [Real; 3] = [200.0, 200.0, 200.0];

/// A tick label in the legend's unit.
fn tick(x: Real) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let s = format!("{:.3}", x.abs());
    let s = s.trim_end_matches('0').trim_end_matches('.');
    format!("{}{s}", if x > 0.0 { '+' } else { '-' })
}

/// Renders `mesh` (see the module docs); `deviations` (mm), one per corner of each triangle
/// (NaN: not known, drawn grey), colour it.
pub fn render_part_view(
    mesh: &DisplayMesh,
    deviations: Option<&[[Real; 3]]>,
    opts: &PartViewOptions,
) -> Result<RgbImage, RenderError> {
    if mesh.triangles.is_empty() {
        return Err(RenderError::NoPoints);
    }
    let finite = mesh
        .vertices
        .iter()
        .all(|p| p.coords.iter().all(|c| c.is_finite()))
        && deviations.is_none_or(|d| d.iter().flatten().all(|x| !x.is_infinite()))
        && opts.range_mm.is_finite()
        && opts.up.iter().all(|c| c.is_finite());
    if !finite || deviations.is_some_and(|d| d.len() != mesh.triangles.len()) {
        return Err(RenderError::NonFinite);
    }
    let (w, h) = (
        opts.width_px.clamp(200, 4096),
        opts.height_px.clamp(200, 4096),
    );
    let eye = opts.eye.into_inner();
    let right = opts.up.cross(&eye);
    if right.norm() < 1e-9 {
        return Err(RenderError::NonFinite);
    }
    let right = right.normalize();
    let up = eye.cross(&right);
    // Screen coordinates (mm) and depth (towards the viewer).
    let proj: Vec<(Real, Real, Real)> = mesh
        .vertices
        .iter()
        .map(|p| (p.coords.dot(&right), p.coords.dot(&up), p.coords.dot(&eye)))
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (
        Real::INFINITY,
        Real::NEG_INFINITY,
        Real::INFINITY,
        Real::NEG_INFINITY,
    );
    for t in &mesh.triangles {
        for &i in t {
            let (x, y, _) = proj[i as usize];
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
    }
    let legend = if deviations.is_some() { LEGEND_W } else { 0 };
    let top = MARGIN + TEXT_H + 16;
    let bottom = 3 * (TEXT_H + 6) + MARGIN;
    let (aw, ah) = (w - 2 * MARGIN - legend, h - top - bottom);
    let span = |a: Real, b: Real| (b - a).max(1e-9);
    let s = (span(x0, x1) / Real::from(aw - 1)).max(span(y0, y1) / Real::from(ah - 1));
    // Centred in the plot area.
    let (ox, oy) = (
        Real::from(MARGIN) + (Real::from(aw) - (x1 - x0) / s) / 2.0,
        Real::from(top) + (Real::from(ah) - (y1 - y0) / s) / 2.0,
    );
    let to_px = |x: Real, y: Real| (ox + (x - x0) / s, oy + (y1 - y) / s);
    let mut img = RgbImage::from_pixel(w, h, WHITE);
    let mut depth = vec![Real::NEG_INFINITY; (w * h) as usize];
    let light = (eye + up * 0.5 - right * 0.3).normalize();
    for (k, t) in mesh.triangles.iter().enumerate() {
        let p = t.map(|i| mesh.vertices[i as usize]);
        let n = (p[1] - p[0]).cross(&(p[2] - p[0]));
        if n.norm() == 0.0 || n.dot(&eye) <= 0.0 {
            continue; // degenerate or facing away
        }
        let shade = 0.45 + 0.55 * n.normalize().dot(&light).max(0.0);
        let v = t.map(|i| {
            let (x, y, z) = proj[i as usize];
            let (px, py) = to_px(x, y);
            (px, py, z)
        });
        let dev = deviations.map(|d| d[k]);
        let area = (v[1].0 - v[0].0) * (v[2].1 - v[0].1) - (v[2].0 - v[0].0) * (v[1].1 - v[0].1);
        if area.abs() < 1e-12 {
            continue;
        }
        let bx0 = v
            .iter()
            .map(|q| q.0)
            .fold(Real::INFINITY, Real::min)
            .floor()
            .max(0.0) as u32;
        let bx1 = v
            .iter()
            .map(|q| q.0)
            .fold(Real::NEG_INFINITY, Real::max)
            .ceil()
            .min(Real::from(w - 1)) as u32;
        let by0 = v
            .iter()
            .map(|q| q.1)
            .fold(Real::INFINITY, Real::min)
            .floor()
            .max(0.0) as u32;
        let by1 = v
            .iter()
            .map(|q| q.1)
            .fold(Real::NEG_INFINITY, Real::max)
            .ceil()
            .min(Real::from(h - 1)) as u32;
        for py in by0..=by1 {
            for px in bx0..=bx1 {
                let (cx, cy) = (Real::from(px) + 0.5, Real::from(py) + 0.5);
                let e = |a: (Real, Real, Real), b: (Real, Real, Real)| {
                    ((b.0 - a.0) * (cy - a.1) - (cx - a.0) * (b.1 - a.1)) / area
                };
                let (l0, l1, l2) = (e(v[1], v[2]), e(v[2], v[0]), e(v[0], v[1]));
                if l0 < 0.0 || l1 < 0.0 || l2 < 0.0 {
                    continue;
                }
                let z = l0 * v[0].2 + l1 * v[1].2 + l2 * v[2].2;
                let k = (py * w + px) as usize;
                if z <= depth[k] {
                    continue;
                }
                depth[k] = z;
                let base = match dev {
                    Some(d) if d.iter().all(|x| x.is_finite()) => {
                        let Rgb(c) =
                            diverging_colour((l0 * d[0] + l1 * d[1] + l2 * d[2]) / opts.range_mm);
                        c.map(Real::from)
                    }
                    _ => GREY,
                };
                let c = base.map(|b| (b * shade).round().clamp(0.0, 255.0) as u8);
                img.put_pixel(px, py, Rgb(c));
            }
        }
    }
    draw_text(&mut img, MARGIN, MARGIN, &opts.title, SCALE, BLACK);
    if deviations.is_some() {
        let (unit, scale) = if opts.range_mm >= 1.0 {
            ("mm", 1.0)
        } else {
            ("\u{b5}m", 1000.0)
        };
        let bar_x = w - MARGIN - LEGEND_W + 24;
        let bar_y = top + TEXT_H + 8;
        let bar_h = ah.saturating_sub(TEXT_H + 8).max(50);
        for y in 0..bar_h {
            let f = 1.0 - 2.0 * Real::from(y) / Real::from(bar_h - 1);
            for x in 0..BAR_W {
                img.put_pixel(bar_x + x, (bar_y + y).min(h - 1), diverging_colour(f));
            }
        }
        for f in [-1.0, -0.5, 0.0, 0.5, 1.0] {
            let y = bar_y + ((1.0 - f) * 0.5 * Real::from(bar_h - 1)).round() as u32;
            for x in 0..6 {
                img.put_pixel((bar_x + BAR_W + x).min(w - 1), y.min(h - 1), BLACK);
            }
            draw_text(
                &mut img,
                bar_x + BAR_W + 10,
                y.saturating_sub(TEXT_H / 2),
                &tick(f * opts.range_mm * scale),
                SCALE,
                BLACK,
            );
        }
        draw_text(&mut img, bar_x, top, unit, SCALE, BLACK);
    }
    let lines = [
        format!(
            "view from ({:+.2}, {:+.2}, {:+.2}), orthographic",
            eye.x, eye.y, eye.z
        ),
        format!(
            "display mesh {} of {} triangles, within {:.1e} mm",
            mesh.triangles.len(),
            mesh.source_triangles,
            mesh.error_mm
        ),
        if deviations.is_some() {
            "colour: deviation (+ material left, - gouge)".to_string()
        } else {
            opts.no_deviation.clone()
        },
    ];
    for (k, l) in lines.iter().enumerate() {
        let y = h - MARGIN - (3 - k as u32) * (TEXT_H + 6) + 6;
        draw_text(&mut img, MARGIN, y, l, SCALE, BLACK);
    }
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Point3;

    /// Two squares facing −y side by side in x: x < 0 at y = 0, x > 0 at y = −1.
    fn two_faces() -> DisplayMesh {
        let mut vertices = Vec::new();
        let mut triangles = Vec::new();
        for (x0, y) in [(-2.0, 0.0), (0.0, -1.0)] {
            let k = vertices.len() as u32;
            vertices.extend([
                Point3::new(x0, y, -1.0),
                Point3::new(x0 + 2.0, y, -1.0),
                Point3::new(x0 + 2.0, y, 1.0),
                Point3::new(x0, y, 1.0),
            ]);
            triangles.extend([[k, k + 1, k + 2], [k, k + 2, k + 3]]);
        }
        DisplayMesh {
            vertices,
            triangles,
            source_triangles: 4,
            error_mm: 0.0,
        }
    }

    fn opts() -> PartViewOptions {
        PartViewOptions {
            title: "two faces".into(),
            width_px: 600,
            height_px: 400,
            eye: UnitVector3::new_normalize(Vector3::new(0.0, -1.0, 0.0)),
            up: Vector3::z(),
            range_mm: 0.5,
            no_deviation: "deviation not known".into(),
        }
    }

    #[test]
    fn faces_of_opposite_deviation_show_red_and_blue() {
        let m = two_faces();
        let dev = [[-0.5; 3], [-0.5; 3], [0.5; 3], [0.5; 3]];
        let img = render_part_view(&m, Some(&dev), &opts()).unwrap();
        // Left half of the plot: blue (gouge); right half: red.
        let y = img.height() / 2;
        let (left, right) = (img.get_pixel(150, y), img.get_pixel(350, y));
        assert!(left[2] > left[0] + 60, "{left:?}");
        assert!(right[0] > right[2] + 60, "{right:?}");
        let again = render_part_view(&m, Some(&dev), &opts()).unwrap();
        assert_eq!(img, again);
    }

    #[test]
    fn without_deviations_the_part_is_grey_and_shaded() {
        let img = render_part_view(&two_faces(), None, &opts()).unwrap();
        let p = img.get_pixel(300, img.height() / 2);
        assert!(
            p[0] == p[1] && p[1] == p[2] && p[0] > 100 && p[0] < 255,
            "{p:?}"
        );
    }

    #[test]
    fn bad_input_is_an_error() {
        let mut m = two_faces();
        assert!(render_part_view(&m, Some(&[[0.0; 3]; 3]), &opts()).is_err());
        m.vertices[0].x = Real::NAN;
        assert!(render_part_view(&m, None, &opts()).is_err());
        m.triangles.clear();
        assert!(render_part_view(&m, None, &opts()).is_err());
    }
}
