//! The virtual laser interferometer: ISO 230-2's standard test of one linear axis, measured
//! on the twin's chain.
//!
//! # Model
//!
//! The interferometer sits on the workpiece side (frame W) with its beam along the measured
//! axis's nominal direction of motion in W, `u`: the unit vector by which the nominal chain
//! moves the tool relative to the workpiece when the axis value grows (the other axes held).
//! The retroreflector rides on the tool side at the **Abbe offset** `h` from the tool point,
//! a vector in the tool frame T. It reads the displacement of the reflector along the beam,
//! `u · (P − P₀)`, with `P = w_from_t(q) · h` through the *deviated* chain, exactly — so an
//! angular error motion moves the reading by its rigid-body lever on `h`, nothing linearised.
//! The reading is zeroed at the first target of run 1 (`P₀`, the reflector there, noise
//! free).
//!
//! **Sign convention.** The reading `x = u · (P − P₀) − (t − t₁)` is *position reached minus
//! target* along the axis's commanded direction: positive when the tool went further in the
//! sense the axis counts (tool relative to workpiece) than commanded. A positioning error
//! motion `EXX = e(x)` on a machine whose X runs along +X of W reads `e(t) − e(t₁)`; a
//! reversal value `B` (`[reversal]`) reads `B` as ISO 230-2's `x̄↑ − x̄↓`.
//!
//! # Test cycle (ISO 230-2, linear)
//!
//! Targets `t₁ < … < t_m` (evenly spaced or any list). Each run starts below `t₁` by the
//! overshoot, reached moving `−` (the end of the run before); it visits every target moving
//! `+` and reads there, overshoots past `t_m`, comes back visiting every target moving `−`,
//! and overshoots below `t₁`. Each move goes through [`Chain::reversal_after_move`], so the
//! axis's lost motion is taken up over the travel as the chain models it, and the approach
//! direction sets the reversal share of every reading. The other axes stay at their held
//! values.
//!
//! # Compensation
//!
//! With a [`CompTable`] the controller compensates the measured axis as LinuxCNC's motion
//! controller applies `[JOINT_n] COMP_FILE` (see [`super::comp_table`]): every commanded
//! value `t` of the axis becomes `t + c(t, d)` on its way to the chain, `d` the direction
//! the command moved in last (kept over a stop), `c` the table's correction. The readings
//! stay *position reached − commanded target*: what the user sees after compensation.
//!
//! # Noise
//!
//! Each reading `k` (0-based, in the order taken) adds `σ·n_k + d·k/(2m)`: a Gaussian
//! repeatability `σ` (µm) with `n_k` the counter-based normal deviate of `(seed, k)`, and a
//! linear drift `d` (µm per run; one run takes `2m` readings). Same set-up and seed, same
//! readings.
//!
//! **Invariant:** the readings are always a complete bidirectional set — every target both
//! ways in every run — that [`super::positioning::evaluate`] takes as it is; a set-up that
//! cannot give one (an axis the machine lacks or that turns, fewer than two runs or targets,
//! a non-finite value) is an error before any reading is taken.

use super::comp_table::CompTable;
use super::positioning::{Direction as Approach, Reading, readings_csv};
use super::table::{
    axis_values_record, number, parse_axis_values_record, parse_vector_record, setup_record,
};
use crate::machine::chain::{AxisKind, Chain};
use crate::machine::error_motion::{Direction, Directions};
use crate::math::{CounterRng, Point3, Real, UnitVector3, Vector3};
use crate::nc::{AxisLetter, AxisValues};

/// Most runs a test may have: far above any real test, low enough to bound memory.
pub const MAX_RUNS: usize = 1_000;

/// Most targets a test may have.
pub const MAX_TARGETS: usize = 100_000;

/// A set-up the laser cannot measure.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LaserError {
    /// The axis is not a linear axis of the machine.
    #[error("axis: {0}")]
    Axis(String),
    /// A set-up value that is out of range or not finite, named by its field.
    #[error("{name}: {message}")]
    Setup {
        /// The set-up field (`targets`, `runs`, `overshoot`, `at`, `abbe`, `noise`, `drift`).
        name: &'static str,
        /// What is wrong with it.
        message: String,
    },
}

fn setup_error(name: &'static str, message: String) -> LaserError {
    LaserError::Setup { name, message }
}

