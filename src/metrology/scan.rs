//! A virtual structured-light scanner (EinScan-SP class; see docs/scanning-and-fitting.md)
//! that measures the cut stock.
//!
//! The surface it sees is the tri-dexel's: every crossing is an exact surface point with
//! its exact normal, and is drawn as a small disc (a *splat*) in its tangent plane, of
//! radius one dexel spacing, which covers any face without holes. A camera ray's first
//! front-facing splat gives the measured point. On a planar face all splats are coplanar,
//! so the points lie on the true plane to rounding, at any viewing angle.
//!
//! The scanner is a pinhole camera and a projector offset by a baseline. A point is measured
//! only if
//! - the projector lights it too (occlusion, as in real triangulation scanners),
//! - it lies within the working range of distances from the camera, and
//! - the surface faces the camera within the grazing limit (steeper surfaces drop out).
//!
//! Range noise is Gaussian along the camera ray: independent per pixel, or, with a
//! correlation length ℓ, a Gaussian random field on the image whose autocorrelation at
//! distance d (on the target plane) is exp(−d²/(2ℓ²)), as real fringe-projection noise is.
//! A scan may take several views on a turntable (the part turns about the table's axis, the
//! scanner stays); each view is merged into the workpiece frame with its own small rigid
//! misregistration, as a real registration would leave. Every random number comes from a
//! counter-based generator keyed by the seed, the view and the pixel, so the cloud is
//! identical for any thread count.
//!
//! **Invariant:** the scanner reads the stock and never changes it; it knows nothing about
//! the machine or the program (a point's source NC line is read off the crossing).

use crate::cutting::stock::TriDexel;
use crate::math::{
    Aabb, CounterRng, Isometry3, Point3, Real, Rotation3, UnitVector3, Vector3, tol,
};
use crate::metrology::cloud::{Frame, PointCloud};
use crate::progress::Progress;
use rayon::prelude::*;

/// Scanner pose and characteristics. All lengths in mm, frame W.
#[derive(Clone, Debug, PartialEq)]
pub struct ScannerConfig {
    /// Camera centre (first view).
    pub position: Point3,
    /// The point the camera looks at; the field of view and pitch are given at its distance.
    pub target: Point3,
    /// A direction that appears upward in the image (not parallel to the view).
    pub up: Vector3,
    /// Projector offset from the camera along the image's right direction. Typical 50–150.
    pub baseline_mm: Real,
    /// Field of view (width, height) at the target distance. EinScan-SP: about 200 × 150.
    pub fov_mm: (Real, Real),
    /// Point spacing at the target distance. EinScan-SP: 0.17–0.20; default 0.185.
    pub pitch_mm: Real,
    /// Standard deviation of the range noise along the viewing ray; 0 turns noise off.
    pub noise_sigma_mm: Real,
    /// Correlation length of the range noise on the target plane (mm); 0: independent per
    /// point. Typical 0.5–2.
    pub noise_correlation_mm: Real,
    /// Distances from the camera at which points are measured (near, far). EinScan-SP:
    /// 290–480.
    pub working_range_mm: (Real, Real),
    /// Largest angle between the surface normal and the direction to the camera at which a
    /// point is still measured (degrees, (0, 90]). Typical 75–80.
    pub grazing_limit_deg: Real,
    /// Per-view rigid registration error.
    pub misregistration: Misregistration,
    /// Views on a turntable; `None`: one view from `position`.
    pub turntable: Option<Turntable>,
    /// Seed of every random number of the scan.
    pub seed: u64,
}

/// Standard deviations of the rigid error each view is registered with.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Misregistration {
    /// Per component of the translation (mm).
    pub translation_sigma_mm: Real,
    /// Per component of the rotation vector (rad), about the view's target point.
    pub rotation_sigma_rad: Real,
}

/// A turntable: the part turns by each angle about the axis, the scanner stays.
#[derive(Clone, Debug, PartialEq)]
pub struct Turntable {
    /// A point on the table's axis (W).
    pub axis_point: Point3,
    /// The axis direction (W).
    pub axis: UnitVector3,
    /// Table angles of the views (degrees).
    pub angles_deg: Vec<Real>,
}

