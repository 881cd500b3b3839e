//! `twinmill study`: many identification trials, planned once, run in shards, merged.

use super::{fail, print_out};
use clap::Subcommand;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use twinmill::study;

/// Plan, run in shards and merge studies of many trials.
///
/// Studies of many identification trials, planned once, run in shards (a Slurm array or a
/// Kubernetes Indexed Job), merged into a summary (docs/studies.md).
#[derive(clap::Args)]
pub struct StudyArgs {
    #[command(subcommand)]
    command: StudyCommand,
}

/// Which study command.
#[derive(Subcommand)]
pub enum StudyCommand {
    /// Fix every trial's inputs: write the manifest (JSON).
    Plan {
        /// The study file (TOML).
        study: PathBuf,
        /// Number of shards.
        #[arg(long, default_value_t = 1)]
        shards: usize,
        /// The manifest to write (default: <study stem>.manifest.json beside the study).
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
    },
    /// Run one shard's trials and write its Parquet file.
    Run {
        /// The manifest.
        manifest: PathBuf,
        /// The shard (default: SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX).
        #[arg(long)]
        shard: Option<usize>,
        /// Folder of the shard files (default: the manifest's folder).
        #[arg(long, value_name = "DIR")]
        dir: Option<PathBuf>,
    },
    /// Check every shard against the manifest and summarise per parameter.
    Merge {
        /// The manifest.
        manifest: PathBuf,
        /// Folder of the shard files (default: the manifest's folder).
        #[arg(long, value_name = "DIR")]
        dir: Option<PathBuf>,
        /// Print the summary as JSON.
        #[arg(long)]
        json: bool,
        /// Also write the summary JSON here.
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
    },
}

/// `twinmill study plan | run | merge`.
pub fn exec(a: StudyArgs) -> ExitCode {
    let folder = |manifest: &Path, dir: Option<PathBuf>| {
        dir.unwrap_or_else(|| {
            manifest
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_else(|| PathBuf::from("."))
        })
    };
    match a.command {
        StudyCommand::Plan {
            study: file,
            shards,
            out,
        } => {
            let m = match study::plan(&file, shards) {
                Ok(m) => m,
                Err(e) => return fail(e),
            };
            let out = out.unwrap_or_else(|| {
                let stem = file
                    .file_stem()
                    .map_or("study".into(), |s| s.to_string_lossy());
                file.with_file_name(format!("{stem}.manifest.json"))
            });
            let bytes = match serde_json::to_vec_pretty(&m) {
                Ok(b) => b,
                Err(e) => return fail(e),
            };
            if let Err(e) = twinmill::output::write_file(&out, &bytes) {
                return fail(e);
            }
            let line = format!(
                "planned {} trials in {} shards: {} (study {})\n",
                m.trials.len(),
                m.shards,
                out.display(),
                m.id
            );
            print_out(|| line, None)
        }
        StudyCommand::Run {
            manifest,
            shard,
            dir,
        } => {
            let m = match study::read_manifest(&manifest) {
                Ok(m) => m,
                Err(e) => return fail(e),
            };
            let i = match study::shard_index(shard) {
                Ok(i) => i,
                Err(e) => return fail(e),
            };
            let rows = match study::run_shard(&m, i) {
                Ok(r) => r,
                Err(e) => return fail(e),
            };
            let bytes = match study::shard_parquet(&m, &rows) {
                Ok(b) => b,
                Err(e) => return fail(e),
            };
            let path = folder(&manifest, dir).join(study::shard_file_name(i, m.shards));
            if let Err(e) = twinmill::output::write_file(&path, &bytes) {
                return fail(e);
            }
            let failed = rows.iter().filter(|r| r.error.is_some()).count();
            let line = format!(
                "shard {i}: {} trials ({failed} failed) in {:.1} s → {}\n",
                rows.len(),
                rows.iter().map(|r| r.seconds).sum::<f64>(),
                path.display()
            );
            print_out(|| line, None)
        }
        StudyCommand::Merge {
            manifest,
            dir,
            json,
            out,
        } => {
            let m = match study::read_manifest(&manifest) {
                Ok(m) => m,
                Err(e) => return fail(e),
            };
            let (summary, _) = match study::merge(&m, &folder(&manifest, dir)) {
                Ok(s) => s,
                Err(e) => return fail(e),
            };
            let text = match serde_json::to_string_pretty(&summary) {
                Ok(t) => t,
                Err(e) => return fail(e),
            };
            if let Some(out) = out
                && let Err(e) = twinmill::output::write_file(&out, text.as_bytes())
            {
                return fail(e);
            }
            print_out(
                || {
                    use std::fmt::Write as _;
                    let mut s = String::new();
                    let _ = writeln!(
                        s,
                        "study {}: {} trials in {} shards, {} failed; {:.1} s of trial work",
                        summary.study,
                        summary.trials,
                        summary.shards,
                        summary.failed,
                        summary.trial_seconds
                    );
                    let _ = writeln!(
                        s,
                        "  {:<22} {:>10} {:>12} {:>12} {:>12} {:>9}",
                        "parameter", "determined", "bias", "spread", "mean σ", "±3σ"
                    );
                    for p in &summary.parameters {
                        let _ = writeln!(
                            s,
                            "  {:<22} {:>9.0}% {:>12.3e} {:>12.3e} {:>12.3e} {:>8.1}%",
                            p.name,
                            100.0 * p.determined_fraction,
                            p.bias,
                            p.spread,
                            p.mean_sigma,
                            100.0 * p.coverage_3sigma
                        );
                    }
                    for f in &summary.failures {
                        let _ = writeln!(s, "  failed: {f}");
                    }
                    s
                },
                json.then_some(Ok(text.clone())),
            )
        }
    }
}
