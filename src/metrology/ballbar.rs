//! The virtual telescoping ball bar: ISO 230-4's circular test of two linear axes, measured
//! on the twin's chain.
//!
//! # Model
//!
//! The two axes of a plane (`XY`, `YZ` or `ZX`: machine axis letters, the first axis then
//! the second) run a circle of radius `R` about the centre command `c` (every axis's value;
//! the axes outside the plane stay there): at the angle `θ` from the first axis towards the
//! second, the command is `c + R(cos θ, sin θ)` on the two axes. The **centre ball** is fixed
//! in W where the nominal chain puts the tool ball at `c`, plus a mounting offset (a set-up
//! error, in W). The **tool ball** is at its offset from the tool point (in the tool frame
//! T) carried by the *deviated* chain. The bar reads its length: the sample at `θ` is
//! `|tool ball − centre ball| − R` (mm), exact in 3-D, nothing linearised — so on the nominal
//! machine every sample is zero, and every error motion, deviation, squareness and reversal
//! of the scene shows as the chain makes it.
//!
//! # A run
//!
//! Counter-clockwise (`ccw`) is `θ` increasing. A run is a feed-in arc of the overshoot
//! angle ending at `θ = 0°`, the data arc of 360° with `points` samples per revolution at
//! `θ = ±k·360°/points` (recorded as angles in [0°, 360°)), and a feed-out arc of the
//! overshoot beyond 360° — as ISO 230-4 and ball-bar software run it, so each axis has its
//! direction of travel established before the first sample. Both directions are one `ccw`
//! run then one `cw` run, the machine moving straight from the end of the first to the start
//! of the second. Every axis's reversal state follows the motion: each step between
//! consecutive points is split where an axis of the plane changes direction (the multiples of
//! 90°), and each piece goes through [`Chain::reversal_after_move`], so a reversal is taken up
//! over the travel exactly as the chain models it. Before the first arc every axis counts as
//! last moved in `+` (the chain's convention before any motion).
//!
//! The twin has no servo dynamics: the feed is recorded, not simulated (servo mismatch reads
//! zero on the twin).
//!
//! # Noise
//!
//! Sample `k` of run `r` adds `σ·n_i`, `n_i` the counter-based normal deviate of
//! `(seed, i = r·points + k)`. Same set-up and seed, same trace.
//!
//! **Invariant:** the trace is exactly what [`super::circular::evaluate`] reads — one or both
//! directions, `points` samples each over the whole circle, every value finite; a set-up
//! that cannot give one (a plane axis the machine lacks or that turns, a radius not
//! positive, too few points, a non-finite value) is an error before any sample is taken.

use super::circular::{Sample, Turn, trace_csv};
use super::table::{
    axis_values_record, number, parse_axis_values_record, parse_vector_record, setup_record,
};
use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::Directions;
use crate::math::{CounterRng, Point3, Real, Vector3};
use crate::nc::{AxisLetter, AxisValues};

/// Fewest samples per revolution (what [`super::circular::evaluate`] needs).
pub const MIN_POINTS: usize = 8;

/// Most samples per revolution: far above any real ball bar (a few thousand), low enough to
/// bound memory and time.
pub const MAX_POINTS: usize = 1_000_000;

/// Longest feed-in or feed-out arc (degrees).
pub const MAX_OVERSHOOT_DEG: Real = 720.0;

/// A set-up the ball bar cannot measure.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BallBarError {
    /// A plane axis that the machine lacks or that is not linear.
    #[error("plane {plane}: {message}")]
    Plane {
        /// The plane as given (`XY`).
        plane: &'static str,
        /// What is wrong.
        message: String,
    },
    /// A set-up value that is out of range or not finite, named by its field.
    #[error("{name}: {message}")]
    Setup {
        /// The set-up field (`centre`, `radius`, `points`, `overshoot`, `feed`, `tool_ball`,
        /// `mount`, `noise`).
        name: &'static str,
        /// What is wrong with it.
        message: String,
    },
}

