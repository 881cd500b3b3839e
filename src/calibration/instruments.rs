//! A serial machine identified from its instruments' readings through [`super::engine`]:
//! the machine's named parameters, laser interferometer readings (ISO 230-2, with the
//! Abbe offset), ball-bar radius samples (ISO 230-4), ball-sensor or probe traces (ISO
//! 10791-6) and cut parts' faces as observations, in any combination, and the
//! identified machine written back as the scene's `[deviations]`, `[error_motions]` and
//! `[reversal]` sections.
//!
//! **Parameters** ([`MachineParameter::parse`]), by the names a scene uses:
//! a joint deviation (`dy_AY`); an ISO 230-7 location or squareness term (`EX0C`,
//! `EC(0X)Y`), applied on top of the chain as [`Chain::apply_iso_term`] does; a coefficient
//! of an ISO 230-1 error motion as the scene models it — `EXX.polynomial[1]` (the
//! coefficient of `q¹`; a polynomial the scene lacks is created), `EBX.table[2]` (the third
//! table value; the table's positions stay), `EYX.periodic[0]` (the first periodic term's
//! amplitude; period and phase stay) — and an axis's lost motion `reversal.X` (ISO 230-2's
//! `B`). Realistic magnitudes: assembly deviations and location terms as
//! [`super::calibrate::component_magnitude`]; an error motion [`MOTION_OFFSET_MM`] or
//! [`MOTION_ANGLE_RAD`] over the travel the measurements cover (a coefficient of `qᵏ` that
//! over `Lᵏ`); a reversal [`REVERSAL_MM`].
//!
//! **Observations.** A laser readings file is modelled by running
//! [`interferometer::measure`] on the chain with the parameters set, noise free, with the
//! set-up the file records: every reading, zeroed at the first target of run 1 as the
//! instrument is. A ball-bar trace is modelled by [`ballbar::measure`] the same way, the
//! centre ball's position across the plane estimated per file (2 nuisance unknowns: where
//! the ball was mounted is never known to the µm; along the plane's normal it moves the
//! radius only to second order and is left out). Each value's σ is the noise the file
//! records, with [`READING_FLOOR_MM`] under it. A feature set ([`Measurement::Features`]:
//! a ball-sensor or probe trace's ball centres, a cut part's faces) is modelled by
//! [`super::calibrate`]'s features on the chain with the parameters set — its pose carries
//! the chain's error motions, so location terms and error motions are solved together —
//! each trace's fixed point and each part's scan registration nuisance unknowns; its
//! observations are the features' whitened residuals.
//!
//! **Invariant:** never touches files (the caller reads them); the identified machine is
//! written only from what [`super::engine`] returns, a parameter the measurements do not
//! determine said to be so beside its (prior) value.

use crate::calibration::calibrate::{
    ANGLE_MAGNITUDE_RAD, Feature, Model, OFFSET_MAGNITUDE_MM, Registration, component_magnitude,
};
use crate::calibration::engine::{self, Block, Forward, Outcome, Problem, Unknown};
use crate::cutting::tool::Tool;
use crate::machine::Component;
use crate::machine::chain::{Chain, DeviationId};
use crate::machine::error_motion::{self, AxisErrorMotions, Term};
use crate::math::{Point3, Real, Vector3};
use crate::metrology::ballbar::{self, BallBarSetup};
use crate::metrology::circular::Sample;
use crate::metrology::interferometer::{self, LaserSetup};
use crate::metrology::positioning::Reading;
use crate::nc::AxisLetter;
use nalgebra::DVector;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// Realistic size of a linear error motion over the measured travel (mm).
pub const MOTION_OFFSET_MM: Real = 0.01;
/// Realistic size of an angular error motion over the measured travel (rad).
pub const MOTION_ANGLE_RAD: Real = 1e-4;
/// Realistic size of an axis's lost motion (mm).
pub const REVERSAL_MM: Real = 0.01;
/// σ floor of a reading (mm): the twin computes a laser reading or a bar length exactly, so
/// a noise-free file is fitted to its rounding and the central differences' error, both far
/// below 10 nm.
pub const READING_FLOOR_MM: Real = 1e-5;
/// Travel assumed for an axis no measurement moves (mm).
const DEFAULT_TRAVEL_MM: Real = 100.0;

/// Which coefficient of an error-motion function.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Slot {
    /// The polynomial's coefficient of `q^k`.
    Polynomial(usize),
    /// The table's value `k`.
    Table(usize),
    /// The periodic term `k`'s amplitude.
    Periodic(usize),
}

/// What one named parameter is on the chain.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    /// A joint deviation.
    Deviation(DeviationId),
    /// An ISO location or squareness term (applied on top of the chain by its change from
    /// the start).
    Iso,
    /// An error-motion coefficient.
    Motion {
        /// The axis.
        axis: AxisLetter,
        /// The component (`EYX`: Dy).
        component: Component,
        /// Which coefficient.
        slot: Slot,
    },
    /// An axis's reversal value.
    Reversal(AxisLetter),
}

/// A named parameter of a serial machine.
#[derive(Clone, Debug, PartialEq)]
pub struct MachineParameter {
    /// The name as the scene writes it.
    pub name: String,
    /// What it is.
    pub target: Target,
    /// Its value on the starting chain.
    pub start: Real,
}

fn motion_name(component: Component, axis: AxisLetter) -> String {
    format!("E{}{}", error_motion::letter_of(component), axis.as_char())
}

