//! The virtual double ball bar (DBB) on a hexapod: seed 000's instrument, run on the twin.
//!
//! # Model
//!
//! The **table ball** is fixed on the table at its nominal centre `c` (base frame, mm) plus
//! a mounting error `m`; the **tool ball** sits at the tool point (the spindle's ball). A
//! circle is run about `c` with the bar of length `R` at an elevation `φ` (the *tilt*) out
//! of a plane with in-plane axes `e₁, e₂` and normal `n = e₁ × e₂` (`XY`, `YZ` or `ZX`): at
//! the angle `θ` from `e₁` towards `e₂` the controller commands the tool point to
//!
//! ```text
//! p(θ) = c + R·(cos φ·cos θ·e₁ + cos φ·sin θ·e₂ + sin φ·n)
//! ```
//!
//! with the platform at the circle's orientation `(a, b, c)`, swung by `s` along the bar's
//! direction: `(a − s·sin θ, b + s·cos θ, c)` (`s = 0`: held). The controller turns the
//! command into strut readings on the *nominal* parameters; the machine reaches
//! `FK_actual(IK_nominal(command))` ([`twin_pose`]). The bar reads its length, and the
//! sample is `|p_reached − (c + m)| − R + σ·n_k` (mm): exact 3-D geometry, nothing
//! linearised, so a perfect machine with a perfectly mounted ball reads zero everywhere. A
//! tilted bar (`φ ≠ 0`) is how seed 000 makes the circles sensitive to z.
//!
//! # Runs and noise
//!
//! `ccw` is `θ` increasing from 0°, `cw` decreasing; each run has `points` samples at
//! `θ = ±k·360°/points`, recorded in [0°, 360°). Sample `k` of run `r` adds `σ·n`, `n` the
//! counter-based normal deviate of `(seed, stream + r·points + k)`: the same set-up and seed
//! give the same trace; distinct `stream` offsets give independent circles.
//!
//! **Invariant:** the trace is what [`super::circular::evaluate`] reads (one or both
//! directions, `points` samples each over the whole circle, every value finite); a set-up
//! with a non-finite or out-of-range value, or a commanded pose the nominal machine cannot
//! reach, is an error before any sample is taken.

use super::ballbar::Turns;
use super::circular::{Sample, Turn, trace_csv};
use crate::machine::hexapod::{Hexapod, HexapodError, Pose, twin_pose};
use crate::math::{CounterRng, Real, Vector3};

/// Fewest samples per revolution (what [`super::circular::evaluate`] needs).
pub const MIN_POINTS: usize = 8;
/// Most samples per revolution: far above a real DBB's sampling, low enough to bound time.
pub const MAX_POINTS: usize = 100_000;
/// Longest bar (mm): DBB extension bars reach about 600 mm.
pub const MAX_RADIUS_MM: Real = 1000.0;
/// Largest |tilt| of the bar out of its plane (degrees): beyond it the circle degenerates.
pub const MAX_TILT_DEG: Real = 85.0;
/// Largest length-noise σ (mm): far above a DBB's ±0.5 µm class, a guard against a unit
/// mistake.
pub const MAX_NOISE_MM: Real = 0.1;

/// The plane a circle is run in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DbbPlane {
    /// In-plane axes x, y; normal +z.
    XY,
    /// In-plane axes y, z; normal +x.
    YZ,
    /// In-plane axes z, x; normal +y.
    ZX,
}

impl DbbPlane {
    /// The plane of `XY`, `YZ` or `ZX` (any case).
    pub fn from_name(name: &str) -> Option<DbbPlane> {
        match name.to_ascii_uppercase().as_str() {
            "XY" => Some(DbbPlane::XY),
            "YZ" => Some(DbbPlane::YZ),
            "ZX" => Some(DbbPlane::ZX),
            _ => None,
        }
    }

    /// `XY`, `YZ` or `ZX`.
    pub fn name(self) -> &'static str {
        match self {
            DbbPlane::XY => "XY",
            DbbPlane::YZ => "YZ",
            DbbPlane::ZX => "ZX",
        }
    }

    /// `(e₁, e₂, n)`.
    pub fn basis(self) -> (Vector3, Vector3, Vector3) {
        let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
        match self {
            DbbPlane::XY => (x, y, z),
            DbbPlane::YZ => (y, z, x),
            DbbPlane::ZX => (z, x, y),
        }
    }
}

