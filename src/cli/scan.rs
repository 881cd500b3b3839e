//! `twinmill scan`: simulate a serial machine's scene and scan the part with its scanner;
//! with `--study`, the scanner-effects study.

use super::{SceneArgs, bars, fail, prepare, print_out, write_report_and_cloud};
use std::process::ExitCode;
use twinmill::metrology::scan::Surface;
use twinmill::pipeline::pages::scan_page;
use twinmill::pipeline::{machine_part, scanner_study};
use twinmill::report::{ScanFileReport, ScanReport};
use twinmill::scene::Need;

/// Why `scan` does not apply to a hexapod.
const SCAN_HEXAPOD: &str = "the virtual scan follows a serial chain's scene; a hexapod cuts with `simulate` and is measured with `measure --instrument ballbar`";

/// Simulate and scan the part with the scene's scanner.
///
/// Simulate the scene's program and scan the part with the scene's scanner (all views);
/// write cloud.ply and scan.json. With --study, also scan it again and again with each
/// scanner effect alone and together, and report how the identified offset moves.
#[derive(clap::Args)]
pub struct ScanArgs {
    #[command(flatten)]
    args: SceneArgs,
    /// Run the scanner-effects study with N seeded trials per case (default: the
    /// scene's [study] trials, 20 if not given).
    #[arg(long, num_args = 0..=1, default_missing_value = "0", value_name = "N")]
    study: Option<usize>,
}

/// `twinmill scan`.
pub fn exec(a: ScanArgs) -> ExitCode {
    let (scan_command, scan_needs): (&str, &[Need]) = match a.study {
        Some(_) => ("scan --study", &[Need::Scanner, Need::StepFaces]),
        None => ("scan", &[Need::Scanner]),
    };
    let (scene, program) = match prepare(&a.args, scan_command, scan_needs, SCAN_HEXAPOD) {
        Ok(x) => x,
        Err(code) => return code,
    };
    let bars = bars(a.args.json);
    let part = match machine_part(&scene, &program, &bars) {
        Ok(p) => p,
        Err(e) => return fail(e),
    };
    // One surface index for the scan and every scan of the study.
    let surface = Surface::new(&part.stock);
    let scanner = match scene.scanner_for(scan_command) {
        Ok(s) => s,
        Err(e) => return fail(e),
    };
    let scanned = match surface.scan(scanner, &bars) {
        Ok(s) => s,
        Err(e) => return fail(format!("{}: [scanner]: {e}", scene.path.display())),
    };
    let cases = match a.study {
        None => Vec::new(),
        Some(n) => {
            let mut opts = scene.study;
            if n > 0 {
                opts.trials = n;
            }
            match scanner_study(&scene, &program, &part.stock, &surface, &opts) {
                Ok(c) => c,
                Err(e) => return fail(e),
            }
        }
    };
    let report = ScanFileReport {
        scene: scene.name.clone(),
        scan: ScanReport::of(&scanned, scanner),
        study: cases,
    };
    let dir = a.args.out.join(format!("{}-scan", scene.name));
    let html = match scan_page(&scene, &report, &part.stock, &scanned.cloud.points) {
        Ok(h) => h,
        Err(e) => return fail(e),
    };
    let files = write_report_and_cloud(&dir, "scan.json", &report, &scanned.cloud, html);
    if let Err(e) = files {
        return fail(e);
    }
    print_out(
        || {
            format!(
                "{}  wrote         {}/{{scan.json, cloud.ply, report.html}}\n",
                report.summary(),
                dir.display()
            )
        },
        a.args.json.then(|| serde_json::to_string_pretty(&report)),
    )
}
