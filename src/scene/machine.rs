//! The machine of a scene, one variant per `[machine] kind`: a serial chain of axes with its
//! deviations, error motions and reversal ([`SerialMachine`], read here), or a hexapod
//! ([`HexapodMachine`], read by [`super::hexapod`]). Code that drives the machine matches on
//! [`Machine`]; [`Scene::chain`] and its neighbours give what every kind has.

use super::Ctx;
use super::Scene;
use super::SceneError;
use super::check::{MAX_ANGLE_DEG, check_coordinate, check_direction, linear_axes_span};
use super::file::{MotionFile, SceneFile, SerialMachineFile};
use crate::cutting::sweep::Kinematics;
use crate::machine::chain::{Axis, AxisKind, Chain};
use crate::machine::error_motion::{self, AxisErrorMotions};
use crate::machine::hexapod::HexapodTwin;
use crate::machine::tcp::{self, Controller};
use crate::math::{Point3, Real};
use crate::nc::{AxisLetter, AxisValues};
use std::collections::BTreeMap;
use std::ops::Range;
use toml::Spanned;

/// A scene's machine, by `[machine] kind`.
#[derive(Clone, Debug)]
pub enum Machine {
    /// `kind = "serial"` (the default): a chain of linear and rotary axes.
    Serial(Box<SerialMachine>),
    /// `kind = "hexapod"`: a Stewart platform, driven pose by pose.
    Hexapod(Box<HexapodMachine>),
}

/// A serial machine: the chain as built, and the model identification starts from.
#[derive(Clone, Debug)]
pub struct SerialMachine {
    /// Machine description (`[machine] name`).
    pub name: String,
    /// The simulated (real) machine: chain with the injected deviations.
    pub chain: Chain,
    /// Deviations injected, by name (mm or rad), as written in the scene.
    pub injected: BTreeMap<String, Real>,
    /// The identification model: nominal chain plus the deviations known a priori.
    pub model: Chain,
    /// Deviations known a priori, by name.
    pub known: BTreeMap<String, Real>,
    /// Axis values before the first move.
    pub home: AxisValues,
    /// How the controller reads the program (`[machine] controller`).
    pub controller: Controller,
}

/// A hexapod that cuts: the machine the sweep drives pose by pose, and the controller's
/// Cartesian kinematics its program is written in.
#[derive(Clone, Debug)]
pub struct HexapodMachine {
    /// Machine description (`[machine] name`).
    pub name: String,
    /// The nominal and actual platforms, the home pose and the table axes.
    pub twin: HexapodTwin,
    /// The controller's Cartesian kinematics ([`HexapodTwin::command_chain`]): the axes a
    /// program may drive, and the chain the pages compare the part with.
    pub command: Chain,
    /// The hexapod's deviations by parameter name (mm), as written in the scene.
    pub injected: BTreeMap<String, Real>,
    /// Axis values at the home pose ([`HexapodTwin::home_axis_values`]).
    pub home: AxisValues,
}

/// No deviations known a priori (a hexapod's).
static NONE_KNOWN: BTreeMap<String, Real> = BTreeMap::new();

impl Scene {
    /// The chain a program's axes are checked against: a serial machine's chain with its
    /// deviations, or a hexapod's Cartesian command chain.
    pub fn chain(&self) -> &Chain {
        match &self.machine {
            Machine::Serial(m) => &m.chain,
            Machine::Hexapod(h) => &h.command,
        }
    }

    /// The identification model: a serial machine's nominal chain with the deviations known
    /// a priori, or a hexapod's command chain.
    pub fn model(&self) -> &Chain {
        match &self.machine {
            Machine::Serial(m) => &m.model,
            Machine::Hexapod(h) => &h.command,
        }
    }

    /// Deviations injected, by name, as written in the scene.
    pub fn injected(&self) -> &BTreeMap<String, Real> {
        match &self.machine {
            Machine::Serial(m) => &m.injected,
            Machine::Hexapod(h) => &h.injected,
        }
    }

