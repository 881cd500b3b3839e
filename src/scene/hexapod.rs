//! A hexapod scene (`[machine] kind = "hexapod"`): the Stewart platform's joints,
//! reference lengths, tool offset, stroke and joint limits, home pose, the deviations of the
//! actual machine by parameter name, the controller's parameters (`[controller]`, nominal
//! by default; a controller file, `--controller FILE`, replaces them), and the optional data the hexapod verbs use (the
//! workspace to map, the drives' lead and encoder, the homing switches, the table, the
//! table's rotary axes). A hexapod scene needs no program, tool or stock; with them it cuts
//! ([`super::Machine::Hexapod`]).
//!
//! The home pose must be reachable (strokes, joint limits, not singular) on the nominal
//! machine and reached by the actual one.

use super::Ctx;
use super::SceneError;
use super::check::{check_coordinate, check_direction};
use super::file::{ControllerFile, HexapodMachineFile, SceneFile, TableAxesFile};
use super::machine::HexapodMachine;
use crate::machine::chain::{Axis, AxisKind, Chain};
use crate::machine::hexapod::{
    Hexapod, HexapodTwin, Limits, ParameterId, Pose, STRUTS, Struts, TableAxes, twin_pose,
};
use crate::machine::hexapod_accuracy::{HomingSetup, Workspace};
use crate::math::{Point3, Real, Vector3};
use crate::nc::AxisLetter;
use std::collections::BTreeMap;
use std::path::PathBuf;
use toml::Spanned;

/// The drives of the struts: a ball screw and a rotary encoder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Drives {
    /// Screw lead T (mm per revolution).
    pub lead_mm: Real,
    /// Encoder counts per revolution.
    pub counts_per_rev: u64,
}

impl Drives {
    /// The strut resolution: one count (mm).
    pub fn resolution_mm(&self) -> Real {
        self.lead_mm / self.counts_per_rev as Real
    }
}

/// The machine table (base frame, mm): its top face.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Table {
    /// Height of the top face.
    pub top_z_mm: Real,
    /// x extent.
    pub x_mm: (Real, Real),
    /// y extent.
    pub y_mm: (Real, Real),
}

/// The default trip-point standard deviation of a homing switch when the scene gives none
/// (mm): 0.1 mm, a mechanical limit switch's repeatability class.
pub const DEFAULT_TRIP_SIGMA_MM: Real = 0.1;

/// A loaded, validated hexapod scene, as the hexapod verbs use it: the machine and its
/// sections (no program, tool or stock needed; [`crate::scene::Scene::load_hexapod_cut`]
/// reads one that cuts).
#[derive(Clone, Debug)]
pub struct HexapodScene {
    /// The scene file.
    pub path: PathBuf,
    /// Scene name.
    pub name: String,
    /// Machine description.
    pub machine_name: String,
    /// The machine as designed (`[machine]`): what the commanded poses mean.
    pub nominal: Hexapod,
    /// The parameters the controller's kinematics run on: nominal plus `[controller]` (or a
    /// controller file's values); the nominal machine when neither gives any.
    pub controller: Hexapod,
    /// The controller's values by parameter name, as deviations from nominal (mm); empty:
    /// the nominal controller.
    pub controller_values: BTreeMap<String, Real>,
    /// Where the controller's values come from: `None` for the scene's own (`[controller]`
    /// or nominal), else the controller file.
    pub controller_file: Option<PathBuf>,
    /// The machine as built: nominal plus the injected deviations.
    pub actual: Hexapod,
    /// Deviations injected, by parameter name (mm).
    pub injected: BTreeMap<String, Real>,
    /// The home pose.
    pub home: Pose,
    /// `[workspace]`: the region the amplification map and the positioning survey cover.
    pub workspace: Option<Workspace>,
    /// `[drives]`: lead and encoder counts.
    pub drives: Option<Drives>,
    /// `[homing]`: the switch-to-index distances (with `[drives]` lead).
    pub homing: Option<HomingSetup>,
    /// `[table]`.
    pub table: Option<Table>,
    /// `[table_axes]`: rotary axes carrying the part (nominal and with their deviations).
    pub table_axes: Option<TableAxes>,
    /// Keep a calibration whose residuals the stated noise cannot explain instead of
    /// refusing it ([`crate::calibration::goodness`]); its outcome then says so on its
    /// first line. Never read from the scene file: the command line's `--accept-misfit`.
    pub accept_misfit: bool,
}