/// Where the targets are (mm).
#[derive(Clone, Debug, PartialEq)]
pub enum Targets {
    /// `count` targets evenly spaced from `start_mm` to `end_mm`, both included.
    Even {
        /// First target.
        start_mm: Real,
        /// Last target.
        end_mm: Real,
        /// How many (at least 2).
        count: usize,
    },
    /// Any positions, any spacing (ISO 230-2 allows irregular spacing, which keeps a
    /// periodic error from hiding between targets); measured in ascending order.
    List(Vec<Real>),
}

impl Targets {
    /// The positions in ascending order, validated: at least two, distinct and finite.
    pub fn positions(&self) -> Result<Vec<Real>, LaserError> {
        let bad = |m: String| setup_error("targets", m);
        let mut t = match self {
            Targets::Even {
                start_mm,
                end_mm,
                count,
            } => {
                if !(start_mm.is_finite() && end_mm.is_finite()) {
                    return Err(bad(format!(
                        "from {start_mm} to {end_mm}: the ends must be finite"
                    )));
                }
                if !(2..=MAX_TARGETS).contains(count) {
                    return Err(bad(format!(
                        "{count} given; 2 to {MAX_TARGETS} targets needed (ISO 230-2 asks for at least 5)"
                    )));
                }
                let n = *count - 1;
                (0..=n)
                    .map(|i| {
                        if i == n {
                            *end_mm
                        } else {
                            start_mm + (end_mm - start_mm) * i as Real / n as Real
                        }
                    })
                    .collect::<Vec<_>>()
            }
            Targets::List(v) => {
                if !(2..=MAX_TARGETS).contains(&v.len()) {
                    return Err(bad(format!(
                        "{} given; 2 to {MAX_TARGETS} targets needed (ISO 230-2 asks for at least 5)",
                        v.len()
                    )));
                }
                if let Some(x) = v.iter().find(|x| !x.is_finite()) {
                    return Err(bad(format!("target {x} is not finite")));
                }
                v.clone()
            }
        };
        t.sort_by(Real::total_cmp);
        if let Some(w) = t.windows(2).find(|w| w[1] <= w[0]) {
            return Err(bad(format!(
                "target {} is given twice (targets must be distinct)",
                w[0]
            )));
        }
        Ok(t)
    }
}

/// The set-up of a laser test of one linear axis.
#[derive(Clone, Debug, PartialEq)]
pub struct LaserSetup {
    /// The linear axis measured.
    pub axis: AxisLetter,
    /// Its targets (mm).
    pub targets: Targets,
    /// Bidirectional runs, 2 to [`MAX_RUNS`] (ISO 230-2 asks for at least 5).
    pub runs: usize,
    /// How far each run travels past the last target and below the first before it turns
    /// (mm, > 0).
    pub overshoot_mm: Real,
    /// The values of the other axes, held during the test (mm, degrees); the measured axis's
    /// value here is ignored.
    pub held: AxisValues,
    /// The retroreflector's offset from the tool point, in the tool frame T (mm).
    pub abbe_offset_mm: Vector3,
    /// Gaussian repeatability of each reading, σ (µm, ≥ 0).
    pub noise_um: Real,
    /// Linear drift of the reading (µm per run).
    pub drift_um_per_run: Real,
    /// Seed of the noise.
    pub seed: u64,
    /// The controller's compensation table of the measured axis, if any (see the module
    /// documentation).
    pub comp: Option<CompTable>,
}

impl LaserSetup {
    /// ISO 230-2's standard test of `axis` over `targets`, the other axes at `held`: five
    /// runs, 5 mm overshoot, the reflector at the tool point, no noise and no drift, seed 1.
    pub fn new(axis: AxisLetter, targets: Targets, held: AxisValues) -> Self {
        Self {
            axis,
            targets,
            runs: 5,
            overshoot_mm: 5.0,
            held,
            abbe_offset_mm: Vector3::zeros(),
            noise_um: 0.0,
            drift_um_per_run: 0.0,
            seed: 1,
            comp: None,
        }
    }

    /// One line describing the set-up on `chain` (for reports and the readings file).
    pub fn describe(&self, chain: &Chain) -> String {
        let targets = match self.targets.positions() {
            Ok(t) => format!("{} targets {} … {} mm", t.len(), t[0], t[t.len() - 1]),
            Err(e) => e.to_string(),
        };
        let held: Vec<String> = chain
            .axes()
            .iter()
            .filter(|a| a.letter != self.axis)
            .map(|a| format!("{} {}", a.letter.as_char(), self.held.get(a.letter)))
            .collect();
        let h = self.abbe_offset_mm;
        format!(
            "laser on {}: {targets}, {} runs each way, overshoot {} mm; held {}; Abbe offset \
             ({}, {}, {}) mm in T; noise σ {} µm, drift {} µm/run, seed {}",
            self.axis.as_char(),
            self.runs,
            self.overshoot_mm,
            if held.is_empty() {
                "nothing".to_string()
            } else {
                held.join(", ")
            },
            h.x,
            h.y,
            h.z,
            self.noise_um,
            self.drift_um_per_run,
            self.seed
        ) + &match &self.comp {
            Some(c) => format!(
                "; compensated by a LinuxCNC table of {} entries",
                c.entries().len()
            ),
            None => String::new(),
        }
    }