/// Settings of the scanner-effects study (see `pipeline::scanner_study`): how much each
/// effect is turned up, and how many seeded trials per case.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StudyOptions {
    /// Seeded trials per case (≥ 1).
    pub trials: usize,
    /// Noise correlation length for the correlated-noise cases (mm).
    pub correlation_mm: Real,
    /// Per-view translation σ for the misregistration cases (mm).
    pub translation_sigma_mm: Real,
    /// Per-view rotation σ for the misregistration cases (rad).
    pub rotation_sigma_rad: Real,
}

/// Errors of the scanner.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ScanError {
    /// A setting is out of range or not finite.
    #[error("scanner {field}: {message}")]
    BadConfig {
        /// The setting's name in scene files.
        field: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The field of view over the pitch asks for too many rays.
    #[error("scanner: {rays} rays requested (fov / pitch); at most {max} allowed")]
    TooManyRays {
        /// Rays the settings ask for.
        rays: u64,
        /// The limit.
        max: u64,
    },
}

/// What happened in one view.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ViewReport {
    /// Turntable angle (degrees; 0 without a turntable).
    pub table_deg: Real,
    /// Points measured.
    pub points: usize,
    /// Seen by the camera but not lit by the projector.
    pub shadowed: usize,
    /// Dropped for facing the camera too obliquely.
    pub grazing: usize,
    /// Dropped for lying outside the working range.
    pub out_of_range: usize,
    /// The registration error applied: translation (mm).
    pub misregistration_mm: [Real; 3],
    /// The registration error applied: rotation vector (rad).
    pub misregistration_rad: [Real; 3],
}

/// The result of a scan.
#[derive(Clone, Debug, PartialEq)]
pub struct Scan {
    /// The measured points of all views, registered into frame W.
    pub cloud: PointCloud,
    /// For each point, the NC line whose cut made the surface there (0: stock face).
    pub lines: Vec<u32>,
    /// For each point, the view it came from.
    pub view_of_point: Vec<u16>,
    /// Camera rays cast, over all views.
    pub rays: usize,
    /// Per view.
    pub views: Vec<ViewReport>,
}

impl Scan {
    /// Points seen by a camera but in the projector's shadow, over all views.
    pub fn shadowed(&self) -> usize {
        self.views.iter().map(|v| v.shadowed).sum()
    }
}

/// Rays per scan (all views), at most.
const MAX_RAYS: u64 = 50_000_000;
/// Views per scan, at most.
const MAX_VIEWS: usize = 360;
/// Longest noise correlation, in point pitches: beyond it the noise is a smooth warp of the
/// whole view, which is what misregistration models.
const MAX_CORRELATION_PITCHES: Real = 50.0;
/// Keys separating the random streams of the scan (noise, field, registration).
const STREAM_REGISTRATION: u64 = 0x5eed_0001;
/// Key of the correlated-noise streams.
const STREAM_FIELD: u64 = 0x5eed_0002;

#[derive(Clone, Copy, Debug)]
struct Splat {
    p: Point3,
    n: Vector3,
    line: u32,
}

/// A uniform grid of cells listing the splats that overlap each.
struct SplatIndex {
    bounds: Aabb,
    cell: Real,
    dims: [usize; 3],
    offsets: Vec<u32>,
    ids: Vec<u32>,
    splats: Vec<Splat>,
    radius: Real,
}