impl Ctx<'_> {
    /// The six joints of `[machine] base_joints` or `platform_joints`.
    fn joints(
        &self,
        v: &Spanned<Vec<Spanned<[Real; 3]>>>,
        what: &str,
    ) -> Result<[Vector3; STRUTS], SceneError> {
        let list = v.get_ref();
        if list.len() != STRUTS {
            return Err(self.err(
                v.span(),
                format!("{what} must list six joints, got {}", list.len()),
            ));
        }
        let mut out = [Vector3::zeros(); STRUTS];
        for (i, j) in list.iter().enumerate() {
            out[i] = Vector3::from(self.coordinates(j, &format!("machine.{what}[{}]", i + 1))?);
        }
        Ok(out)
    }

    /// `[table_axes]`: rotary axes A, B or C (the letters the platform then holds at home),
    /// from the workpiece to the base frame.
    fn table_axes(&self, t: &TableAxesFile) -> Result<Chain, SceneError> {
        let mut axes = Vec::new();
        if t.axes.get_ref().is_empty() {
            return Err(self.err(t.axes.span(), "table_axes.axes is empty"));
        }
        for a in t.axes.get_ref() {
            let letter = match a.name.get_ref().as_str() {
                "A" => AxisLetter::A,
                "B" => AxisLetter::B,
                "C" => AxisLetter::C,
                other => {
                    return Err(self.err(
                        a.name.span(),
                        format!("a table axis is rotary, named A, B or C; got '{other}'"),
                    ));
                }
            };
            let key = format!("table_axes.{}", a.name.get_ref());
            let direction = check_direction(*a.direction.get_ref(), &format!("{key}.direction"))
                .map_err(|e| self.err(a.direction.span(), e))?;
            let origin = match &a.origin {
                Some(o) => Point3::from(Vector3::from(
                    self.coordinates(o, &format!("{key}.origin"))?,
                )),
                None => Point3::origin(),
            };
            axes.push(Axis {
                letter,
                kind: AxisKind::Rotary,
                direction,
                origin,
            });
        }
        Chain::new(axes, "S").map_err(|e| self.err(t.axes.span(), e.to_string()))
    }

    /// A joint's angular limit in (0, 180] degrees, in radians.
    fn limit(&self, v: &Option<Spanned<Real>>, what: &str) -> Result<Option<Real>, SceneError> {
        let Some(v) = v else { return Ok(None) };
        let d = self.finite(v, what)?;
        if d > 0.0 && d <= 180.0 {
            Ok(Some(d.to_radians()))
        } else {
            Err(self.err(
                v.span(),
                format!("{what} must lie in (0, 180] degrees, got {d}"),
            ))
        }
    }
}