fn setup_error(name: &'static str, message: String) -> BallBarError {
    BallBarError::Setup { name, message }
}

/// The plane of the circle, by its two machine axes (first, second).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plane {
    /// X then Y: θ from +X towards +Y.
    Xy,
    /// Y then Z: θ from +Y towards +Z.
    Yz,
    /// Z then X: θ from +Z towards +X.
    Zx,
}

impl Plane {
    /// The plane named `XY`, `YZ` or `ZX` (any case).
    pub fn from_name(name: &str) -> Option<Plane> {
        match name.to_ascii_uppercase().as_str() {
            "XY" => Some(Plane::Xy),
            "YZ" => Some(Plane::Yz),
            "ZX" => Some(Plane::Zx),
            _ => None,
        }
    }

    /// `XY`, `YZ` or `ZX`.
    pub fn name(self) -> &'static str {
        match self {
            Plane::Xy => "XY",
            Plane::Yz => "YZ",
            Plane::Zx => "ZX",
        }
    }

    /// The first and second axes.
    pub fn axes(self) -> (AxisLetter, AxisLetter) {
        match self {
            Plane::Xy => (AxisLetter::X, AxisLetter::Y),
            Plane::Yz => (AxisLetter::Y, AxisLetter::Z),
            Plane::Zx => (AxisLetter::Z, AxisLetter::X),
        }
    }
}

/// Which directions are run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Turns {
    /// Counter-clockwise only.
    Ccw,
    /// Clockwise only.
    Cw,
    /// One counter-clockwise run, then one clockwise run.
    Both,
}

impl Turns {
    /// The runs in order.
    pub fn runs(self) -> &'static [Turn] {
        match self {
            Turns::Ccw => &[Turn::Ccw],
            Turns::Cw => &[Turn::Cw],
            Turns::Both => &[Turn::Ccw, Turn::Cw],
        }
    }
}

/// The set-up of a ball-bar test.
#[derive(Clone, Debug, PartialEq)]
pub struct BallBarSetup {
    /// The plane of the circle.
    pub plane: Plane,
    /// The centre command: every axis's value (mm, degrees); the axes outside the plane
    /// stay at theirs.
    pub centre: AxisValues,
    /// The bar's nominal length, the circle's radius (mm, > 0).
    pub radius_mm: Real,
    /// The directions run.
    pub turns: Turns,
    /// The programmed feed (mm/min, > 0): recorded; the twin has no servo dynamics.
    pub feed_mm_per_min: Real,
    /// The feed-in and feed-out arcs (degrees, 0 to [`MAX_OVERSHOOT_DEG`]).
    pub overshoot_deg: Real,
    /// Samples per revolution ([`MIN_POINTS`] to [`MAX_POINTS`]).
    pub points: usize,
    /// The tool ball's centre in the tool frame T (mm).
    pub tool_ball_mm: Vector3,
    /// The centre ball's mounting offset from where the nominal machine puts the tool ball
    /// at the centre command, in W (mm).
    pub mount_offset_mm: Vector3,
    /// Gaussian noise of each sample, σ (µm, ≥ 0).
    pub noise_um: Real,
    /// Seed of the noise.
    pub seed: u64,
}

impl BallBarSetup {
    /// A circle of `radius_mm` in `plane` about `centre`, as ball-bar software runs it by
    /// default: both directions, 180° feed-in and feed-out, 360 points per revolution, feed
    /// 1000 mm/min, balls at the tool point and the centre command, no noise, seed 1.
    pub fn new(plane: Plane, centre: AxisValues, radius_mm: Real) -> Self {
        Self {
            plane,
            centre,
            radius_mm,
            turns: Turns::Both,
            feed_mm_per_min: 1000.0,
            overshoot_deg: 180.0,
            points: 360,
            tool_ball_mm: Vector3::zeros(),
            mount_offset_mm: Vector3::zeros(),
            noise_um: 0.0,
            seed: 1,
        }
    }

