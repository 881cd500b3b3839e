//! **Scene files** (TOML), read once by one reader: the machine — a serial chain and its
//! deviations, or a hexapod (`[machine] kind`), held as a [`Machine`] variant — and the
//! tool, stock, program, scanner, identification, study and report sections. Also reads the
//! NC program the scene names, and the closed OBJ/STL meshes of a mesh stock, fixtures and
//! the design model (paths relative to the scene). May use every stage before it (math,
//! nc, machine, cutting, metrology, calibration, report) for the types a scene sets up.
//!
//! Every value is checked when the scene loads; an error names the file, line and column
//! of the offending value. TOML accepts `nan` and `inf`: they are rejected here.
//!
//! The folder, in reading order: `file` (the serde structs of the format), `check` (the
//! bounds of coordinates, angles and directions), `memory`
//! (the stock's memory budget), `machine` (a serial chain, and the [`Machine`] variants),
//! `deviations` (an identified machine's deviations file, `--deviations`, replacing a
//! serial machine's deviation model),
//! `hexapod` (a hexapod and its sections), `cut` (tool, holder, stock, fixtures, design
//! model, sweep), `scanner` (the virtual scanner and the scanner-effects study),
//! `identify` (`[identify]`), `report` (`[report]`), `program` (the files a scene
//! names and the program read from them), `read` (the one reader that puts them
//! together) and `write` (a scene written back for a designed test).
//!
//! **Invariant:** this folder and [`crate::output`] are the only modules that touch files;
//! a scene file is parsed once, whatever its machine kind.

mod file;
mod check;
mod memory;
mod machine;
mod deviations;
mod hexapod;
mod cut;
mod scanner;
mod identify;
mod report;
mod program;
mod read;
mod write;

pub use check::{
    DIRECTION_SCALE, MAX_ANGLE_DEG, MAX_COORDINATE_MM, MIN_AXIS_ANGLE_DEG, check_coordinate,
    check_direction,
};
pub use file::machine_kind;
pub use hexapod::{DEFAULT_TRIP_SIGMA_MM, Drives, HexapodScene, Table};
pub use identify::DEFAULT_LOOP_TOLERANCE_MM;
pub use machine::{HexapodMachine, Machine, SerialMachine};
pub use memory::{INSTALLED_MEMORY_FRACTION, MemoryBudget};
pub use program::{FileKey, NcFiles};
pub use write::design_scene_toml;

use crate::calibration::calibrate::Registration;
use crate::calibration::identify::{FaceOptions, FaceSpec};
use crate::cutting::collide::{Fixture, Holder};
use crate::cutting::shape::{ClosedMesh, Cylinder, read_obj, read_stl};
use crate::cutting::sweep::SweepOptions;
use crate::cutting::tool::Tool;
use crate::math::{Aabb, Real, UnitVector3, Vector3};
use crate::metrology::scan::{ScannerConfig, StudyOptions};
use crate::nc::NcError;
use crate::report::deviation_map::DesignModel;
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
    /// load it with [`HexapodScene`] (or, to cut it, [`Scene::load_hexapod_cut`]).
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

/// A loaded, validated scene that cuts: its machine, and the program, tool, stock and the
/// sections around them.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The scene file.
    pub path: PathBuf,
    /// Scene name (names the output folder).
    pub name: String,
    /// The machine: a serial chain or a hexapod, with its deviations.
    pub machine: Machine,
    /// The NC program file.
    pub program_path: PathBuf,
    /// `[nc]` tool table, var file and INI (resolved paths), and their length unit.
    pub nc_files: NcFiles,
    /// Where the scene names the program and the `[nc]` files (read by
    /// [`Scene::load_program`]).
    pub file_keys: Vec<FileKey>,
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
    /// Keep an identification whose residuals the stated noise cannot explain instead of
    /// refusing it ([`crate::calibration::goodness`]); its report then says so on its
    /// first line. Never read from the scene file: the command line's `--accept-misfit`.
    pub accept_misfit: bool,
}

/// Where messages point: the scene file and its text.
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

impl Ctx<'_> {
    /// An array of finite numbers (a hexapod's joints, ranges and poses).
    fn finite_array<const N: usize>(
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

    /// A range `[min, max]` of finite numbers with min ≤ max.
    fn range(&self, v: &Spanned<[Real; 2]>, what: &str) -> Result<(Real, Real), SceneError> {
        let [lo, hi] = self.finite_array(v, what)?;
        if lo <= hi {
            Ok((lo, hi))
        } else {
            Err(self.err(v.span(), format!("{what} [{lo}, {hi}] must have min ≤ max")))
        }
    }

    /// A direction that is not zero, or `default`.
    fn axis(
        &self,
        v: &Option<Spanned<[Real; 3]>>,
        what: &str,
        default: UnitVector3,
    ) -> Result<UnitVector3, SceneError> {
        let Some(v) = v else { return Ok(default) };
        check_direction(*v.get_ref(), &format!("machine.{what}")).map_err(|e| self.err(v.span(), e))
    }

    /// Finite coordinates (mm), each within [`MAX_COORDINATE_MM`].
    fn coordinates<const N: usize>(
        &self,
        v: &Spanned<[Real; N]>,
        what: &str,
    ) -> Result<[Real; N], SceneError> {
        let a = self.finite_array(v, what)?;
        for c in a {
            check_coordinate(c, what).map_err(|e| self.err(v.span(), e))?;
        }
        Ok(a)
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_col_counts_from_one() {
        assert_eq!(line_col("ab\ncd", 0), (1, 1));
        assert_eq!(line_col("ab\ncd", 4), (2, 2));
    }
}