    /// Deviations known a priori, by name (none on a hexapod).
    pub fn known(&self) -> &BTreeMap<String, Real> {
        match &self.machine {
            Machine::Serial(m) => &m.known,
            Machine::Hexapod(_) => &NONE_KNOWN,
        }
    }

    /// Axis values before the first move.
    pub fn home(&self) -> AxisValues {
        match &self.machine {
            Machine::Serial(m) => m.home,
            Machine::Hexapod(h) => h.home,
        }
    }

    /// How the controller reads the program's axis words: joint values, or the tool tip in
    /// the workpiece frame (`[machine] controller = "tcp"`; a hexapod's program is its own
    /// Cartesian one, `Joint` here).
    pub fn controller(&self) -> Controller {
        match &self.machine {
            Machine::Serial(m) => m.controller,
            Machine::Hexapod(_) => Controller::Joint,
        }
    }

    /// Machine description (`[machine] name`).
    pub fn machine_name(&self) -> &str {
        match &self.machine {
            Machine::Serial(m) => &m.name,
            Machine::Hexapod(h) => &h.name,
        }
    }

    /// The machine the sweep drives: the hexapod pose by pose, or the deviated chain.
    pub fn kinematics(&self) -> Kinematics<'_> {
        match &self.machine {
            Machine::Serial(m) => Kinematics::Chain(&m.chain),
            Machine::Hexapod(h) => Kinematics::Poses(&h.twin),
        }
    }

    /// The serial machine, to change (a hexapod: `None`).
    pub fn serial_mut(&mut self) -> Option<&mut SerialMachine> {
        match &mut self.machine {
            Machine::Serial(m) => Some(m.as_mut()),
            Machine::Hexapod(_) => None,
        }
    }
}