impl MachineParameter {
    /// Parses `name` on `chain`, whose ISO terms' values are `iso_values` (the scene's
    /// `[deviations]`): an error naming what the machine has instead.
    pub fn parse(
        chain: &Chain,
        iso_values: &BTreeMap<String, Real>,
        name: &str,
    ) -> Result<Self, String> {
        let axes = || {
            chain
                .axes()
                .iter()
                .map(|a| a.letter.as_char().to_string())
                .collect::<Vec<_>>()
                .join(" ")
        };
        let letter = |s: &str| {
            let mut c = s.chars();
            match (c.next(), c.next()) {
                (Some(c), None) => AxisLetter::from_char(c).filter(|l| chain.has_axis(*l)),
                _ => None,
            }
        };
        if let Some(a) = name.strip_prefix("reversal.") {
            let axis = letter(a).ok_or_else(|| {
                format!(
                    "'{name}': '{a}' is not an axis of this machine ({})",
                    axes()
                )
            })?;
            let start = chain.error_motions(axis).map_or(0.0, |e| e.reversal);
            return Ok(Self {
                name: name.into(),
                target: Target::Reversal(axis),
                start,
            });
        }
        if let Some((func, rest)) = name.split_once('.') {
            let (component, axis) =
                error_motion::parse_name(func).map_err(|e| format!("'{name}': {e}"))?;
            if !chain.has_axis(axis) {
                return Err(format!(
                    "'{name}' names axis {}, which this machine does not have (axes: {})",
                    axis.as_char(),
                    axes()
                ));
            }
            let bad = || {
                format!(
                    "'{name}': expected {func}.polynomial[K], {func}.table[K] or {func}.periodic[K]"
                )
            };
            let (kind, index) = rest
                .strip_suffix(']')
                .and_then(|r| r.split_once('['))
                .ok_or_else(bad)?;
            let k: usize = index.parse().map_err(|_| bad())?;
            let terms = chain
                .error_motions(axis)
                .map(|e| e.functions[component as usize].terms.clone())
                .unwrap_or_default();
            let (slot, start) = match kind {
                "polynomial" => {
                    if k > 8 {
                        return Err(format!("'{name}': degree {k} is above 8"));
                    }
                    let start = terms
                        .iter()
                        .find_map(|t| match t {
                            Term::Polynomial(c) => Some(c.get(k).copied().unwrap_or(0.0)),
                            _ => None,
                        })
                        .unwrap_or(0.0);
                    (Slot::Polynomial(k), start)
                }
                "table" => {
                    let v = terms
                        .iter()
                        .find_map(|t| match t {
                            Term::Table { v, .. } => Some(v.clone()),
                            _ => None,
                        })
                        .ok_or_else(|| {
                            format!("'{name}': the scene gives {func} no table (its positions are the scene's)")
                        })?;
                    let start = *v.get(k).ok_or_else(|| {
                        format!("'{name}': {func}'s table has {} values", v.len())
                    })?;
                    (Slot::Table(k), start)
                }
                "periodic" => {
                    let start = terms
                        .iter()
                        .filter_map(|t| match t {
                            Term::Periodic { amplitude, .. } => Some(*amplitude),
                            _ => None,
                        })
                        .nth(k)
                        .ok_or_else(|| {
                            format!("'{name}': the scene gives {func} no periodic term {k} (its period is the scene's)")
                        })?;
                    (Slot::Periodic(k), start)
                }
                _ => return Err(bad()),
            };
            return Ok(Self {
                name: name.into(),
                target: Target::Motion {
                    axis,
                    component,
                    slot,
                },
                start,
            });
        }
        if let Ok(id) = chain.deviation_id(name) {
            return Ok(Self {
                name: name.into(),
                target: Target::Deviation(id),
                start: chain.deviation(id),
            });
        }
        match chain.iso_term_id(name) {
            Ok(_) => Ok(Self {
                name: name.into(),
                target: Target::Iso,
                start: iso_values.get(name).copied().unwrap_or(0.0),
            }),
            Err(e) => Err(format!(
                "'{name}' is not a parameter of this machine: not a joint deviation ({}), not \
                 an ISO term ({e}), not an error-motion coefficient (EXX.polynomial[1], \
                 EBX.table[0], EYX.periodic[0]) or a reversal (reversal.X)",
                chain.deviation_names().join(", ")
            )),
        }
    }

    /// Its realistic magnitude, an error motion's over `travel` (mm, per axis index).
    pub fn magnitude(&self, chain: &Chain, travel: &[Real; 6]) -> Real {
        match &self.target {
            Target::Deviation(id) => component_magnitude(id.component),
            Target::Iso => chain
                .iso_term_id(&self.name)
                .map_or(MOTION_ANGLE_RAD, |(_, c)| component_magnitude(c)),
            Target::Motion {
                axis,
                component,
                slot,
            } => {
                let size = if component.is_angle() {
                    MOTION_ANGLE_RAD
                } else {
                    MOTION_OFFSET_MM
                };
                match slot {
                    Slot::Polynomial(k) => size / travel[axis.index()].powi(*k as i32),
                    _ => size,
                }
            }
            Target::Reversal(_) => REVERSAL_MM,
        }
    }
}

