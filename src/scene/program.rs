//! The files a scene names besides meshes — the NC program and the `[nc]` tool table, var
//! file and INI — and the program read from them, checked against the machine's axes.

use super::Ctx;
use super::Scene;
use super::SceneError;
use super::file::NcFile;
use super::line_col;
use super::read_text;
use crate::machine::tcp::{self, Controller};
use crate::nc::{InterpOptions, LengthUnit, Program, interpret_program, options_from_texts};
use std::path::{Path, PathBuf};
use toml::Spanned;

/// Files that set up the interpreter for a scene's program (`[nc]`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NcFiles {
    /// LinuxCNC tool table.
    pub tool_table: Option<PathBuf>,
    /// LinuxCNC parameter (var) file.
    pub var_file: Option<PathBuf>,
    /// INI file (\[RS274NGC\] SUBROUTINE_PATH, DISABLE_FANUC_STYLE_SUB).
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

/// The program and `[nc]` files, resolved against the scene's folder, and where the scene
/// names each.
pub(super) fn named_files(
    ctx: &Ctx,
    program: &Spanned<String>,
    nc: Option<&NcFile>,
) -> Result<(PathBuf, NcFiles, Vec<FileKey>), SceneError> {
    let dir = ctx.path.parent().unwrap_or(Path::new("."));
    let mut file_keys = Vec::new();
    let mut name_file = |key: &str, f: &Spanned<String>| {
        let path = dir.join(f.get_ref());
        let (line, column) = line_col(ctx.text, f.span().start);
        file_keys.push(FileKey {
            key: key.to_string(),
            path: path.clone(),
            line,
            column,
        });
        path
    };
    let program_path = name_file("program", program);
    let mut nc_files = NcFiles::default();
    if let Some(nc) = nc {
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
    Ok((program_path, nc_files, file_keys))
}

impl Scene {
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
    /// With `[machine] controller = "tcp"` the program is a tool-centre-point one, started at
    /// the tip's position at home, and is returned as the joint moves its controller makes
    /// through the nominal chain ([`tcp::joint_program`]): every command downstream reads
    /// joint moves.
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
        let controller = self.controller();
        let nominal = self.chain().nominal();
        // A TCP controller starts where the tool tip is at home.
        let start = match controller {
            Controller::Joint => self.home(),
            Controller::Tcp => tcp::tcp_from_joint(&nominal, &self.home()),
        };
        let program = interpret_program(
            text,
            &self.program_path,
            InterpOptions {
                start,
                max_idle_blocks: f.max_idle_blocks.unwrap_or(opts.max_idle_blocks),
                ..opts
            },
        )
        .map_err(SceneError::Program)?;
        if let Some(letter) = program
            .axes_used
            .iter()
            .find(|l| !self.chain().has_axis(**l))
        {
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
                    self.machine_name(),
                    letter.as_char()
                ),
            });
        }
        match controller {
            Controller::Joint => Ok(program),
            Controller::Tcp => {
                tcp::joint_program(&nominal, &program).map_err(|e| SceneError::Invalid {
                    path: self.program_path.clone(),
                    line: e.line(),
                    column: 1,
                    message: format!("tool-centre-point program: {e}"),
                })
            }
        }
    }
}