impl SplatIndex {
    fn build(stock: &TriDexel) -> Self {
        let radius = stock.max_spacing();
        let mut splats = Vec::new();
        for g in stock.grids() {
            g.for_each_crossing(|p, c| {
                splats.push(Splat {
                    p,
                    n: c.normal(),
                    line: c.line,
                })
            });
        }
        let bounds = stock.bounds().inflated(radius * 1.01);
        let ext = bounds.max - bounds.min;
        // Cells three splat radii wide (a splat overlaps ≤ 2 cells per axis; measured fastest
        // of 2, 3 and 4 radii on the built-in scene: fewer index entries against more splats
        // tested per cell), and no more than 2^25 of them.
        let cell = (3.0 * radius).max((ext.x * ext.y * ext.z / (1u64 << 25) as Real).cbrt());
        let dims = [0, 1, 2].map(|k| ((ext[k] / cell).ceil() as usize).max(1));
        // The cells a splat's bounding cube overlaps, computed once per splat. Relative to the
        // inflated bounds every coordinate is ≥ 0, so truncation is the floor.
        let inv = 1.0 / cell;
        let ranges: Vec<[(usize, usize); 3]> = splats
            .par_iter()
            .with_min_len(4096)
            .map(|s| {
                let span = |k: usize| {
                    let lo = (s.p[k] - radius - bounds.min[k]).max(0.0) * inv;
                    let hi = (s.p[k] + radius - bounds.min[k]).max(0.0) * inv;
                    (
                        (lo as usize).min(dims[k] - 1),
                        (hi as usize).min(dims[k] - 1),
                    )
                };
                [span(0), span(1), span(2)]
            })
            .collect();
        let ncells = dims[0] * dims[1] * dims[2];
        let mut counts = vec![0u32; ncells + 1];
        let for_cells = |r: &[(usize, usize); 3], f: &mut dyn FnMut(usize)| {
            for k in r[2].0..=r[2].1 {
                for j in r[1].0..=r[1].1 {
                    for i in r[0].0..=r[0].1 {
                        f((k * dims[1] + j) * dims[0] + i);
                    }
                }
            }
        };
        for r in &ranges {
            for_cells(r, &mut |c| counts[c + 1] += 1);
        }
        for c in 0..ncells {
            counts[c + 1] += counts[c];
        }
        let mut fill = counts.clone();
        let mut ids = vec![0u32; counts[ncells] as usize];
        for (id, r) in ranges.iter().enumerate() {
            for_cells(r, &mut |c| {
                ids[fill[c] as usize] = id as u32;
                fill[c] += 1;
            });
        }
        Self {
            bounds,
            cell,
            dims,
            offsets: counts,
            ids,
            splats,
            radius,
        }
    }

    /// First front-facing splat hit by `o + t·d` (`d` unit) with `t > t_min`.
    fn first_hit(&self, o: &Point3, d: &Vector3, t_min: Real) -> Option<(Real, usize)> {
        let (t0, t1) = self.bounds.ray_interval(o, d)?;
        let t_start = t0.max(t_min);
        if t_start > t1 {
            return None;
        }
        let p = o + d * t_start;
        let mut cell = [0usize; 3];
        let mut step = [0isize; 3];
        let mut t_next = [Real::INFINITY; 3];
        let mut t_delta = [Real::INFINITY; 3];
        for k in 0..3 {
            let c = ((p[k] - self.bounds.min[k]) / self.cell).floor();
            cell[k] = (c.max(0.0) as usize).min(self.dims[k] - 1);
            if d[k] > 0.0 {
                step[k] = 1;
                let edge = self.bounds.min[k] + (cell[k] + 1) as Real * self.cell;
                t_next[k] = t_start + (edge - p[k]) / d[k];
                t_delta[k] = self.cell / d[k];
            } else if d[k] < 0.0 {
                step[k] = -1;
                let edge = self.bounds.min[k] + cell[k] as Real * self.cell;
                t_next[k] = t_start + (edge - p[k]) / d[k];
                t_delta[k] = -self.cell / d[k];
            }
        }
        let r2 = self.radius * self.radius;
        let mut best: Option<(Real, usize)> = None;
        let mut t_enter = t_start;
        loop {
            if best.is_some_and(|(bt, _)| bt < t_enter) {
                break;
            }
            let c = (cell[2] * self.dims[1] + cell[1]) * self.dims[0] + cell[0];
            for &id in &self.ids[self.offsets[c] as usize..self.offsets[c + 1] as usize] {
                let s = &self.splats[id as usize];
                let denom = s.n.dot(d);
                if denom > -tol::GRAZING_COS {
                    continue; // back-facing or edge-on
                }
                let t = s.n.dot(&(s.p - o)) / denom;
                if t <= t_min || best.is_some_and(|(bt, _)| t >= bt) {
                    continue;
                }
                let h = o + d * t;
                if (h - s.p).norm_squared() <= r2 {
                    best = Some((t, id as usize));
                }
            }
            // Advance to the next cell.
            let k = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
                0
            } else if t_next[1] <= t_next[2] {
                1
            } else {
                2
            };
            if t_next[k] > t1 {
                break;
            }
            t_enter = t_next[k];
            let nc = cell[k] as isize + step[k];
            if nc < 0 || nc >= self.dims[k] as isize {
                break;
            }
            cell[k] = nc as usize;
            t_next[k] += t_delta[k];
        }
        best
    }
}