/// `[machine]` (kind hexapod), `[deviations]` and the hexapod sections.
pub(super) fn read_hexapod(
    ctx: &Ctx,
    file: &SceneFile<HexapodMachineFile>,
) -> Result<HexapodScene, SceneError> {
    let path = ctx.path;
    let m = &file.machine;
    if m.kind.get_ref() != "hexapod" {
        return Err(ctx.err(
            m.kind.span(),
            format!(
                "the hexapod commands need [machine] kind = \"hexapod\", got '{}'",
                m.kind.get_ref()
            ),
        ));
    }
    let name = match &file.name {
        Some(n) => {
            let t = n.get_ref().trim();
            if t.is_empty()
                || t.starts_with('.')
                || !t
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
            {
                return Err(ctx.err(
                    n.span(),
                    "name must be non-empty and use only letters, digits, '-', '_', '.'",
                ));
            }
            t.to_string()
        }
        None => path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "hexapod".into()),
    };
    let base = ctx.joints(&m.base_joints, "base_joints")?;
    let platform = ctx.joints(&m.platform_joints, "platform_joints")?;
    let tool = match &m.tool_offset {
        Some(v) => Vector3::from(ctx.coordinates(v, "machine.tool_offset")?),
        None => Vector3::zeros(),
    };
    let home = ctx.finite_array(&m.home, "home")?;
    for (i, v) in home.iter().enumerate() {
        if i < 3 {
            check_coordinate(*v, "machine.home").map_err(|e| ctx.err(m.home.span(), e))?;
        } else if v.abs() > 180.0 {
            return Err(ctx.err(
                m.home.span(),
                format!("machine.home: got the angle {v:e}°, expected within ±180°"),
            ));
        }
    }
    let home = Pose::from_mm_deg(home);
    let stroke = match &m.stroke_mm {
        Some(v) => {
            let (lo, hi) = ctx.range(v, "stroke_mm")?;
            if !(lo > 0.0 && lo < hi) {
                return Err(ctx.err(
                    v.span(),
                    format!("stroke_mm [{lo}, {hi}] must have 0 < min < max"),
                ));
            }
            Some((lo, hi))
        }
        None => None,
    };
    let limits = Limits {
        stroke_mm: stroke,
        base_axis: ctx.axis(&m.base_joint_axis, "base_joint_axis", Vector3::z_axis())?,
        base_max_rad: ctx.limit(&m.base_joint_limit_deg, "base_joint_limit_deg")?,
        platform_axis: ctx.axis(
            &m.platform_joint_axis,
            "platform_joint_axis",
            -Vector3::z_axis(),
        )?,
        platform_max_rad: ctx.limit(&m.platform_joint_limit_deg, "platform_joint_limit_deg")?,
    };
    let geometry_err =
        |e: crate::machine::hexapod::HexapodError| ctx.err(m.base_joints.span(), e.to_string());
    let unreferenced =
        Hexapod::try_new(base, platform, [0.0; STRUTS], tool, limits).map_err(geometry_err)?;
    let reference: Struts = match &m.strut_reference_mm {
        Some(v) => ctx.coordinates(v, "machine.strut_reference_mm")?,
        None => unreferenced.strut_lengths(&home),
    };
    let nominal =
        Hexapod::try_new(base, platform, reference, tool, limits).map_err(geometry_err)?;
    nominal
        .check_pose(&home)
        .map_err(|e| ctx.err(m.home.span(), format!("home pose {home}: {e}")))?;
    // Table axes.
    let mut table_chain = match file.table_axes.as_ref().map(Spanned::get_ref) {
        Some(t) => Some(ctx.table_axes(t)?),
        None => None,
    };
    let table_nominal = table_chain.clone();
    // Deviations: the platform's parameters by name; with table axes, their joints'
    // deviations by chain name (`dx_C`, `gamma_C`, …).
    let mut actual = nominal.clone();
    let mut injected = BTreeMap::new();
    for (k, v) in &file.deviations {
        let x = ctx.finite(v, k)?;
        match (ParameterId::from_name(k), table_chain.as_mut()) {
            (Err(_), Some(chain)) if chain.deviation_id(k).is_ok() => {
                let id = chain
                    .deviation_id(k)
                    .map_err(|e| ctx.err(v.span(), e.to_string()))?;
                chain.set_deviation(id, x);
            }
            _ => actual
                .add_deviation(k, x)
                .map_err(|e| ctx.err(v.span(), e.to_string()))?,
        }
        injected.insert(k.clone(), x);
    }
    if let Err(e) = twin_pose(&nominal, &actual, &home) {
        let span = file
            .deviations
            .values()
            .next()
            .map_or(m.home.span(), |v| v.span());
        return Err(ctx.err(
            span,
            format!("with the injected deviations the machine does not reach home: {e}"),
        ));
    }
    let (controller, controller_values) = read_controller(
        ctx,
        &file.controller,
        &nominal,
        &actual,
        &home,
        "[controller]",
    )?;
    let workspace = match file.workspace.as_ref().map(Spanned::get_ref) {
        Some(w) => {
            let ws = Workspace {
                x_mm: ctx.range(&w.x_mm, "workspace.x_mm")?,
                y_mm: ctx.range(&w.y_mm, "workspace.y_mm")?,
                z_mm: ctx.range(&w.z_mm, "workspace.z_mm")?,
                tilt_deg: match &w.tilt_deg {
                    Some(t) => ctx.finite(t, "workspace.tilt_deg")?,
                    None => 0.0,
                },
            };
            let span = w.tilt_deg.as_ref().map_or(w.x_mm.span(), |t| t.span());
            ws.validate().map_err(|e| ctx.err(span, e))?;
            Some(ws)
        }
        None => None,
    };
    let drives = match file.drives.as_ref().map(Spanned::get_ref) {
        Some(d) => {
            let lead = ctx.finite(&d.lead_mm, "drives.lead_mm")?;
            if lead <= 0.0 {
                return Err(ctx.err(d.lead_mm.span(), "drives.lead_mm must be positive"));
            }
            if *d.counts_per_rev.get_ref() == 0 {
                return Err(ctx.err(
                    d.counts_per_rev.span(),
                    "drives.counts_per_rev must be positive",
                ));
            }
            Some(Drives {
                lead_mm: lead,
                counts_per_rev: *d.counts_per_rev.get_ref(),
            })
        }
        None => None,
    };
    let homing = match file.homing.as_ref().map(Spanned::get_ref) {
        Some(h) => {
            let Some(d) = drives else {
                return Err(ctx.err(
                    h.switch_to_index_mm.span(),
                    "[homing] needs [drives] lead_mm (the index pulses come once per lead)",
                ));
            };
            let s = ctx.finite_array(&h.switch_to_index_mm, "homing.switch_to_index_mm")?;
            if let Some(x) = s.iter().find(|x| !(**x >= 0.0 && **x < d.lead_mm)) {
                return Err(ctx.err(
                    h.switch_to_index_mm.span(),
                    format!(
                        "homing.switch_to_index_mm {x} must lie in [0, lead) = [0, {})",
                        d.lead_mm
                    ),
                ));
            }
            let sigma = match &h.trip_sigma_mm {
                Some(v) => {
                    let x = ctx.finite(v, "homing.trip_sigma_mm")?;
                    if x < 0.0 {
                        return Err(ctx.err(v.span(), "homing.trip_sigma_mm must not be negative"));
                    }
                    x
                }
                None => DEFAULT_TRIP_SIGMA_MM,
            };
            Some(HomingSetup {
                lead_mm: d.lead_mm,
                switch_to_index_mm: s,
                trip_sigma_mm: sigma,
            })
        }
        None => None,
    };
    let table = match file.table.as_ref().map(Spanned::get_ref) {
        Some(t) => {
            let table = Table {
                top_z_mm: ctx.finite(&t.top_z_mm, "table.top_z_mm")?,
                x_mm: ctx.range(&t.x_mm, "table.x_mm")?,
                y_mm: ctx.range(&t.y_mm, "table.y_mm")?,
            };
            if home.position.z <= table.top_z_mm {
                return Err(ctx.err(
                    m.home.span(),
                    format!(
                        "home puts the tool point at z = {} mm, not above the table top (z = {} mm)",
                        home.position.z, table.top_z_mm
                    ),
                ));
            }
            if let Some(w) = &workspace
                && w.z_mm.0 < table.top_z_mm
            {
                return Err(ctx.err(
                    t.top_z_mm.span(),
                    format!(
                        "the workspace reaches z = {} mm, below the table top (z = {} mm)",
                        w.z_mm.0, table.top_z_mm
                    ),
                ));
            }
            Some(table)
        }
        None => None,
    };
    Ok(HexapodScene {
        path: path.to_path_buf(),
        name,
        machine_name: m.name.clone(),
        nominal,
        controller,
        controller_values,
        controller_file: None,
        actual,
        injected,
        home,
        workspace,
        drives,
        homing,
        table,
        table_axes: table_nominal
            .zip(table_chain)
            .map(|(nominal, actual)| TableAxes { nominal, actual }),
        accept_misfit: false,
    })
}

