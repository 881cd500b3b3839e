//! The `twinmill` command line: parses arguments, calls the library, prints, picks the exit
//! code. Nothing else happens here.

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Mutex;
use twinmill::nc::Program;
use twinmill::output::{json_bytes, ply_bytes, write_files, write_outcome};
use twinmill::pipeline::{machine_part, run, scanner_study};
use twinmill::progress::Progress;
use twinmill::report::{ScanFileReport, ScanReport};
use twinmill::scene::{Scene, SceneError};

/// twinmill: a digital twin of machine-tool accuracy.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a scene's program on its deviated machine, scan the part, fit the faces and
    /// identify the deviations; write report.json, cloud.ply and faces.png.
    Run {
        /// The scene file (TOML).
        scene: PathBuf,
        /// Folder for outputs; they go to <out>/<scene name>/.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Print the report as JSON on stdout instead of the summary.
        #[arg(long)]
        json: bool,
        /// Worker threads (default: all cores). Results do not depend on it.
        #[arg(long)]
        threads: Option<usize>,
        /// List every problem found in the NC program, not only the first.
        #[arg(short, long)]
        verbose: bool,
    },
    /// Simulate the scene's program and scan the part with the scene's scanner (all views);
    /// write cloud.ply and scan.json. With --study, also scan it again and again with each
    /// scanner effect alone and together, and report how the identified offset moves.
    Scan {
        /// The scene file (TOML).
        scene: PathBuf,
        /// Folder for outputs; they go to <out>/<scene name>-scan/.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Print scan.json on stdout instead of the summary.
        #[arg(long)]
        json: bool,
        /// Worker threads (default: all cores). Results do not depend on it.
        #[arg(long)]
        threads: Option<usize>,
        /// Run the scanner-effects study with N seeded trials per case (default: the
        /// scene's [study] trials, 20 if not given).
        #[arg(long, num_args = 0..=1, default_missing_value = "0", value_name = "N")]
        study: Option<usize>,
        /// List every problem found in the NC program, not only the first.
        #[arg(short, long)]
        verbose: bool,
    },
}

/// Sets the thread count, loads the scene and its program.
fn prepare(
    scene: &Path,
    threads: Option<usize>,
    verbose: bool,
) -> Result<(Scene, Program), ExitCode> {
    if let Some(n) = threads
        && let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global()
    {
        return Err(fail(e));
    }
    let scene = Scene::load(scene).map_err(fail)?;
    let program = match scene.load_program() {
        Ok(p) => p,
        Err(SceneError::Program(e)) if verbose => {
            let _ = write!(std::io::stderr(), "{}", e.full_report());
            return Err(fail(e));
        }
        Err(e) => return Err(fail(e)),
    };
    Ok((scene, program))
}

/// Prints `text` (or `json`) on stdout.
fn print_out(
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

/// Progress bars on stderr when it is a terminal.
struct Bars {
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

fn fail(msg: impl std::fmt::Display) -> ExitCode {
    let _ = writeln!(std::io::stderr(), "twinmill: error: {msg}");
    ExitCode::FAILURE
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Run {
            scene,
            out,
            json,
            threads,
            verbose,
        } => {
            let (scene, program) = match prepare(&scene, threads, verbose) {
                Ok(x) => x,
                Err(code) => return code,
            };
            let bars = bars(json);
            let outcome = match run(&scene, &program, &bars) {
                Ok(o) => o,
                Err(e) => return fail(e),
            };
            let dir = out.join(&scene.name);
            if let Err(e) = write_outcome(&outcome, &dir) {
                return fail(e);
            }
            print_out(
                || {
                    format!(
                        "{}  wrote         {}/{{report.json, cloud.ply, faces.png}}\n",
                        outcome.report.summary(),
                        dir.display()
                    )
                },
                json.then(|| serde_json::to_string_pretty(&outcome.report)),
            )
        }
        Command::Scan {
            scene,
            out,
            json,
            threads,
            study,
            verbose,
        } => {
            let (scene, program) = match prepare(&scene, threads, verbose) {
                Ok(x) => x,
                Err(code) => return code,
            };
            let bars = bars(json);
            let part = match machine_part(&scene, &program, &bars) {
                Ok(p) => p,
                Err(e) => return fail(e),
            };
            let scanned = match twinmill::scan::scan(&part.stock, &scene.scanner, &bars) {
                Ok(s) => s,
                Err(e) => return fail(format!("{}: [scanner]: {e}", scene.path.display())),
            };
            let cases = match study {
                None => Vec::new(),
                Some(n) => {
                    let mut opts = scene.study;
                    if n > 0 {
                        opts.trials = n;
                    }
                    match scanner_study(&scene, &program, &opts, &bars) {
                        Ok(c) => c,
                        Err(e) => return fail(e),
                    }
                }
            };
            let report = ScanFileReport {
                scene: scene.name.clone(),
                scan: ScanReport {
                    rays: scanned.rays,
                    points: scanned.cloud.points.len(),
                    shadowed: scanned.shadowed(),
                    pitch_mm: scene.scanner.pitch_mm,
                    noise_sigma_mm: scene.scanner.noise_sigma_mm,
                    seed: scene.scanner.seed,
                    views: scanned.views.clone(),
                },
                study: cases,
            };
            let dir = out.join(format!("{}-scan", scene.name));
            let files = json_bytes(&report, &dir.join("scan.json"))
                .and_then(|j| {
                    Ok(vec![
                        ("scan.json", j),
                        (
                            "cloud.ply",
                            ply_bytes(&scanned.cloud, &dir.join("cloud.ply"))?,
                        ),
                    ])
                })
                .and_then(|files| write_files(&dir, &files));
            if let Err(e) = files {
                return fail(e);
            }
            print_out(
                || {
                    format!(
                        "{}  wrote         {}/{{scan.json, cloud.ply}}\n",
                        report.summary(),
                        dir.display()
                    )
                },
                json.then(|| serde_json::to_string_pretty(&report)),
            )
        }
    }
}

fn bars(json: bool) -> Bars {
    Bars {
        bar: Mutex::new(None),
        enabled: !json && std::io::stderr().is_terminal(),
    }
}
