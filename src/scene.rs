//! Scene files (TOML): the machine chain and its deviations, tool, stock, program, scanner
//! and the faces to identify. Also reads the NC program the scene names, and the closed
//! OBJ/STL meshes of a mesh stock, fixtures and the design model (paths relative to the scene).
//!
//! Every value is checked when the scene loads; an error names the file, line and column
//! of the offending value. TOML accepts `nan` and `inf`: they are rejected here.
//!
//! **Invariant:** this module and [`crate::output`] are the only ones that touch files.

use crate::calibration::calibrate::Registration;
use crate::calibration::identify::{FaceKind, FaceOptions, FaceRegion, FaceSpec};
use crate::cutting::collide::{Fixture, Holder, HolderSection};
use crate::cutting::shape::{ClosedMesh, Cylinder, Solid, read_obj, read_stl};
use crate::cutting::sweep::{Kinematics, SweepOptions};
use crate::cutting::tool::{Tool, ToolKind};
use crate::machine::chain::{Axis, AxisKind, Chain};
use crate::machine::error_motion::{self, AxisErrorMotions};
use crate::machine::hexapod::HexapodTwin;
use crate::math::{Aabb, Point3, Real, UnitVector3, Vector3, tol};
use crate::metrology::fit::RobustRule;
use crate::metrology::scan::{Misregistration, ScanError, ScannerConfig, StudyOptions, Turntable};
use crate::nc::{
    AxisLetter, AxisValues, InterpOptions, LengthUnit, NcError, Program, interpret_program,
    options_from_texts,
};
use crate::report::deviation_map::DesignModel;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// A problem with a scene or the files it names.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// A file could not be read.
    #[error("{path}: cannot read: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A value is malformed or out of range.
    #[error("{path}:{line}:{column}: {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// The NC program has errors.
    #[error("{0}")]
    Program(NcError),
    /// A command needs a section the scene does not have (or has in another form).
    #[error("{path}: {command} needs {what}")]
    Missing {
        /// The scene file.
        path: PathBuf,
        /// The command (`run`, `scan`, …).
        command: String,
        /// The sections it needs, and what they hold.
        what: String,
    },
    /// The scene describes a hexapod (`[machine] kind = "hexapod"`), not a serial chain:
    /// load it with [`crate::hexapod_scene::HexapodScene`].
    #[error("{}: a hexapod scene ([machine] kind = \"hexapod\"): only the `twinmill hexapod` commands drive it", path.display())]
    Hexapod {
        /// The scene file.
        path: PathBuf,
    },
}

/// A part of a scene that a command needs beyond `[machine]`, `[tool]`, `[stock]` and the
/// program (which every command needs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Need {
    /// `[scanner]`: the virtual scanner that measures the cut part.
    Scanner,
    /// `[identify] faces`: the two faces of the 0°/180° experiment.
    StepFaces,
    /// `[identify] parameters` and the faces to identify them from.
    Parameters,
}

/// A scene file; `M` is the `[machine]` table: a serial chain's ([`MachineFile`]) or, for
/// a hexapod scene that cuts, any table (read by [`crate::hexapod_scene`]).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile<M> {
    #[serde(default)]
    name: Option<Spanned<String>>,
    program: Spanned<String>,
    machine: M,
    /// Hexapod sections (read by [`crate::hexapod_scene`]; refused in a serial scene).
    #[serde(default)]
    workspace: Option<Spanned<toml::Value>>,
    #[serde(default)]
    drives: Option<Spanned<toml::Value>>,
    #[serde(default)]
    homing: Option<Spanned<toml::Value>>,
    #[serde(default)]
    table: Option<Spanned<toml::Value>>,
    #[serde(default)]
    table_axes: Option<Spanned<toml::Value>>,
    #[serde(default)]
    deviations: BTreeMap<String, Spanned<Real>>,
    #[serde(default)]
    error_motions: BTreeMap<String, Spanned<MotionFile>>,
    #[serde(default)]
    reversal: BTreeMap<String, Spanned<Real>>,
    tool: ToolFile,
    stock: StockFile,
    #[serde(default)]
    sweep: SweepFile,
    #[serde(default)]
    scanner: Option<ScannerFile>,
    #[serde(default)]
    identify: Option<IdentifyFile>,
    #[serde(default)]
    study: Option<StudyFile>,
    #[serde(default)]
    nc: Option<NcFile>,
    #[serde(default)]
    fixtures: Vec<MeshFile>,
    #[serde(default)]
    design: Option<MeshFile>,
    #[serde(default)]
    report: Option<ReportFile>,
}

/// `[report]`: how the pages and pictures show the part.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ReportFile {
    /// `"faces"`, `"iso"`, `"+x"` … `"-z"`, or `[dx, dy, dz]`.
    #[serde(default)]
    view: Option<Spanned<toml::Value>>,
}

/// One `[error_motions]` entry: a sum of a table, a polynomial and periodic terms.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MotionFile {
    #[serde(default)]
    table: Option<Spanned<TableFile>>,
    #[serde(default)]
    polynomial: Option<Vec<Spanned<Real>>>,
    #[serde(default)]
    periodic: Vec<Spanned<PeriodicFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TableFile {
    q: Vec<Spanned<Real>>,
    values: Vec<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PeriodicFile {
    amplitude: Spanned<Real>,
    period: Spanned<Real>,
    #[serde(default)]
    phase_deg: Option<Spanned<Real>>,
}

/// `[[fixtures]]` and `[design]`: a closed OBJ or STL mesh, relative to the scene file, and
/// where it sits in the workpiece frame (W).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MeshFile {
    /// Name in reports (fixtures only; default: the file name).
    #[serde(default)]
    name: Option<Spanned<String>>,
    file: Spanned<String>,
    /// Translation (mm), applied after the rotation.
    #[serde(default)]
    position: Option<Spanned<[Real; 3]>>,
    /// Rotation about x, y, z (degrees): a mesh point p goes to position + Rx·Ry·Rz·p.
    #[serde(default)]
    rotation_deg: Option<Spanned<[Real; 3]>>,
}