/// The controller of `[controller]` (or a controller file's section, `what`): `nominal`
/// with each named parameter moved by its value (mm; the names of `[deviations]`:
/// `bx_1`, `l0_3`, …). It must hold the home pose (strokes, joint limits, not singular), and
/// the `actual` machine it drives must reach it.
fn read_controller(
    ctx: &Ctx,
    entries: &BTreeMap<String, Spanned<Real>>,
    nominal: &Hexapod,
    actual: &Hexapod,
    home: &Pose,
    what: &str,
) -> Result<(Hexapod, BTreeMap<String, Real>), SceneError> {
    let mut controller = nominal.clone();
    let mut values = BTreeMap::new();
    for (k, v) in entries {
        let x = ctx.finite(v, k)?;
        if ParameterId::from_name(k).is_err() {
            return Err(ctx.err(
                v.span(),
                format!(
                    "{what} names the platform's kinematic parameters (bx_1 … bz_6, ax_1 … az_6, l0_1 … l0_6); got '{k}'"
                ),
            ));
        }
        controller
            .add_deviation(k, x)
            .map_err(|e| ctx.err(v.span(), e.to_string()))?;
        values.insert(k.clone(), x);
    }
    let span = entries.values().next().map_or(0..0, |v| v.span());
    controller.check_pose(home).map_err(|e| {
        ctx.err(
            span.clone(),
            format!("with the {what} parameters the controller cannot hold home {home}: {e}"),
        )
    })?;
    twin_pose(&controller, actual, home).map_err(|e| {
        ctx.err(
            span,
            format!("driven by the {what} parameters the machine does not reach home: {e}"),
        )
    })?;
    Ok((controller, values))
}