/// `base` with the parameters at `values` (exact; joint deviations set first, then ISO
/// terms applied by their change from the start, then error motions and reversals).
pub fn chain_with(
    base: &Chain,
    params: &[MachineParameter],
    values: &[Real],
) -> Result<Chain, String> {
    let mut c = base.clone();
    for (p, v) in params.iter().zip(values) {
        if let Target::Deviation(id) = p.target {
            c.set_deviation(id, *v);
        }
    }
    for (p, v) in params.iter().zip(values) {
        if p.target == Target::Iso && *v != p.start {
            c.apply_identified_term(&p.name, v - p.start)
                .map_err(|e| format!("{}: {e}", p.name))?;
        }
    }
    for (p, v) in params.iter().zip(values) {
        let axis = match p.target {
            Target::Motion { axis, .. } | Target::Reversal(axis) => axis,
            _ => continue,
        };
        let mut e = c
            .error_motions(axis)
            .cloned()
            .unwrap_or_else(|| AxisErrorMotions::for_axis(axis));
        match p.target {
            Target::Reversal(_) => e.reversal = *v,
            Target::Motion {
                component, slot, ..
            } => {
                let terms = &mut e.functions[component as usize].terms;
                match slot {
                    Slot::Polynomial(k) => {
                        if !terms.iter().any(|t| matches!(t, Term::Polynomial(_))) {
                            terms.push(Term::Polynomial(Vec::new()));
                        }
                        if let Some(Term::Polynomial(c)) =
                            terms.iter_mut().find(|t| matches!(t, Term::Polynomial(_)))
                        {
                            if c.len() <= k {
                                c.resize(k + 1, 0.0);
                            }
                            c[k] = *v;
                        }
                    }
                    Slot::Table(k) => {
                        if let Some(Term::Table { v: vals, .. }) =
                            terms.iter_mut().find(|t| matches!(t, Term::Table { .. }))
                        {
                            vals[k] = *v;
                        }
                    }
                    Slot::Periodic(k) => {
                        if let Some(Term::Periodic { amplitude, .. }) = terms
                            .iter_mut()
                            .filter(|t| matches!(t, Term::Periodic { .. }))
                            .nth(k)
                        {
                            *amplitude = *v;
                        }
                    }
                }
            }
            _ => {}
        }
        c.set_error_motions(axis, e)
            .map_err(|e| format!("{}: {e}", p.name))?;
    }
    Ok(c)
}

/// Every parameter the scene models: each `[deviations]` entry, each coefficient of each
/// error-motion term (polynomial coefficients, table values, periodic amplitudes) and each
/// reversal, in that order.
pub fn scene_parameters(
    chain: &Chain,
    deviations: &BTreeMap<String, Real>,
) -> Result<Vec<MachineParameter>, String> {
    let mut names: Vec<String> = deviations.keys().cloned().collect();
    for a in chain.axes() {
        let Some(e) = chain.error_motions(a.letter) else {
            continue;
        };
        for c in Component::ALL {
            let f = motion_name(c, a.letter);
            let mut periodic = 0;
            for t in &e.functions[c as usize].terms {
                match t {
                    Term::Polynomial(co) => {
                        names.extend((0..co.len()).map(|k| format!("{f}.polynomial[{k}]")));
                    }
                    Term::Table { v, .. } => {
                        names.extend((0..v.len()).map(|k| format!("{f}.table[{k}]")));
                    }
                    Term::Periodic { .. } => {
                        names.push(format!("{f}.periodic[{periodic}]"));
                        periodic += 1;
                    }
                }
            }
        }
    }
    for a in chain.axes() {
        if chain
            .error_motions(a.letter)
            .is_some_and(|e| e.reversal != 0.0)
        {
            names.push(format!("reversal.{}", a.letter.as_char()));
        }
    }
    names
        .iter()
        .map(|n| MachineParameter::parse(chain, deviations, n))
        .collect()
}

/// One measurement file's readings with the set-up they were taken with.
#[derive(Clone, Debug, PartialEq)]
pub enum Measurement {
    /// An ISO 230-2 laser test.
    Laser {
        /// The file (named in messages).
        name: String,
        /// The set-up (noise σ: the readings' standard uncertainty).
        setup: LaserSetup,
        /// The readings.
        readings: Vec<Reading>,
    },
    /// An ISO 230-4 ball-bar circle.
    BallBar {
        /// The file.
        name: String,
        /// The set-up (the mounting offset is estimated, not taken from here).
        setup: BallBarSetup,
        /// The samples.
        samples: Vec<Sample>,
    },
    /// Features of [`super::calibrate`]: the ball centres of a rotary-axis trace (ISO
    /// 10791-6 ball sensor, probed sphere; their fixed points estimated) or the faces of a
    /// cut part's scan (in the scan's own registration, estimated).
    Features {
        /// The file (or the part's source).
        name: String,
        /// The features, their fixed points numbered from 0 within this measurement.
        features: Vec<Feature>,
        /// The tool that cut the faces (unused by ball centres).
        tool: Tool,
    },
}

impl Measurement {
    /// The file's name.
    pub fn name(&self) -> &str {
        match self {
            Measurement::Laser { name, .. }
            | Measurement::BallBar { name, .. }
            | Measurement::Features { name, .. } => name,
        }
    }
}

/// How a file's values map onto a simulation of its set-up: for each value, the index of
/// the simulated reading or sample.
struct Modelled {
    measurement: Measurement,
    order: Vec<usize>,
    /// Ball bar: the W directions of the plane's two axes (nominal), for the centre's
    /// nuisance offsets.
    plane_dirs: Option<[Vector3; 2]>,
}