fn finite_point(p: &Point3) -> bool {
    p.coords.iter().all(|c| c.is_finite())
}

impl ScannerConfig {
    /// Checks every setting; the error names the offending field.
    pub fn validate(&self) -> Result<(), ScanError> {
        let bad = |field: &'static str, m: &str| {
            Err(ScanError::BadConfig {
                field,
                message: m.to_string(),
            })
        };
        for (field, ok) in [
            ("position", finite_point(&self.position)),
            ("target", finite_point(&self.target)),
            ("up", self.up.iter().all(|c| c.is_finite())),
        ] {
            if !ok {
                return bad(field, "must be finite");
            }
        }
        let view = self.target - self.position;
        if view.norm() < 1.0 {
            return bad("target", "must be at least 1 mm from the camera position");
        }
        if view.normalize().cross(&self.up).norm() < tol::GRAZING_COS {
            return bad("up", "must not be parallel to the viewing direction");
        }
        if !(self.pitch_mm.is_finite() && self.pitch_mm > 0.0) {
            return bad("pitch_mm", "must be positive and finite");
        }
        let (w, h) = self.fov_mm;
        if !(w.is_finite() && h.is_finite() && w > 0.0 && h > 0.0) {
            return bad("fov_mm", "must be two positive finite numbers");
        }
        if !(self.noise_sigma_mm.is_finite() && self.noise_sigma_mm >= 0.0) {
            return bad("noise_sigma_mm", "must be finite and not negative");
        }
        if !self.baseline_mm.is_finite() {
            return bad("baseline_mm", "must be finite");
        }
        if !(self.noise_correlation_mm.is_finite() && self.noise_correlation_mm >= 0.0) {
            return bad("noise_correlation_mm", "must be finite and not negative");
        }
        if self.noise_correlation_mm > MAX_CORRELATION_PITCHES * self.pitch_mm {
            return bad(
                "noise_correlation_mm",
                "must be at most 50 point pitches (a longer correlation is a misregistration)",
            );
        }
        let (near, far) = self.working_range_mm;
        if !(near.is_finite() && far.is_finite() && near >= 0.0 && far > near) {
            return bad(
                "working_range_mm",
                "must be two finite distances, near < far",
            );
        }
        if !(self.grazing_limit_deg > 0.0 && self.grazing_limit_deg <= 90.0) {
            return bad("grazing_limit_deg", "must be in (0, 90]");
        }
        let m = &self.misregistration;
        if !(m.translation_sigma_mm.is_finite()
            && m.translation_sigma_mm >= 0.0
            && m.rotation_sigma_rad.is_finite()
            && m.rotation_sigma_rad >= 0.0)
        {
            return bad("misregistration", "sigmas must be finite and not negative");
        }
        if let Some(t) = &self.turntable {
            if !finite_point(&t.axis_point) || !t.axis.iter().all(|c| c.is_finite()) {
                return bad("turntable", "axis point and direction must be finite");
            }
            if t.angles_deg.is_empty() || t.angles_deg.len() > MAX_VIEWS {
                return bad("turntable", "needs 1 to 360 view angles");
            }
            if !t.angles_deg.iter().all(|a| a.is_finite()) {
                return bad("turntable", "angles must be finite");
            }
        }
        let rays =
            (self.fov_mm.0 / self.pitch_mm).round() * (self.fov_mm.1 / self.pitch_mm).round();
        let views = self.turntable.as_ref().map_or(1, |t| t.angles_deg.len()) as Real;
        let rays = rays * views;
        if rays > MAX_RAYS as Real {
            return Err(ScanError::TooManyRays {
                rays: rays as u64,
                max: MAX_RAYS,
            });
        }
        Ok(())
    }
}