/// A controller file's text: its `[controller]` section read against the machine of a
/// scene (`nominal`, `actual`, `home`). Errors name the file, line and column.
fn controller_of_text(
    text: &str,
    path: &std::path::Path,
    nominal: &Hexapod,
    actual: &Hexapod,
    home: &Pose,
) -> Result<(Hexapod, BTreeMap<String, Real>), SceneError> {
    let ctx = Ctx { path, text };
    let file: ControllerFile =
        toml::from_str(text).map_err(|e| super::toml_error(text, path, &e))?;
    read_controller(
        &ctx,
        &file.controller,
        nominal,
        actual,
        home,
        "[controller]",
    )
}

impl HexapodScene {
    /// Replaces the controller's parameters by a controller file's (`--controller FILE`:
    /// the `[controller]` section `identify --readings … --corrected` writes), as deviations
    /// from the scene's nominal machine. On an error the scene is unchanged.
    pub fn apply_controller_file(&mut self, path: &std::path::Path) -> Result<(), SceneError> {
        let text = super::read_text(path)?;
        self.apply_controller_text(&text, path)
    }

    /// [`HexapodScene::apply_controller_file`] on the file's text; `path` locates messages.
    pub fn apply_controller_text(
        &mut self,
        text: &str,
        path: &std::path::Path,
    ) -> Result<(), SceneError> {
        let (controller, values) =
            controller_of_text(text, path, &self.nominal, &self.actual, &self.home)?;
        self.controller = controller;
        self.controller_values = values;
        self.controller_file = Some(path.to_path_buf());
        Ok(())
    }

    /// Whether the controller runs on parameters other than the nominal machine's.
    pub fn calibrated_controller(&self) -> bool {
        self.controller != self.nominal
    }

    /// What the controller runs on, for summaries: `nominal`, `[controller]` or the file.
    pub fn controller_label(&self) -> String {
        match (&self.controller_file, self.calibrated_controller()) {
            (Some(p), _) => format!("the controller of {}", p.display()),
            (None, true) => "the scene's [controller]".into(),
            (None, false) => "the nominal controller".into(),
        }
    }
}

impl super::Scene {
    /// A hexapod scene that cuts: replaces its controller's parameters by a controller
    /// file's ([`HexapodScene::apply_controller_file`]). A serial scene refuses it.
    pub fn apply_controller_file(&mut self, path: &std::path::Path) -> Result<(), SceneError> {
        let text = super::read_text(path)?;
        let super::Machine::Hexapod(h) = &mut self.machine else {
            return Err(SceneError::Invalid {
                path: path.to_path_buf(),
                line: 1,
                column: 1,
                message: format!(
                    "a controller file holds a hexapod controller's parameters; {} is a serial machine (its identified deviations go with --deviations)",
                    self.path.display()
                ),
            });
        };
        let t = &h.twin;
        let (controller, _) = controller_of_text(&text, path, &t.nominal, &t.actual, &t.home)?;
        h.twin.controller = controller;
        Ok(())
    }
}

impl HexapodScene {
    /// The machine as an NC program drives it.
    pub fn twin(&self) -> HexapodTwin {
        HexapodTwin {
            nominal: self.nominal.clone(),
            controller: self.controller.clone(),
            actual: self.actual.clone(),
            home: self.home,
            table: self.table_axes.clone(),
        }
    }

    /// The hexapod as the machine of a scene that cuts: its twin, the controller's
    /// Cartesian kinematics and the axis values at home.
    pub(super) fn cutting_machine(&self, ctx: &Ctx) -> Result<HexapodMachine, SceneError> {
        let twin = self.twin();
        let command = twin
            .command_chain()
            .map_err(|e| ctx.err(0..0, format!("[table_axes]: {e}")))?;
        Ok(HexapodMachine {
            name: self.machine_name.clone(),
            home: twin.home_axis_values(),
            twin,
            command,
            injected: self.injected.clone(),
        })
    }
}