/// The forward model of a set of measurements on a serial machine.
pub struct MachineModel {
    base: Chain,
    params: Vec<MachineParameter>,
    files: Vec<Modelled>,
}

fn noiseless_laser(s: &LaserSetup) -> LaserSetup {
    LaserSetup {
        noise_um: 0.0,
        drift_um_per_run: 0.0,
        ..s.clone()
    }
}

fn noiseless_ballbar(s: &BallBarSetup, mount: Vector3) -> BallBarSetup {
    BallBarSetup {
        noise_um: 0.0,
        mount_offset_mm: mount,
        ..s.clone()
    }
}

impl MachineModel {
    /// The model of `measurements` on `base` with `params` free: each file's values matched
    /// to its set-up's simulation (an error naming the file when they cannot be: a reading
    /// the set-up does not take, a sample count or angle that differs).
    pub fn new(
        base: &Chain,
        params: Vec<MachineParameter>,
        measurements: Vec<Measurement>,
    ) -> Result<Self, String> {
        let nominal = base.nominal();
        let mut files = Vec::new();
        for m in measurements {
            let (order, plane_dirs) = match &m {
                Measurement::Laser {
                    name,
                    setup,
                    readings,
                } => {
                    let sim = interferometer::measure(&nominal, &noiseless_laser(setup))
                        .map_err(|e| format!("{name}: the recorded set-up: {e}"))?;
                    let key = |r: &Reading| (r.target_mm.to_bits(), r.direction, r.run);
                    let index: BTreeMap<_, usize> = sim
                        .readings
                        .iter()
                        .enumerate()
                        .map(|(k, r)| (key(r), k))
                        .collect();
                    if readings.len() != sim.readings.len() {
                        return Err(format!(
                            "{name}: {} readings, but its set-up takes {}",
                            readings.len(),
                            sim.readings.len()
                        ));
                    }
                    let order = readings
                        .iter()
                        .map(|r| {
                            index.get(&key(r)).copied().ok_or_else(|| {
                                format!(
                                    "{name}: the reading at {} mm, {}, run {} is not one its set-up takes",
                                    r.target_mm,
                                    r.direction.sign(),
                                    r.run
                                )
                            })
                        })
                        .collect::<Result<Vec<_>, _>>()?;
                    (order, None)
                }
                Measurement::BallBar {
                    name,
                    setup,
                    samples,
                } => {
                    let sim =
                        ballbar::measure(&nominal, &noiseless_ballbar(setup, Vector3::zeros()))
                            .map_err(|e| format!("{name}: the recorded set-up: {e}"))?;
                    if samples.len() != sim.samples.len() {
                        return Err(format!(
                            "{name}: {} samples, but its set-up takes {}",
                            samples.len(),
                            sim.samples.len()
                        ));
                    }
                    for (k, (a, b)) in samples.iter().zip(&sim.samples).enumerate() {
                        let gap = (a.angle_rad - b.angle_rad).abs();
                        if a.turn != b.turn || gap.min(std::f64::consts::TAU - gap) > 1e-9 {
                            return Err(format!(
                                "{name}: sample {} at {:.6}° is not where its set-up samples ({:.6}°)",
                                k + 1,
                                a.angle_rad.to_degrees(),
                                b.angle_rad.to_degrees()
                            ));
                        }
                    }
                    let (a1, a2) = setup.plane.axes();
                    let ball = Point3::from(setup.tool_ball_mm);
                    let p0 = nominal.w_from_t(&setup.centre) * ball;
                    let dir = |a: AxisLetter| {
                        let q = setup.centre.with(a, setup.centre.get(a) + 1.0);
                        (nominal.w_from_t(&q) * ball - p0).normalize()
                    };
                    ((0..samples.len()).collect(), Some([dir(a1), dir(a2)]))
                }
                Measurement::Features {
                    name,
                    features,
                    tool,
                } => {
                    if features.is_empty() {
                        return Err(format!("{name}: no feature to identify from"));
                    }
                    let m = feature_model(base, features, tool);
                    if m.residuals(&m.start()).is_none() {
                        return Err(format!(
                            "{name}: a feature's prediction is degenerate on the scene's machine"
                        ));
                    }
                    (Vec::new(), None)
                }
            };
            files.push(Modelled {
                measurement: m,
                order,
                plane_dirs,
            });
        }
        Ok(Self {
            base: base.clone(),
            params,
            files,
        })
    }

    /// The nuisance unknowns: each ball-bar file's centre across its plane; each feature
    /// set's scan registration (when it has faces) and fixed points, at [`Model::start`]
    /// on the scene's machine, offsets at [`OFFSET_MAGNITUDE_MM`] and turns at
    /// [`ANGLE_MAGNITUDE_RAD`] as [`super::calibrate::FeatureForward`] takes them.
    pub fn nuisance(&self) -> Vec<Unknown> {
        let mut out = Vec::new();
        for f in &self.files {
            match &f.measurement {
                Measurement::Laser { .. } => {}
                Measurement::BallBar { name, setup, .. } => {
                    let (a1, a2) = setup.plane.axes();
                    out.extend([a1, a2].map(|a| Unknown {
                        name: format!("{name}: centre ball along {}", a.as_char()),
                        start: 0.0,
                        magnitude: MOTION_OFFSET_MM,
                    }));
                }
                Measurement::Features {
                    name,
                    features,
                    tool,
                } => {
                    let m = feature_model(&self.base, features, tool);
                    let x0 = m.start();
                    out.extend(
                        m.nuisance_names()
                            .into_iter()
                            .enumerate()
                            .map(|(k, n)| Unknown {
                                name: format!("{name}: {n}"),
                                start: x0[k],
                                magnitude: if k < m.reg_cols() && k >= 3 {
                                    ANGLE_MAGNITUDE_RAD
                                } else {
                                    OFFSET_MAGNITUDE_MM
                                },
                            }),
                    );
                }
            }
        }
        out
    }