/// `[machine]` (kind serial), `[deviations]`, `[error_motions]`, `[reversal]` and
/// `[identify] known`: the chain as built and the identification model.
pub(super) fn read_serial(
    ctx: &Ctx,
    file: &SceneFile<SerialMachineFile>,
) -> Result<SerialMachine, SceneError> {
    let ctx = *ctx;
    if let Some(k) = &file.machine.kind
        && k.get_ref() != "serial"
    {
        return Err(ctx.err(
            k.span(),
            format!(
                "machine kind must be 'serial' or 'hexapod', got '{}'",
                k.get_ref()
            ),
        ));
    }
    let mut axes = Vec::new();
    for a in file.machine.axes.get_ref() {
        let mut chars = a.name.get_ref().chars();
        let letter = match (chars.next().and_then(AxisLetter::from_char), chars.next()) {
            (Some(l), None) => l,
            _ => {
                return Err(ctx.err(
                    a.name.span(),
                    format!(
                        "axis name must be one of X Y Z A B C, got '{}'",
                        a.name.get_ref()
                    ),
                ));
            }
        };
        let kind = match a.kind.get_ref().as_str() {
            "linear" => AxisKind::Linear,
            "rotary" => AxisKind::Rotary,
            other => {
                return Err(ctx.err(
                    a.kind.span(),
                    format!("axis kind must be 'linear' or 'rotary', got '{other}'"),
                ));
            }
        };
        if (kind == AxisKind::Rotary) != letter.is_rotary() {
            return Err(ctx.err(
                a.kind.span(),
                format!(
                    "axis {} must be {}",
                    letter.as_char(),
                    if letter.is_rotary() {
                        "rotary"
                    } else {
                        "linear"
                    }
                ),
            ));
        }
        let key = |what: &str| format!("machine.axes.{}.{what}", letter.as_char());
        let direction = check_direction(*a.direction.get_ref(), &key("direction"))
            .map_err(|e| ctx.err(a.direction.span(), e))?;
        let origin = match &a.origin {
            Some(o) => {
                let v = ctx.vec3(o, &key("origin"))?;
                for c in v.iter() {
                    check_coordinate(*c, &key("origin")).map_err(|e| ctx.err(o.span(), e))?;
                }
                Point3::from(v)
            }
            None => Point3::origin(),
        };
        axes.push(Axis {
            letter,
            kind,
            direction,
            origin,
        });
    }
    linear_axes_span(&axes)
        .map_err(|e| ctx.err(file.machine.axes.span(), format!("machine.axes: {e}")))?;
    let mut chain = Chain::new(axes, &file.machine.spindle)
        .map_err(|e| ctx.err(file.machine.axes.span(), e.to_string()))?;
    let mut home = AxisValues::default();
    for (k, v) in &file.machine.home {
        let letter = match k.chars().collect::<Vec<_>>()[..] {
            [c] => AxisLetter::from_char(c).filter(|l| chain.has_axis(*l)),
            _ => None,
        }
        .ok_or_else(|| {
            ctx.err(
                v.span(),
                format!("home: '{k}' is not an axis of this machine"),
            )
        })?;
        let x = ctx.finite(v, &format!("home.{k}"))?;
        let x = if letter.is_rotary() {
            if x.abs() > MAX_ANGLE_DEG {
                return Err(ctx.err(
                    v.span(),
                    format!(
                        "machine.home.{k}: got {x:e}°, expected within ±{MAX_ANGLE_DEG}° \
                         (a hundred turns)"
                    ),
                ));
            }
            x
        } else {
            check_coordinate(x, &format!("machine.home.{k}")).map_err(|e| ctx.err(v.span(), e))?
        };
        home.set(letter, x);
    }
    let controller = match file.machine.controller.as_ref() {
        None => Controller::Joint,
        Some(c) => match c.get_ref().as_str() {
            "joint" => Controller::Joint,
            "tcp" if tcp::has_rotary(&chain) => Controller::Tcp,
            "tcp" => {
                return Err(ctx.err(
                    c.span(),
                    "machine.controller = \"tcp\" needs a rotary axis: on a machine of linear \
                     axes the program's X Y Z already move the tool tip (use \"joint\")",
                ));
            }
            other => {
                return Err(ctx.err(
                    c.span(),
                    format!("machine.controller must be \"joint\" or \"tcp\", got \"{other}\""),
                ));
            }
        },
    };
    let model_nominal = chain.nominal();
    let injected = deviation_map(&ctx, &mut chain, &file.deviations)?;
    error_motions(&ctx, &mut chain, &file.error_motions, &file.reversal)?;
    // The model knows the machine's error motions (measured, like `known`).
    let mut model = model_nominal.with_error_motions_of(&chain);
    let known = match &file.identify {
        Some(id) => deviation_map(&ctx, &mut model, &id.known)?,
        None => BTreeMap::new(),
    };
    Ok(SerialMachine {
        name: file.machine.name.clone(),
        chain,
        injected,
        model,
        known,
        home,
        controller,
    })
}

/// Sets the deviations of `map` on `chain`: names `<component>_<joint>` first, then the
/// ISO location and squareness names (`EY0A`, `EC(0X)Y`, …) composed onto them.
pub(super) fn deviation_map(
    ctx: &Ctx,
    chain: &mut Chain,
    map: &BTreeMap<String, Spanned<Real>>,
) -> Result<BTreeMap<String, Real>, SceneError> {
    let mut out = BTreeMap::new();
    for iso in [false, true] {
        for (name, value) in map.iter().filter(|(n, _)| n.contains('_') != iso) {
            let v = ctx.finite(value, name)?;
            if iso {
                chain
                    .apply_iso_term(name, v)
                    .map_err(|e| ctx.err(value.span(), e.to_string()))?;
            } else {
                let id = chain
                    .deviation_id(name)
                    .map_err(|e| ctx.err(value.span(), e.to_string()))?;
                chain.set_deviation(id, v);
            }
            out.insert(name.clone(), v);
        }
    }
    Ok(out)
}

