//! `twinmill run`: the whole loop on a serial machine's scene — simulate, scan, fit the
//! faces, identify the deviations — and its report, cloud, picture and page.

use super::{SceneArgs, bars, fail, prepare, print_out};
use std::process::ExitCode;
use twinmill::output::write_outcome;
use twinmill::pipeline::pages::run_page;
use twinmill::pipeline::run;
use twinmill::scene::Need;

/// Why `run` does not apply to a hexapod.
const RUN_HEXAPOD: &str = "the loop identifies a serial chain's deviations from the faces of a cut part; a hexapod's loop is `measure --instrument ballbar`, `identify` from the traces and `design` of the circles";

/// The whole loop: simulate, scan, fit, identify; write the report.
///
/// Simulate a scene's program on its deviated machine, scan the part, fit the faces and
/// identify the deviations; write report.json, cloud.ply, faces.png and report.html (a
/// self-contained page with the part in 3-D). Serial machines only.
#[derive(clap::Args)]
pub struct RunArgs {
    #[command(flatten)]
    args: SceneArgs,
}

/// `twinmill run`.
pub fn exec(a: RunArgs) -> ExitCode {
    let (scene, program) = match prepare(
        &a.args,
        "run",
        &[Need::Scanner, Need::StepFaces],
        RUN_HEXAPOD,
    ) {
        Ok(x) => x,
        Err(code) => return code,
    };
    let bars = bars(a.args.json);
    let outcome = match run(&scene, &program, &bars) {
        Ok(o) => o,
        Err(e) => return fail(e),
    };
    let dir = a.args.out.join(&scene.name);
    let html = match run_page(&scene, &program, &outcome) {
        Ok(h) => h,
        Err(e) => return fail(e),
    };
    if let Err(e) = write_outcome(&outcome, &html, &dir) {
        return fail(e);
    }
    print_out(
        || {
            format!(
                "{}  wrote         {}/{{report.json, cloud.ply, faces.png, report.html}}\n",
                outcome.report.summary(),
                dir.display()
            )
        },
        a.args
            .json
            .then(|| serde_json::to_string_pretty(&outcome.report)),
    )
}