    /// The observations, one block a file, σ from the noise each records; a feature set's
    /// features one block each (`FILE: FEATURE`), their whitened residuals observed 0 at σ 1.
    pub fn blocks(&self) -> Vec<Block> {
        self.files
            .iter()
            .flat_map(|f| {
                let (name, values, noise_um): (&str, Vec<Real>, Real) = match &f.measurement {
                    Measurement::Laser {
                        name,
                        setup,
                        readings,
                    } => (
                        name,
                        readings.iter().map(|r| r.deviation_mm).collect(),
                        setup.noise_um,
                    ),
                    Measurement::BallBar {
                        name,
                        setup,
                        samples,
                    } => (
                        name,
                        samples.iter().map(|s| s.deviation_mm).collect(),
                        setup.noise_um,
                    ),
                    Measurement::Features { name, features, .. } => {
                        return features
                            .iter()
                            .map(|x| Block {
                                name: format!("{name}: {}", x.name()),
                                values: vec![0.0; x.residual_count()],
                                sigma: vec![1.0; x.residual_count()],
                            })
                            .collect();
                    }
                };
                let sigma = (noise_um * 1e-3).hypot(READING_FLOOR_MM);
                vec![Block {
                    name: name.to_string(),
                    sigma: vec![sigma; values.len()],
                    values,
                }]
            })
            .collect()
    }

    /// The travel each axis covers in the measurements (mm, per axis index): the largest
    /// |value| it takes, at least 1 mm; `DEFAULT_TRAVEL_MM` where none moves it.
    pub fn travel(&self) -> [Real; 6] {
        let mut t = [0.0; 6];
        for f in &self.files {
            match &f.measurement {
                Measurement::Laser {
                    setup, readings, ..
                } => {
                    for r in readings {
                        let i = setup.axis.index();
                        t[i] = Real::max(t[i], r.target_mm.abs());
                    }
                }
                Measurement::BallBar { setup, .. } => {
                    let (a1, a2) = setup.plane.axes();
                    for a in [a1, a2] {
                        let i = a.index();
                        t[i] = Real::max(t[i], setup.centre.get(a).abs() + setup.radius_mm);
                    }
                }
                Measurement::Features { features, .. } => {
                    for q in features.iter().flat_map(|x| match x {
                        Feature::Ball(b) => vec![b.q],
                        Feature::Plane(p) => vec![p.cut.start, p.cut.end],
                    }) {
                        for a in self.base.axes() {
                            let i = a.letter.index();
                            t[i] = Real::max(t[i], q.get(a.letter).abs());
                        }
                    }
                }
            }
        }
        t.map(|x| {
            if x > 0.0 {
                x.max(1.0)
            } else {
                DEFAULT_TRAVEL_MM
            }
        })
    }

    /// The parameters.
    pub fn parameters(&self) -> &[MachineParameter] {
        &self.params
    }

    /// The engine's problem: parameters with their magnitudes, the ball bars' centres,
    /// one block a file.
    pub fn problem(&self) -> Problem<'_> {
        let travel = self.travel();
        Problem {
            parameters: self
                .params
                .iter()
                .map(|p| Unknown {
                    name: p.name.clone(),
                    start: p.start,
                    magnitude: p.magnitude(&self.base, &travel),
                })
                .collect(),
            nuisance: self.nuisance(),
            blocks: self.blocks(),
            forward: self,
            statistic: if self
                .files
                .iter()
                .any(|f| matches!(f.measurement, Measurement::Features { .. }))
            {
                "readings, samples, ball centres and faces at their stated σ".into()
            } else {
                "laser readings and ball-bar samples at their stated σ".into()
            },
        }
    }
}

impl Forward for MachineModel {
    fn predict(&self, x: &[Real]) -> Result<Vec<Real>, String> {
        let np = self.params.len();
        let chain = chain_with(&self.base, &self.params, &x[..np])?;
        let mut nuisance = x[np..].iter();
        let mut out = Vec::new();
        for f in &self.files {
            match &f.measurement {
                Measurement::Laser { name, setup, .. } => {
                    let sim = interferometer::measure(&chain, &noiseless_laser(setup))
                        .map_err(|e| format!("{name}: {e}"))?;
                    out.extend(f.order.iter().map(|&k| sim.readings[k].deviation_mm));
                }
                Measurement::BallBar { name, setup, .. } => {
                    let [d1, d2] = f.plane_dirs.unwrap_or([Vector3::zeros(); 2]);
                    let (u1, u2) = (
                        nuisance.next().copied().unwrap_or(0.0),
                        nuisance.next().copied().unwrap_or(0.0),
                    );
                    let sim =
                        ballbar::measure(&chain, &noiseless_ballbar(setup, d1 * u1 + d2 * u2))
                            .map_err(|e| format!("{name}: {e}"))?;
                    out.extend(f.order.iter().map(|&k| sim.samples[k].deviation_mm));
                }
                Measurement::Features {
                    name,
                    features,
                    tool,
                } => {
                    let m = feature_model(&chain, features, tool);
                    let at: Vec<Real> = nuisance.by_ref().take(m.cols()).copied().collect();
                    let r = m.residuals(&DVector::from_vec(at)).ok_or_else(|| {
                        format!(
                            "{name}: a feature's prediction is degenerate at the solve's unknowns"
                        )
                    })?;
                    out.extend(r.iter());
                }
            }
        }
        Ok(out)
    }
}

