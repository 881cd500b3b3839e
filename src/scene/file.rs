//! The scene file's format: the serde structs of every section, for both machine kinds. A
//! scene file is one [`SceneFile`] whose `[machine]` table is read by kind: a serial chain's
//! ([`SerialMachineFile`]) or a hexapod's ([`HexapodMachineFile`]). Values keep their place
//! in the text ([`Spanned`]) so that a check made later names the line and column.

use crate::math::Real;
use serde::Deserialize;
use std::collections::BTreeMap;
use toml::Spanned;

/// A scene file; `M` is the `[machine]` table of its kind. `program`, `[tool]` and
/// `[stock]` are optional here: a serial scene needs them (checked by the reader as
/// toml would), a hexapod scene only to cut.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SceneFile<M> {
    #[serde(default)]
    pub name: Option<Spanned<String>>,
    #[serde(default)]
    pub program: Option<Spanned<String>>,
    pub machine: M,
    /// Hexapod sections (refused in a serial scene).
    #[serde(default)]
    pub workspace: Option<Spanned<WorkspaceFile>>,
    #[serde(default)]
    pub drives: Option<Spanned<DrivesFile>>,
    #[serde(default)]
    pub homing: Option<Spanned<HomingFile>>,
    #[serde(default)]
    pub table: Option<Spanned<HexapodTableFile>>,
    #[serde(default)]
    pub table_axes: Option<Spanned<TableAxesFile>>,
    #[serde(default)]
    pub deviations: BTreeMap<String, Spanned<Real>>,
    /// A hexapod's controller: its parameters as deviations from nominal (refused in a
    /// serial scene).
    #[serde(default)]
    pub controller: BTreeMap<String, Spanned<Real>>,
    #[serde(default)]
    pub error_motions: BTreeMap<String, Spanned<MotionFile>>,
    #[serde(default)]
    pub reversal: BTreeMap<String, Spanned<Real>>,
    #[serde(default)]
    pub tool: Option<ToolFile>,
    #[serde(default)]
    pub stock: Option<StockFile>,
    #[serde(default)]
    pub sweep: SweepFile,
    #[serde(default)]
    pub scanner: Option<ScannerFile>,
    #[serde(default)]
    pub identify: Option<IdentifyFile>,
    #[serde(default)]
    pub study: Option<StudyFile>,
    #[serde(default)]
    pub nc: Option<NcFile>,
    #[serde(default)]
    pub fixtures: Vec<MeshFile>,
    #[serde(default)]
    pub design: Option<MeshFile>,
    #[serde(default)]
    pub report: Option<ReportFile>,
}

/// A controller file (`--controller FILE`, what `identify --readings … --corrected` writes):
/// the `[controller]` section alone.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ControllerFile {
    pub controller: BTreeMap<String, Spanned<Real>>,
}

/// The sections a serial scene cannot do without, in the order toml reports the first one
/// missing (read only when one is).
#[derive(Deserialize)]
#[expect(
    dead_code,
    reason = "read only for toml's message on the first one missing"
)]
pub(super) struct Required {
    pub program: serde::de::IgnoredAny,
    pub machine: serde::de::IgnoredAny,
    pub tool: serde::de::IgnoredAny,
    pub stock: serde::de::IgnoredAny,
}

/// `[report]`: how the pages and pictures show the part.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ReportFile {
    /// `"faces"`, `"iso"`, `"+x"` … `"-z"`, or `[dx, dy, dz]`.
    #[serde(default)]
    pub view: Option<Spanned<toml::Value>>,
}

/// One `[error_motions]` entry: a sum of a table, a polynomial and periodic terms.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MotionFile {
    #[serde(default)]
    pub table: Option<Spanned<TableFile>>,
    #[serde(default)]
    pub polynomial: Option<Vec<Spanned<Real>>>,
    #[serde(default)]
    pub periodic: Vec<Spanned<PeriodicFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TableFile {
    pub q: Vec<Spanned<Real>>,
    pub values: Vec<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct PeriodicFile {
    pub amplitude: Spanned<Real>,
    pub period: Spanned<Real>,
    #[serde(default)]
    pub phase_deg: Option<Spanned<Real>>,
}

/// `[[fixtures]]` and `[design]`: a closed OBJ or STL mesh, relative to the scene file, and
/// where it sits in the workpiece frame (W).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MeshFile {
    /// Name in reports (fixtures only; default: the file name).
    #[serde(default)]
    pub name: Option<Spanned<String>>,
    pub file: Spanned<String>,
    /// Translation (mm), applied after the rotation.
    #[serde(default)]
    pub position: Option<Spanned<[Real; 3]>>,
    /// Rotation about x, y, z (degrees): a mesh point p goes to position + Rx·Ry·Rz·p.
    #[serde(default)]
    pub rotation_deg: Option<Spanned<[Real; 3]>>,
}

