//! The `twinmill` command line: parses arguments, calls the library, prints, picks the exit
//! code. Nothing else happens here.

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Mutex;
use twinmill::output::write_outcome;
use twinmill::pipeline::run;
use twinmill::progress::Progress;
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
            if let Some(n) = threads
                && let Err(e) = rayon::ThreadPoolBuilder::new()
                    .num_threads(n.max(1))
                    .build_global()
            {
                return fail(e);
            }
            let scene = match Scene::load(&scene) {
                Ok(s) => s,
                Err(e) => return fail(e),
            };
            let program = match scene.load_program() {
                Ok(p) => p,
                Err(SceneError::Program(e)) if verbose => {
                    let _ = write!(std::io::stderr(), "{}", e.full_report());
                    return fail(e);
                }
                Err(e) => return fail(e),
            };
            let bars = Bars {
                bar: Mutex::new(None),
                enabled: !json && std::io::stderr().is_terminal(),
            };
            let outcome = match run(&scene, &program, &bars) {
                Ok(o) => o,
                Err(e) => return fail(e),
            };
            let dir = out.join(&scene.name);
            if let Err(e) = write_outcome(&outcome, &dir) {
                return fail(e);
            }
            let mut stdout = std::io::stdout().lock();
            let printed = if json {
                serde_json::to_string_pretty(&outcome.report)
                    .map_err(std::io::Error::other)
                    .and_then(|s| writeln!(stdout, "{s}"))
            } else {
                write!(stdout, "{}", outcome.report.summary()).and_then(|_| {
                    writeln!(
                        stdout,
                        "  wrote         {}/{{report.json, cloud.ply, faces.png}}",
                        dir.display()
                    )
                })
            };
            match printed {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => fail(e),
            }
        }
    }
}