/// The features' model on `chain`: no parameter of its own (they are set on the chain),
/// the scan's registration estimated when there are faces, the fixed points always.
fn feature_model<'a>(chain: &'a Chain, features: &'a [Feature], tool: &'a Tool) -> Model<'a> {
    Model {
        chain,
        ids: &[],
        iso_terms: &[],
        tool,
        features,
        registration: Registration::Estimate,
    }
}

/// Identifies `params` on `base` from `measurements` (see the module documentation).
pub fn identify(
    base: &Chain,
    params: Vec<MachineParameter>,
    measurements: Vec<Measurement>,
) -> Result<(MachineModel, Outcome), String> {
    let model = MachineModel::new(base, params, measurements)?;
    let outcome = engine::solve(&model.problem()).map_err(|e| e.to_string())?;
    Ok((model, outcome))
}

/// A number as TOML reads it back bit for bit.
fn toml_number(v: Real) -> String {
    format!("{v:?}")
}

/// The identified machine as the scene's `[deviations]`, `[error_motions]` and
/// `[reversal]` sections (replacing the scene's own): every value the machine now has, each
/// identified parameter with its σ beside it, each one the measurements do not determine
/// on its own said to be so (its value is the prior moved only along what was determined).
/// `deviations` are the scene's `[deviations]` entries; `sources` name the files.
pub fn fragment(
    model: &MachineModel,
    deviations: &BTreeMap<String, Real>,
    outcome: &Outcome,
    sources: &[String],
) -> Result<String, String> {
    let params = &model.params;
    let chain = chain_with(&model.base, params, &outcome.solution)?;
    let notes: Vec<(String, String)> = params
        .iter()
        .map(|p| {
            let name = p.name.as_str();
            let n = match outcome.parameters.iter().find(|e| e.name == name) {
                Some(e) => format!("{name}: σ {:.3e}", e.sigma),
                None if outcome.identifiability.no_data.iter().any(|n| n == name) => {
                    format!("{name}: no measurement sees it, the scene's value kept")
                }
                None => format!("{name}: not determined on its own, not identified"),
            };
            (p.name.clone(), n)
        })
        .collect();
    let mut dev = deviations.clone();
    for (p, v) in params.iter().zip(&outcome.solution) {
        // A rotary table's offset along its own line and the zero of its angle are not
        // location terms a scene takes: named in the report when not identified, not
        // written.
        let own = p.target == Target::Iso
            && model.base.clone().apply_iso_term(&p.name, 0.0).is_err()
            && !outcome.parameters.iter().any(|e| e.name == p.name);
        if matches!(p.target, Target::Deviation(_) | Target::Iso) && !own {
            dev.insert(p.name.clone(), *v);
        }
    }
    Ok(machine_sections(&chain, &dev, &notes, sources))
}

/// The machine `chain` as the `[deviations]` (the entries of `deviations`), `[error_motions]`
/// and `[reversal]` sections a deviations file holds, one format for every identification:
/// each value followed by its note from `notes` (by name; an error motion's by its
/// function's prefix `EXX.`), the rest marked as the scene's, not identified.
pub fn machine_sections(
    chain: &Chain,
    deviations: &BTreeMap<String, Real>,
    notes: &[(String, String)],
    sources: &[String],
) -> String {
    let note = |name: &str| {
        notes
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, t)| t.clone())
    };
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# The machine identified by twinmill from {} (values in mm and rad; σ is the \
         standard uncertainty from the measurements' stated noise).",
        sources.join(", ")
    );
    let _ = writeln!(s, "[deviations]");
    for (k, v) in deviations {
        let _ = write!(s, "\"{k}\" = {}", toml_number(*v));
        match note(k) {
            Some(n) => {
                let _ = writeln!(s, "  # {n}");
            }
            None => {
                let _ = writeln!(s, "  # the scene's value, not identified");
            }
        }
    }
    let _ = writeln!(s, "\n[error_motions]");
    let mut reversals = Vec::new();
    for a in chain.axes() {
        let Some(e) = chain.error_motions(a.letter) else {
            continue;
        };
        for c in Component::ALL {
            let terms = &e.functions[c as usize].terms;
            if terms.is_empty() {
                continue;
            }
            let f = motion_name(c, a.letter);
            let list = |v: &[Real]| {
                v.iter()
                    .map(|x| toml_number(*x))
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let mut parts = Vec::new();
            let mut periodic = Vec::new();
            for t in terms {
                match t {
                    Term::Polynomial(co) => parts.push(format!("polynomial = [{}]", list(co))),
                    Term::Table { q, v } => parts.push(format!(
                        "table = {{ q = [{}], values = [{}] }}",
                        list(q),
                        list(v)
                    )),
                    Term::Periodic {
                        amplitude,
                        period,
                        phase_deg,
                    } => periodic.push(format!(
                        "{{ amplitude = {}, period = {}, phase_deg = {} }}",
                        toml_number(*amplitude),
                        toml_number(*period),
                        toml_number(*phase_deg)
                    )),
                }
            }
            if !periodic.is_empty() {
                parts.push(format!("periodic = [{}]", periodic.join(", ")));
            }
            let notes: Vec<String> = notes
                .iter()
                .filter(|(n, _)| n.starts_with(&format!("{f}.")))
                .map(|(_, t)| t.clone())
                .collect();
            let _ = write!(s, "{f} = {{ {} }}", parts.join(", "));
            if notes.is_empty() {
                let _ = writeln!(s, "  # the scene's, not identified");
            } else {
                let _ = writeln!(s, "  # {}", notes.join("; "));
            }
        }
        if e.reversal != 0.0 {
            reversals.push((a.letter, e.reversal));
        }
    }
    let _ = writeln!(s, "\n[reversal]");
    for (a, b) in reversals {
        let name = format!("reversal.{}", a.as_char());
        let n = note(&name).unwrap_or_else(|| "the scene's, not identified".into());
        let _ = writeln!(s, "{} = {}  # {n}", a.as_char(), toml_number(b));
    }
    s
}

