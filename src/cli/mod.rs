//! **The command line's arguments**, one file per verb (in pipeline order: `nc`, `simulate`,
//! `scan`, `measure`, `evaluate`, `fit`, `identify`, `design`, `correct`, `run`, `study`,
//! `hexapod`): each turns its arguments into the library's plain requests, calls
//! [`twinmill::pipeline`] (or the stage it needs), writes the outcome through
//! [`twinmill::output`] and prints it. This folder belongs to the binary crate: the library
//! cannot name it, so no arrow can point from the pipeline back to the command line. What
//! the verbs share is here: the scene's common options, loading a scene for a verb (and the
//! one-line refusal of a verb that does not apply to the scene's machine), printing, the
//! progress bars, and the number parsers of the hexapod's options.

pub mod nc;
pub mod simulate;
pub mod scan;
pub mod measure;
pub mod evaluate;
pub mod fit;
pub mod identify;
pub mod design;
pub mod correct;
pub mod run;
pub mod study;
pub mod hexapod;

use indicatif::{ProgressBar, ProgressStyle};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Mutex;
use twinmill::nc::Program;
use twinmill::output::{json_bytes, ply_bytes, write_files};
use twinmill::progress::Progress;
use twinmill::scene::{Machine, MemoryBudget, Need, Scene, SceneError};

/// `--accept-misfit`, set once from the command line before any verb runs; every scene a
/// verb loads takes it.
static ACCEPT_MISFIT: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Sets `--accept-misfit` for the verb about to run.
pub fn set_accept_misfit(accept: bool) {
    ACCEPT_MISFIT.store(accept, std::sync::atomic::Ordering::Relaxed);
}

/// `--accept-misfit`: keep an identification whose residuals the stated noise cannot explain.
pub fn accept_misfit() -> bool {
    ACCEPT_MISFIT.load(std::sync::atomic::Ordering::Relaxed)
}

/// What the scene verbs (`simulate`, `scan`, `identify`, `design`, `run`) share.
#[derive(clap::Args)]
pub struct SceneArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,
    /// Folder for outputs: run writes <out>/<scene name>/, the other verbs
    /// <out>/<scene name>-<verb>/ (correct: <out>/<scene name>-corrected.ngc, …).
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Print the report as JSON on stdout instead of the summary.
    #[arg(long)]
    pub json: bool,
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// List every problem found in the NC program, not only the first.
    #[arg(short, long)]
    pub verbose: bool,
    /// Memory the tri-dexel stock may use, e.g. 2G, 512M, 1.5GiB (default: half the
    /// installed memory).
    #[arg(long, value_name = "SIZE")]
    pub memory: Option<String>,
    /// Replace the machine's deviations, error motions and reversals by an identified
    /// machine's (the file `identify --measurement … --deviations-out` writes): the twin
    /// simulates it and correct's model is it.
    #[arg(long, value_name = "FILE")]
    pub deviations: Option<PathBuf>,
    /// A hexapod: run its controller on these calibrated parameters (the `[controller]` file
    /// `identify … --corrected` writes) instead of the scene's.
    #[arg(long, value_name = "FILE")]
    pub controller: Option<PathBuf>,
}

/// A scene loaded for a verb: a serial machine's scene with its program, or a hexapod's
/// scene file (the verb loads what it needs of it).
pub enum Loaded {
    /// A serial chain (or a hexapod that cuts, for `simulate`) and its program.
    Serial(Box<Scene>, Program),
    /// A hexapod scene.
    Hexapod(PathBuf),
}

/// Sets the thread count (once per process).
pub fn set_threads(threads: Option<usize>) -> Result<(), ExitCode> {
    if let Some(n) = threads
        && let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global()
    {
        return Err(fail(e));
    }
    Ok(())
}