    /// The set-up as the readings file records it (see [`super::table::SETUP_MARKER`]):
    /// `laser axis=X runs=5 overshoot_mm=5.0 held=X:0.0,… abbe_mm=0.0,0.0,0.0
    /// noise_um=0.5 drift_um_per_run=0.0`, every number exact. The targets are the
    /// readings' own.
    pub fn record(&self) -> String {
        let h = self.abbe_offset_mm;
        let comp = match &self.comp {
            Some(c) => format!(" comp_entries={}", c.entries().len()),
            None => String::new(),
        };
        format!(
            "laser axis={} runs={} overshoot_mm={:?} held={} abbe_mm={:?},{:?},{:?} noise_um={:?} drift_um_per_run={:?}{comp}",
            self.axis.as_char(),
            self.runs,
            self.overshoot_mm,
            axis_values_record(&self.held),
            h.x,
            h.y,
            h.z,
            self.noise_um,
            self.drift_um_per_run
        )
    }

    /// The set-up a readings file records ([`LaserSetup::record`]) with the targets of
    /// its readings: `None` without a record, or the record's line and what is wrong.
    pub fn from_record(
        text: &str,
        readings: &[Reading],
    ) -> Option<Result<LaserSetup, (usize, String)>> {
        let (line, pairs) = setup_record(text, "laser")?;
        let parse = || -> Result<LaserSetup, String> {
            let mut targets: Vec<Real> = readings.iter().map(|r| r.target_mm).collect();
            targets.sort_by(Real::total_cmp);
            targets.dedup();
            let mut s =
                LaserSetup::new(AxisLetter::X, Targets::List(targets), AxisValues::default());
            let mut axis = None;
            for (k, v) in &pairs {
                match k.as_str() {
                    "axis" => {
                        let mut c = v.chars();
                        axis = match (c.next(), c.next()) {
                            (Some(c), None) => AxisLetter::from_char(c),
                            _ => None,
                        };
                        s.axis = axis.ok_or_else(|| format!("axis '{v}' is not an axis letter"))?;
                    }
                    "runs" => {
                        s.runs = v
                            .parse()
                            .map_err(|_| format!("runs '{v}' is not a count"))?
                    }
                    "overshoot_mm" => s.overshoot_mm = number(v, "overshoot_mm")?,
                    "held" => s.held = parse_axis_values_record(v)?,
                    "abbe_mm" => s.abbe_offset_mm = parse_vector_record(v, "abbe_mm")?,
                    "noise_um" => s.noise_um = number(v, "noise_um")?,
                    "drift_um_per_run" => s.drift_um_per_run = number(v, "drift_um_per_run")?,
                    "comp_entries" => {
                        return Err(format!(
                            "the readings were taken through a compensation table ({v} \
                             entries), which the record does not hold: measure again without \
                             --comp to model the machine"
                        ));
                    }
                    other => return Err(format!("unknown set-up key '{other}'")),
                }
            }
            if axis.is_none() {
                return Err("the record names no axis".into());
            }
            Ok(s)
        };
        Some(parse().map_err(|m| (line, m)))
    }