    /// The set-up as the trace file records it (see [`super::table::SETUP_MARKER`]):
    /// `ballbar plane=XY centre=X:0.0,… radius_mm=100.0 turns=both overshoot_deg=180.0
    /// points=360 tool_ball_mm=0.0,0.0,0.0 noise_um=0.5`, every number exact. The centre
    /// ball's mounting error is not recorded: the user does not know it, and an
    /// identification estimates it.
    pub fn record(&self) -> String {
        let t = self.tool_ball_mm;
        format!(
            "ballbar plane={} centre={} radius_mm={:?} turns={} overshoot_deg={:?} points={} tool_ball_mm={:?},{:?},{:?} noise_um={:?}",
            self.plane.name(),
            axis_values_record(&self.centre),
            self.radius_mm,
            match self.turns {
                Turns::Ccw => "ccw",
                Turns::Cw => "cw",
                Turns::Both => "both",
            },
            self.overshoot_deg,
            self.points,
            t.x,
            t.y,
            t.z,
            self.noise_um
        )
    }

    /// The set-up a trace file records ([`BallBarSetup::record`]), the mounting error
    /// zero: `None` without a record, or the record's line and what is wrong.
    pub fn from_record(text: &str) -> Option<Result<BallBarSetup, (usize, String)>> {
        let (line, pairs) = setup_record(text, "ballbar")?;
        let parse = || -> Result<BallBarSetup, String> {
            let mut s = BallBarSetup::new(Plane::Xy, AxisValues::default(), 0.0);
            let (mut plane, mut radius) = (false, false);
            for (k, v) in &pairs {
                match k.as_str() {
                    "plane" => {
                        s.plane = Plane::from_name(v)
                            .ok_or_else(|| format!("plane '{v}': expected XY, YZ or ZX"))?;
                        plane = true;
                    }
                    "centre" => s.centre = parse_axis_values_record(v)?,
                    "radius_mm" => {
                        s.radius_mm = number(v, "radius_mm")?;
                        radius = true;
                    }
                    "turns" => {
                        s.turns = match v.as_str() {
                            "ccw" => Turns::Ccw,
                            "cw" => Turns::Cw,
                            "both" => Turns::Both,
                            _ => return Err(format!("turns '{v}': expected ccw, cw or both")),
                        }
                    }
                    "overshoot_deg" => s.overshoot_deg = number(v, "overshoot_deg")?,
                    "points" => {
                        s.points = v
                            .parse()
                            .map_err(|_| format!("points '{v}' is not a count"))?
                    }
                    "tool_ball_mm" => s.tool_ball_mm = parse_vector_record(v, "tool_ball_mm")?,
                    "noise_um" => s.noise_um = number(v, "noise_um")?,
                    other => return Err(format!("unknown set-up key '{other}'")),
                }
            }
            if !(plane && radius) {
                return Err("the record needs plane and radius_mm".into());
            }
            Ok(s)
        };
        Some(parse().map_err(|m| (line, m)))
    }

    /// One line describing the set-up on `chain` (for reports and the trace file).
    pub fn describe(&self, chain: &Chain) -> String {
        let centre: Vec<String> = chain
            .axes()
            .iter()
            .map(|a| format!("{} {}", a.letter.as_char(), self.centre.get(a.letter)))
            .collect();
        let runs: Vec<&str> = self
            .turns
            .runs()
            .iter()
            .map(|t| match t {
                Turn::Ccw => "ccw",
                Turn::Cw => "cw",
            })
            .collect();
        let (b, o) = (self.tool_ball_mm, self.mount_offset_mm);
        format!(
            "ball bar in {}: radius {} mm about {}; {}; feed {} mm/min, overshoot {}°, {} \
             points per revolution; tool ball ({}, {}, {}) mm in T, centre ball mounted ({}, \
             {}, {}) mm off; noise σ {} µm, seed {}",
            self.plane.name(),
            self.radius_mm,
            centre.join(", "),
            runs.join(" then "),
            self.feed_mm_per_min,
            self.overshoot_deg,
            self.points,
            b.x,
            b.y,
            b.z,
            o.x,
            o.y,
            o.z,
            self.noise_um,
            self.seed
        )
    }