/// The `[error_motions]` and `[reversal]` sections set on `chain`.
pub(super) fn error_motions(
    ctx: &Ctx,
    chain: &mut Chain,
    motions: &BTreeMap<String, Spanned<MotionFile>>,
    reversal: &BTreeMap<String, Spanned<Real>>,
) -> Result<(), SceneError> {
    let mut per_axis: BTreeMap<usize, AxisErrorMotions> = BTreeMap::new();
    let axes_list = || {
        chain
            .axes()
            .iter()
            .map(|a| a.letter.as_char().to_string())
            .collect::<Vec<_>>()
            .join(" ")
    };
    let axis_of = |name: &str, letter: AxisLetter, span: Range<usize>| {
        if chain.has_axis(letter) {
            Ok(letter)
        } else {
            Err(ctx.err(
                span,
                format!(
                    "'{name}' names axis {}, which this machine does not have (axes: {})",
                    letter.as_char(),
                    axes_list()
                ),
            ))
        }
    };
    for (name, entry) in motions {
        let (component, letter) =
            error_motion::parse_name(name).map_err(|e| ctx.err(entry.span(), e.to_string()))?;
        let letter = axis_of(name, letter, entry.span())?;
        let f = entry.get_ref();
        let mut terms = Vec::new();
        if let Some(t) = &f.table {
            let tf = t.get_ref();
            let mut q = Vec::with_capacity(tf.q.len());
            for (k, x) in tf.q.iter().enumerate() {
                let v = ctx.finite(x, &format!("{name}.table.q[{k}]"))?;
                if let Some(&prev) = q.last()
                    && v <= prev
                {
                    return Err(ctx.err(
                        x.span(),
                        format!(
                            "{name}.table.q must increase strictly: q[{k}] = {v} after q[{}] = {prev}",
                            k - 1
                        ),
                    ));
                }
                q.push(v);
            }
            let mut vals = Vec::with_capacity(tf.values.len());
            for (k, x) in tf.values.iter().enumerate() {
                vals.push(ctx.finite(x, &format!("{name}.table.values[{k}]"))?);
            }
            terms.push(
                error_motion::Term::table(q, vals)
                    .map_err(|e| ctx.err(t.span(), format!("{name}.table: {e}")))?,
            );
        }
        if let Some(p) = &f.polynomial {
            let mut c = Vec::with_capacity(p.len());
            for (k, x) in p.iter().enumerate() {
                c.push(ctx.finite(x, &format!("{name}.polynomial[{k}]"))?);
            }
            terms.push(
                error_motion::Term::polynomial(c)
                    .map_err(|e| ctx.err(entry.span(), format!("{name}.polynomial: {e}")))?,
            );
        }
        for (k, p) in f.periodic.iter().enumerate() {
            let pf = p.get_ref();
            let what = |field: &str| format!("{name}.periodic[{k}].{field}");
            let amplitude = ctx.finite(&pf.amplitude, &what("amplitude"))?;
            let period = ctx.positive(&pf.period, &what("period"))?;
            let phase = ctx.opt(&pf.phase_deg, &what("phase_deg"), 0.0)?;
            terms.push(
                error_motion::Term::periodic(amplitude, period, phase)
                    .map_err(|e| ctx.err(p.span(), format!("{}: {e}", what("period"))))?,
            );
        }
        if terms.is_empty() {
            return Err(ctx.err(
                entry.span(),
                format!("{name} needs a table, a polynomial or periodic terms"),
            ));
        }
        per_axis
            .entry(letter.index())
            .or_insert_with(|| AxisErrorMotions::for_axis(letter))
            .functions[component as usize]
            .terms = terms;
    }
    for (name, value) in reversal {
        let letter = match name.chars().collect::<Vec<_>>()[..] {
            [c] => AxisLetter::from_char(c),
            _ => None,
        }
        .ok_or_else(|| {
            ctx.err(
                value.span(),
                format!("reversal: '{name}' is not an axis letter (X Y Z A B C)"),
            )
        })?;
        let letter = axis_of(&format!("reversal.{name}"), letter, value.span())?;
        let b = ctx.finite(value, &format!("reversal.{name}"))?;
        per_axis
            .entry(letter.index())
            .or_insert_with(|| AxisErrorMotions::for_axis(letter))
            .reversal = b;
    }
    for (index, e) in per_axis {
        chain
            .set_error_motions(AxisLetter::ALL[index], e)
            .map_err(|e| ctx.err(0..0, e.to_string()))?;
    }
    Ok(())
}
