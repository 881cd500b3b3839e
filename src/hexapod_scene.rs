//! Hexapod scene files (TOML, `[machine] kind = "hexapod"`): the Stewart platform's joints,
//! reference lengths, tool offset, stroke and joint limits, home pose, the deviations of the
//! actual machine by parameter name, and the optional data the hexapod commands use (the
//! workspace to map, the drives' lead and encoder, the homing switches, the table).
//!
//! A hexapod scene needs no program, tool or stock: only what the `twinmill hexapod`
//! commands use. The serial-chain commands refuse it ([`crate::scene::SceneError::Hexapod`]).
//! Every value is checked when the scene loads and an error names the file, line and
//! column; `nan` and `inf` are refused; the home pose must be reachable (strokes, joint
//! limits, not singular) on the nominal machine and reached by the actual one.
//!
//! **Invariant:** reads only the scene file it is given, through [`crate::scene::read_text`].

use crate::machine::chain::{Axis, AxisKind, Chain};
use crate::machine::hexapod::{
    Hexapod, HexapodTwin, Limits, ParameterId, Pose, STRUTS, Struts, TableAxes, twin_pose,
};
use crate::machine::hexapod_accuracy::{HomingSetup, Workspace};
use crate::math::Point3;
use crate::math::{Real, UnitVector3, Vector3};
use crate::nc::AxisLetter;
use crate::scene::{MemoryBudget, Scene};
use crate::scene::{
    SceneError, check_coordinate, check_direction, line_col, read_text, toml_error,
};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use toml::Spanned;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
#[expect(
    dead_code,
    reason = "the cutting sections are accepted here and read by Scene::parse_hexapod_cut"
)]
struct HexapodFile {
    #[serde(default)]
    name: Option<Spanned<String>>,
    machine: MachineFile,
    #[serde(default)]
    deviations: BTreeMap<String, Spanned<Real>>,
    #[serde(default)]
    workspace: Option<WorkspaceFile>,
    #[serde(default)]
    drives: Option<DrivesFile>,
    #[serde(default)]
    homing: Option<HomingFile>,
    #[serde(default)]
    table: Option<TableFile>,
    #[serde(default)]
    table_axes: Option<TableAxesFile>,
    // The cutting sections, read by `Scene::parse_hexapod_cut` (see [`HexapodScene::load_cut`]).
    #[serde(default)]
    program: Option<toml::Value>,
    #[serde(default)]
    tool: Option<toml::Value>,
    #[serde(default)]
    stock: Option<toml::Value>,
    #[serde(default)]
    sweep: Option<toml::Value>,
    #[serde(default)]
    nc: Option<toml::Value>,
    #[serde(default)]
    design: Option<toml::Value>,
    #[serde(default)]
    scanner: Option<toml::Value>,
    #[serde(default)]
    study: Option<toml::Value>,
    #[serde(default)]
    fixtures: Option<toml::Value>,
    #[serde(default)]
    identify: Option<toml::Value>,
    #[serde(default)]
    error_motions: Option<toml::Value>,
    #[serde(default)]
    reversal: Option<toml::Value>,
}