    fn validate(&self, chain: &Chain) -> Result<(), BallBarError> {
        let (a1, a2) = self.plane.axes();
        let letters: Vec<String> = chain
            .axes()
            .iter()
            .map(|a| a.letter.as_char().to_string())
            .collect();
        for l in [a1, a2] {
            match chain.axes().iter().find(|a| a.letter == l) {
                None => {
                    return Err(BallBarError::Plane {
                        plane: self.plane.name(),
                        message: format!(
                            "the machine has no axis {} (axes: {})",
                            l.as_char(),
                            letters.join(" ")
                        ),
                    });
                }
                Some(a) if a.kind != AxisKind::Linear => {
                    return Err(BallBarError::Plane {
                        plane: self.plane.name(),
                        message: format!("{} is not a linear axis", l.as_char()),
                    });
                }
                Some(_) => {}
            }
        }
        if let Some(a) = chain
            .axes()
            .iter()
            .find(|a| !self.centre.get(a.letter).is_finite())
        {
            return Err(setup_error(
                "centre",
                format!(
                    "{} = {} is not finite",
                    a.letter.as_char(),
                    self.centre.get(a.letter)
                ),
            ));
        }
        if !(self.radius_mm.is_finite() && self.radius_mm > 0.0) {
            return Err(setup_error(
                "radius",
                format!("must be a positive length (mm), got {}", self.radius_mm),
            ));
        }
        if !(MIN_POINTS..=MAX_POINTS).contains(&self.points) {
            return Err(setup_error(
                "points",
                format!(
                    "{} given; {MIN_POINTS} to {MAX_POINTS} points per revolution needed",
                    self.points
                ),
            ));
        }
        if !(self.overshoot_deg.is_finite()
            && (0.0..=MAX_OVERSHOOT_DEG).contains(&self.overshoot_deg))
        {
            return Err(setup_error(
                "overshoot",
                format!(
                    "must be 0 to {MAX_OVERSHOOT_DEG}° of arc, got {}",
                    self.overshoot_deg
                ),
            ));
        }
        if !(self.feed_mm_per_min.is_finite() && self.feed_mm_per_min > 0.0) {
            return Err(setup_error(
                "feed",
                format!("must be positive (mm/min), got {}", self.feed_mm_per_min),
            ));
        }
        for (name, v) in [
            ("tool_ball", self.tool_ball_mm),
            ("mount", self.mount_offset_mm),
        ] {
            if !v.iter().all(|c| c.is_finite()) {
                return Err(setup_error(
                    name,
                    format!("the offset {:?} must be finite", v.as_slice()),
                ));
            }
        }
        if !(self.noise_um.is_finite() && self.noise_um >= 0.0) {
            return Err(setup_error(
                "noise",
                format!("σ must be 0 or positive (µm), got {}", self.noise_um),
            ));
        }
        Ok(())
    }
}

/// What the ball bar measured.
#[derive(Clone, Debug, PartialEq)]
pub struct BallBarMeasurement {
    /// The trace: per run in order, its samples in the order taken (angles in [0, 2π)).
    pub samples: Vec<Sample>,
    /// Where the centre ball is, in W (mm).
    pub centre_ball: Point3,
    /// The set-up measured.
    pub setup: BallBarSetup,
}

impl BallBarMeasurement {
    /// The trace file (`circular`'s CSV) with `comments` as `#` lines above it, then the
    /// set-up record ([`BallBarSetup::record`]).
    pub fn csv(&self, comments: &[String]) -> String {
        let mut c = comments.to_vec();
        c.push(format!("set-up: {}", self.setup.record()));
        trace_csv(&self.samples, &c)
    }
}