/// `[nc]`: how the program is interpreted (all optional).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct NcFile {
    /// LinuxCNC tool table, relative to the scene file.
    pub tool_table: Option<Spanned<String>>,
    /// LinuxCNC parameter (var) file, relative to the scene file.
    pub var_file: Option<Spanned<String>>,
    /// INI file with an [RS274NGC] section, relative to the scene file.
    pub ini: Option<Spanned<String>>,
    /// Unit of tool-table and var-file lengths: "mm" (default) or "inch".
    pub external_units: Option<Spanned<String>>,
    /// Lines in a row without motion before the program is stopped as an endless loop.
    pub max_idle_blocks: Option<Spanned<u64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct StudyFile {
    #[serde(default)]
    pub trials: Option<Spanned<usize>>,
    #[serde(default)]
    pub correlation_mm: Option<Spanned<Real>>,
    #[serde(default)]
    pub translation_sigma_mm: Option<Spanned<Real>>,
    #[serde(default)]
    pub rotation_sigma_rad: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, rename = "MachineFile")]
pub(super) struct SerialMachineFile {
    /// "serial" (the default).
    #[serde(default)]
    pub kind: Option<Spanned<String>>,
    #[serde(default)]
    pub name: String,
    pub axes: Spanned<Vec<AxisFile>>,
    #[serde(default = "default_spindle")]
    pub spindle: String,
    #[serde(default)]
    pub home: BTreeMap<String, Spanned<Real>>,
    /// "joint" (the default) or "tcp": how the controller reads the program's axis words.
    #[serde(default)]
    pub controller: Option<Spanned<String>>,
}

/// `[machine] controller`'s value and where it stands, if the text has one as a string (read
/// leniently, as [`machine_kind`]).
pub(super) fn machine_controller_at(text: &str) -> Option<Spanned<String>> {
    #[derive(Deserialize)]
    struct Peek {
        machine: Option<ControllerPeek>,
    }
    #[derive(Deserialize)]
    struct ControllerPeek {
        controller: Option<Spanned<String>>,
    }
    toml::from_str::<Peek>(text).ok()?.machine?.controller
}

/// `[machine] kind` of a scene text, if it has one (read leniently: the full parse reports
/// any other problem).
pub fn machine_kind(text: &str) -> Option<String> {
    #[derive(Deserialize)]
    struct Peek {
        machine: Option<KindPeek>,
    }
    #[derive(Deserialize)]
    struct KindPeek {
        kind: Option<String>,
    }
    toml::from_str::<Peek>(text).ok()?.machine?.kind
}

/// `[machine] kind`'s value and where it stands, if the text has one (read leniently, as
/// [`machine_kind`]).
pub(super) fn machine_kind_at(text: &str) -> Option<Spanned<String>> {
    #[derive(Deserialize)]
    struct Peek {
        machine: Option<KindPeek>,
    }
    #[derive(Deserialize)]
    struct KindPeek {
        kind: Option<Spanned<String>>,
    }
    toml::from_str::<Peek>(text).ok()?.machine?.kind
}

