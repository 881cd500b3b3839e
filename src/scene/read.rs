//! The one reader: a scene file's text parsed once into [`SceneFile`], its `[machine]` read
//! by kind ([`super::machine`], [`super::hexapod`]), then the sections every scene that cuts
//! shares ([`super::cut`], [`super::scanner`], [`super::identify`], [`super::report`],
//! [`super::program`]).

use super::Ctx;
use super::Need;
use super::Scene;
use super::SceneError;
use super::cut::read_cut;
use super::file::{
    HexapodMachineFile, Required, SceneFile, SerialMachineFile, StockFile, ToolFile,
    machine_controller_at, machine_kind, machine_kind_at,
};
use super::hexapod::{HexapodScene, read_hexapod};
use super::identify::{IdentifySetup, identify_setup};
use super::machine::{Machine, read_serial};
use super::memory::MemoryBudget;
use super::program::named_files;
use super::read_text;
use super::report::report_view;
use super::scanner::{scanner_config, study_options};
use super::toml_error;
use crate::metrology::scan::ScannerConfig;
use serde::de::DeserializeOwned;
use std::path::Path;
use toml::Spanned;

/// Parses scene text as a [`SceneFile`] whose `[machine]` is an `M`; a TOML or format error
/// names its line and column.
fn parse_file<M: DeserializeOwned>(ctx: &Ctx) -> Result<SceneFile<M>, SceneError> {
    toml::from_str(ctx.text).map_err(|e| toml_error(ctx.text, ctx.path, &e))
}

/// Refuses a `[machine] kind` that is neither machine, and a hexapod's `[machine]
/// controller` (a string: TCP mode), at its line and column, before the sections are read by
/// a kind's rules.
fn known_kind(ctx: &Ctx) -> Result<(), SceneError> {
    match machine_kind_at(ctx.text) {
        Some(k) if !["serial", "hexapod"].contains(&k.get_ref().as_str()) => Err(ctx.err(
            k.span(),
            format!(
                "machine.kind: got \"{}\", expected \"serial\" or \"hexapod\"",
                k.get_ref()
            ),
        )),
        Some(k) if k.get_ref() == "hexapod" => match machine_controller_at(ctx.text) {
            Some(c) => Err(ctx.err(
                c.span(),
                "machine.controller applies to serial machines: a hexapod's program is \
                 already Cartesian (the tool's pose), its controller's kinematics turn it into \
                 strut lengths",
            )),
            None => Ok(()),
        },
        _ => Ok(()),
    }
}

/// A serial scene's program, `[tool]` and `[stock]`: the first one missing is reported as
/// toml reports a missing field.
fn required<'f, M>(
    ctx: &Ctx,
    file: &'f SceneFile<M>,
) -> Result<(&'f Spanned<String>, &'f ToolFile, &'f StockFile), SceneError> {
    match (&file.program, &file.tool, &file.stock) {
        (Some(p), Some(t), Some(s)) => Ok((p, t, s)),
        _ => Err(match parse_file_required(ctx) {
            Err(e) => e,
            Ok(()) => ctx.err(
                0..0,
                "program, tool or stock: missing, expected a value for each of these keys",
            ),
        }),
    }
}

/// toml's own message on the first of program, `[machine]`, `[tool]`, `[stock]` missing.
fn parse_file_required(ctx: &Ctx) -> Result<(), SceneError> {
    toml::from_str::<Required>(ctx.text)
        .map(|_| ())
        .map_err(|e| toml_error(ctx.text, ctx.path, &e))
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
        known_kind(&ctx)?;
        if machine_kind(text).as_deref() == Some("hexapod") {
            return Err(SceneError::Hexapod {
                path: path.to_path_buf(),
            });
        }
        let file: SceneFile<SerialMachineFile> = parse_file(&ctx)?;
        let (program, tool, stock) = required(&ctx, &file)?;
        for (section, span) in [
            ("workspace", file.workspace.as_ref().map(Spanned::span)),
            ("drives", file.drives.as_ref().map(Spanned::span)),
            ("homing", file.homing.as_ref().map(Spanned::span)),
            ("table", file.table.as_ref().map(Spanned::span)),
            ("table_axes", file.table_axes.as_ref().map(Spanned::span)),
            (
                "controller",
                file.controller.values().next().map(Spanned::span),
            ),
        ] {
            if let Some(span) = span {
                return Err(ctx.err(
                    span,
                    format!(
                        "[{section}] applies to hexapod scenes only ([machine] kind = \"hexapod\")"
                    ),
                ));
            }
        }
        let machine = read_serial(&ctx, &file)?;
        finish(
            &ctx,
            &file,
            Machine::Serial(Box::new(machine)),
            (program, tool, stock),
            memory,
        )
    }

    /// Loads a hexapod scene that cuts (a program, tool and stock besides the machine): its
    /// machine is [`Machine::Hexapod`], which the sweep drives pose by pose, and the
    /// program's axes are the controller's Cartesian kinematics; the stock must fit in
    /// `memory`. Error motions, reversal, `[identify]`, fixtures and a holder are refused
    /// (no identification or collision checks on a hexapod).
    pub fn load_hexapod_cut(path: &Path, memory: &MemoryBudget) -> Result<Scene, SceneError> {
        let text = read_text(path)?;
        Self::parse_hexapod_cut(&text, path, memory)
    }

    /// [`Scene::load_hexapod_cut`] of scene text; `path` locates messages and relative file
    /// names.
    pub fn parse_hexapod_cut(
        text: &str,
        path: &Path,
        memory: &MemoryBudget,
    ) -> Result<Scene, SceneError> {
        let ctx = Ctx { path, text };
        known_kind(&ctx)?;
        let file: SceneFile<HexapodMachineFile> = parse_file(&ctx)?;
        let hex = read_hexapod(&ctx, &file)?;
        let (Some(program), Some(tool), Some(stock)) = (&file.program, &file.tool, &file.stock)
        else {
            let absent: Vec<&str> = [
                ("program", file.program.is_none()),
                ("tool", file.tool.is_none()),
                ("stock", file.stock.is_none()),
            ]
            .into_iter()
            .filter_map(|(k, absent)| absent.then_some(k))
            .collect();
            return Err(SceneError::Missing {
                path: path.to_path_buf(),
                command: "cutting on a hexapod".into(),
                what: format!(
                    "program, [tool] and [stock] (this scene has no {})",
                    absent.join(", ")
                ),
            });
        };
        let refuse = |span: Option<std::ops::Range<usize>>, what: &str| match span {
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
        let t = tool;
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
                program.span(),
                "[identify] does not apply to a hexapod scene (`twinmill simulate` cuts it)",
            ));
        }
        let machine = hex.cutting_machine(&ctx)?;
        finish(
            &ctx,
            &file,
            Machine::Hexapod(Box::new(machine)),
            (program, tool, stock),
            memory,
        )
    }
}