/// cos θ and sin θ of an angle in degrees, exact at the multiples of 90° (where an axis of
/// the plane turns round).
fn cos_sin_deg(deg: Real) -> (Real, Real) {
    let d = deg.rem_euclid(360.0);
    let quadrant = (d / 90.0).floor();
    if quadrant * 90.0 == d {
        // Exactly on an axis: 0°, 90°, 180° or 270°.
        [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)][quadrant as usize % 4]
    } else {
        let (s, c) = d.to_radians().sin_cos();
        (c, s)
    }
}

/// Runs the circular test of `setup` on `chain` (see the module documentation).
pub fn measure(chain: &Chain, setup: &BallBarSetup) -> Result<BallBarMeasurement, BallBarError> {
    setup.validate(chain)?;
    let (a1, a2) = setup.plane.axes();
    let (c1, c2) = (setup.centre.get(a1), setup.centre.get(a2));
    let r = setup.radius_mm;
    let at = |deg: Real| {
        let (c, s) = cos_sin_deg(deg);
        setup.centre.with(a1, c1 + r * c).with(a2, c2 + r * s)
    };
    let ball = Point3::from(setup.tool_ball_mm);
    let centre_ball = chain.nominal().w_from_t(&setup.centre) * ball + setup.mount_offset_mm;
    // The reversal shares after moving along the circle from `a` to `b` (degrees): split
    // where an axis of the plane turns round, so that each piece moves each axis one way.
    let advance = |state: [Real; 6], a: Real, b: Real| {
        let (lo, hi) = (a.min(b), a.max(b));
        let mut marks: Vec<Real> = ((lo / 90.0).floor() as i64 + 1..=(hi / 90.0).ceil() as i64)
            .map(|m| m as Real * 90.0)
            .filter(|m| *m > lo && *m < hi)
            .collect();
        if b < a {
            marks.reverse();
        }
        let mut from = a;
        let mut state = state;
        for to in marks.into_iter().chain([b]) {
            state = chain.reversal_after_move(&state, &at(from), &at(to));
            from = to;
        }
        state
    };
    // Arc steps of at most one sample spacing from `a` to `b`.
    let step = 360.0 / setup.points as Real;
    let arc = |state: [Real; 6], a: Real, b: Real| {
        let n = ((b - a).abs() / step).ceil() as usize;
        let mut state = state;
        let mut from = a;
        for i in 1..=n {
            let to = if i == n {
                b
            } else {
                a + (b - a) * i as Real / n as Real
            };
            state = advance(state, from, to);
            from = to;
        }
        state
    };
    let rng = CounterRng::new(setup.seed);
    let sigma = setup.noise_um * 1e-3;
    let os = setup.overshoot_deg;
    let mut state = chain.reversal_state(&Directions::default());
    let mut position: Option<AxisValues> = None;
    let runs = setup.turns.runs();
    let mut samples = Vec::with_capacity(runs.len() * setup.points);
    for (run, &turn) in runs.iter().enumerate() {
        let dir = match turn {
            Turn::Ccw => 1.0,
            Turn::Cw => -1.0,
        };
        // Straight from where the last run ended to this one's start, then the feed-in arc.
        let start = -dir * os;
        if let Some(p) = position {
            state = chain.reversal_after_move(&state, &p, &at(start));
        }
        state = arc(state, start, 0.0);
        let mut theta: Real = 0.0;
        for k in 0..setup.points {
            let next = dir * k as Real * step;
            state = advance(state, theta, next);
            theta = next;
            let q = at(theta);
            let tool = chain.w_from_t_state(&q, &state) * ball;
            let i = (run * setup.points + k) as u64;
            let deviation = (tool - centre_ball).norm() - r + sigma * rng.normal(i);
            samples.push(Sample {
                turn,
                angle_rad: (theta.rem_euclid(360.0) + 0.0).to_radians(),
                deviation_mm: deviation,
            });
        }
        // The rest of the data arc to 360°, then the feed-out arc.
        let end = dir * (360.0 + os);
        state = arc(state, theta, end);
        position = Some(at(end));
    }
    Ok(BallBarMeasurement {
        samples,
        centre_ball,
        setup: setup.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::error_motion::AxisErrorMotions;

    fn xyz() -> Chain {
        crate::machine::chain::xyz_for_tests()
    }

    #[test]
    fn a_nominal_machine_reads_zero_in_every_plane() {
        let chain = xyz();
        let centre = AxisValues::default()
            .with(AxisLetter::X, 12.0)
            .with(AxisLetter::Y, -40.0)
            .with(AxisLetter::Z, 75.0);
        for plane in [Plane::Xy, Plane::Yz, Plane::Zx] {
            let mut s = BallBarSetup::new(plane, centre, 150.0);
            s.tool_ball_mm = Vector3::new(1.0, -2.0, 30.0);
            let m = measure(&chain, &s).expect("measures");
            assert_eq!(m.samples.len(), 720);
            assert!(m.samples.iter().all(|x| x.deviation_mm.abs() < 1e-12));
            assert!(
                m.samples
                    .iter()
                    .all(|x| (0.0..std::f64::consts::TAU).contains(&x.angle_rad))
            );
        }
    }

    #[test]
    fn a_lost_motion_shows_on_the_side_each_axis_last_moved() {
        // X lags b/2 behind its motion (B = −b): at θ = 90° (ccw) X moves −, so the tool is
        // b/2 further +X than commanded; at 270° b/2 further −X. Neither changes the radius
        // there to first order, but at 1° and 181° (X past its reversal) it does: ±b/2.
        let mut chain = xyz();
        let mut e = AxisErrorMotions::for_axis(AxisLetter::X);
        e.reversal = -0.004;
        chain.set_error_motions(AxisLetter::X, e).expect("axis");
        let mut s = BallBarSetup::new(Plane::Xy, AxisValues::default(), 100.0);
        s.turns = Turns::Ccw;
        let m = measure(&chain, &s).expect("measures");
        let at = |deg: usize| m.samples[deg].deviation_mm;
        // At 1°: X moves −, offset +0.002 along +X: radius grows by ≈ 0.002·cos 1°.
        assert!((at(1) - 0.002).abs() < 1e-5, "{}", at(1));
        // At 181°: X moves +, offset −0.002 along X, the point is at −X: radius grows.
        assert!((at(181) - 0.002).abs() < 1e-5, "{}", at(181));
        // At 0°, X still carries + from the feed-in: offset −0.002 at +X: shrinks.
        assert!((at(0) + 0.002).abs() < 1e-9, "{}", at(0));
    }

    #[test]
    fn bad_set_ups_are_refused_by_name() {
        let chain = xyz();
        let ok = BallBarSetup::new(Plane::Xy, AxisValues::default(), 100.0);
        let err = |s: BallBarSetup| measure(&chain, &s).expect_err("refused").to_string();
        assert!(
            err(BallBarSetup {
                radius_mm: 0.0,
                ..ok.clone()
            })
            .starts_with("radius:")
        );
        assert!(
            err(BallBarSetup {
                points: 4,
                ..ok.clone()
            })
            .starts_with("points:")
        );
        assert!(
            err(BallBarSetup {
                overshoot_deg: Real::NAN,
                ..ok.clone()
            })
            .starts_with("overshoot:")
        );
        assert!(
            err(BallBarSetup {
                centre: AxisValues::default().with(AxisLetter::Z, Real::INFINITY),
                ..ok.clone()
            })
            .starts_with("centre:")
        );
        let two = Chain::new(chain.axes()[..2].to_vec(), "S").expect("valid");
        let e = measure(
            &two,
            &BallBarSetup {
                plane: Plane::Yz,
                ..ok
            },
        )
        .expect_err("no Z")
        .to_string();
        assert!(e.contains("plane YZ") && e.contains("no axis Z"), "{e}");
    }
}