/// A unit-variance Gaussian random field on an `nx × ny` pixel grid whose autocorrelation at
/// a lag of d pixels is exp(−d²/(2·corr_px²)): white noise smoothed by a separable Gaussian of
/// standard deviation corr_px/√2 (the autocorrelation of a Gaussian smoothing is the kernel
/// convolved with itself). The white noise covers a margin of the kernel's reach so every
/// pixel has the full kernel and exactly unit variance.
fn correlated_field(nx: usize, ny: usize, corr_px: Real, rng: &CounterRng) -> Vec<Real> {
    let s = corr_px / std::f64::consts::SQRT_2;
    let reach = (3.0 * s).ceil() as usize;
    let kernel: Vec<Real> = (0..=2 * reach)
        .map(|k| {
            let x = k as Real - reach as Real;
            (-x * x / (2.0 * s * s)).exp()
        })
        .collect();
    let norm = kernel.iter().map(|w| w * w).sum::<Real>().sqrt();
    let kernel: Vec<Real> = kernel.iter().map(|w| w / norm).collect();
    let (wx, wy) = (nx + 2 * reach, ny + 2 * reach);
    // Rows of white noise, smoothed along x.
    let rows: Vec<Vec<Real>> = (0..wy)
        .into_par_iter()
        .map(|j| {
            let white: Vec<Real> = (0..wx).map(|i| rng.normal((j * wx + i) as u64)).collect();
            (0..nx)
                .map(|i| kernel.iter().zip(&white[i..]).map(|(k, w)| k * w).sum())
                .collect()
        })
        .collect();
    // Then along y.
    (0..ny)
        .into_par_iter()
        .flat_map_iter(|j| {
            let rows = &rows;
            let kernel = &kernel;
            (0..nx).map(move |i| kernel.iter().zip(&rows[j..]).map(|(k, r)| k * r[i]).sum())
        })
        .collect()
}

/// The rigid registration error of view `view`: rotation about `centre` then translation.
fn registration_error(
    cfg: &ScannerConfig,
    view: usize,
    centre: &Point3,
) -> (Isometry3, [Real; 3], [Real; 3]) {
    let rng = CounterRng::new(cfg.seed ^ STREAM_REGISTRATION);
    let m = &cfg.misregistration;
    let g = |k: usize| rng.normal((view * 8 + k) as u64);
    let t = [g(0), g(1), g(2)].map(|x| x * m.translation_sigma_mm);
    let r = [g(3), g(4), g(5)].map(|x| x * m.rotation_sigma_rad);
    let rot = Rotation3::from_scaled_axis(Vector3::new(r[0], r[1], r[2]));
    let c = centre.coords;
    let shift = c - rot * c + Vector3::new(t[0], t[1], t[2]);
    (Isometry3::from_parts(shift.into(), rot), t, r)
}

struct ViewOutput {
    points: Vec<Point3>,
    lines: Vec<u32>,
    report: ViewReport,
}

