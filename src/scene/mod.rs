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
//! The folder, in reading order: [`file`] (the serde structs of the format), [`memory`]
//! (the stock's memory budget), [`machine`] (a serial chain, and the [`Machine`] variants),
//! [`hexapod`] (a hexapod and its sections), [`cut`] (tool, holder, stock, fixtures, design
//! model, sweep), [`scanner`] (the virtual scanner and the scanner-effects study),
//! [`identify`] (`[identify]`), [`report`] (`[report]`), [`program`] (the files a scene
//! names and the program read from them), [`read`] (the one reader that puts them
//! together) and [`write`] (a scene written back for a designed test).
//!
//! **Invariant:** this folder and [`crate::output`] are the only modules that touch files;
//! a scene file is parsed once, whatever its machine kind.

mod file;
mod memory;
mod machine;
mod hexapod;
mod cut;
mod scanner;
mod identify;
mod report;
mod program;
mod read;
mod write;

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
use crate::math::{Aabb, Real, UnitVector3, Vector3, tol};
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
        let a = Vector3::from(self.finite_array(v, what)?);
        UnitVector3::try_new(a, tol::LENGTH_EPS)
            .ok_or_else(|| self.err(v.span(), format!("{what} must not be zero")))
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