/// A TOML string (a JSON string's escapes are TOML's).
fn toml_string(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

fn toml_strings(v: &[String]) -> String {
    format!(
        "[{}]",
        v.iter()
            .map(|s| toml_string(s))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// What a deviations file records of its identification (its `[identified]` section).
pub struct IdentifiedRecord<'a> {
    /// The machine's name.
    pub machine: &'a str,
    /// The scene's name.
    pub scene: &'a str,
    /// The machine's axes, in chain order.
    pub axes: &'a [String],
    /// The measurement files.
    pub sources: &'a [String],
    /// Whether a misfit was accepted on request.
    pub misfit_accepted: bool,
    /// The parameters not determined on their own.
    pub not_determined: &'a [String],
    /// Each identified parameter's standard uncertainty.
    pub sigma: &'a [(String, Real)],
}

/// The deviations file of every identification: the machine's sections (`fragment`), then
/// `[identified]` and `[identified.sigma]`, which `--deviations` reads back.
pub fn identified_file(fragment: &str, r: &IdentifiedRecord) -> String {
    use std::fmt::Write as _;
    let mut s = fragment.to_string();
    let _ = writeln!(
        s,
        "\n# What these sections were identified for and from; read back by `--deviations`."
    );
    let _ = writeln!(s, "[identified]");
    let _ = writeln!(s, "machine = {}", toml_string(r.machine));
    let _ = writeln!(s, "scene = {}", toml_string(r.scene));
    let _ = writeln!(s, "axes = {}", toml_strings(r.axes));
    let _ = writeln!(s, "sources = {}", toml_strings(r.sources));
    let _ = writeln!(s, "misfit_accepted = {}", r.misfit_accepted);
    let _ = writeln!(s, "not_determined = {}", toml_strings(r.not_determined));
    let _ = writeln!(
        s,
        "\n# Each identified parameter's standard uncertainty (its units)."
    );
    let _ = writeln!(s, "[identified.sigma]");
    for (name, sigma) in r.sigma {
        let _ = writeln!(s, "{} = {:?}", toml_string(name), sigma);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrology::ballbar::Plane;
    use crate::metrology::interferometer::Targets;
    use crate::nc::AxisValues;

    /// The injected truth of a 3-axis machine: positioning scale, straightness bows,
    /// squareness and lost motion (mm, rad; polynomials in mm of travel).
    const TRUTH: &[(&str, Real)] = &[
        ("EXX.polynomial[1]", 15e-6),
        ("EYY.polynomial[1]", -10e-6),
        ("EZZ.polynomial[1]", 8e-6),
        ("EYX.polynomial[2]", 3e-7),
        ("EZX.polynomial[2]", -2e-7),
        ("EXY.polynomial[2]", 2e-7),
        ("EZY.polynomial[2]", 2.5e-7),
        ("EXZ.polynomial[2]", -3e-7),
        ("EYZ.polynomial[2]", 1.5e-7),
        ("EC(0X)Y", 20e-6),
        ("EB(0X)Z", -15e-6),
        ("EA(0Y)Z", 10e-6),
        ("reversal.X", -0.003),
        ("reversal.Y", -0.002),
        ("reversal.Z", 0.0015),
    ];

    const NOISE_UM: Real = 0.5;

    /// The truth built on the chain directly (not through [`chain_with`]): error motions
    /// as polynomials, reversals, then the squareness terms.
    fn truth_chain() -> Chain {
        use AxisLetter::{X, Y, Z};
        use Component::{Dx, Dy, Dz};
        let mut c = crate::machine::chain::xyz_for_tests();
        let value = |name: &str| TRUTH.iter().find(|(n, _)| *n == name).expect("in TRUTH").1;
        for axis in [X, Y, Z] {
            let mut e = AxisErrorMotions::for_axis(axis);
            for comp in [Dx, Dy, Dz] {
                let own = error_motion::component_of(axis) == comp;
                let k = if own { 1 } else { 2 };
                let mut co = vec![0.0; k + 1];
                co[k] = value(&format!("{}.polynomial[{k}]", motion_name(comp, axis)));
                e.functions[comp as usize].terms = vec![Term::polynomial(co).expect("finite")];
            }
            e.reversal = value(&format!("reversal.{}", axis.as_char()));
            c.set_error_motions(axis, e).expect("axis");
        }
        for name in ["EC(0X)Y", "EB(0X)Z", "EA(0Y)Z"] {
            c.apply_iso_term(name, value(name)).expect("term");
        }
        c
    }

    fn laser(chain: &Chain, axis: AxisLetter, seed: u64) -> (LaserSetup, Vec<Reading>) {
        let mut s = LaserSetup::new(
            axis,
            Targets::Even {
                start_mm: -100.0,
                end_mm: 100.0,
                count: 9,
            },
            AxisValues::default(),
        );
        s.noise_um = NOISE_UM;
        s.seed = seed;
        let m = interferometer::measure(chain, &s).expect("measures");
        (s, m.readings)
    }

    fn circle(chain: &Chain, plane: Plane, seed: u64) -> (BallBarSetup, Vec<Sample>) {
        let mut s = BallBarSetup::new(plane, AxisValues::default(), 100.0);
        s.noise_um = NOISE_UM;
        s.seed = seed;
        // A mounting error the identification does not know.
        s.mount_offset_mm = Vector3::new(0.012, -0.007, 0.004);
        let m = ballbar::measure(chain, &s).expect("measures");
        (
            BallBarSetup {
                mount_offset_mm: Vector3::zeros(),
                ..s
            },
            m.samples,
        )
    }

    /// The volumetric set: laser on X, Y, Z and ball bar in XY, YZ, ZX.
    fn volumetric(chain: &Chain, seed: u64) -> Vec<Measurement> {
        let mut out = Vec::new();
        for (k, axis) in [AxisLetter::X, AxisLetter::Y, AxisLetter::Z]
            .into_iter()
            .enumerate()
        {
            let (setup, readings) = laser(chain, axis, seed * 16 + k as u64);
            out.push(Measurement::Laser {
                name: format!("laser-{}.csv", axis.as_char()),
                setup,
                readings,
            });
        }
        for (k, plane) in [Plane::Xy, Plane::Yz, Plane::Zx].into_iter().enumerate() {
            let (setup, samples) = circle(chain, plane, seed * 16 + 8 + k as u64);
            out.push(Measurement::BallBar {
                name: format!("ballbar-{}.csv", plane.name()),
                setup,
                samples,
            });
        }
        out
    }

    /// The parameters solved for: the truth's, and a constant X offset no measurement of
    /// the set can see (the laser is zeroed, the ball bar's centre absorbs it).
    fn unknowns(start: &Chain) -> Vec<MachineParameter> {
        TRUTH
            .iter()
            .map(|(n, _)| *n)
            .chain(["EXX.polynomial[0]"])
            .map(|n| MachineParameter::parse(start, &BTreeMap::new(), n).expect("valid"))
            .collect()
    }

    #[test]
    fn the_volumetric_set_recovers_a_three_axis_machine_and_names_what_it_cannot_see() {
        let truth = truth_chain();
        let start = crate::machine::chain::xyz_for_tests();
        let (_, o) = identify(&start, unknowns(&start), volumetric(&truth, 1)).expect("identifies");
        assert!(o.fit.fits, "{}", o.fit.describe());
        for (name, value) in TRUTH {
            let e = o
                .parameters
                .iter()
                .find(|e| e.name == *name)
                .unwrap_or_else(|| {
                    panic!("{name} identified: {:?}", o.identifiability.not_identified)
                });
            assert!(
                (e.value - value).abs() <= 4.0 * e.sigma,
                "{name}: {} ± {} against {value}",
                e.value,
                e.sigma
            );
            // Determined: σ well below the injected size.
            assert!(
                e.sigma < 0.1 * value.abs(),
                "{name}: σ {} for {value}",
                e.sigma
            );
        }
        let blind = "EXX.polynomial[0]".to_string();
        assert!(o.identifiability.not_identified.contains(&blind));
        assert!(o.parameters.iter().all(|e| e.name != blind));
        assert!(
            o.identifiability
                .undetermined_combinations
                .iter()
                .any(|c| c.name.contains("EXX.polynomial[0]"))
        );
    }

    #[test]
    fn a_laser_file_of_another_axis_given_as_x_is_refused_naming_it() {
        let truth = truth_chain();
        let start = crate::machine::chain::xyz_for_tests();
        let mut set = volumetric(&truth, 2);
        // The Y readings, handed over as the X laser's.
        let Measurement::Laser {
            setup, readings, ..
        } = set[1].clone()
        else {
            unreachable!()
        };
        set[0] = Measurement::Laser {
            name: "laser-Y-given-as-X.csv".into(),
            setup: LaserSetup {
                axis: AxisLetter::X,
                ..setup
            },
            readings,
        };
        let (_, mut o) = identify(&start, unknowns(&start), set).expect("solves");
        assert!(!o.fit.fits);
        // Blamed first (with any file that alone would explain the misfit as well).
        let file = "laser-Y-given-as-X.csv".to_string();
        assert!(
            o.fit.blame.first().is_some_and(|g| g.contains(&file)),
            "{:?}",
            o.fit.blame
        );
        let refusal = o.fit.enforce("identify", false).expect_err("refused");
        assert!(
            refusal.0.contains("laser-Y-given-as-X.csv"),
            "{}",
            refusal.0
        );
        assert!(o.fit.enforce("identify", true).is_ok() && o.fit.misfit_accepted);
    }
}