fn default_spindle() -> String {
    "S".into()
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AxisFile {
    pub name: Spanned<String>,
    pub kind: Spanned<String>,
    pub direction: Spanned<[Real; 3]>,
    #[serde(default)]
    pub origin: Option<Spanned<[Real; 3]>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ToolFile {
    pub kind: Spanned<String>,
    /// Flat, ball, bull-nose: the diameter; tapered flat: the tip's; tapered ball: the ball's.
    pub diameter_mm: Spanned<Real>,
    pub length_mm: Spanned<Real>,
    /// Bull-nose only.
    pub corner_radius_mm: Option<Spanned<Real>>,
    /// Tapered flat and tapered ball only (degrees, in (0, 90)).
    pub taper_half_angle_deg: Option<Spanned<Real>>,
    /// Shank above the flutes and holder above the shank (all four or none).
    pub shank_diameter_mm: Option<Spanned<Real>>,
    pub shank_length_mm: Option<Spanned<Real>>,
    pub holder_diameter_mm: Option<Spanned<Real>>,
    pub holder_length_mm: Option<Spanned<Real>>,
    /// The holder as stacked frusta, lowest first (instead of the holder cylinder).
    pub holder_sections: Option<Spanned<Vec<SectionFile>>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SectionFile {
    pub length_mm: Spanned<Real>,
    pub radius_bottom_mm: Spanned<Real>,
    pub radius_top_mm: Spanned<Real>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct StockFile {
    /// "box" (default), "cylinder" or "mesh".
    pub kind: Option<Spanned<String>>,
    /// Box.
    pub min: Option<Spanned<[Real; 3]>>,
    pub max: Option<Spanned<[Real; 3]>>,
    /// Cylinder: the centres of its end faces, or `base`, `axis` and `length_mm`.
    pub ends: Option<Spanned<[[Real; 3]; 2]>>,
    pub base: Option<Spanned<[Real; 3]>>,
    pub axis: Option<Spanned<[Real; 3]>>,
    pub length_mm: Option<Spanned<Real>>,
    pub radius_mm: Option<Spanned<Real>>,
    /// Mesh: file and placement.
    pub file: Option<Spanned<String>>,
    pub position: Option<Spanned<[Real; 3]>>,
    pub rotation_deg: Option<Spanned<[Real; 3]>>,
    pub pitch_mm: Spanned<Real>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct SweepFile {
    pub rotary_step_bound_mm: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ScannerFile {
    pub position: Spanned<[Real; 3]>,
    pub target: Spanned<[Real; 3]>,
    pub up: Spanned<[Real; 3]>,
    #[serde(default)]
    pub baseline_mm: Option<Spanned<Real>>,
    #[serde(default)]
    pub fov_mm: Option<Spanned<[Real; 2]>>,
    #[serde(default)]
    pub pitch_mm: Option<Spanned<Real>>,
    #[serde(default)]
    pub noise_sigma_mm: Option<Spanned<Real>>,
    #[serde(default)]
    pub noise_correlation_mm: Option<Spanned<Real>>,
    #[serde(default)]
    pub working_range_mm: Option<Spanned<[Real; 2]>>,
    #[serde(default)]
    pub grazing_limit_deg: Option<Spanned<Real>>,
    #[serde(default)]
    pub misregistration: Option<MisregistrationFile>,
    #[serde(default)]
    pub turntable: Option<TurntableFile>,
    #[serde(default)]
    pub seed: Option<u64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MisregistrationFile {
    #[serde(default)]
    pub translation_sigma_mm: Option<Spanned<Real>>,
    #[serde(default)]
    pub rotation_sigma_rad: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TurntableFile {
    pub axis_point: Spanned<[Real; 3]>,
    pub axis: Spanned<[Real; 3]>,
    pub angles_deg: Spanned<Vec<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct IdentifyFile {
    pub faces: Spanned<Vec<FaceFile>>,
    #[serde(default)]
    pub margin_mm: Option<Spanned<Real>>,
    #[serde(default)]
    pub band_mm: Option<Spanned<Real>>,
    #[serde(default)]
    pub known: BTreeMap<String, Spanned<Real>>,
    #[serde(default)]
    pub parameters: Option<Spanned<Vec<Spanned<String>>>>,
    #[serde(default)]
    pub registration: Option<Spanned<String>>,
    #[serde(default)]
    pub monte_carlo: Option<MonteCarloFile>,
    #[serde(default)]
    pub loop_tolerance_mm: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MonteCarloFile {
    pub trials: Spanned<usize>,
    #[serde(default)]
    pub seed: Option<u64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FaceFile {
    pub name: String,
    pub line: Spanned<usize>,
    #[serde(default, rename = "box")]
    pub bbox: Option<BoxFile>,
    #[serde(default)]
    pub seed: Option<Spanned<[Real; 3]>>,
    #[serde(default)]
    pub kind: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct BoxFile {
    pub min: Spanned<[Real; 3]>,
    pub max: Spanned<[Real; 3]>,
}

/// `[table_axes]`: serial axes carrying the part.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TableAxesFile {
    pub axes: Spanned<Vec<TableAxisFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TableAxisFile {
    pub name: Spanned<String>,
    pub direction: Spanned<[Real; 3]>,
    #[serde(default)]
    pub origin: Option<Spanned<[Real; 3]>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, rename = "MachineFile")]
pub(super) struct HexapodMachineFile {
    pub kind: Spanned<String>,
    #[serde(default)]
    pub name: String,
    pub base_joints: Spanned<Vec<Spanned<[Real; 3]>>>,
    pub platform_joints: Spanned<Vec<Spanned<[Real; 3]>>>,
    #[serde(default)]
    pub tool_offset: Option<Spanned<[Real; 3]>>,
    pub home: Spanned<[Real; 6]>,
    #[serde(default)]
    pub strut_reference_mm: Option<Spanned<[Real; 6]>>,
    #[serde(default)]
    pub stroke_mm: Option<Spanned<[Real; 2]>>,
    #[serde(default)]
    pub base_joint_axis: Option<Spanned<[Real; 3]>>,
    #[serde(default)]
    pub base_joint_limit_deg: Option<Spanned<Real>>,
    #[serde(default)]
    pub platform_joint_axis: Option<Spanned<[Real; 3]>>,
    #[serde(default)]
    pub platform_joint_limit_deg: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct WorkspaceFile {
    pub x_mm: Spanned<[Real; 2]>,
    pub y_mm: Spanned<[Real; 2]>,
    pub z_mm: Spanned<[Real; 2]>,
    #[serde(default)]
    pub tilt_deg: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct DrivesFile {
    pub lead_mm: Spanned<Real>,
    pub counts_per_rev: Spanned<u64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct HomingFile {
    pub switch_to_index_mm: Spanned<[Real; 6]>,
    #[serde(default)]
    pub trip_sigma_mm: Option<Spanned<Real>>,
}

/// `[table]`: the machine table's top face.
#[derive(Deserialize)]
#[serde(deny_unknown_fields, rename = "TableFile")]
pub(super) struct HexapodTableFile {
    pub top_z_mm: Spanned<Real>,
    pub x_mm: Spanned<[Real; 2]>,
    pub y_mm: Spanned<[Real; 2]>,
}