/// Sets the thread count, loads the scene, and for a serial machine checks that it has what
/// `command` needs and loads its program. A hexapod scene comes back unloaded, except for
/// `simulate` and `correct`, which cut a hexapod scene's program.
pub fn load(a: &SceneArgs, command: &str, needs: &[Need]) -> Result<Loaded, ExitCode> {
    set_threads(a.threads)?;
    let budget = match &a.memory {
        Some(m) => MemoryBudget::parse(m).map_err(fail)?,
        None => MemoryBudget::installed(),
    };
    let scene = match Scene::load_with(&a.scene, &budget) {
        Err(SceneError::Hexapod { .. }) if matches!(command, "simulate" | "correct") => {
            let mut s = Scene::load_hexapod_cut(&a.scene, &budget).map_err(fail)?;
            if let Some(c) = &a.controller {
                s.apply_controller_file(c).map_err(fail)?;
            }
            s
        }
        Err(SceneError::Hexapod { path }) => {
            return match &a.deviations {
                Some(d) => Err(refuse_deviations(&path, d)),
                None => Ok(Loaded::Hexapod(path)),
            };
        }
        r => r.map_err(fail)?,
    };
    let mut scene = Scene {
        accept_misfit: accept_misfit(),
        ..scene
    };
    if let (Some(c), Machine::Serial(_)) = (&a.controller, &scene.machine) {
        return Err(refuse_controller(&scene.path, c));
    }
    if let Some(d) = &a.deviations {
        scene.apply_deviations_file(d).map_err(fail)?;
    }
    scene.require(command, needs).map_err(fail)?;
    let program = match scene.load_program() {
        Ok(p) => p,
        Err(SceneError::Program(e)) if a.verbose => {
            let _ = write!(std::io::stderr(), "{}", e.full_report());
            return Err(fail(e));
        }
        Err(e) => return Err(fail(e)),
    };
    Ok(Loaded::Serial(Box::new(scene), program))
}

/// The one-line refusal of `--controller` on a serial scene.
pub fn refuse_controller(scene: &Path, controller: &Path) -> ExitCode {
    fail(format!(
        "{}: --controller gives a hexapod controller's calibrated parameters; {} is a serial machine (its identified deviations go with --deviations)",
        controller.display(),
        scene.display()
    ))
}

/// The one-line refusal of `--deviations` on a hexapod scene.
pub fn refuse_deviations(scene: &Path, deviations: &Path) -> ExitCode {
    fail(format!(
        "{}: --deviations replaces a serial machine's deviations; {} is a hexapod scene",
        deviations.display(),
        scene.display()
    ))
}

/// The scene's serial machine only (no program, no stock), with `--deviations` applied:
/// for the verbs that use the machine alone.
pub fn load_machine(a: &SceneArgs, command: &str, why: &str) -> Result<Scene, ExitCode> {
    set_threads(a.threads)?;
    let budget = MemoryBudget {
        bytes: f64::INFINITY,
        source: format!("{command} builds no stock"),
    };
    let mut scene = match Scene::load_with(&a.scene, &budget) {
        Err(SceneError::Hexapod { path }) => return Err(refuse_hexapod(&path, command, why)),
        r => r.map_err(fail)?,
    };
    scene.accept_misfit = accept_misfit();
    if let Some(c) = &a.controller {
        return Err(refuse_controller(&scene.path, c));
    }
    if let Some(d) = &a.deviations {
        scene.apply_deviations_file(d).map_err(fail)?;
    }
    Ok(scene)
}

/// [`load`] for a verb that does not apply to a hexapod: refuses one in one line, `why`.
pub fn prepare(
    a: &SceneArgs,
    command: &str,
    needs: &[Need],
    why: &str,
) -> Result<(Scene, Program), ExitCode> {
    match load(a, command, needs)? {
        Loaded::Serial(scene, program) => Ok((*scene, program)),
        Loaded::Hexapod(path) => Err(refuse_hexapod(&path, command, why)),
    }
}

/// The one-line refusal of `command` on a hexapod scene, saying `why`.
pub fn refuse_hexapod(path: &Path, command: &str, why: &str) -> ExitCode {
    fail(format!(
        "{}: `{command}` does not apply to a hexapod ([machine] kind = \"hexapod\"): {why}",
        path.display()
    ))
}