    /// Checks the set-up against `chain`; the targets in ascending order.
    fn validate(&self, chain: &Chain) -> Result<Vec<Real>, LaserError> {
        let letters: Vec<String> = chain
            .axes()
            .iter()
            .map(|a| a.letter.as_char().to_string())
            .collect();
        match chain.axes().iter().find(|a| a.letter == self.axis) {
            None => {
                return Err(LaserError::Axis(format!(
                    "the machine has no axis {} (axes: {})",
                    self.axis.as_char(),
                    letters.join(" ")
                )));
            }
            Some(a) if a.kind != AxisKind::Linear => {
                return Err(LaserError::Axis(format!(
                    "{} is a rotary axis; the laser measures a linear one",
                    self.axis.as_char()
                )));
            }
            Some(_) => {}
        }
        let targets = self.targets.positions()?;
        if !(2..=MAX_RUNS).contains(&self.runs) {
            return Err(setup_error(
                "runs",
                format!(
                    "{} given; 2 to {MAX_RUNS} runs needed for a standard uncertainty (ISO 230-2 asks for 5)",
                    self.runs
                ),
            ));
        }
        if !(self.overshoot_mm.is_finite() && self.overshoot_mm > 0.0) {
            return Err(setup_error(
                "overshoot",
                format!("must be a positive length (mm), got {}", self.overshoot_mm),
            ));
        }
        for a in chain.axes() {
            let v = self.held.get(a.letter);
            if a.letter != self.axis && !v.is_finite() {
                return Err(setup_error(
                    "at",
                    format!("{} = {v} is not finite", a.letter.as_char()),
                ));
            }
        }
        if !self.abbe_offset_mm.iter().all(|c| c.is_finite()) {
            return Err(setup_error(
                "abbe",
                format!(
                    "the offset {:?} must be finite",
                    self.abbe_offset_mm.as_slice()
                ),
            ));
        }
        if !(self.noise_um.is_finite() && self.noise_um >= 0.0) {
            return Err(setup_error(
                "noise",
                format!("σ must be 0 or positive (µm), got {}", self.noise_um),
            ));
        }
        if !self.drift_um_per_run.is_finite() {
            return Err(setup_error(
                "drift",
                format!("must be finite (µm per run), got {}", self.drift_um_per_run),
            ));
        }
        Ok(targets)
    }
}

/// What the laser measured.
#[derive(Clone, Debug, PartialEq)]
pub struct LaserMeasurement {
    /// Every reading in the order taken: `target, direction, run, deviation` (mm), a
    /// complete bidirectional set for [`super::positioning::evaluate`].
    pub readings: Vec<Reading>,
    /// The targets in ascending order (mm).
    pub targets_mm: Vec<Real>,
    /// The beam's direction in W: the axis's nominal direction of motion.
    pub beam: UnitVector3,
    /// Where the set-up falls short of ISO 230-2 (fewer than 5 runs, fewer than 5 targets
    /// per metre); empty when it conforms.
    pub notes: Vec<String>,
    /// The set-up measured.
    pub setup: LaserSetup,
}

impl LaserMeasurement {
    /// The readings file (`positioning`'s long CSV) with `comments` as `#` lines above it,
    /// then the set-up record ([`LaserSetup::record`]).
    pub fn csv(&self, comments: &[String]) -> String {
        let mut c = comments.to_vec();
        c.push(format!("set-up: {}", self.setup.record()));
        readings_csv(&self.readings, &c)
    }
}