/// `[table_axes]`: serial axes carrying the part.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TableAxesFile {
    axes: Spanned<Vec<TableAxisFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TableAxisFile {
    name: Spanned<String>,
    direction: Spanned<[Real; 3]>,
    #[serde(default)]
    origin: Option<Spanned<[Real; 3]>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MachineFile {
    kind: Spanned<String>,
    #[serde(default)]
    name: String,
    base_joints: Spanned<Vec<Spanned<[Real; 3]>>>,
    platform_joints: Spanned<Vec<Spanned<[Real; 3]>>>,
    #[serde(default)]
    tool_offset: Option<Spanned<[Real; 3]>>,
    home: Spanned<[Real; 6]>,
    #[serde(default)]
    strut_reference_mm: Option<Spanned<[Real; 6]>>,
    #[serde(default)]
    stroke_mm: Option<Spanned<[Real; 2]>>,
    #[serde(default)]
    base_joint_axis: Option<Spanned<[Real; 3]>>,
    #[serde(default)]
    base_joint_limit_deg: Option<Spanned<Real>>,
    #[serde(default)]
    platform_joint_axis: Option<Spanned<[Real; 3]>>,
    #[serde(default)]
    platform_joint_limit_deg: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WorkspaceFile {
    x_mm: Spanned<[Real; 2]>,
    y_mm: Spanned<[Real; 2]>,
    z_mm: Spanned<[Real; 2]>,
    #[serde(default)]
    tilt_deg: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DrivesFile {
    lead_mm: Spanned<Real>,
    counts_per_rev: Spanned<u64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct HomingFile {
    switch_to_index_mm: Spanned<[Real; 6]>,
    #[serde(default)]
    trip_sigma_mm: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TableFile {
    top_z_mm: Spanned<Real>,
    x_mm: Spanned<[Real; 2]>,
    y_mm: Spanned<[Real; 2]>,
}

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

/// A loaded, validated hexapod scene.
#[derive(Clone, Debug)]
pub struct HexapodScene {
    /// The scene file.
    pub path: PathBuf,
    /// Scene name.
    pub name: String,
    /// Machine description.
    pub machine_name: String,
    /// The machine as the controller knows it.
    pub nominal: Hexapod,
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

struct Ctx<'a> {
    path: &'a Path,
    text: &'a str,
}

impl Ctx<'_> {
    fn err(&self, span: Range<usize>, message: impl Into<String>) -> SceneError {
        let (line, column) = line_col(self.text, span.start);
        SceneError::Invalid {
            path: self.path.to_path_buf(),
            line,
            column,
            message: message.into(),
        }
    }

    fn finite<const N: usize>(
        &self,
        v: &Spanned<[Real; N]>,
        what: &str,
    ) -> Result<[Real; N], SceneError> {
        let a = *v.get_ref();
        if a.iter().all(|c| c.is_finite()) {
            Ok(a)
        } else {
            Err(self.err(v.span(), format!("{what} must be finite, got {a:?}")))
        }
    }

    fn number(&self, v: &Spanned<Real>, what: &str) -> Result<Real, SceneError> {
        let x = *v.get_ref();
        if x.is_finite() {
            Ok(x)
        } else {
            Err(self.err(v.span(), format!("{what} must be a finite number, got {x}")))
        }
    }

    fn range(&self, v: &Spanned<[Real; 2]>, what: &str) -> Result<(Real, Real), SceneError> {
        let [lo, hi] = self.finite(v, what)?;
        if lo <= hi {
            Ok((lo, hi))
        } else {
            Err(self.err(v.span(), format!("{what} [{lo}, {hi}] must have min ≤ max")))
        }
    }

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

    /// Finite coordinates (mm), each within [`crate::scene::MAX_COORDINATE_MM`].
    fn coordinates<const N: usize>(
        &self,
        v: &Spanned<[Real; N]>,
        what: &str,
    ) -> Result<[Real; N], SceneError> {
        let a = self.finite(v, what)?;
        for c in a {
            check_coordinate(c, what).map_err(|e| self.err(v.span(), e))?;
        }
        Ok(a)
    }

    fn axis(
        &self,
        v: &Option<Spanned<[Real; 3]>>,
        what: &str,
        default: UnitVector3,
    ) -> Result<UnitVector3, SceneError> {
        let Some(v) = v else { return Ok(default) };
        check_direction(*v.get_ref(), &format!("machine.{what}")).map_err(|e| self.err(v.span(), e))
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

    fn limit(&self, v: &Option<Spanned<Real>>, what: &str) -> Result<Option<Real>, SceneError> {
        let Some(v) = v else { return Ok(None) };
        let d = self.number(v, what)?;
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

impl HexapodScene {
    /// Loads and validates a hexapod scene file.
    pub fn load(path: &Path) -> Result<HexapodScene, SceneError> {
        let text = read_text(path)?;
        Self::parse(&text, path)
    }

    /// Parses and validates hexapod scene text; `path` locates messages.
    pub fn parse(text: &str, path: &Path) -> Result<HexapodScene, SceneError> {
        let ctx = Ctx { path, text };
        let file: HexapodFile = toml::from_str(text).map_err(|e| toml_error(text, path, &e))?;
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
        let home = ctx.finite(&m.home, "home")?;
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
        let mut table_chain = match &file.table_axes {
            Some(t) => Some(ctx.table_axes(t)?),
            None => None,
        };
        let table_nominal = table_chain.clone();
        // Deviations: the platform's parameters by name; with table axes, their joints'
        // deviations by chain name (`dx_C`, `gamma_C`, …).
        let mut actual = nominal.clone();
        let mut injected = BTreeMap::new();
        for (k, v) in &file.deviations {
            let x = ctx.number(v, k)?;
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
        let workspace = match &file.workspace {
            Some(w) => {
                let ws = Workspace {
                    x_mm: ctx.range(&w.x_mm, "workspace.x_mm")?,
                    y_mm: ctx.range(&w.y_mm, "workspace.y_mm")?,
                    z_mm: ctx.range(&w.z_mm, "workspace.z_mm")?,
                    tilt_deg: match &w.tilt_deg {
                        Some(t) => ctx.number(t, "workspace.tilt_deg")?,
                        None => 0.0,
                    },
                };
                let span = w.tilt_deg.as_ref().map_or(w.x_mm.span(), |t| t.span());
                ws.validate().map_err(|e| ctx.err(span, e))?;
                Some(ws)
            }
            None => None,
        };
        let drives = match &file.drives {
            Some(d) => {
                let lead = ctx.number(&d.lead_mm, "drives.lead_mm")?;
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
        let homing = match &file.homing {
            Some(h) => {
                let Some(d) = drives else {
                    return Err(ctx.err(
                        h.switch_to_index_mm.span(),
                        "[homing] needs [drives] lead_mm (the index pulses come once per lead)",
                    ));
                };
                let s = ctx.finite(&h.switch_to_index_mm, "homing.switch_to_index_mm")?;
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
                        let x = ctx.number(v, "homing.trip_sigma_mm")?;
                        if x < 0.0 {
                            return Err(
                                ctx.err(v.span(), "homing.trip_sigma_mm must not be negative")
                            );
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
        let table = match &file.table {
            Some(t) => {
                let table = Table {
                    top_z_mm: ctx.number(&t.top_z_mm, "table.top_z_mm")?,
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

    /// The machine as an NC program drives it.
    pub fn twin(&self) -> HexapodTwin {
        HexapodTwin {
            nominal: self.nominal.clone(),
            actual: self.actual.clone(),
            home: self.home,
            table: self.table_axes.clone(),
        }
    }

    /// Loads a hexapod scene that cuts (a program, tool and stock besides the machine) as a
    /// [`Scene`] whose sweep drives the hexapod ([`Scene::hexapod`]); the stock must fit in
    /// `memory`.
    pub fn load_cut(path: &Path, memory: &MemoryBudget) -> Result<Scene, SceneError> {
        let text = read_text(path)?;
        let hex = Self::parse(&text, path)?;
        let table: toml::Table = toml::from_str(&text).unwrap_or_default();
        let absent: Vec<&str> = ["program", "tool", "stock"]
            .into_iter()
            .filter(|k| !table.contains_key(*k))
            .collect();
        if !absent.is_empty() {
            return Err(SceneError::Missing {
                path: path.to_path_buf(),
                command: "cutting on a hexapod".into(),
                what: format!(
                    "program, [tool] and [stock] (this scene has no {})",
                    absent.join(", ")
                ),
            });
        }
        Scene::parse_hexapod_cut(
            &text,
            path,
            memory,
            hex.twin(),
            hex.machine_name.clone(),
            hex.injected.clone(),
        )
    }
}
