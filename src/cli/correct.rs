//! `twinmill correct`: correct a serial machine's NC program for its deviations and check
//! the corrected part on the twin.

use super::{SceneArgs, bars, fail, prepare, print_out};
use std::io::Write;
use std::process::ExitCode;
use twinmill::calibration::correct::write_gcode;
use twinmill::output::{json_bytes, write_streamed};
use twinmill::pipeline::pages::correct_page;
use twinmill::pipeline::{correct, correct_hexapod, identified_model, run};
use twinmill::scene::{Machine, Need};

/// Why `correct --model identified` does not apply to a hexapod.
const CORRECT_HEXAPOD: &str = "--model identified identifies a serial chain's deviations from a scanned part; a hexapod's parameters come from `identify --readings … --corrected FILE`, and `correct --controller FILE` corrects the program for the machine run by that controller";

/// Which deviations `correct` corrects for.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum ModelSource {
    /// The scene's injected deviations (the simulated machine itself).
    Injected,
    /// The deviations identified from the scene's simulated scan (plus the known ones).
    Identified,
}

/// Correct the NC program for the deviations; check it on the twin.
///
/// Correct the scene's NC program for its machine's deviations: simulate the corrected
/// program on the deviated machine, compare the milled faces and the tool path with the
/// nominal ones, refine until within the accuracy; write <out>/<scene>-corrected.ngc and
/// <out>/<scene>-correct.json. On a hexapod every commanded pose is rewritten so that the
/// machine as built, run by its controller (the scene's, or `--controller FILE`), reaches
/// the nominal pose in all six degrees of freedom.
#[derive(clap::Args)]
pub struct CorrectArgs {
    #[command(flatten)]
    args: SceneArgs,
    /// The deviations to correct for: the scene's injected ones, or those identified by
    /// simulating, scanning and fitting the scene first (`run`), as on a real machine.
    #[arg(long, value_enum, default_value = "injected")]
    model: ModelSource,
    /// Accuracy the corrected part must reach on the twin (mm, > 0).
    #[arg(long, default_value_t = 0.001, allow_hyphen_values = true)]
    accuracy_mm: f64,
}

/// `twinmill correct`.
pub fn exec(a: CorrectArgs) -> ExitCode {
    let accuracy_mm = a.accuracy_mm;
    if !(a.accuracy_mm.is_finite() && a.accuracy_mm > 0.0) {
        return fail(format!(
            "--accuracy-mm must be a positive number of mm, got {accuracy_mm}"
        ));
    }
    let (correct_command, correct_needs): (&str, &[Need]) = match a.model {
        ModelSource::Injected => ("correct", &[]),
        ModelSource::Identified => (
            "correct --model identified",
            &[Need::Scanner, Need::StepFaces],
        ),
    };
    let (scene, program) = match prepare(&a.args, correct_command, correct_needs, CORRECT_HEXAPOD) {
        Ok(x) => x,
        Err(code) => return code,
    };
    let bars = bars(a.args.json);
    let hexapod = matches!(scene.machine, Machine::Hexapod(_));
    let (chain, warning) = match a.model {
        ModelSource::Injected if hexapod => (scene.chain().clone(), None),
        ModelSource::Injected => (scene.chain().clone(), None),
        ModelSource::Identified => {
            match run(&scene, &program, &bars)
                .and_then(|o| identified_model(&scene, &o.report).map(|c| (c, o.report.warning)))
            {
                Ok(c) => c,
                Err(e) => return fail(e),
            }
        }
    };
    let corrected = if hexapod {
        correct_hexapod(&scene, &program, a.accuracy_mm, &bars)
    } else {
        correct(&scene, &program, &chain, a.accuracy_mm, &bars)
    };
    let mut outcome = match corrected {
        Ok(o) => o,
        Err(e) => return fail(e),
    };
    outcome.report.warning = warning;
    let report = &outcome.report;
    let ngc = report.corrected_program.clone();
    let json_name = format!("{}-correct.json", scene.name);
    let html_name = format!("{}-correct.html", scene.name);
    let html = match correct_page(&scene, &program, report, &outcome.corrected.moves) {
        Ok(h) => h,
        Err(e) => return fail(e),
    };
    let report_bytes = match json_bytes(report, &a.args.out.join(&json_name)) {
        Ok(b) => b,
        Err(e) => return fail(e),
    };
    let files: Vec<twinmill::output::StreamedFile> = vec![
        (
            ngc.clone(),
            Box::new(|w: &mut dyn Write| write_gcode(&outcome.corrected, &outcome.header, w)),
        ),
        (
            json_name.clone(),
            Box::new(move |w: &mut dyn Write| w.write_all(&report_bytes)),
        ),
        (
            html_name.clone(),
            Box::new(move |w: &mut dyn Write| w.write_all(html.as_bytes())),
        ),
    ];
    if let Err(e) = write_streamed(&a.args.out, files) {
        return fail(e);
    }
    let code = print_out(
        || {
            format!(
                "{}  wrote         {}/{{{ngc}, {json_name}, {html_name}}}\n",
                report.summary(),
                a.args.out.display()
            )
        },
        a.args.json.then(|| serde_json::to_string_pretty(report)),
    );
    if code == ExitCode::SUCCESS && !report.met {
        // Written and reported, but the twin predicts the accuracy is not met.
        let _ = writeln!(
            std::io::stderr(),
            "twinmill: accuracy {accuracy_mm} mm not met: {}",
            report.status
        );
        return ExitCode::from(2);
    }
    code
}
