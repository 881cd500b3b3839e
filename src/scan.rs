//! A virtual structured-light scanner (EinScan-SP class, BRIEF §6) that measures the cut
//! stock.
//!
//! The surface it sees is the tri-dexel's: every crossing is an exact surface point with
//! its exact normal, and is drawn as a small disc (a *splat*) in its tangent plane, of
//! radius one dexel spacing, which covers any face without holes. A camera ray's first
//! front-facing splat gives the measured point. On a planar face all splats are coplanar,
//! so the points lie on the true plane to rounding, at any viewing angle.
//!
//! The scanner is a pinhole camera and a projector offset by a baseline: a point is
//! measured only if the projector lights it too (occlusion, as in real triangulation
//! scanners). Range noise is Gaussian along the camera ray, from a counter-based generator
//! keyed by the seed and the pixel index, so the cloud is identical for any thread count.
//!
//! **Invariant:** the scanner reads the stock and never changes it; it knows nothing about
//! the machine or the program (a point's source NC line is read off the crossing).

use crate::cloud::{Frame, PointCloud};
use crate::math::{Aabb, CounterRng, Point3, Real, Vector3, tol};
use crate::progress::Progress;
use crate::stock::TriDexel;
use rayon::prelude::*;

/// Scanner pose and characteristics. All lengths in mm, frame W.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScannerConfig {
    /// Camera centre.
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
    /// Seed of the noise.
    pub seed: u64,
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

/// The result of a scan.
#[derive(Clone, Debug, PartialEq)]
pub struct Scan {
    /// The measured points, frame W.
    pub cloud: PointCloud,
    /// For each point, the NC line whose cut made the surface there (0: stock face).
    pub lines: Vec<u32>,
    /// Camera rays cast.
    pub rays: usize,
    /// Points seen by the camera but in the projector's shadow (not measured).
    pub shadowed: usize,
}

/// Rays per scan, at most.
const MAX_RAYS: u64 = 50_000_000;

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
        let rays =
            (self.fov_mm.0 / self.pitch_mm).round() * (self.fov_mm.1 / self.pitch_mm).round();
        if rays > MAX_RAYS as Real {
            return Err(ScanError::TooManyRays {
                rays: rays as u64,
                max: MAX_RAYS,
            });
        }
        Ok(())
    }
}

/// Scans the stock.
pub fn scan(
    stock: &TriDexel,
    cfg: &ScannerConfig,
    progress: &dyn Progress,
) -> Result<Scan, ScanError> {
    cfg.validate()?;
    let index = SplatIndex::build(stock);
    let forward = (cfg.target - cfg.position).normalize();
    let right = forward.cross(&cfg.up).normalize();
    let up = right.cross(&forward);
    let projector = cfg.position + right * cfg.baseline_mm;
    let nx = ((cfg.fov_mm.0 / cfg.pitch_mm).round() as usize).max(1);
    let ny = ((cfg.fov_mm.1 / cfg.pitch_mm).round() as usize).max(1);
    let (px, py) = (cfg.fov_mm.0 / nx as Real, cfg.fov_mm.1 / ny as Real);
    let rng = CounterRng::new(cfg.seed);
    // A projector ray blocked more than this before the point is a shadow: two splat radii
    // cover the splat discs' overhang at edges.
    let shadow_tol = 2.0 * index.radius;
    progress.start("scan", ny as u64);
    let rows: Vec<(Vec<Point3>, Vec<u32>, usize)> = (0..ny)
        .into_par_iter()
        .map(|j| {
            let mut pts = Vec::new();
            let mut lines = Vec::new();
            let mut shadowed = 0;
            for i in 0..nx {
                let on_target = cfg.target
                    + right * (-cfg.fov_mm.0 / 2.0 + (i as Real + 0.5) * px)
                    + up * (cfg.fov_mm.1 / 2.0 - (j as Real + 0.5) * py);
                let d = (on_target - cfg.position).normalize();
                let Some((t, id)) = index.first_hit(&cfg.position, &d, 0.0) else {
                    continue;
                };
                let h = cfg.position + d * t;
                let splat = &index.splats[id];
                let to_point = h - projector;
                let dist = to_point.norm();
                let lit = splat.n.dot(&to_point) < 0.0
                    && match index.first_hit(&projector, &(to_point / dist), 0.0) {
                        Some((tp, _)) => tp >= dist - shadow_tol,
                        None => false,
                    };
                if !lit {
                    shadowed += 1;
                    continue;
                }
                let pixel = (j * nx + i) as u64;
                let noise = if cfg.noise_sigma_mm > 0.0 {
                    cfg.noise_sigma_mm * rng.normal(pixel)
                } else {
                    0.0
                };
                pts.push(h + d * noise);
                lines.push(splat.line);
            }
            progress.advance(1);
            (pts, lines, shadowed)
        })
        .collect();
    progress.finish();
    let mut points = Vec::new();
    let mut lines = Vec::new();
    let mut shadowed = 0;
    for (p, l, s) in rows {
        points.extend(p);
        lines.extend(l);
        shadowed += s;
    }
    Ok(Scan {
        cloud: PointCloud {
            frame: Frame::Workpiece,
            points,
        },
        lines,
        rays: nx * ny,
        shadowed,
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
            seed: 1,
        }
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