impl HexapodScene {
    /// Loads and validates a hexapod scene file (its machine and the hexapod sections; the
    /// sections of a scene that cuts are checked for their form only).
    pub fn load(path: &Path) -> Result<HexapodScene, SceneError> {
        let text = read_text(path)?;
        Self::parse(&text, path)
    }

    /// Parses and validates hexapod scene text; `path` locates messages.
    pub fn parse(text: &str, path: &Path) -> Result<HexapodScene, SceneError> {
        let ctx = Ctx { path, text };
        known_kind(&ctx)?;
        let file: SceneFile<HexapodMachineFile> = parse_file(&ctx)?;
        read_hexapod(&ctx, &file)
    }
}

/// The rest of a scene once its machine is read: tool, holder, stock, fixtures, design,
/// sweep, scanner, study, report, identification and the files it names.
fn finish<M>(
    ctx: &Ctx,
    file: &SceneFile<M>,
    machine: Machine,
    (program, tool, stock): (&Spanned<String>, &ToolFile, &StockFile),
    memory: &MemoryBudget,
) -> Result<Scene, SceneError> {
    let name = scene_name(ctx, file.name.as_ref())?;
    let cut = read_cut(ctx, file, tool, stock, memory)?;
    let scanner = match &file.scanner {
        Some(s) => Some(scanner_config(ctx, s)?),
        None => None,
    };
    let study = study_options(ctx, file.study.as_ref())?;
    let view = match file.report.as_ref().and_then(|r| r.view.as_ref()) {
        Some(v) => report_view(ctx, v)?,
        None => None,
    };
    let chain = match &machine {
        Machine::Serial(m) => &m.chain,
        Machine::Hexapod(h) => &h.command,
    };
    let identify = match &file.identify {
        Some(f) => identify_setup(ctx, chain, f)?,
        None => IdentifySetup::none(),
    };
    let (program_path, nc_files, file_keys) = named_files(ctx, program, file.nc.as_ref())?;
    Ok(Scene {
        path: ctx.path.to_path_buf(),
        name,
        machine,
        program_path,
        nc_files,
        file_keys,
        tool: cut.tool,
        stock_box: cut.stock_box,
        stock_shape: cut.stock_shape,
        holder: cut.holder,
        fixtures: cut.fixtures,
        design: cut.design,
        pitch_mm: cut.pitch_mm,
        memory: memory.clone(),
        sweep: cut.sweep,
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
        accept_misfit: false,
    })
}

#[cfg(test)]
mod tests {
    use super::super::line_col;
    use super::*;
    use serde::Deserialize;

    /// A serial scene needs a program, `[tool]` and `[stock]`: one that lacks any of them is
    /// refused where toml refuses a struct whose field is missing, naming the key in our
    /// words (the reader keeps them optional for hexapod scenes).
    #[test]
    fn a_serial_scene_without_program_tool_or_stock_is_refused_as_a_missing_field() {
        #[derive(Deserialize)]
        #[expect(dead_code, reason = "only toml's error matters")]
        struct Serial {
            program: String,
            machine: toml::Value,
            tool: toml::Value,
            stock: toml::Value,
        }
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/xyz-pocket.toml");
        let text = std::fs::read_to_string(&path).expect("scene");
        // The text without the line that starts with `start`, or without the section it
        // opens (up to the next section).
        let without = |start: &str| {
            let mut out = String::new();
            let mut skipping = false;
            for l in text.lines() {
                if l.starts_with(start) {
                    skipping = start.starts_with('[');
                    continue;
                }
                if skipping && l.starts_with('[') {
                    skipping = false;
                }
                if !skipping {
                    out.push_str(l);
                    out.push('\n');
                }
            }
            assert!(out.len() < text.len(), "{start} removed");
            out
        };
        let memory = MemoryBudget::parse("1G").expect("size");
        for (start, key) in [
            ("program = ", "program"),
            ("[tool]", "tool"),
            ("[stock]", "stock"),
        ] {
            let cut = without(start);
            let e = toml::from_str::<Serial>(&cut)
                .err()
                .expect("a missing field");
            let (line, column) = line_col(&cut, e.span().unwrap_or(0..0).start);
            assert!(e.message().contains(key), "{}", e.message());
            // in our words, as every TOML file's missing key is reported
            let want = format!("{key}: missing, expected a value for this key");
            match Scene::parse_with(&cut, &path, &memory) {
                Err(SceneError::Invalid {
                    line: l,
                    column: c,
                    message,
                    ..
                }) => assert_eq!((l, c, message), (line, column, want)),
                other => panic!("{key}: {:?}", other.map(|s| s.name)),
            }
        }
    }
}