/// Prints `text` (or `json`) on stdout.
pub fn print_out(
    text: impl FnOnce() -> String,
    json: Option<Result<String, serde_json::Error>>,
) -> ExitCode {
    let mut stdout = std::io::stdout().lock();
    let printed = match json {
        Some(j) => j
            .map_err(std::io::Error::other)
            .and_then(|s| writeln!(stdout, "{s}")),
        None => write!(stdout, "{}", text()),
    };
    match printed {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fail(e),
    }
}

/// Prints `twinmill: error: MESSAGE` on one line (a line break inside the message, from a
/// file's text or a library's, is printed as a space) and returns the failure exit code.
pub fn fail(msg: impl std::fmt::Display) -> ExitCode {
    let msg: String = msg
        .to_string()
        .trim_end()
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    let _ = writeln!(std::io::stderr(), "twinmill: error: {msg}");
    ExitCode::FAILURE
}

/// Writes `bytes` to `path`, or says why not.
pub fn write(path: &Path, bytes: &[u8]) -> Result<(), String> {
    twinmill::output::write_file(path, bytes).map_err(|e| e.to_string())
}

/// Progress bars on stderr when it is a terminal.
pub struct Bars {
    bar: Mutex<Option<ProgressBar>>,
    enabled: bool,
}

impl Progress for Bars {
    fn start(&self, stage: &str, total: u64) {
        if !self.enabled {
            return;
        }
        let bar = ProgressBar::new(total);
        if let Ok(style) =
            ProgressStyle::with_template("{prefix:>8} [{bar:40}] {pos}/{len} {elapsed}")
        {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_prefix(stage.to_string());
        if let Ok(mut b) = self.bar.lock() {
            *b = Some(bar);
        }
    }
    fn advance(&self, n: u64) {
        if let Ok(b) = self.bar.lock()
            && let Some(bar) = b.as_ref()
        {
            bar.inc(n);
        }
    }
    fn finish(&self) {
        if let Ok(mut b) = self.bar.lock()
            && let Some(bar) = b.take()
        {
            bar.finish_and_clear();
        }
    }
}

/// Progress bars, unless the output is JSON or stderr is not a terminal.
pub fn bars(json: bool) -> Bars {
    Bars {
        bar: Mutex::new(None),
        enabled: !json && std::io::stderr().is_terminal(),
    }
}

/// Writes a JSON report, the point cloud (`cloud.ply`) and the page (`report.html`) into
/// `dir`, all or nothing.
pub fn write_report_and_cloud(
    dir: &Path,
    report_name: &str,
    report: &impl serde::Serialize,
    cloud: &twinmill::metrology::cloud::PointCloud,
    html: String,
) -> Result<PathBuf, twinmill::output::OutputError> {
    let files = vec![
        (report_name, json_bytes(report, &dir.join(report_name))?),
        ("cloud.ply", ply_bytes(cloud, &dir.join("cloud.ply"))?),
        ("report.html", html.into_bytes()),
    ];
    write_files(dir, &files)
}

/// `n` finite comma-separated numbers.
pub fn numbers(text: &str, n: usize, what: &str) -> Result<Vec<f64>, String> {
    let v: Result<Vec<f64>, _> = text.split(',').map(|t| t.trim().parse::<f64>()).collect();
    match v {
        Ok(v) if v.len() == n && v.iter().all(|x| x.is_finite()) => Ok(v),
        _ => Err(format!(
            "--{what} needs {n} finite comma-separated numbers, got '{text}'"
        )),
    }
}

/// `--procedure` of the hexapod's calibration: jig-free or ball-plate (default).
pub fn procedure_arg(
    name: Option<&str>,
) -> Result<twinmill::calibration::hexapod_calibrate::Procedure, String> {
    use twinmill::calibration::hexapod_calibrate::Procedure;
    match name {
        None => Ok(Procedure::BallPlate),
        Some(p) => Procedure::from_name(p)
            .ok_or_else(|| format!("--procedure must be jig-free or ball-plate, got '{p}'")),
    }
}