/// One DBB circle (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct DbbCircle {
    /// The table ball's nominal centre (base frame, mm).
    pub centre_mm: Vector3,
    /// The bar length R (mm, in (0, [`MAX_RADIUS_MM`]]).
    pub radius_mm: Real,
    /// The plane.
    pub plane: DbbPlane,
    /// The bar's elevation out of the plane, towards its normal (degrees, |φ| ≤
    /// [`MAX_TILT_DEG`]).
    pub tilt_deg: Real,
    /// The platform's orientation a, b, c at the circle's centre angle (degrees).
    pub orientation_deg: [Real; 3],
    /// The platform's swing while the circle runs (degrees, |s| ≤ [`MAX_TILT_DEG`]): at `θ`
    /// the orientation is `(a − s·sin θ, b + s·cos θ, c)`, the tool leaning along the bar's
    /// direction — seed 000's arcs run while the tilt changes.
    pub swing_deg: Real,
    /// Directions run.
    pub turns: Turns,
    /// Samples per revolution ([`MIN_POINTS`]…[`MAX_POINTS`]).
    pub points: usize,
}

/// The instrument's set-up apart from the circle: the table ball's mounting error and the
/// length noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DbbInstrument {
    /// Table ball's centre minus its nominal centre (base frame, mm).
    pub mount_mm: Vector3,
    /// σ of the length reading (mm, in [0, [`MAX_NOISE_MM`]]).
    pub noise_sigma_mm: Real,
    /// Seed of the noise.
    pub seed: u64,
    /// First noise stream of this circle.
    pub stream: u64,
}

/// A set-up the DBB cannot measure.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DbbError {
    /// A value out of its range or not finite.
    #[error("ball bar: {0}")]
    Setup(String),
    /// A commanded pose the nominal machine cannot reach, or the actual machine's forward
    /// kinematics failing there.
    #[error("ball bar: at θ = {angle_deg:.3}° ({pose}): {source}")]
    Unreachable {
        /// The angle of the sample (degrees).
        angle_deg: Real,
        /// The commanded pose.
        pose: String,
        /// Why.
        source: HexapodError,
    },
}

impl DbbCircle {
    /// Checks every value (see the field docs).
    pub fn validate(&self) -> Result<(), DbbError> {
        let bad = |m: String| Err(DbbError::Setup(m));
        if !self.centre_mm.iter().all(|v| v.is_finite()) {
            return bad("the centre must be finite".into());
        }
        if !(self.radius_mm.is_finite() && self.radius_mm > 0.0 && self.radius_mm <= MAX_RADIUS_MM)
        {
            return bad(format!(
                "the radius {} mm must lie in (0, {MAX_RADIUS_MM}] mm",
                self.radius_mm
            ));
        }
        if !(self.tilt_deg.is_finite() && self.tilt_deg.abs() <= MAX_TILT_DEG) {
            return bad(format!(
                "the tilt {}° must lie in [−{MAX_TILT_DEG}°, {MAX_TILT_DEG}°]",
                self.tilt_deg
            ));
        }
        if !(self.swing_deg.is_finite() && self.swing_deg.abs() <= MAX_TILT_DEG) {
            return bad(format!(
                "the swing {}° must lie in [−{MAX_TILT_DEG}°, {MAX_TILT_DEG}°]",
                self.swing_deg
            ));
        }
        if !self.orientation_deg.iter().all(|v| v.is_finite()) {
            return bad("the orientation must be finite".into());
        }
        if !(MIN_POINTS..=MAX_POINTS).contains(&self.points) {
            return bad(format!(
                "{} points per revolution: must lie in {MIN_POINTS}…{MAX_POINTS}",
                self.points
            ));
        }
        Ok(())
    }

    /// The commanded tool pose at `θ` (rad).
    pub fn command(&self, theta: Real) -> Pose {
        let (e1, e2, n) = self.plane.basis();
        let (sp, cp) = self.tilt_deg.to_radians().sin_cos();
        let (st, ct) = theta.sin_cos();
        let p = self.centre_mm + self.radius_mm * (cp * ct * e1 + cp * st * e2 + sp * n);
        let o = self.orientation_deg;
        let sw = self.swing_deg;
        let mut pose = Pose::from_mm_deg([0.0, 0.0, 0.0, o[0] - sw * st, o[1] + sw * ct, o[2]]);
        pose.position = p;
        pose
    }

