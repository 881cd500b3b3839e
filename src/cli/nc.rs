//! `twinmill nc`: the NC program on its own — its machine-coordinate motion as JSON lines
//! (LinuxCNC's dialect), and the synthetic benchmark program.

use super::fail;
use clap::Subcommand;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use twinmill::nc::{Interpreter, LengthUnit, write_jsonl};

/// Interpret NC programs: motion as JSON lines, the benchmark program.
///
/// The RS274/NGC interpreter on its own, in LinuxCNC's dialect: `motion` prints a
/// program's machine-coordinate motion (and with --events its other records) as JSON
/// lines, as LinuxCNC's `rs274` records them (docs/nc.md); `bench-program` prints the
/// synthetic benchmark program.
#[derive(clap::Args)]
pub struct NcArgs {
    #[command(subcommand)]
    command: NcCommand,
}

/// Which NC command.
#[derive(Subcommand)]
pub enum NcCommand {
    /// Interpret a program and print its machine-coordinate motion (LinuxCNC dialect).
    Motion {
        /// The NC program (.ngc).
        program: PathBuf,
        /// LinuxCNC tool table (.tbl).
        #[arg(long)]
        tool_table: Option<PathBuf>,
        /// LinuxCNC parameter file (.var).
        #[arg(long)]
        var: Option<PathBuf>,
        /// INI file: [RS274NGC] SUBROUTINE_PATH and DISABLE_FANUC_STYLE_SUB.
        #[arg(long)]
        ini: Option<PathBuf>,
        /// Block delete switch on: skip lines starting with '/'.
        #[arg(long)]
        block_delete: bool,
        /// Unit of tool-table / var-file lengths: mm (default) or inch (LinuxCNC's
        /// standalone rs274).
        #[arg(long, default_value = "mm", value_parser = ["mm", "inch"])]
        external_units: String,
        /// Do not accept Fanuc-style O1000 ... M99 subprograms and M98 calls.
        #[arg(long)]
        no_fanuc_subs: bool,
        /// Print JSON lines (the only output format for now).
        #[arg(long)]
        jsonl: bool,
        /// Also print non-motion records (tool, spindle, offsets, ...).
        #[arg(long)]
        events: bool,
        /// Stop as an endless loop after this many lines in a row without motion.
        #[arg(long, default_value_t = twinmill::nc::DEFAULT_MAX_IDLE_BLOCKS,
              value_parser = clap::value_parser!(u64).range(1..))]
        max_idle_blocks: u64,
    },
    /// Print the synthetic benchmark program (G1 with A words, every fifth block a G3).
    BenchProgram {
        /// Number of motion blocks (200000 makes the 6.3 MB benchmark file).
        #[arg(default_value_t = 200_000)]
        blocks: usize,
    },
}

/// `twinmill nc motion | bench-program`.
pub fn exec(a: NcArgs) -> ExitCode {
    match a.command {
        NcCommand::BenchProgram { blocks } => {
            let mut text = String::new();
            twinmill::nc::synthetic::bench_program(blocks, &mut text);
            match std::io::stdout().write_all(text.as_bytes()) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => fail(e),
            }
        }
        NcCommand::Motion {
            program,
            tool_table,
            var,
            ini,
            block_delete,
            external_units,
            no_fanuc_subs,
            jsonl: _,
            events,
            max_idle_blocks,
        } => {
            let unit = if external_units == "inch" {
                LengthUnit::Inch
            } else {
                LengthUnit::Mm
            };
            let mut opts = match twinmill::nc::options_from_files(
                tool_table.as_deref(),
                var.as_deref(),
                ini.as_deref(),
                unit,
            ) {
                Ok(o) => o,
                Err(e) => return fail(e),
            };
            opts.block_delete = block_delete;
            opts.max_idle_blocks = max_idle_blocks;
            if no_fanuc_subs {
                opts.fanuc_subs = false;
            }
            let interp = match Interpreter::from_file(&program, opts) {
                Ok(i) => i,
                Err(e) => return fail(e),
            };
            let stdout = std::io::stdout();
            let mut out = std::io::BufWriter::with_capacity(1 << 16, stdout.lock());
            let r = write_jsonl(interp, events, |s| out.write_all(s));
            let _ = out.flush();
            match r {
                Ok(Ok(())) => ExitCode::SUCCESS,
                Ok(Err(e)) => fail(e),
                Err(e) => fail(e),
            }
        }
    }
}