/// Runs ISO 230-2's standard test cycle of `setup` on `chain` (see the module
/// documentation).
pub fn measure(chain: &Chain, setup: &LaserSetup) -> Result<LaserMeasurement, LaserError> {
    let targets = setup.validate(chain)?;
    let axis = setup.axis;
    let m = targets.len();
    let (first, last) = (targets[0], targets[m - 1]);
    let at = |t: Real| setup.held.with(axis, t);
    let h = Point3::from(setup.abbe_offset_mm);
    // The nominal chain moves the reflector along a straight line as the axis runs: the beam.
    let nominal = chain.nominal();
    let span = nominal.w_from_t(&at(last)) * h - nominal.w_from_t(&at(first)) * h;
    let beam = UnitVector3::try_new(span, 0.0).ok_or_else(|| {
        LaserError::Axis(format!(
            "{} does not move the tool on the nominal machine",
            axis.as_char()
        ))
    })?;
    let rng = CounterRng::new(setup.seed);
    let (sigma, drift) = (setup.noise_um * 1e-3, setup.drift_um_per_run * 1e-3);
    let per_run = (2 * m) as Real;
    // The cycle starts below the first target, reached moving − as every later run's start.
    let mut q = at(first - setup.overshoot_mm);
    let mut state = chain.reversal_state(&Directions::default().with(axis, Direction::Negative));
    let mut zero: Option<Point3> = None;
    let mut readings = Vec::with_capacity(2 * m * setup.runs);
    // The commanded value of the axis and the direction it last moved in, for the
    // compensation (the cycle starts moving − to below the first target).
    let mut commanded = first - setup.overshoot_mm;
    let mut moving = Approach::Backward;
    if let Some(c) = &setup.comp {
        q = at(commanded + c.correction(commanded, moving));
    }
    for run in 1..=setup.runs {
        let up = targets.iter().map(|&t| (t, Some(Approach::Forward)));
        let down = targets.iter().rev().map(|&t| (t, Some(Approach::Backward)));
        let stops = up
            .chain([(last + setup.overshoot_mm, None)])
            .chain(down)
            .chain([(first - setup.overshoot_mm, None)]);
        for (t, approach) in stops {
            if t != commanded {
                moving = if t > commanded {
                    Approach::Forward
                } else {
                    Approach::Backward
                };
            }
            commanded = t;
            let next = match &setup.comp {
                Some(c) => at(t + c.correction(t, moving)),
                None => at(t),
            };
            state = chain.reversal_after_move(&state, &q, &next);
            q = next;
            let Some(direction) = approach else { continue };
            let p = chain.w_from_t_state(&q, &state) * h;
            let p0 = *zero.get_or_insert(p);
            let k = readings.len();
            let noise = sigma * rng.normal(k as u64) + drift * (k as Real / per_run);
            readings.push(Reading {
                target_mm: t,
                direction,
                run: run as u32,
                deviation_mm: beam.dot(&(p - p0)) - (t - first) + noise,
            });
        }
    }
    let mut notes = Vec::new();
    if setup.runs < 5 {
        notes.push(format!(
            "{} runs: ISO 230-2 asks for at least 5 in each direction",
            setup.runs
        ));
    }
    let needed = ((last - first) / 1000.0 * 5.0).ceil().max(5.0);
    if (m as Real) < needed {
        notes.push(format!(
            "{m} targets over {} mm: ISO 230-2 asks for at least 5 per metre and 5 in all ({needed})",
            last - first
        ));
    }
    Ok(LaserMeasurement {
        readings,
        targets_mm: targets,
        beam,
        notes,
        setup: setup.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::error_motion::{AxisErrorMotions, Term};
    use crate::metrology::positioning::evaluate;
    use std::path::Path;

    fn xyz() -> Chain {
        crate::machine::chain::xyz_for_tests()
    }

    #[test]
    fn a_nominal_machine_reads_zero_and_a_reversal_reads_b() {
        let mut chain = xyz();
        let setup = LaserSetup::new(
            AxisLetter::X,
            Targets::Even {
                start_mm: 0.0,
                end_mm: 100.0,
                count: 6,
            },
            AxisValues::default().with(AxisLetter::Z, 50.0),
        );
        let m = measure(&chain, &setup).expect("measures");
        assert_eq!(m.readings.len(), 6 * 2 * 5);
        assert!(m.readings.iter().all(|r| r.deviation_mm.abs() < 1e-12));
        assert!((m.beam.into_inner() - Vector3::x()).norm() < 1e-15);
        let mut e = AxisErrorMotions::for_axis(AxisLetter::X);
        e.reversal = -0.003;
        e.functions[0].terms = vec![Term::polynomial(vec![0.0, 1e-5]).expect("valid")];
        chain.set_error_motions(AxisLetter::X, e).expect("axis");
        let m = measure(&chain, &setup).expect("measures");
        let f = evaluate(&m.readings, Path::new("laser")).expect("complete");
        assert!((f.b - 0.003).abs() < 1e-12 && (f.b_mean + 0.003).abs() < 1e-12);
        assert!((f.m - 1e-3).abs() < 1e-12, "M {}", f.m);
    }

    #[test]
    fn bad_set_ups_are_refused_by_name() {
        let chain = xyz();
        let ok = LaserSetup::new(
            AxisLetter::X,
            Targets::List(vec![0.0, 10.0, 20.0]),
            AxisValues::default(),
        );
        let err = |s: LaserSetup| measure(&chain, &s).expect_err("refused").to_string();
        assert!(
            err(LaserSetup {
                axis: AxisLetter::A,
                ..ok.clone()
            })
            .contains("no axis A")
        );
        assert!(
            err(LaserSetup {
                runs: 1,
                ..ok.clone()
            })
            .starts_with("runs:")
        );
        assert!(
            err(LaserSetup {
                targets: Targets::List(vec![0.0, 0.0]),
                ..ok.clone()
            })
            .contains("twice")
        );
        assert!(
            err(LaserSetup {
                noise_um: Real::NAN,
                ..ok.clone()
            })
            .starts_with("noise:")
        );
        assert!(
            err(LaserSetup {
                held: AxisValues::default().with(AxisLetter::Y, Real::INFINITY),
                ..ok.clone()
            })
            .starts_with("at:")
        );
        assert!(
            err(LaserSetup {
                overshoot_mm: 0.0,
                ..ok
            })
            .starts_with("overshoot:")
        );
    }
}