    /// The samples' angles in run order, with their direction (rad, in [0, 2π)).
    pub fn angles(&self) -> Vec<(Turn, Real)> {
        let tau = std::f64::consts::TAU;
        let mut out = Vec::with_capacity(self.turns.runs().len() * self.points);
        for &turn in self.turns.runs() {
            for k in 0..self.points {
                let t = tau * k as Real / self.points as Real;
                let t = match turn {
                    Turn::Ccw => t,
                    Turn::Cw => (tau - t).rem_euclid(tau),
                };
                out.push((turn, t));
            }
        }
        out
    }

    /// Path length of the runs (mm): the tool ball's circles, `2π·R·cos φ` per run.
    pub fn path_length_mm(&self) -> Real {
        let runs = self.turns.runs().len() as Real;
        runs * std::f64::consts::TAU * self.radius_mm * self.tilt_deg.to_radians().cos()
    }

    /// One line: centre, radius, plane, tilt, orientation.
    pub fn describe(&self) -> String {
        let c = self.centre_mm;
        let o = self.orientation_deg;
        format!(
            "centre ({:.1}, {:.1}, {:.1}) mm, R {} mm, {} plane, tilt {}°, platform a {}° b {}° c {}°, swing {}°",
            c.x,
            c.y,
            c.z,
            self.radius_mm,
            self.plane.name(),
            self.tilt_deg,
            o[0],
            o[1],
            o[2],
            self.swing_deg
        )
    }
}

/// The circle a trace file's header records: its `#` line in [`DbbCircle::describe`]'s
/// form, which `twinmill ballbar --out` writes (the centre to 0.1 mm, the rest as given).
#[derive(Clone, Debug, PartialEq)]
pub struct RecordedCircle {
    /// 1-based line of the header line in the file.
    pub line: usize,
    /// The line as written (without the `#`).
    pub text: String,
    /// The table ball's nominal centre (mm, to 0.1 mm).
    pub centre_mm: Vector3,
    /// Bar length (mm).
    pub radius_mm: Real,
    /// The plane.
    pub plane: DbbPlane,
    /// Bar tilt (degrees).
    pub tilt_deg: Real,
    /// Platform orientation a, b, c (degrees).
    pub orientation_deg: [Real; 3],
    /// Swing (degrees).
    pub swing_deg: Real,
}

impl RecordedCircle {
    /// The first `#` line of `text` that describes a circle, or `None` (a trace from
    /// another instrument's software records none).
    pub fn from_header(text: &str) -> Option<RecordedCircle> {
        text.lines().enumerate().find_map(|(i, l)| {
            let body = l.trim().strip_prefix('#')?.trim();
            Self::parse(body).map(|mut r| {
                r.line = i + 1;
                r
            })
        })
    }

    fn parse(body: &str) -> Option<RecordedCircle> {
        // centre (x, y, z) mm, R r mm, P plane, tilt t°, platform a A° b B° c C°, swing S°
        let num = |t: &str| t.trim().parse::<Real>().ok().filter(|v| v.is_finite());
        let (centre, rest) = body.strip_prefix("centre (")?.split_once(") mm, R ")?;
        let c: Vec<Real> = centre.split(',').map(num).collect::<Option<_>>()?;
        let [x, y, z] = c[..] else { return None };
        let (r, rest) = rest.split_once(" mm, ")?;
        let (plane, rest) = rest.split_once(" plane, tilt ")?;
        let (tilt, rest) = rest.split_once("°, platform a ")?;
        let (a, rest) = rest.split_once("° b ")?;
        let (b, rest) = rest.split_once("° c ")?;
        let (cc, rest) = rest.split_once("°, swing ")?;
        let swing = rest.strip_suffix('°')?;
        Some(RecordedCircle {
            line: 0,
            text: body.to_string(),
            centre_mm: Vector3::new(x, y, z),
            radius_mm: num(r)?,
            plane: DbbPlane::from_name(plane.trim())?,
            tilt_deg: num(tilt)?,
            orientation_deg: [num(a)?, num(b)?, num(cc)?],
            swing_deg: num(swing)?,
        })
    }