/// One view: the part turned by `table` (W → W), scanned from the configured pose.
fn scan_view(
    index: &SplatIndex,
    cfg: &ScannerConfig,
    view: usize,
    table_deg: Real,
    table: &Isometry3,
    rays_per_view: u64,
    progress: &dyn Progress,
) -> ViewOutput {
    // Turning the part by `table` is turning the scanner by its inverse.
    let inv = table.inverse();
    let position = inv * cfg.position;
    let target = inv * cfg.target;
    let forward = (target - position).normalize();
    let right = forward.cross(&(inv * cfg.up)).normalize();
    let up = right.cross(&forward);
    let projector = position + right * cfg.baseline_mm;
    let nx = ((cfg.fov_mm.0 / cfg.pitch_mm).round() as usize).max(1);
    let ny = ((cfg.fov_mm.1 / cfg.pitch_mm).round() as usize).max(1);
    let (px, py) = (cfg.fov_mm.0 / nx as Real, cfg.fov_mm.1 / ny as Real);
    let rng = CounterRng::new(cfg.seed);
    let stream = view as u64 * rays_per_view;
    let field = (cfg.noise_sigma_mm > 0.0 && cfg.noise_correlation_mm > 0.0).then(|| {
        // Each view's field from its own generator: the white grid is larger than the image.
        let key = (view as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        let field_rng = CounterRng::new(cfg.seed ^ STREAM_FIELD ^ key);
        correlated_field(nx, ny, cfg.noise_correlation_mm / px.min(py), &field_rng)
    });
    let cos_limit = cfg.grazing_limit_deg.to_radians().cos();
    let (near, far) = cfg.working_range_mm;
    // A projector ray blocked more than this before the point is a shadow: two splat radii
    // cover the splat discs' overhang at edges.
    let shadow_tol = 2.0 * index.radius;
    let (registration, t, r) = registration_error(cfg, view, &target);
    #[derive(Default)]
    struct Row {
        points: Vec<Point3>,
        lines: Vec<u32>,
        shadowed: usize,
        grazing: usize,
        out_of_range: usize,
    }
    let rows: Vec<Row> = (0..ny)
        .into_par_iter()
        .map(|j| {
            let mut row = Row::default();
            for i in 0..nx {
                let on_target = target
                    + right * (-cfg.fov_mm.0 / 2.0 + (i as Real + 0.5) * px)
                    + up * (cfg.fov_mm.1 / 2.0 - (j as Real + 0.5) * py);
                let d = (on_target - position).normalize();
                let Some((t, id)) = index.first_hit(&position, &d, 0.0) else {
                    continue;
                };
                let splat = &index.splats[id];
                if t < near || t > far {
                    row.out_of_range += 1;
                    continue;
                }
                if -splat.n.dot(&d) < cos_limit {
                    row.grazing += 1;
                    continue;
                }
                let h = position + d * t;
                let to_point = h - projector;
                let dist = to_point.norm();
                let lit = splat.n.dot(&to_point) < 0.0
                    && match index.first_hit(&projector, &(to_point / dist), 0.0) {
                        Some((tp, _)) => tp >= dist - shadow_tol,
                        None => false,
                    };
                if !lit {
                    row.shadowed += 1;
                    continue;
                }
                let pixel = j * nx + i;
                let noise = match &field {
                    Some(f) => cfg.noise_sigma_mm * f[pixel],
                    None if cfg.noise_sigma_mm > 0.0 => {
                        cfg.noise_sigma_mm * rng.normal(stream + pixel as u64)
                    }
                    None => 0.0,
                };
                row.points.push(registration * (h + d * noise));
                row.lines.push(splat.line);
            }
            progress.advance(1);
            row
        })
        .collect();
    let mut out = ViewOutput {
        points: Vec::new(),
        lines: Vec::new(),
        report: ViewReport {
            table_deg,
            points: 0,
            shadowed: 0,
            grazing: 0,
            out_of_range: 0,
            misregistration_mm: t,
            misregistration_rad: r,
        },
    };
    for row in rows {
        out.points.extend(row.points);
        out.lines.extend(row.lines);
        out.report.shadowed += row.shadowed;
        out.report.grazing += row.grazing;
        out.report.out_of_range += row.out_of_range;
    }
    out.report.points = out.points.len();
    out
}

/// The stock's surface prepared for scanning (its splats, indexed): build once, scan many
/// times with different scanner settings.
pub struct Surface {
    index: SplatIndex,
}

impl Surface {
    /// Indexes the stock's crossings.
    pub fn new(stock: &TriDexel) -> Self {
        Self {
            index: SplatIndex::build(stock),
        }
    }

    /// Scans it: every view, merged into frame W.
    pub fn scan(&self, cfg: &ScannerConfig, progress: &dyn Progress) -> Result<Scan, ScanError> {
        scan_surface(&self.index, cfg, progress)
    }
}

/// Scans the stock: every view, merged into frame W.
pub fn scan(
    stock: &TriDexel,
    cfg: &ScannerConfig,
    progress: &dyn Progress,
) -> Result<Scan, ScanError> {
    cfg.validate()?;
    Surface::new(stock).scan(cfg, progress)
}

fn scan_surface(
    index: &SplatIndex,
    cfg: &ScannerConfig,
    progress: &dyn Progress,
) -> Result<Scan, ScanError> {
    cfg.validate()?;
    let tables: Vec<(Real, Isometry3)> = match &cfg.turntable {
        None => vec![(0.0, Isometry3::identity())],
        Some(t) => t
            .angles_deg
            .iter()
            .map(|&a| {
                let rot = Rotation3::from_axis_angle(&t.axis, a.to_radians());
                let c = t.axis_point.coords;
                (a, Isometry3::from_parts((c - rot * c).into(), rot))
            })
            .collect(),
    };
    let nx = ((cfg.fov_mm.0 / cfg.pitch_mm).round() as usize).max(1);
    let ny = ((cfg.fov_mm.1 / cfg.pitch_mm).round() as usize).max(1);
    progress.start("scan", (ny * tables.len()) as u64);
    let mut points = Vec::new();
    let mut lines = Vec::new();
    let mut view_of_point = Vec::new();
    let mut views = Vec::new();
    for (v, (deg, table)) in tables.iter().enumerate() {
        let out = scan_view(index, cfg, v, *deg, table, (nx * ny) as u64, progress);
        view_of_point.extend(std::iter::repeat_n(v as u16, out.points.len()));
        points.extend(out.points);
        lines.extend(out.lines);
        views.push(out.report);
    }
    progress.finish();
    Ok(Scan {
        cloud: PointCloud::new(Frame::Workpiece, points),
        lines,
        view_of_point,
        rays: nx * ny * tables.len(),
        views,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progress::NoProgress;

    fn cfg() -> ScannerConfig {
        ScannerConfig {
            position: Point3::new(0.0, -300.0, 50.0),
            target: Point3::new(0.0, 0.0, 0.0),
            up: Vector3::z(),
            baseline_mm: 80.0,
            fov_mm: (40.0, 30.0),
            pitch_mm: 0.5,
            noise_sigma_mm: 0.0,
            noise_correlation_mm: 0.0,
            working_range_mm: (200.0, 400.0),
            grazing_limit_deg: 80.0,
            misregistration: Misregistration::default(),
            turntable: None,
            seed: 1,
        }
    }

    fn front_face(c: &Scan) -> Vec<Point3> {
        c.cloud
            .points
            .iter()
            .filter(|p| p.z < 4.0 && p.x.abs() < 9.0 && p.y < 1.0)
            .copied()
            .collect()
    }

    #[test]
    fn correlated_field_has_unit_variance_and_the_given_correlation() {
        let (nx, ny, corr) = (400, 400, 5.0);
        let f = correlated_field(nx, ny, corr, &CounterRng::new(3));
        let n = f.len() as Real;
        let mean = f.iter().sum::<Real>() / n;
        let var = f.iter().map(|x| (x - mean).powi(2)).sum::<Real>() / n;
        // About 160,000 / (2π·25) ≈ 1,000 independent patches: σ(var) ≈ 0.045.
        assert!((var - 1.0).abs() < 0.15, "variance {var}");
        let lag = corr as usize;
        let mut acc = 0.0;
        let mut count = 0.0;
        for j in 0..ny {
            for i in 0..nx - lag {
                acc += (f[j * nx + i] - mean) * (f[j * nx + i + lag] - mean);
                count += 1.0;
            }
        }
        let rho = acc / count / var;
        // exp(−ℓ²/(2ℓ²)) = e^(−1/2) = 0.607 at a lag of one correlation length.
        assert!(
            (rho - (-0.5f64).exp()).abs() < 0.08,
            "autocorrelation {rho}"
        );
    }

    #[test]
    fn steep_faces_and_far_points_drop_out() {
        let stock = box_stock();
        // The top face z = 5 is seen at about 81.5° from its normal from this pose
        // (camera 50 mm up at 300 mm): an 89° limit keeps it, 60° drops it; the front face
        // (seen at ~10°) stays.
        let mut c = cfg();
        c.grazing_limit_deg = 89.0;
        let all = scan(&stock, &c, &NoProgress).expect("scans");
        c.grazing_limit_deg = 60.0;
        let steep = scan(&stock, &c, &NoProgress).expect("scans");
        let top = |s: &Scan| {
            s.cloud
                .points
                .iter()
                .filter(|p| (p.z - 5.0).abs() < 1e-9)
                .count()
        };
        assert!(
            top(&all) > 0 && top(&steep) == 0,
            "top {} / {}",
            top(&all),
            top(&steep)
        );
        assert_eq!(front_face(&all).len(), front_face(&steep).len());
        assert!(steep.views[0].grazing > 0);
        // Working range that ends before the part: nothing measured.
        c.working_range_mm = (100.0, 250.0);
        let near = scan(&stock, &c, &NoProgress).expect("scans");
        assert!(near.cloud.points.is_empty() && near.views[0].out_of_range > 0);
    }

    #[test]
    fn misregistration_moves_a_view_rigidly() {
        let stock = box_stock();
        let exact = scan(&stock, &cfg(), &NoProgress).expect("scans");
        let mut c = cfg();
        c.misregistration.translation_sigma_mm = 0.05;
        let moved = scan(&stock, &c, &NoProgress).expect("scans");
        let t = moved.views[0].misregistration_mm;
        assert!(t.iter().any(|x| x.abs() > 1e-4));
        assert_eq!(exact.cloud.points.len(), moved.cloud.points.len());
        for (a, b) in exact.cloud.points.iter().zip(&moved.cloud.points) {
            assert!((b - a - Vector3::new(t[0], t[1], t[2])).norm() < 1e-12);
        }
    }

    #[test]
    fn turntable_views_are_merged_in_the_workpiece_frame() {
        let stock = box_stock();
        let mut c = cfg();
        c.turntable = Some(Turntable {
            axis_point: Point3::new(0.0, 5.0, 0.0),
            axis: Vector3::z_axis(),
            angles_deg: vec![0.0, 180.0],
        });
        let s = scan(&stock, &c, &NoProgress).expect("scans");
        assert_eq!(s.views.len(), 2);
        assert_eq!(s.view_of_point.len(), s.cloud.points.len());
        // The second view sees the back face y = 10, registered where it is.
        let back: Vec<_> = s
            .cloud
            .points
            .iter()
            .filter(|p| p.z < 4.0 && p.x.abs() < 9.0 && p.y > 9.0)
            .collect();
        assert!(back.len() > 600, "back points {}", back.len());
        assert!(back.iter().all(|p| (p.y - 10.0).abs() < 1e-9));
        assert!(front_face(&s).iter().all(|p| p.y.abs() < 1e-9));
    }

    /// A 20 × 10 × 10 mm box whose front face is y = 0.
    fn box_stock() -> TriDexel {
        let bounds = Aabb {
            min: Point3::new(-10.0, 0.0, -5.0),
            max: Point3::new(10.0, 10.0, 5.0),
        };
        TriDexel::new_box(bounds, 0.3, 1e9).expect("fits")
    }

    #[test]
    fn points_of_a_box_face_lie_on_it() {
        let stock = box_stock();
        let s = scan(&stock, &cfg(), &NoProgress).expect("scans");
        // The camera sees the front face y = 0 and the top face z = 5.
        let front = s
            .cloud
            .points
            .iter()
            .filter(|p| p.z < 4.0 && p.x.abs() < 9.0)
            .count();
        // 18 × 9 mm of the front face at 0.5 mm pitch: about 650 points.
        assert!(front > 600, "front points {front}");
        for p in s
            .cloud
            .points
            .iter()
            .filter(|p| p.z < 4.0 && p.x.abs() < 9.0)
        {
            assert!(p.y.abs() < 1e-9, "{p}");
        }
    }

    #[test]
    fn noise_is_along_the_ray_with_the_given_sigma() {
        let stock = box_stock();
        let mut c = cfg();
        c.noise_sigma_mm = 0.025;
        let s = scan(&stock, &c, &NoProgress).expect("scans");
        let ys: Vec<Real> = s
            .cloud
            .points
            .iter()
            .filter(|p| p.z < 4.0 && p.x.abs() < 9.0)
            .map(|p| p.y)
            .collect();
        let n = ys.len() as Real;
        let mean = ys.iter().sum::<Real>() / n;
        let sd = (ys.iter().map(|y| (y - mean).powi(2)).sum::<Real>() / (n - 1.0)).sqrt();
        // Along y the ray noise is scaled by the ray's y component (≈ 0.98 here).
        assert!((sd / 0.025 - 0.985).abs() < 0.05, "sd {sd}");
        assert!(mean.abs() < 4.0 * sd / n.sqrt(), "mean {mean}");
        // Same seed, same cloud.
        assert_eq!(scan(&stock, &c, &NoProgress).expect("scans"), s);
    }
}