/// `[nc]`: how the program is interpreted (all optional).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct NcFile {
    /// LinuxCNC tool table, relative to the scene file.
    tool_table: Option<Spanned<String>>,
    /// LinuxCNC parameter (var) file, relative to the scene file.
    var_file: Option<Spanned<String>>,
    /// INI file with an [RS274NGC] section, relative to the scene file.
    ini: Option<Spanned<String>>,
    /// Unit of tool-table and var-file lengths: "mm" (default) or "inch".
    external_units: Option<Spanned<String>>,
    /// Lines in a row without motion before the program is stopped as an endless loop.
    max_idle_blocks: Option<Spanned<u64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StudyFile {
    #[serde(default)]
    trials: Option<Spanned<usize>>,
    #[serde(default)]
    correlation_mm: Option<Spanned<Real>>,
    #[serde(default)]
    translation_sigma_mm: Option<Spanned<Real>>,
    #[serde(default)]
    rotation_sigma_rad: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MachineFile {
    /// "serial" (the default); "hexapod" scenes are loaded by `hexapod_scene`.
    #[serde(default)]
    kind: Option<Spanned<String>>,
    #[serde(default)]
    name: String,
    axes: Spanned<Vec<AxisFile>>,
    #[serde(default = "default_spindle")]
    spindle: String,
    #[serde(default)]
    home: BTreeMap<String, Spanned<Real>>,
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

fn default_spindle() -> String {
    "S".into()
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AxisFile {
    name: Spanned<String>,
    kind: Spanned<String>,
    direction: Spanned<[Real; 3]>,
    #[serde(default)]
    origin: Option<Spanned<[Real; 3]>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ToolFile {
    kind: Spanned<String>,
    /// Flat, ball, bull-nose: the diameter; tapered flat: the tip's; tapered ball: the ball's.
    diameter_mm: Spanned<Real>,
    length_mm: Spanned<Real>,
    /// Bull-nose only.
    corner_radius_mm: Option<Spanned<Real>>,
    /// Tapered flat and tapered ball only (degrees, in (0, 90)).
    taper_half_angle_deg: Option<Spanned<Real>>,
    /// Shank above the flutes and holder above the shank (all four or none).
    shank_diameter_mm: Option<Spanned<Real>>,
    shank_length_mm: Option<Spanned<Real>>,
    holder_diameter_mm: Option<Spanned<Real>>,
    holder_length_mm: Option<Spanned<Real>>,
    /// The holder as stacked frusta, lowest first (instead of the holder cylinder).
    holder_sections: Option<Spanned<Vec<SectionFile>>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SectionFile {
    length_mm: Spanned<Real>,
    radius_bottom_mm: Spanned<Real>,
    radius_top_mm: Spanned<Real>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StockFile {
    /// "box" (default), "cylinder" or "mesh".
    kind: Option<Spanned<String>>,
    /// Box.
    min: Option<Spanned<[Real; 3]>>,
    max: Option<Spanned<[Real; 3]>>,
    /// Cylinder: the centres of its end faces, or `base`, `axis` and `length_mm`.
    ends: Option<Spanned<[[Real; 3]; 2]>>,
    base: Option<Spanned<[Real; 3]>>,
    axis: Option<Spanned<[Real; 3]>>,
    length_mm: Option<Spanned<Real>>,
    radius_mm: Option<Spanned<Real>>,
    /// Mesh: file and placement.
    file: Option<Spanned<String>>,
    position: Option<Spanned<[Real; 3]>>,
    rotation_deg: Option<Spanned<[Real; 3]>>,
    pitch_mm: Spanned<Real>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct SweepFile {
    rotary_step_bound_mm: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ScannerFile {
    position: Spanned<[Real; 3]>,
    target: Spanned<[Real; 3]>,
    up: Spanned<[Real; 3]>,
    #[serde(default)]
    baseline_mm: Option<Spanned<Real>>,
    #[serde(default)]
    fov_mm: Option<Spanned<[Real; 2]>>,
    #[serde(default)]
    pitch_mm: Option<Spanned<Real>>,
    #[serde(default)]
    noise_sigma_mm: Option<Spanned<Real>>,
    #[serde(default)]
    noise_correlation_mm: Option<Spanned<Real>>,
    #[serde(default)]
    working_range_mm: Option<Spanned<[Real; 2]>>,
    #[serde(default)]
    grazing_limit_deg: Option<Spanned<Real>>,
    #[serde(default)]
    misregistration: Option<MisregistrationFile>,
    #[serde(default)]
    turntable: Option<TurntableFile>,
    #[serde(default)]
    seed: Option<u64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MisregistrationFile {
    #[serde(default)]
    translation_sigma_mm: Option<Spanned<Real>>,
    #[serde(default)]
    rotation_sigma_rad: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TurntableFile {
    axis_point: Spanned<[Real; 3]>,
    axis: Spanned<[Real; 3]>,
    angles_deg: Spanned<Vec<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct IdentifyFile {
    faces: Spanned<Vec<FaceFile>>,
    #[serde(default)]
    margin_mm: Option<Spanned<Real>>,
    #[serde(default)]
    band_mm: Option<Spanned<Real>>,
    #[serde(default)]
    known: BTreeMap<String, Spanned<Real>>,
    #[serde(default)]
    parameters: Option<Spanned<Vec<Spanned<String>>>>,
    #[serde(default)]
    registration: Option<Spanned<String>>,
    #[serde(default)]
    monte_carlo: Option<MonteCarloFile>,
    #[serde(default)]
    loop_tolerance_mm: Option<Spanned<Real>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MonteCarloFile {
    trials: Spanned<usize>,
    #[serde(default)]
    seed: Option<u64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FaceFile {
    name: String,
    line: Spanned<usize>,
    #[serde(default, rename = "box")]
    bbox: Option<BoxFile>,
    #[serde(default)]
    seed: Option<Spanned<[Real; 3]>>,
    #[serde(default)]
    kind: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BoxFile {
    min: Spanned<[Real; 3]>,
    max: Spanned<[Real; 3]>,
}

/// Default tolerance of the model-correction loop: 0.5 µm, the accuracy the twin's faces are
/// tested to.
pub const DEFAULT_LOOP_TOLERANCE_MM: Real = 5e-4;

/// The largest coordinate a machine may have (mm): 100 m, beyond any machine tool's travel.
/// A `home` position, an axis origin or a joint beyond it is refused.
pub const MAX_COORDINATE_MM: Real = 1e5;

/// The largest rotary-axis position a scene may give (degrees): a hundred turns.
pub const MAX_ANGLE_DEG: Real = 36_000.0;

/// A direction vector's length must lie in `[1 / DIRECTION_SCALE, DIRECTION_SCALE]`: it is
/// normalised on reading, and a component a million times another's is a typing error, not
/// a direction.
pub const DIRECTION_SCALE: Real = 1e3;

/// The smallest angle between two linear axes (and between a linear axis and the plane of
/// two others), degrees: axes closer to parallel do not span the space a machine moves in.
pub const MIN_AXIS_ANGLE_DEG: Real = 1.0;

/// A direction given as `[dx, dy, dz]`, normalised; the key names it in messages.
pub fn check_direction(v: [Real; 3], key: &str) -> Result<UnitVector3, String> {
    let d = Vector3::new(v[0], v[1], v[2]);
    // the length without overflow: [1, 1e308, 0] is 1e308 long, not infinite
    let big = d.amax();
    let n = if big > 0.0 && big.is_finite() {
        big * (d / big).norm()
    } else {
        big
    };
    if !(n.is_finite() && (1.0 / DIRECTION_SCALE..=DIRECTION_SCALE).contains(&n)) {
        return Err(format!(
            "{key}: got {v:?} (length {n:e}), expected a direction of length {} to {}",
            1.0 / DIRECTION_SCALE,
            DIRECTION_SCALE
        ));
    }
    Ok(UnitVector3::new_normalize(d))
}

/// A machine coordinate (mm), at most [`MAX_COORDINATE_MM`] from the origin.
pub fn check_coordinate(v: Real, key: &str) -> Result<Real, String> {
    if v.is_finite() && v.abs() <= MAX_COORDINATE_MM {
        Ok(v)
    } else {
        Err(format!(
            "{key}: got {v:e} mm, expected within ±{MAX_COORDINATE_MM} mm (100 m, beyond \
             any machine's travel)"
        ))
    }
}

/// Checks that the linear axes among `axes` span space: no two within
/// [`MIN_AXIS_ANGLE_DEG`] of parallel, three not within it of one plane.
fn linear_axes_span(axes: &[Axis]) -> Result<(), String> {
    let lin: Vec<&Axis> = axes.iter().filter(|a| a.kind == AxisKind::Linear).collect();
    let min_sin = MIN_AXIS_ANGLE_DEG.to_radians().sin();
    for (i, a) in lin.iter().enumerate() {
        for b in &lin[..i] {
            let sin = a.direction.cross(&b.direction).norm();
            if sin < min_sin {
                return Err(format!(
                    "axes {} and {} are {:.3}° from parallel, expected linear axes at least \
                     {MIN_AXIS_ANGLE_DEG}° apart",
                    b.letter.as_char(),
                    a.letter.as_char(),
                    sin.min(1.0).asin().to_degrees()
                ));
            }
        }
    }
    if let [a, b, c] = lin[..] {
        let det = a.direction.dot(&b.direction.cross(&c.direction)).abs();
        if det < min_sin {
            return Err(format!(
                "axes {}, {} and {} lie {:.3}° from one plane, expected linear axes that \
                 span space (at least {MIN_AXIS_ANGLE_DEG}° from a common plane)",
                a.letter.as_char(),
                b.letter.as_char(),
                c.letter.as_char(),
                det.min(1.0).asin().to_degrees()
            ));
        }
    }
    Ok(())
}

/// Default `[identify] margin_mm`: points kept this far inside a face's edges (mm).
const DEFAULT_MARGIN_MM: Real = 1.0;

/// Default `[identify] band_mm`: points kept within this of the expected plane (mm).
const DEFAULT_BAND_MM: Real = 2.0;

/// Files that set up the interpreter for a scene's program (`[nc]`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NcFiles {
    /// LinuxCNC tool table.
    pub tool_table: Option<PathBuf>,
    /// LinuxCNC parameter (var) file.
    pub var_file: Option<PathBuf>,
    /// INI file ([RS274NGC] SUBROUTINE_PATH, DISABLE_FANUC_STYLE_SUB).
    pub ini: Option<PathBuf>,
    /// Unit of tool-table and var-file lengths.
    pub external_unit: LengthUnit,
    /// Lines in a row without motion before the program is stopped as an endless loop
    /// (default [`crate::nc::DEFAULT_MAX_IDLE_BLOCKS`]).
    pub max_idle_blocks: Option<u64>,
}

/// A file the scene names and reads after loading (the program, the `[nc]` files): its key,
/// its resolved path, and where its value stands in the scene file, so that a file that
/// cannot be read is reported at that line and column.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FileKey {
    /// The scene key (`program`, `nc.tool_table`, …).
    pub key: String,
    /// The file, resolved against the scene's folder.
    pub path: PathBuf,
    /// 1-based line of the value in the scene file.
    pub line: usize,
    /// 1-based column of the value.
    pub column: usize,
}

/// The stock's initial solid (workpiece frame, mm).
#[derive(Clone, Debug)]
pub enum StockShape {
    /// The box [`Scene::stock_box`].
    Box,
    /// A circular cylinder.
    Cylinder(Cylinder),
    /// A closed mesh read from a file.
    Mesh {
        /// The file.
        path: PathBuf,
        /// The placed mesh.
        mesh: Box<ClosedMesh>,
    },
}

/// A loaded, validated scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The scene file.
    pub path: PathBuf,
    /// Scene name (names the output folder).
    pub name: String,
    /// Machine description.
    pub machine_name: String,
    /// The NC program file.
    pub program_path: PathBuf,
    /// `[nc]` tool table, var file and INI (resolved paths), and their length unit.
    pub nc_files: NcFiles,
    /// Where the scene names the program and the `[nc]` files (read by
    /// [`Scene::load_program`]).
    pub file_keys: Vec<FileKey>,
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
    /// The cutter.
    pub tool: Tool,
    /// Stock box (workpiece frame, mm): the box stock, or the box around a cylinder or mesh
    /// stock (the tri-dexel's grids span it).
    pub stock_box: Aabb,
    /// The stock's initial solid (`[stock] kind`).
    pub stock_shape: StockShape,
    /// Shank and holder above the flutes (`[tool] shank_*`, `holder_*`), for collision
    /// checks.
    pub holder: Option<Holder>,
    /// Fixtures (`[[fixtures]]`), never cut; the sweep reports what touches them.
    pub fixtures: Vec<Fixture>,
    /// The design model (`[design]`) the cut part is compared with, and its file.
    pub design: Option<(PathBuf, DesignModel)>,
    /// Tri-dexel pitch (mm).
    pub pitch_mm: Real,
    /// The memory the tri-dexel may use ([`MemoryBudget`]: half the installed memory, or
    /// `--memory`).
    pub memory: MemoryBudget,
    /// Sweep options.
    pub sweep: SweepOptions,
    /// The virtual scanner (`[scanner]`), for the commands that scan.
    pub scanner: Option<ScannerConfig>,
    /// The faces to measure (`[identify] faces`): the two of the 0/180 experiment (`run`), or
    /// any number for general identification (`identify`, when `parameters` is given); empty
    /// when the scene has no `[identify]`.
    pub faces: Vec<FaceSpec>,
    /// Deviations to identify (`[identify] parameters`), by name; empty: the 0/180
    /// experiment's two.
    pub parameters: Vec<String>,
    /// How the scan's frame relates to W (`[identify] registration`: "estimate", the
    /// default, or "workpiece").
    pub registration: Registration,
    /// Monte-Carlo trials over scanner noise (`[identify] monte_carlo.trials`, 0: none).
    pub monte_carlo_trials: usize,
    /// Seed of the first Monte-Carlo trial (then +1 per trial).
    pub monte_carlo_seed: u64,
    /// The model-correction loop stops when every predicted face is within this of the
    /// measured one at its centroid (mm); default 0.5 µm.
    pub loop_tolerance_mm: Real,
    /// Face extraction options.
    pub face_options: FaceOptions,
    /// The scanner-effects study (`twinmill scan --study`).
    pub study: StudyOptions,
    /// The direction from the part towards the eye of `part.png` and of the pages' 3-D
    /// view (`[report] view`); `None`: the direction the machined faces face
    /// ([`crate::report::display::view_direction`]).
    pub view: Option<UnitVector3>,
    /// A hexapod scene that cuts: the machine the sweep drives pose by pose. `chain` and
    /// `model` are then the controller's Cartesian kinematics ([`HexapodTwin::command_chain`]),
    /// and `injected` the hexapod's deviations by parameter name.
    pub hexapod: Option<HexapodTwin>,
    /// Keep an identification whose residuals the stated noise cannot explain instead of
    /// refusing it ([`crate::calibration::goodness`]); its report then says so on its
    /// first line. Never read from the scene file: the command line's `--accept-misfit`.
    pub accept_misfit: bool,
}

/// `[report] view`: `"faces"` (the default: `None`), `"iso"` (from +x, −y, +z), an axis
/// direction `"+x"` … `"-z"`, or a vector `[dx, dy, dz]` — always from the part towards
/// the eye.
fn report_view(ctx: &Ctx<'_>, v: &Spanned<toml::Value>) -> Result<Option<UnitVector3>, SceneError> {
    let bad = |got: String| {
        ctx.err(
            v.span(),
            format!(
                "report view must be \"faces\", \"iso\", \"+x\", \"-x\", \"+y\", \"-y\", \"+z\", \"-z\" or a direction [dx, dy, dz] (from the part towards the eye), got {got}"
            ),
        )
    };
    let d = match v.get_ref() {
        toml::Value::String(s) => match s.as_str() {
            "faces" => return Ok(None),
            "iso" => Vector3::new(1.0, -1.0, 1.0),
            "+x" => Vector3::x(),
            "-x" => -Vector3::x(),
            "+y" => Vector3::y(),
            "-y" => -Vector3::y(),
            "+z" => Vector3::z(),
            "-z" => -Vector3::z(),
            other => return Err(bad(format!("\"{other}\""))),
        },
        toml::Value::Array(a) => {
            let c: Vec<Real> = a
                .iter()
                .filter_map(|x| match x {
                    toml::Value::Float(f) => Some(*f),
                    toml::Value::Integer(i) => Some(*i as Real),
                    _ => None,
                })
                .collect();
            match c[..] {
                [x, y, z] if c.len() == a.len() && c.iter().all(|x| x.is_finite()) => {
                    Vector3::new(x, y, z)
                }
                _ => return Err(bad(format!("{}", v.get_ref()))),
            }
        }
        other => return Err(bad(format!("{other}"))),
    };
    if d.norm() < 1e-9 {
        return Err(ctx.err(v.span(), "report view [0, 0, 0] has no direction"));
    }
    Ok(Some(UnitVector3::new_normalize(d)))
}

/// The machine part of a scene, built from `[machine]` and the deviations.
struct MachineParts {
    machine_name: String,
    chain: Chain,
    injected: BTreeMap<String, Real>,
    model: Chain,
    known: BTreeMap<String, Real>,
    home: AxisValues,
    hexapod: Option<HexapodTwin>,
}

#[derive(Clone, Copy)]
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

    fn finite(&self, v: &Spanned<Real>, what: &str) -> Result<Real, SceneError> {
        let x = *v.get_ref();
        if x.is_finite() {
            Ok(x)
        } else {
            Err(self.err(v.span(), format!("{what} must be a finite number, got {x}")))
        }
    }

    /// An optional finite number, or `default`.
    fn opt(
        &self,
        v: &Option<Spanned<Real>>,
        what: &str,
        default: Real,
    ) -> Result<Real, SceneError> {
        v.as_ref().map_or(Ok(default), |v| self.finite(v, what))
    }

    fn positive(&self, v: &Spanned<Real>, what: &str) -> Result<Real, SceneError> {
        let x = self.finite(v, what)?;
        if x > 0.0 {
            Ok(x)
        } else {
            Err(self.err(v.span(), format!("{what} must be positive, got {x}")))
        }
    }

    /// Reads the closed OBJ or STL mesh `file` (relative to `dir`) named by scene key `key`
    /// and places it: p ↦ position + Rx·Ry·Rz·p.
    fn mesh(
        &self,
        dir: &Path,
        file: &Spanned<String>,
        position: &Option<Spanned<[Real; 3]>>,
        rotation_deg: &Option<Spanned<[Real; 3]>>,
        key: &str,
    ) -> Result<(PathBuf, ClosedMesh), SceneError> {
        let p = dir.join(file.get_ref());
        let ext = p
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        let bytes = match ext.as_deref() {
            Some("obj" | "stl") => std::fs::read(&p).map_err(|e| {
                self.err(
                    file.span(),
                    format!("{key}: {}: cannot read: {e}", p.display()),
                )
            })?,
            _ => {
                return Err(self.err(
                    file.span(),
                    format!(
                        "{key} must name an .obj or .stl file, got '{}'",
                        file.get_ref()
                    ),
                ));
            }
        };
        let read = if ext.as_deref() == Some("obj") {
            String::from_utf8(bytes)
                .map_err(|_| {
                    self.err(
                        file.span(),
                        format!("{key}: {}: not valid UTF-8", p.display()),
                    )
                })
                .and_then(|text| {
                    read_obj(&text, &p).map_err(|e| self.err(file.span(), format!("{key}: {e}")))
                })?
        } else {
            read_stl(&bytes, &p).map_err(|e| self.err(file.span(), format!("{key}: {e}")))?
        };
        let key_of = |what: &str| format!("{}.{what}", key.trim_end_matches(".file"));
        let t = match position {
            Some(v) => self.vec3(v, &key_of("position"))?,
            None => Vector3::zeros(),
        };
        let r = match rotation_deg {
            Some(v) => self.vec3(v, &key_of("rotation_deg"))?,
            None => Vector3::zeros(),
        };
        if t == Vector3::zeros() && r == Vector3::zeros() {
            return Ok((p, read));
        }
        let rot = |axis: Vector3, deg: Real| {
            crate::math::Rotation3::from_axis_angle(
                &UnitVector3::new_unchecked(axis),
                deg.to_radians(),
            )
        };
        let w_from_mesh = crate::math::Isometry3::from_parts(
            t.into(),
            rot(Vector3::x(), r.x) * rot(Vector3::y(), r.y) * rot(Vector3::z(), r.z),
        );
        let vertices = read.vertices().iter().map(|v| w_from_mesh * v).collect();
        let placed = ClosedMesh::try_new(vertices, read.triangles().to_vec(), &p, &[])
            .map_err(|e| self.err(file.span(), format!("{key}: placed: {e}")))?;
        Ok((p, placed))
    }

    fn vec3(&self, v: &Spanned<[Real; 3]>, what: &str) -> Result<Vector3, SceneError> {
        let a = v.get_ref();
        if a.iter().all(|c| c.is_finite()) {
            Ok(Vector3::new(a[0], a[1], a[2]))
        } else {
            Err(self.err(
                v.span(),
                format!("{what} must have finite components, got {a:?}"),
            ))
        }
    }
}

/// `[identify]`: the faces and how they are measured and identified.
fn identify_setup(ctx: &Ctx, chain: &Chain, f: &IdentifyFile) -> Result<IdentifySetup, SceneError> {
    let faces = f.faces.get_ref();
    let general = f.parameters.is_some();
    if general && faces.is_empty() {
        return Err(ctx.err(f.faces.span(), "identify.faces is empty"));
    }
    if !general && faces.len() != 2 {
        return Err(ctx.err(
            f.faces.span(),
            format!(
                "identify.faces must list exactly two faces (cut at A = 0° and 180°), got {}",
                faces.len()
            ),
        ));
    }
    let spec = |face: &FaceFile| -> Result<FaceSpec, SceneError> {
        let region = match (&face.bbox, &face.seed) {
            (Some(_), Some(s)) => {
                return Err(ctx.err(s.span(), "a face takes a box or a seed, not both"));
            }
            (Some(b), None) => {
                let (mn, mx) = (ctx.vec3(&b.min, "box.min")?, ctx.vec3(&b.max, "box.max")?);
                if (0..3).any(|k| mx[k] <= mn[k]) {
                    return Err(ctx.err(b.max.span(), "box.max must exceed box.min on every axis"));
                }
                FaceRegion::Box(Aabb {
                    min: mn.into(),
                    max: mx.into(),
                })
            }
            (None, Some(s)) => FaceRegion::Seed(ctx.vec3(s, "seed")?.into()),
            (None, None) => FaceRegion::Auto,
        };
        let kind = match face.kind.as_ref().map(|k| (k.get_ref().as_str(), k.span())) {
            None | Some(("flank", _)) => FaceKind::Flank,
            Some(("floor", _)) => FaceKind::Floor,
            Some((other, span)) => {
                return Err(ctx.err(
                    span,
                    format!("face kind must be 'flank' or 'floor', got '{other}'"),
                ));
            }
        };
        Ok(FaceSpec {
            kind,
            name: face.name.clone(),
            line: *face.line.get_ref(),
            region,
        })
    };
    let margin = ctx.opt(&f.margin_mm, "margin_mm", DEFAULT_MARGIN_MM)?;
    let band = ctx.opt(&f.band_mm, "band_mm", DEFAULT_BAND_MM)?;
    if margin < 0.0 {
        return Err(ctx.err(
            f.margin_mm.as_ref().map_or(0..0, |m| m.span()),
            "margin_mm must not be negative",
        ));
    }
    if band <= 0.0 {
        return Err(ctx.err(
            f.band_mm.as_ref().map_or(0..0, |m| m.span()),
            "band_mm must be positive",
        ));
    }
    let mut parameters = Vec::new();
    if let Some(ps) = &f.parameters {
        for p in ps.get_ref() {
            chain
                .deviation_id(p.get_ref())
                .map_err(|e| ctx.err(p.span(), e.to_string()))?;
            if parameters.contains(p.get_ref()) {
                return Err(ctx.err(p.span(), format!("parameter '{}' given twice", p.get_ref())));
            }
            parameters.push(p.get_ref().clone());
        }
        if parameters.is_empty() {
            return Err(ctx.err(ps.span(), "identify.parameters is empty"));
        }
    }
    let registration = match f
        .registration
        .as_ref()
        .map(|r| (r.get_ref().as_str(), r.span()))
    {
        None | Some(("estimate", _)) => Registration::Estimate,
        Some(("workpiece", _)) => Registration::Workpiece,
        Some((other, span)) => {
            return Err(ctx.err(
                span,
                format!("registration must be 'estimate' or 'workpiece', got '{other}'"),
            ));
        }
    };
    let (monte_carlo_trials, monte_carlo_seed) = match &f.monte_carlo {
        Some(m) if *m.trials.get_ref() > 10_000 => {
            return Err(ctx.err(m.trials.span(), "monte_carlo.trials must be at most 10000"));
        }
        Some(m) => (*m.trials.get_ref(), m.seed.unwrap_or(1)),
        None => (0, 1),
    };
    let loop_tolerance_mm = match &f.loop_tolerance_mm {
        Some(v) => ctx.positive(v, "loop_tolerance_mm")?,
        None => DEFAULT_LOOP_TOLERANCE_MM,
    };
    Ok(IdentifySetup {
        faces: faces.iter().map(spec).collect::<Result<_, _>>()?,
        parameters,
        registration,
        monte_carlo_trials,
        monte_carlo_seed,
        loop_tolerance_mm,
        face_options: FaceOptions {
            margin_mm: margin,
            band_mm: band,
            robust: RobustRule::default(),
        },
    })
}

/// What `[identify]` sets, or its defaults when the scene has none (no faces).
struct IdentifySetup {
    faces: Vec<FaceSpec>,
    parameters: Vec<String>,
    registration: Registration,
    monte_carlo_trials: usize,
    monte_carlo_seed: u64,
    loop_tolerance_mm: Real,
    face_options: FaceOptions,
}

impl IdentifySetup {
    fn none() -> Self {
        IdentifySetup {
            faces: Vec::new(),
            parameters: Vec::new(),
            registration: Registration::Estimate,
            monte_carlo_trials: 0,
            monte_carlo_seed: 1,
            loop_tolerance_mm: DEFAULT_LOOP_TOLERANCE_MM,
            face_options: FaceOptions {
                margin_mm: DEFAULT_MARGIN_MM,
                band_mm: DEFAULT_BAND_MM,
                robust: RobustRule::default(),
            },
        }
    }
}

/// The scene's name (`name`, or the file's stem): it names the output folder.
fn scene_name(ctx: &Ctx, name: Option<&Spanned<String>>) -> Result<String, SceneError> {
    let (text, span) = match name {
        Some(n) => (n.get_ref().trim().to_string(), n.span()),
        None => (
            ctx.path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            0..0,
        ),
    };
    if text.is_empty()
        || !text
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        || text.starts_with('.')
    {
        let what = if name.is_some() {
            "name".to_string()
        } else {
            format!("the file name '{text}' (used when the scene has no name)")
        };
        return Err(ctx.err(
            span,
            format!("{what} must be non-empty and use only letters, digits, '-', '_', '.'"),
        ));
    }
    Ok(text)
}

/// `[scanner]`: the virtual scanner, with the defaults of an EinScan-SP class instrument.
fn scanner_config(ctx: &Ctx, s: &ScannerFile) -> Result<ScannerConfig, SceneError> {
    let fov = match &s.fov_mm {
        Some(f) => (f.get_ref()[0], f.get_ref()[1]),
        None => (200.0, 150.0),
    };
    let scanner = ScannerConfig {
        position: ctx.vec3(&s.position, "position")?.into(),
        target: ctx.vec3(&s.target, "target")?.into(),
        up: ctx.vec3(&s.up, "up")?,
        baseline_mm: ctx.opt(&s.baseline_mm, "baseline_mm", 100.0)?,
        fov_mm: fov,
        pitch_mm: ctx.opt(&s.pitch_mm, "pitch_mm", 0.185)?,
        noise_sigma_mm: ctx.opt(&s.noise_sigma_mm, "noise_sigma_mm", 0.025)?,
        noise_correlation_mm: ctx.opt(&s.noise_correlation_mm, "noise_correlation_mm", 0.0)?,
        working_range_mm: match &s.working_range_mm {
            Some(r) => (r.get_ref()[0], r.get_ref()[1]),
            None => (290.0, 480.0),
        },
        grazing_limit_deg: ctx.opt(&s.grazing_limit_deg, "grazing_limit_deg", 80.0)?,
        misregistration: match &s.misregistration {
            Some(m) => Misregistration {
                translation_sigma_mm: ctx.opt(
                    &m.translation_sigma_mm,
                    "translation_sigma_mm",
                    0.0,
                )?,
                rotation_sigma_rad: ctx.opt(&m.rotation_sigma_rad, "rotation_sigma_rad", 0.0)?,
            },
            None => Misregistration::default(),
        },
        turntable: match &s.turntable {
            Some(t) => Some(Turntable {
                axis_point: ctx.vec3(&t.axis_point, "axis_point")?.into(),
                axis: UnitVector3::try_new(ctx.vec3(&t.axis, "axis")?, tol::LENGTH_EPS)
                    .ok_or_else(|| ctx.err(t.axis.span(), "turntable axis must not be zero"))?,
                angles_deg: t.angles_deg.get_ref().clone(),
            }),
            None => None,
        },
        seed: s.seed.unwrap_or(1),
    };
    scanner.validate().map_err(|e| {
        let span = match &e {
            ScanError::BadConfig { field, .. } => match *field {
                "position" => s.position.span(),
                "target" => s.target.span(),
                "up" => s.up.span(),
                "pitch_mm" => s.pitch_mm.as_ref().map_or(s.position.span(), |v| v.span()),
                "fov_mm" => s.fov_mm.as_ref().map_or(s.position.span(), |v| v.span()),
                "noise_sigma_mm" => s
                    .noise_sigma_mm
                    .as_ref()
                    .map_or(s.position.span(), |v| v.span()),
                "noise_correlation_mm" => s
                    .noise_correlation_mm
                    .as_ref()
                    .map_or(s.position.span(), |v| v.span()),
                "working_range_mm" => s
                    .working_range_mm
                    .as_ref()
                    .map_or(s.position.span(), |v| v.span()),
                "grazing_limit_deg" => s
                    .grazing_limit_deg
                    .as_ref()
                    .map_or(s.position.span(), |v| v.span()),
                "turntable" => s
                    .turntable
                    .as_ref()
                    .map_or(s.position.span(), |t| t.angles_deg.span()),
                "misregistration" => s
                    .misregistration
                    .as_ref()
                    .and_then(|m| {
                        m.translation_sigma_mm
                            .as_ref()
                            .or(m.rotation_sigma_rad.as_ref())
                    })
                    .map_or(s.position.span(), |v| v.span()),
                _ => s.position.span(),
            },
            ScanError::TooManyRays { .. } => {
                s.pitch_mm.as_ref().map_or(s.position.span(), |v| v.span())
            }
        };
        ctx.err(span, e.to_string())
    })?;
    Ok(scanner)
}

/// 1-based line and column (in characters) of byte offset `at`.
pub fn line_col(text: &str, at: usize) -> (usize, usize) {
    let at = at.min(text.len());
    let before = text.get(..at).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

/// A TOML file's error in one line and in our words, located at its line and column:
/// `key: what is wrong, expected what` (the key as a dotted path, `machine.axes[2].kind`;
/// none for a syntax error outside any key). Used for every TOML file twinmill reads.
pub fn toml_error(text: &str, path: &Path, e: &toml::de::Error) -> SceneError {
    let at = e.span().map_or(0, |s| s.start);
    let key = toml_key_at(text, at);
    let what = toml_words(e.message());
    let (what, key) = match what.strip_prefix("missing field \"") {
        // the span is the table's: the missing key belongs under it
        Some(rest) => {
            let field = rest.split('"').next().unwrap_or("");
            let key = if key.is_empty() {
                field.to_string()
            } else {
                format!("{key}.{field}")
            };
            ("missing, expected a value for this key".to_string(), key)
        }
        None => match what
            .strip_prefix("unknown key \"")
            .and_then(|r| r.split_once("\", "))
        {
            // the span is the key's own: the path already names it
            Some((k, rest)) if key == k || key.ends_with(&format!(".{k}")) => {
                (format!("unknown key, {rest}"), key)
            }
            _ => (what, key),
        },
    };
    let (line, column) = line_col(text, at);
    SceneError::Invalid {
        path: path.to_path_buf(),
        line,
        column,
        message: if key.is_empty() {
            what
        } else {
            format!("{key}: {what}")
        },
    }
}

/// The dotted key of the innermost value or key of `text` that holds byte `at` (empty when
/// none does, or the text does not parse).
fn toml_key_at(text: &str, at: usize) -> String {
    use toml::de::{DeTable, DeValue};
    let holds = |r: std::ops::Range<usize>| r.start <= at && at < r.end.max(r.start + 1);
    // The path below `v` to what holds `at`: a `[table]`'s span is its header only, so
    // tables and arrays are searched whether or not their own span holds it.
    fn find(v: &DeValue<'_>, holds: &dyn Fn(std::ops::Range<usize>) -> bool) -> Option<String> {
        let deeper = |v: &DeValue<'_>| matches!(v, DeValue::Table(_) | DeValue::Array(_));
        match v {
            DeValue::Table(t) => t.iter().find_map(|(k, v)| {
                let here = holds(k.span()) || holds(v.span());
                let below = if here || deeper(v.get_ref()) {
                    find(v.get_ref(), holds)
                } else {
                    None
                };
                match below {
                    Some(sub) if sub.starts_with('[') => Some(format!("{}{sub}", k.get_ref())),
                    Some(sub) => Some(format!("{}.{sub}", k.get_ref())),
                    None => here.then(|| k.get_ref().to_string()),
                }
            }),
            DeValue::Array(a) => a.iter().enumerate().find_map(|(i, v)| {
                let here = holds(v.span());
                let below = if here || deeper(v.get_ref()) {
                    find(v.get_ref(), holds)
                } else {
                    None
                };
                match below {
                    Some(sub) if sub.starts_with('[') => Some(format!("[{}]{sub}", i + 1)),
                    Some(sub) => Some(format!("[{}].{sub}", i + 1)),
                    None => here.then(|| format!("[{}]", i + 1)),
                }
            }),
            _ => None,
        }
    }
    let Ok(doc) = DeTable::parse(text) else {
        return String::new();
    };
    find(&DeValue::Table(doc.into_inner()), &holds).unwrap_or_default()
}

/// serde's and the TOML parser's wording (`invalid type: string "ball", expected f64`) in
/// ours (`got the string "ball", expected a number`), on one line.
fn toml_words(message: &str) -> String {
    let one_line = message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(", ");
    let expected = |e: &str| -> String {
        let e = e.trim();
        match e {
            "f64" | "f32" => "a number".into(),
            "u64" | "usize" | "u32" | "u16" | "u8" => "a whole number, 0 or more".into(),
            "i64" | "i32" | "isize" => "a whole number".into(),
            "a boolean" | "bool" => "true or false".into(),
            "a sequence" => "an array".into(),
            "a map" => "a table".into(),
            _ if e.starts_with("struct ") || e.starts_with("a map") => "a table".into(),
            _ => e.replace('`', "\""),
        }
    };
    let got = |g: &str| -> String {
        let g = g.trim();
        let words = [
            ("string ", "the string "),
            ("integer ", "the integer "),
            ("floating point ", "the number "),
            ("boolean ", "the boolean "),
        ];
        for (from, to) in words {
            if let Some(rest) = g.strip_prefix(from) {
                return format!("{to}{}", rest.replace('`', ""));
            }
        }
        match g {
            "sequence" => "an array".into(),
            "map" => "a table".into(),
            _ => g.replace('`', "\""),
        }
    };
    for prefix in ["invalid type: ", "invalid value: "] {
        if let Some(rest) = one_line.strip_prefix(prefix)
            && let Some((g, e)) = rest.rsplit_once(", expected ")
        {
            return format!("got {}, expected {}", got(g), expected(e));
        }
    }
    if let Some(rest) = one_line.strip_prefix("invalid length ")
        && let Some((n, e)) = rest.split_once(", expected ")
    {
        return format!("got {n} values, expected {}", expected(e));
    }
    if let Some(rest) = one_line.strip_prefix("unknown field `")
        && let Some((k, e)) = rest.split_once("`, expected ")
    {
        return format!("unknown key \"{k}\", expected {}", expected(e));
    }
    if let Some(rest) = one_line.strip_prefix("unknown variant `")
        && let Some((k, e)) = rest.split_once("`, expected ")
    {
        return format!("unknown value \"{k}\", expected {}", expected(e));
    }
    one_line.replace('`', "\"")
}

/// Reads a scene file as UTF-8 text.
pub fn read_text(path: &Path) -> Result<String, SceneError> {
    let bytes = std::fs::read(path).map_err(|source| SceneError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let text = String::from_utf8_lossy(e.as_bytes());
        let (line, column) = line_col(&text, at);
        SceneError::Invalid {
            path: path.to_path_buf(),
            line,
            column,
            message: "not valid UTF-8".into(),
        }
    })
}

/// Sets the deviations of `map` on `chain`: names `<component>_<joint>` first, then the
/// ISO location and squareness names (`EY0A`, `EC(0X)Y`, …) composed onto them.
fn deviation_map(
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
fn error_motions(
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

/// The memory the tri-dexel may use, and where that figure comes from (for messages).
///
/// By default half the machine's installed memory (`MemTotal` in `/proc/meminfo`; 16 GiB
/// assumed where it cannot be read): a stable figure, so that whether a scene loads does
/// not depend on what else the machine is doing at that moment. The stock is the
/// pipeline's largest structure; the other half is left to the scan, the mesh and the rest
/// of the machine. `--memory SIZE` sets it instead.
#[derive(Clone, Debug, PartialEq)]
pub struct MemoryBudget {
    /// Bytes.
    pub bytes: Real,
    /// Where the figure comes from, as messages say it: `the budget is half of the
    /// installed 23.4 GiB; …`, `the budget is --memory 2G`.
    pub source: String,
}

/// The fraction of the installed memory the tri-dexel may use by default.
pub const INSTALLED_MEMORY_FRACTION: Real = 0.5;

/// Installed memory assumed where `/proc/meminfo` cannot be read (bytes).
const ASSUMED_INSTALLED_BYTES: Real = 16.0 * GIB;

const GIB: Real = 1073741824.0;

impl MemoryBudget {
    /// [`INSTALLED_MEMORY_FRACTION`] of the installed memory.
    pub fn installed() -> Self {
        let total = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("MemTotal:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<Real>().ok())
                .map(|kb| kb * 1024.0)
        });
        let (bytes, what) = match total {
            Some(t) => (t, "installed"),
            None => (ASSUMED_INSTALLED_BYTES, "assumed installed"),
        };
        MemoryBudget {
            bytes: bytes * INSTALLED_MEMORY_FRACTION,
            source: format!(
                "the budget is half of the {what} {:.1} GiB; --memory sets another",
                bytes / GIB
            ),
        }
    }

    /// A budget given as a size: a number of bytes with an optional unit `K`, `M`, `G` or
    /// `T` (powers of 1024; `KiB`, `MB`, … accepted alike), e.g. `2G`, `1.5GiB`, `512M`.
    pub fn parse(text: &str) -> Result<Self, String> {
        let t = text.trim();
        let split = t.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(t.len());
        let (num, unit) = (t[..split].trim(), t[split..].trim());
        let scale = match unit.to_ascii_uppercase().as_str() {
            "" | "B" => 1.0,
            "K" | "KB" | "KIB" => 1024.0,
            "M" | "MB" | "MIB" => 1048576.0,
            "G" | "GB" | "GIB" => GIB,
            "T" | "TB" | "TIB" => 1024.0 * GIB,
            _ => {
                return Err(format!(
                    "--memory: '{}': expected a size such as 2G, 512M or 1.5GiB",
                    text.escape_debug()
                ));
            }
        };
        match num.parse::<Real>() {
            Ok(v) if v.is_finite() && v > 0.0 && (v * scale).is_finite() => Ok(MemoryBudget {
                bytes: v * scale,
                source: format!("the budget is --memory {t}"),
            }),
            _ => Err(format!(
                "--memory: '{}': expected a positive size such as 2G, 512M or 1.5GiB",
                text.escape_debug()
            )),
        }
    }
}

impl Scene {
    /// Checks that the scene has what `command` needs: one error naming every missing part.
    pub fn require(&self, command: &str, needs: &[Need]) -> Result<(), SceneError> {
        let mut missing = Vec::new();
        for need in needs {
            match need {
                Need::Scanner if self.scanner.is_none() => missing.push(
                    "[scanner] (the virtual scanner that measures the cut part: position, target, up)"
                        .to_string(),
                ),
                Need::StepFaces if self.faces.is_empty() => missing.push(
                    "[identify] faces (the two faces cut 180° apart, each named by the NC line \
                     of its cut: faces = [{ name, line }, { name, line }])"
                        .to_string(),
                ),
                Need::StepFaces if self.faces.len() != 2 || !self.parameters.is_empty() => {
                    missing.push(format!(
                        "[identify] with exactly two faces cut 180° apart and no parameters (this \
                         scene lists {} faces and {} parameters for `twinmill identify`)",
                        self.faces.len(),
                        self.parameters.len()
                    ))
                }
                Need::Parameters if self.parameters.is_empty() => missing.push(
                    "[identify] parameters (the deviations to solve for, e.g. parameters = \
                     [\"dy_AY\"]) and faces (the cuts to measure, each by its NC line)"
                        .to_string(),
                ),
                _ => {}
            }
        }
        if missing.is_empty() {
            return Ok(());
        }
        Err(SceneError::Missing {
            path: self.path.clone(),
            command: command.to_string(),
            what: missing.join(" and "),
        })
    }

    /// The scanner, or the error saying that `command` needs one.
    pub fn scanner_for(&self, command: &str) -> Result<&ScannerConfig, SceneError> {
        self.require(command, &[Need::Scanner])?;
        self.scanner.as_ref().ok_or_else(|| SceneError::Missing {
            path: self.path.clone(),
            command: command.to_string(),
            what: "[scanner]".into(),
        })
    }

    /// Loads and validates a scene file, with the default memory budget
    /// ([`MemoryBudget::installed`]).
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        Self::load_with(path, &MemoryBudget::installed())
    }

    /// Loads and validates a scene file; the stock must fit in `memory`.
    pub fn load_with(path: &Path, memory: &MemoryBudget) -> Result<Scene, SceneError> {
        let text = read_text(path)?;
        Self::parse_with(&text, path, memory)
    }

    /// Parses and validates scene text; `path` locates messages and relative file names.
    /// The default memory budget ([`MemoryBudget::installed`]).
    pub fn parse(text: &str, path: &Path) -> Result<Scene, SceneError> {
        Self::parse_with(text, path, &MemoryBudget::installed())
    }

    /// Parses and validates scene text; the stock must fit in `memory`.
    pub fn parse_with(text: &str, path: &Path, memory: &MemoryBudget) -> Result<Scene, SceneError> {
        let ctx = Ctx { path, text };
        if machine_kind(text).as_deref() == Some("hexapod") {
            return Err(SceneError::Hexapod {
                path: path.to_path_buf(),
            });
        }
        let file: SceneFile<MachineFile> =
            toml::from_str(text).map_err(|e| toml_error(text, path, &e))?;
        for (section, v) in [
            ("workspace", &file.workspace),
            ("drives", &file.drives),
            ("homing", &file.homing),
            ("table", &file.table),
            ("table_axes", &file.table_axes),
        ] {
            if let Some(v) = v {
                return Err(ctx.err(
                    v.span(),
                    format!(
                        "[{section}] applies to hexapod scenes only ([machine] kind = \"hexapod\")"
                    ),
                ));
            }
        }
        // Machine.
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
                check_coordinate(x, &format!("machine.home.{k}"))
                    .map_err(|e| ctx.err(v.span(), e))?
            };
            home.set(letter, x);
        }
        let model_nominal = chain.nominal();
        let injected = deviation_map(&ctx, &mut chain, &file.deviations)?;
        error_motions(&ctx, &mut chain, &file.error_motions, &file.reversal)?;
        // The model knows the machine's error motions (measured, like `known`).
        let mut model = model_nominal.with_error_motions_of(&chain);
        let known = match &file.identify {
            Some(id) => deviation_map(&ctx, &mut model, &id.known)?,
            None => BTreeMap::new(),
        };
        let machine_name = file.machine.name.clone();
        finish(
            &ctx,
            file,
            MachineParts {
                machine_name,
                chain,
                injected,
                model,
                known,
                home,
                hexapod: None,
            },
            memory,
        )
    }

    /// Parses the cutting part of a hexapod scene (program, tool, stock, sweep, design) for
    /// the machine `twin` whose deviations by name are `injected` (`[machine]` and the
    /// hexapod sections are read by [`crate::hexapod_scene`]). The scene's `chain` is the
    /// controller's Cartesian kinematics; error motions, reversal, `[identify]`, fixtures and
    /// a holder are refused (no identification or collision checks on a hexapod).
    pub fn parse_hexapod_cut(
        text: &str,
        path: &Path,
        memory: &MemoryBudget,
        twin: HexapodTwin,
        machine_name: String,
        injected: BTreeMap<String, Real>,
    ) -> Result<Scene, SceneError> {
        let ctx = Ctx { path, text };
        let file: SceneFile<toml::Value> =
            toml::from_str(text).map_err(|e| toml_error(text, path, &e))?;
        let refuse = |span: Option<Range<usize>>, what: &str| match span {
            Some(span) => Err(ctx.err(span, format!("{what} does not apply to a hexapod scene"))),
            None => Ok(()),
        };
        refuse(
            file.error_motions.values().next().map(|v| v.span()),
            "[error_motions]",
        )?;
        refuse(
            file.reversal.values().next().map(|v| v.span()),
            "[reversal]",
        )?;
        refuse(
            file.fixtures.first().map(|f| f.file.span()),
            "[[fixtures]] (collision checks are not run on a hexapod)",
        )?;
        let t = &file.tool;
        refuse(
            [
                &t.shank_diameter_mm,
                &t.shank_length_mm,
                &t.holder_diameter_mm,
                &t.holder_length_mm,
            ]
            .into_iter()
            .flatten()
            .map(|v| v.span())
            .next()
            .or(t.holder_sections.as_ref().map(|h| h.span())),
            "a shank or holder (collision checks are not run on a hexapod)",
        )?;
        if file.identify.is_some() {
            return Err(ctx.err(
                file.program.span(),
                "[identify] does not apply to a hexapod scene (`twinmill simulate` cuts it)",
            ));
        }
        let chain = twin
            .command_chain()
            .map_err(|e| ctx.err(0..0, format!("[table_axes]: {e}")))?;
        let home = twin.home_axis_values();
        finish(
            &ctx,
            file,
            MachineParts {
                machine_name,
                model: chain.clone(),
                chain,
                injected,
                known: BTreeMap::new(),
                home,
                hexapod: Some(twin),
            },
            memory,
        )
    }
}

/// The rest of a scene once its machine is built: tool, holder, stock, fixtures, design,
/// sweep, scanner, study, identification and the files it names.
fn finish<M>(
    ctx: &Ctx,
    file: SceneFile<M>,
    machine: MachineParts,
    memory: &MemoryBudget,
) -> Result<Scene, SceneError> {
    let (ctx, path, text) = (*ctx, ctx.path, ctx.text);
    let MachineParts {
        machine_name,
        chain,
        injected,
        model,
        known,
        home,
        hexapod,
    } = machine;
    let name = scene_name(&ctx, file.name.as_ref())?;
    {
        // Tool.
        let diameter = ctx.positive(&file.tool.diameter_mm, "diameter_mm")?;
        let length = ctx.positive(&file.tool.length_mm, "length_mm")?;
        let kind_name = file.tool.kind.get_ref().as_str();
        let extra = |field: &Option<Spanned<Real>>, name: &str, wanted: bool| match (field, wanted)
        {
            (Some(f), false) => Err(ctx.err(
                f.span(),
                format!("tool.{name} does not apply to a '{kind_name}' tool"),
            )),
            (None, true) => Err(ctx.err(
                file.tool.kind.span(),
                format!("a '{kind_name}' tool needs tool.{name}"),
            )),
            (Some(f), true) => Ok(Some(ctx.finite(f, name)?)),
            (None, false) => Ok(None),
        };
        let bull = kind_name == "bull_nose";
        let tapered = matches!(kind_name, "tapered_flat" | "tapered_ball");
        let corner = extra(&file.tool.corner_radius_mm, "corner_radius_mm", bull)?;
        let angle = extra(
            &file.tool.taper_half_angle_deg,
            "taper_half_angle_deg",
            tapered,
        )?;
        let made = match (kind_name, corner, angle) {
            ("flat", ..) => Tool::try_new(ToolKind::Flat, diameter, length),
            ("ball", ..) => Tool::try_new(ToolKind::Ball, diameter, length),
            ("bull_nose", Some(rc), _) => Tool::try_bull_nose(diameter, rc, length),
            ("tapered_flat", _, Some(a)) => Tool::try_tapered_flat(diameter, a, length),
            ("tapered_ball", _, Some(a)) => Tool::try_tapered_ball(diameter, a, length),
            (other, ..) => {
                return Err(ctx.err(
                    file.tool.kind.span(),
                    format!(
                        "tool kind must be 'flat', 'ball', 'bull_nose', 'tapered_flat' or 'tapered_ball', got '{other}'"
                    ),
                ));
            }
        };
        let tool = made.map_err(|e| ctx.err(file.tool.length_mm.span(), e.to_string()))?;
        // Shank and holder.
        let t = &file.tool;
        let holder_keys = [
            (&t.shank_diameter_mm, "shank_diameter_mm"),
            (&t.shank_length_mm, "shank_length_mm"),
            (&t.holder_diameter_mm, "holder_diameter_mm"),
            (&t.holder_length_mm, "holder_length_mm"),
        ];
        let holder = if let Some(secs) = &t.holder_sections {
            // The holder as sections: with the shank, without the holder cylinder's keys.
            for (given, key) in &holder_keys[2..] {
                if let Some(g) = given {
                    return Err(ctx.err(
                        g.span(),
                        format!("tool.{key} and tool.holder_sections both describe the holder: give one of them"),
                    ));
                }
            }
            let mut shank = [0.0; 2];
            for (k, (field, key)) in holder_keys[..2].iter().enumerate() {
                let f = field.as_ref().ok_or_else(|| {
                    ctx.err(
                        secs.span(),
                        format!("tool.{key} is missing: holder_sections need shank_diameter_mm and shank_length_mm"),
                    )
                })?;
                shank[k] = ctx.positive(f, &format!("tool.{key}"))?;
            }
            if secs.get_ref().is_empty() {
                return Err(ctx.err(
                    secs.span(),
                    "tool.holder_sections is empty: give at least one { length_mm, radius_bottom_mm, radius_top_mm }".to_string(),
                ));
            }
            let mut sections = Vec::new();
            for (i, sec) in secs.get_ref().iter().enumerate() {
                let key = |f: &str| format!("tool.holder_sections[{i}].{f}");
                sections.push(HolderSection {
                    length: ctx.positive(&sec.length_mm, &key("length_mm"))?,
                    radius_bottom: ctx.positive(&sec.radius_bottom_mm, &key("radius_bottom_mm"))?,
                    radius_top: ctx.positive(&sec.radius_top_mm, &key("radius_top_mm"))?,
                });
            }
            let span = holder_keys[0].0.as_ref().map_or(secs.span(), |v| v.span());
            Some(
                Holder::try_sections(shank[0] / 2.0, shank[1], &sections)
                    .map_err(|e| ctx.err(span, format!("tool: {e}")))?,
            )
        } else {
            match holder_keys.iter().find(|(v, _)| v.is_some()) {
                None => None,
                Some((given, _)) => {
                    let span = given.as_ref().map_or(0..0, |v| v.span());
                    let mut v = [0.0; 4];
                    for (k, (field, key)) in holder_keys.iter().enumerate() {
                        let f = field.as_ref().ok_or_else(|| {
                            ctx.err(
                                span.clone(),
                                format!("tool.{key} is missing: a holder needs shank_diameter_mm, shank_length_mm, holder_diameter_mm and holder_length_mm"),
                            )
                        })?;
                        v[k] = ctx.positive(f, &format!("tool.{key}"))?;
                    }
                    Some(
                        Holder::try_new(v[0] / 2.0, v[1], v[2] / 2.0, v[3])
                            .map_err(|e| ctx.err(span, format!("tool: {e}")))?,
                    )
                }
            }
        };
        // Stock.
        let dir = path.parent().unwrap_or(Path::new("."));
        let st = &file.stock;
        let stock_kind = st.kind.as_ref().map_or("box", |k| k.get_ref().as_str());
        let kind_span = st.kind.as_ref().map_or(st.pitch_mm.span(), |k| k.span());
        let keys: [(&str, Option<Range<usize>>); 10] = [
            ("min", st.min.as_ref().map(|v| v.span())),
            ("max", st.max.as_ref().map(|v| v.span())),
            ("ends", st.ends.as_ref().map(|v| v.span())),
            ("base", st.base.as_ref().map(|v| v.span())),
            ("axis", st.axis.as_ref().map(|v| v.span())),
            ("length_mm", st.length_mm.as_ref().map(|v| v.span())),
            ("radius_mm", st.radius_mm.as_ref().map(|v| v.span())),
            ("file", st.file.as_ref().map(|v| v.span())),
            ("position", st.position.as_ref().map(|v| v.span())),
            ("rotation_deg", st.rotation_deg.as_ref().map(|v| v.span())),
        ];
        let allowed: &[&str] = match stock_kind {
            "box" => &["min", "max"],
            "cylinder" => &["ends", "base", "axis", "length_mm", "radius_mm"],
            "mesh" => &["file", "position", "rotation_deg"],
            other => {
                return Err(ctx.err(
                    kind_span,
                    format!("stock kind must be 'box', 'cylinder' or 'mesh', got '{other}'"),
                ));
            }
        };
        if let Some((key, Some(span))) = keys
            .iter()
            .find(|(k, s)| s.is_some() && !allowed.contains(k))
        {
            return Err(ctx.err(
                span.clone(),
                format!("stock.{key} does not apply to a '{stock_kind}' stock"),
            ));
        }
        let need = |v: &Option<Spanned<[Real; 3]>>, key: &str| match v {
            Some(v) => ctx.vec3(v, &format!("stock.{key}")),
            None => Err(ctx.err(
                kind_span.clone(),
                format!("a '{stock_kind}' stock needs stock.{key}"),
            )),
        };
        let (stock_box, stock_shape) = match stock_kind {
            "box" => {
                let (mn, mx) = (need(&st.min, "min")?, need(&st.max, "max")?);
                if (0..3).any(|k| mx[k] <= mn[k]) {
                    return Err(ctx.err(
                        st.max.as_ref().map_or(0..0, |m| m.span()),
                        "stock.max must exceed stock.min on every axis",
                    ));
                }
                let b = Aabb {
                    min: mn.into(),
                    max: mx.into(),
                };
                (b, StockShape::Box)
            }
            "cylinder" => {
                let radius = match &st.radius_mm {
                    Some(r) => ctx.positive(r, "stock.radius_mm")?,
                    None => {
                        return Err(ctx.err(kind_span, "a 'cylinder' stock needs stock.radius_mm"));
                    }
                };
                let (base, axis, length, span) = match (&st.ends, &st.base) {
                    (Some(e), None) => {
                        let [a, b] = *e.get_ref();
                        if !a.iter().chain(b.iter()).all(|c| c.is_finite()) {
                            return Err(ctx.err(
                                e.span(),
                                format!(
                                    "stock.ends must have finite components, got {:?}",
                                    e.get_ref()
                                ),
                            ));
                        }
                        if st.axis.is_some() || st.length_mm.is_some() {
                            return Err(ctx.err(
                                e.span(),
                                "stock.ends replaces stock.axis and stock.length_mm: give one or the other",
                            ));
                        }
                        let (a, b) = (Vector3::from(a), Vector3::from(b));
                        (a, b - a, (b - a).norm(), e.span())
                    }
                    (None, Some(b)) => {
                        let base = ctx.vec3(b, "stock.base")?;
                        let axis = need(&st.axis, "axis")?;
                        let length = match &st.length_mm {
                            Some(l) => ctx.positive(l, "stock.length_mm")?,
                            None => {
                                return Err(ctx.err(
                                    kind_span,
                                    "a 'cylinder' stock needs stock.length_mm with stock.base",
                                ));
                            }
                        };
                        (base, axis, length, b.span())
                    }
                    (Some(e), Some(_)) => {
                        return Err(ctx.err(e.span(), "give stock.ends or stock.base, not both"));
                    }
                    (None, None) => {
                        return Err(ctx.err(
                            kind_span,
                            "a 'cylinder' stock needs stock.ends (or stock.base, stock.axis and stock.length_mm)",
                        ));
                    }
                };
                let c = Cylinder::try_new(base.into(), axis, radius, length)
                    .map_err(|e| ctx.err(span, format!("stock: {e}")))?;
                (c.bounds(), StockShape::Cylinder(c))
            }
            _ => {
                let f = st
                    .file
                    .as_ref()
                    .ok_or_else(|| ctx.err(kind_span.clone(), "a 'mesh' stock needs stock.file"))?;
                let (mesh_path, mesh) =
                    ctx.mesh(dir, f, &st.position, &st.rotation_deg, "stock.file")?;
                (
                    mesh.bounds(),
                    StockShape::Mesh {
                        path: mesh_path,
                        mesh: Box::new(mesh),
                    },
                )
            }
        };
        let pitch_mm = ctx.positive(&file.stock.pitch_mm, "pitch_mm")?;
        crate::cutting::stock::check_memory(&stock_box, pitch_mm, memory.bytes).map_err(|e| {
            ctx.err(
                file.stock.pitch_mm.span(),
                format!("stock.pitch_mm = {pitch_mm}: {e} ({})", memory.source),
            )
        })?;
        // Fixtures and design model.
        let mut fixtures: Vec<Fixture> = Vec::new();
        for (k, f) in file.fixtures.iter().enumerate() {
            let key = format!("fixtures[{k}].file");
            let (p, mesh) = ctx.mesh(dir, &f.file, &f.position, &f.rotation_deg, &key)?;
            let name = match &f.name {
                Some(n) => n.get_ref().clone(),
                None => p.file_name().map_or_else(
                    || f.file.get_ref().clone(),
                    |n| n.to_string_lossy().into_owned(),
                ),
            };
            let span = f.name.as_ref().map_or(f.file.span(), |n| n.span());
            if fixtures.iter().any(|g| g.name() == name) {
                return Err(ctx.err(span, format!("fixture name '{name}' given twice")));
            }
            fixtures.push(
                Fixture::try_new(&name, mesh)
                    .map_err(|e| ctx.err(f.file.span(), format!("{key}: {e}")))?,
            );
        }
        let design = match &file.design {
            Some(d) => {
                if let Some(n) = &d.name {
                    return Err(ctx.err(
                        n.span(),
                        "design.name does not apply (only fixtures have names)",
                    ));
                }
                let (p, mesh) =
                    ctx.mesh(dir, &d.file, &d.position, &d.rotation_deg, "design.file")?;
                let model = DesignModel::try_new(mesh).map_err(|e| {
                    ctx.err(d.file.span(), format!("design.file: {}: {e}", p.display()))
                })?;
                Some((p, model))
            }
            None => None,
        };
        // Sweep.
        let bound = match &file.sweep.rotary_step_bound_mm {
            Some(v) => {
                let b = ctx.positive(v, "rotary_step_bound_mm")?;
                if b > 1.0 {
                    return Err(ctx.err(v.span(), "rotary_step_bound_mm must be at most 1 mm"));
                }
                b
            }
            None => tol::ROTARY_STEP_BOUND,
        };
        let scanner = match &file.scanner {
            Some(s) => Some(scanner_config(&ctx, s)?),
            None => None,
        };
        let study = {
            let f = file.study.as_ref();
            let pick = |v: Option<&Spanned<Real>>,
                        what: &str,
                        default: Real|
             -> Result<Real, SceneError> {
                match v {
                    Some(v) => {
                        let x = ctx.finite(v, what)?;
                        if x < 0.0 {
                            return Err(ctx.err(v.span(), format!("{what} must not be negative")));
                        }
                        Ok(x)
                    }
                    None => Ok(default),
                }
            };
            let trials = match f.and_then(|f| f.trials.as_ref()) {
                Some(t) if *t.get_ref() == 0 || *t.get_ref() > 10_000 => {
                    return Err(ctx.err(t.span(), "study trials must be 1 to 10000"));
                }
                Some(t) => *t.get_ref(),
                None => 20,
            };
            StudyOptions {
                trials,
                correlation_mm: pick(
                    f.and_then(|f| f.correlation_mm.as_ref()),
                    "correlation_mm",
                    0.5,
                )?,
                translation_sigma_mm: pick(
                    f.and_then(|f| f.translation_sigma_mm.as_ref()),
                    "translation_sigma_mm",
                    0.02,
                )?,
                rotation_sigma_rad: pick(
                    f.and_then(|f| f.rotation_sigma_rad.as_ref()),
                    "rotation_sigma_rad",
                    5e-5,
                )?,
            }
        };
        let view = match file.report.as_ref().and_then(|r| r.view.as_ref()) {
            Some(v) => report_view(&ctx, v)?,
            None => None,
        };
        let identify = match &file.identify {
            Some(f) => identify_setup(&ctx, &chain, f)?,
            None => IdentifySetup::none(),
        };
        let mut file_keys = Vec::new();
        let mut name_file = |key: &str, f: &Spanned<String>| {
            let path = dir.join(f.get_ref());
            let (line, column) = line_col(text, f.span().start);
            file_keys.push(FileKey {
                key: key.to_string(),
                path: path.clone(),
                line,
                column,
            });
            path
        };
        let program_path = name_file("program", &file.program);
        let mut nc_files = NcFiles::default();
        if let Some(nc) = &file.nc {
            let mut resolve =
                |key: &str, f: &Option<Spanned<String>>| f.as_ref().map(|f| name_file(key, f));
            nc_files.tool_table = resolve("nc.tool_table", &nc.tool_table);
            nc_files.var_file = resolve("nc.var_file", &nc.var_file);
            nc_files.ini = resolve("nc.ini", &nc.ini);
            if let Some(n) = &nc.max_idle_blocks {
                if *n.get_ref() == 0 {
                    return Err(ctx.err(
                        n.span(),
                        "nc.max_idle_blocks: got 0, expected 1 or more lines",
                    ));
                }
                nc_files.max_idle_blocks = Some(*n.get_ref());
            }
            if let Some(u) = &nc.external_units {
                nc_files.external_unit = match u.get_ref().as_str() {
                    "mm" => LengthUnit::Mm,
                    "inch" => LengthUnit::Inch,
                    other => {
                        return Err(ctx.err(
                            u.span(),
                            format!("nc.external_units must be 'mm' or 'inch', got '{other}'"),
                        ));
                    }
                };
            }
        }
        Ok(Scene {
            path: path.to_path_buf(),
            name,
            machine_name,
            program_path,
            nc_files,
            file_keys,
            chain,
            injected,
            model,
            known,
            home,
            tool,
            stock_box,
            stock_shape,
            holder,
            fixtures,
            design,
            pitch_mm,
            memory: memory.clone(),
            sweep: SweepOptions {
                rotary_step_bound_mm: bound,
            },
            scanner,
            faces: identify.faces,
            parameters: identify.parameters,
            registration: identify.registration,
            monte_carlo_trials: identify.monte_carlo_trials,
            monte_carlo_seed: identify.monte_carlo_seed,
            loop_tolerance_mm: identify.loop_tolerance_mm,
            study,
            face_options: identify.face_options,
            view,
            hexapod,
            accept_misfit: false,
        })
    }
}

impl Scene {
    /// The machine the sweep drives: the hexapod pose by pose, or the deviated chain.
    pub fn kinematics(&self) -> Kinematics<'_> {
        match &self.hexapod {
            Some(twin) => Kinematics::Poses(twin),
            None => Kinematics::Chain(&self.chain),
        }
    }

    /// Reads a file the scene names; one that cannot be read is reported at the scene's
    /// line and column of its key (`scene.toml:2:11: program: p.ngc: cannot read: …`).
    fn read_named(&self, path: &Path) -> Result<String, SceneError> {
        read_text(path).map_err(
            |e| match (e, self.file_keys.iter().find(|k| k.path == path)) {
                (SceneError::Io { path, source }, Some(k)) => SceneError::Invalid {
                    path: self.path.clone(),
                    line: k.line,
                    column: k.column,
                    message: format!("{}: {}: cannot read: {source}", k.key, path.display()),
                },
                (e, _) => e,
            },
        )
    }

    /// Reads and parses the scene's NC program, checking that it drives only axes the
    /// machine has.
    pub fn load_program(&self) -> Result<Program, SceneError> {
        let text = self.read_named(&self.program_path)?;
        self.program_from_text(&text)
    }

    /// Parses `text` as the scene's NC program (with the scene's `[nc]` files), checking
    /// that it drives only axes the machine has; messages name the scene's program file.
    pub fn program_from_text(&self, text: &str) -> Result<Program, SceneError> {
        let f = &self.nc_files;
        let read = |p: &Option<PathBuf>| p.as_ref().map(|p| self.read_named(p)).transpose();
        let (table, var, ini) = (read(&f.tool_table)?, read(&f.var_file)?, read(&f.ini)?);
        let opts = options_from_texts(
            table.as_deref().zip(f.tool_table.as_deref()),
            var.as_deref().zip(f.var_file.as_deref()),
            ini.as_deref().zip(f.ini.as_deref()),
            f.external_unit,
        )
        .map_err(SceneError::Program)?;
        let program = interpret_program(
            text,
            &self.program_path,
            InterpOptions {
                start: self.home,
                max_idle_blocks: f.max_idle_blocks.unwrap_or(opts.max_idle_blocks),
                ..opts
            },
        )
        .map_err(SceneError::Program)?;
        if let Some(letter) = program.axes_used.iter().find(|l| !self.chain.has_axis(**l)) {
            let line = program
                .moves
                .iter()
                .find(|m| m.start.get(*letter) != m.end.get(*letter))
                .map_or(1, |m| m.line);
            let col = text
                .lines()
                .nth(line - 1)
                .and_then(|l| l.to_ascii_uppercase().find(letter.as_char()))
                .map_or(1, |c| c + 1);
            return Err(SceneError::Invalid {
                path: self.program_path.clone(),
                line,
                column: col,
                message: format!(
                    "the machine '{}' has no {} axis",
                    self.machine_name,
                    letter.as_char()
                ),
            });
        }
        Ok(program)
    }
}

/// A scene file (TOML text) for a designed test: the machine, deviations, tool, sweep and
/// face options of `scene`, the design's bar as stock, a scanner on a turntable about the
/// rotary axis (four views at the bar's corners, the camera 30° off the axis so that faces
/// across the bar's +x end are seen too), the design's faces and the parameters.
pub fn design_scene_toml(
    scene: &Scene,
    design: &crate::calibration::design::Design,
    opts: &crate::calibration::design::DesignOptions,
    parameters: &[String],
    name: &str,
    program_file: &str,
) -> Result<String, SceneError> {
    use std::fmt::Write as _;
    let sc = scene.scanner_for("design")?;
    let mut s = String::new();
    let v = |p: &Vector3| format!("[{}, {}, {}]", p.x, p.y, p.z);
    let _ = writeln!(
        s,
        "# Test cuts designed by twinmill for: {}",
        parameters.join(", ")
    );
    let _ = writeln!(s, "name = \"{name}\"\nprogram = \"{program_file}\"\n");
    let _ = writeln!(s, "[machine]\nname = \"{}\"\naxes = [", scene.machine_name);
    for a in scene.chain.axes() {
        let kind = match a.kind {
            AxisKind::Linear => "linear",
            AxisKind::Rotary => "rotary",
        };
        let _ = writeln!(
            s,
            "  {{ name = \"{}\", kind = \"{kind}\", direction = {}, origin = {} }},",
            a.letter.as_char(),
            v(&a.direction.into_inner()),
            v(&a.origin.coords)
        );
    }
    let spindle = scene.chain.joint_name(scene.chain.axes().len() - 1);
    let _ = writeln!(s, "]\nspindle = \"{}\"", &spindle[1..]);
    let _ = writeln!(s, "home = {{ Z = {}, A = 0 }}\n", opts.safe_z_mm);
    // The simulated machine carries only the requested deviations: one outside them is held
    // at zero by the identification, so its faces could not fit (the misfit refusal), and
    // the promise is made on a scan the requested model can produce.
    let _ = writeln!(s, "[deviations]");
    for (k, val) in &scene.injected {
        if parameters.iter().any(|p| p == k) {
            let _ = writeln!(s, "{k} = {val:e}");
        } else {
            let _ = writeln!(
                s,
                "# {k} = {val:e} (not simulated: not among the parameters)"
            );
        }
    }
    use crate::cutting::tool::ToolSizes;
    let tool_fields = match scene.tool.sizes() {
        ToolSizes::Plain { diameter } => format!(
            "kind = \"{}\"\ndiameter_mm = {diameter}",
            if scene.tool.kind() == crate::cutting::tool::ToolKind::Ball {
                "ball"
            } else {
                "flat"
            }
        ),
        ToolSizes::BullNose {
            diameter,
            corner_radius,
        } => format!(
            "kind = \"bull_nose\"\ndiameter_mm = {diameter}\ncorner_radius_mm = {corner_radius}"
        ),
        ToolSizes::TaperedFlat {
            tip_diameter,
            half_angle_deg,
        } => format!(
            "kind = \"tapered_flat\"\ndiameter_mm = {tip_diameter}\ntaper_half_angle_deg = {half_angle_deg}"
        ),
        ToolSizes::TaperedBall {
            ball_diameter,
            half_angle_deg,
        } => format!(
            "kind = \"tapered_ball\"\ndiameter_mm = {ball_diameter}\ntaper_half_angle_deg = {half_angle_deg}"
        ),
        ToolSizes::Profile => format!(
            "# a general profile cannot be written back; its enclosing flat tool:\nkind = \"flat\"\ndiameter_mm = {}",
            2.0 * scene.tool.radius()
        ),
    };
    let st = opts.stock();
    let _ = writeln!(
        s,
        "\n[tool]\n{tool_fields}\nlength_mm = {}\n",
        scene.tool.length()
    );
    let _ = writeln!(
        s,
        "[stock]\nmin = {}\nmax = {}\npitch_mm = {}\n",
        v(&st.min.coords),
        v(&st.max.coords),
        scene.pitch_mm
    );
    let _ = writeln!(
        s,
        "[sweep]\nrotary_step_bound_mm = {}\n",
        scene.sweep.rotary_step_bound_mm
    );
    let dist = 0.5 * (sc.working_range_mm.0 + sc.working_range_mm.1);
    let (sn, cs) = SCANNER_TILT_DEG.to_radians().sin_cos();
    let _ = writeln!(
        s,
        "[scanner]\nposition = [{}, 0.0, {}]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]",
        dist * sn,
        dist * cs
    );
    let _ = writeln!(
        s,
        "baseline_mm = {}\nfov_mm = [{}, {}]\npitch_mm = {}\nnoise_sigma_mm = {}",
        sc.baseline_mm,
        opts.length_mm * 1.5,
        opts.half_section_mm * 5.0,
        sc.pitch_mm,
        sc.noise_sigma_mm
    );
    let _ = writeln!(
        s,
        "working_range_mm = [{}, {}]\ngrazing_limit_deg = {}\nseed = {}",
        sc.working_range_mm.0, sc.working_range_mm.1, sc.grazing_limit_deg, sc.seed
    );
    let _ = writeln!(
        s,
        "turntable = {{ axis_point = [0.0, 0.0, 0.0], axis = [1.0, 0.0, 0.0], angles_deg = [45.0, 135.0, 225.0, 315.0] }}\n"
    );
    let _ = writeln!(s, "[identify]\nfaces = [");
    for f in &design.faces {
        let _ = writeln!(
            s,
            "  {{ name = \"{}\", line = {}, kind = \"{}\" }},",
            f.name,
            f.line,
            crate::calibration::design::kind_name(f.kind)
        );
    }
    let _ = writeln!(
        s,
        "]\nparameters = [{}]\nregistration = \"estimate\"\nmargin_mm = {}\nband_mm = {}",
        parameters
            .iter()
            .map(|p| format!("\"{p}\""))
            .collect::<Vec<_>>()
            .join(", "),
        scene.face_options.margin_mm,
        scene.face_options.band_mm
    );
    let _ = writeln!(s, "known = {{}}");
    Ok(s)
}

/// How far the designed scene's camera leans from the rotary axis's normal towards +x
/// (degrees): enough to see the faces across the bar's +x end at 60° incidence.
const SCANNER_TILT_DEG: Real = 30.0;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_col_counts_from_one() {
        assert_eq!(line_col("ab\ncd", 0), (1, 1));
        assert_eq!(line_col("ab\ncd", 4), (2, 2));
    }

    #[test]
    fn memory_sizes_parse_in_powers_of_1024_and_bad_ones_are_refused() {
        for (text, bytes) in [
            ("2G", 2.0 * 1073741824.0),
            ("1.5GiB", 1.5 * 1073741824.0),
            ("512M", 512.0 * 1048576.0),
            ("64 kb", 64.0 * 1024.0),
            ("1T", 1099511627776.0),
            ("1000", 1000.0),
            ("1000B", 1000.0),
        ] {
            let b = MemoryBudget::parse(text).expect(text);
            assert_eq!(b.bytes, bytes, "{text}");
            assert!(b.source.contains(text.trim()), "{}", b.source);
        }
        for bad in [
            "", "G", "0", "-1G", "nan", "inf", "1e400", "1e300T", "2X", "1.5.2M", "½G",
        ] {
            let e = MemoryBudget::parse(bad).expect_err(bad);
            assert!(e.starts_with("--memory:") && !e.contains('\n'), "{e}");
        }
    }

    /// The default budget is a fixed fraction of the installed memory, read each time the
    /// same: it does not follow what is free at the moment.
    #[test]
    fn the_default_budget_is_half_the_installed_memory() {
        let a = MemoryBudget::installed();
        assert_eq!(INSTALLED_MEMORY_FRACTION, 0.5);
        assert!(a.bytes.is_finite() && a.bytes > 0.0);
        assert_eq!(MemoryBudget::installed(), a);
        assert!(a.source.contains("installed"), "{}", a.source);
    }
}