    /// How the recorded circle differs from `circle`, in words (empty: it is that circle).
    /// The centre is compared to the 0.1 mm it is written to, the rest to 1e-9.
    pub fn differences(&self, circle: &DbbCircle) -> Vec<String> {
        let mut out = Vec::new();
        let same = |a: Real, b: Real| (a - b).abs() <= 1e-9 * (1.0 + b.abs());
        if (self.centre_mm - circle.centre_mm)
            .iter()
            .any(|d| d.abs() > 0.05 + 1e-9)
        {
            let c = circle.centre_mm;
            out.push(format!(
                "centre ({:.1}, {:.1}, {:.1}) mm, not ({:.1}, {:.1}, {:.1})",
                self.centre_mm.x, self.centre_mm.y, self.centre_mm.z, c.x, c.y, c.z
            ));
        }
        if !same(self.radius_mm, circle.radius_mm) {
            out.push(format!("R {} mm, not {}", self.radius_mm, circle.radius_mm));
        }
        if self.plane != circle.plane {
            out.push(format!(
                "{} plane, not {}",
                self.plane.name(),
                circle.plane.name()
            ));
        }
        if !same(self.tilt_deg, circle.tilt_deg) {
            out.push(format!("tilt {}°, not {}°", self.tilt_deg, circle.tilt_deg));
        }
        let (o, p) = (self.orientation_deg, circle.orientation_deg);
        if !(0..3).all(|k| same(o[k], p[k])) {
            out.push(format!(
                "platform a {}° b {}° c {}°, not a {}° b {}° c {}°",
                o[0], o[1], o[2], p[0], p[1], p[2]
            ));
        }
        if !same(self.swing_deg, circle.swing_deg) {
            out.push(format!(
                "swing {}°, not {}°",
                self.swing_deg, circle.swing_deg
            ));
        }
        out
    }
}

impl DbbInstrument {
    /// Checks the mounting error and the noise.
    pub fn validate(&self) -> Result<(), DbbError> {
        if !self.mount_mm.iter().all(|v| v.is_finite()) {
            return Err(DbbError::Setup("the mounting error must be finite".into()));
        }
        if !(self.noise_sigma_mm.is_finite() && (0.0..=MAX_NOISE_MM).contains(&self.noise_sigma_mm))
        {
            return Err(DbbError::Setup(format!(
                "the noise σ {} mm must lie in [0, {MAX_NOISE_MM}] mm",
                self.noise_sigma_mm
            )));
        }
        Ok(())
    }
}

/// What the DBB measured on one circle.
#[derive(Clone, Debug, PartialEq)]
pub struct DbbMeasurement {
    /// The trace (per run in order; deviation = bar length − R).
    pub samples: Vec<Sample>,
    /// The commanded pose of each sample.
    pub commands: Vec<Pose>,
    /// Where the table ball is (base frame, mm).
    pub table_ball_mm: Vector3,
}

impl DbbMeasurement {
    /// The trace file (`circular`'s CSV) with `comments` as `#` lines above it.
    pub fn csv(&self, comments: &[String]) -> String {
        trace_csv(&self.samples, comments)
    }

    /// The bar lengths read (mm): `R` plus each deviation.
    pub fn lengths_mm(&self, radius_mm: Real) -> Vec<Real> {
        self.samples
            .iter()
            .map(|s| radius_mm + s.deviation_mm)
            .collect()
    }
}

/// Runs `circle` with `instrument` on the `actual` machine commanded through `nominal`.
pub fn measure(
    nominal: &Hexapod,
    actual: &Hexapod,
    circle: &DbbCircle,
    instrument: &DbbInstrument,
) -> Result<DbbMeasurement, DbbError> {
    circle.validate()?;
    instrument.validate()?;
    let angles = circle.angles();
    let commands: Vec<Pose> = angles.iter().map(|&(_, t)| circle.command(t)).collect();
    let rng = CounterRng::new(instrument.seed);
    let ball = circle.centre_mm + instrument.mount_mm;
    let mut samples = Vec::with_capacity(angles.len());
    for (k, (&(turn, theta), cmd)) in angles.iter().zip(&commands).enumerate() {
        let reached = twin_pose(nominal, actual, cmd).map_err(|source| DbbError::Unreachable {
            angle_deg: theta.to_degrees(),
            pose: cmd.to_string(),
            source,
        })?;
        let noise = if instrument.noise_sigma_mm > 0.0 {
            instrument.noise_sigma_mm * rng.normal(instrument.stream + k as u64)
        } else {
            0.0
        };
        let deviation = (reached.position - ball).norm() - circle.radius_mm + noise;
        samples.push(Sample {
            turn,
            angle_rad: theta,
            deviation_mm: deviation,
        });
    }
    Ok(DbbMeasurement {
        samples,
        commands,
        table_ball_mm: ball,
    })
}
