//! `twinmill simulate`: cut a scene's program into its stock on the deviated machine
//! (serial or hexapod) and write the part, its picture, page and report.

use super::{Loaded, SceneArgs, bars, fail, load, print_out};
use std::process::ExitCode;
use twinmill::output::{MeshFormat, write_simulation};
use twinmill::pipeline::simulate;

/// Cut the program on the deviated machine: mesh, picture, report.
///
/// Cut the scene's program into its stock on the deviated machine (no scan): write the
/// part's surface mesh, a shaded picture of it (part.png, coloured by deviation where
/// known), report.html (the page, with the part in 3-D) and report.json with the removed
/// volume, the sweep's approximation bounds and the collisions (rapids through material,
/// shank or holder in the stock, fixtures hit); with a [design] mesh, also its deviation
/// map (deviation.png, max/min/RMS in report.json). A hexapod scene cuts when it has a
/// program, [tool] and [stock].
#[derive(clap::Args)]
pub struct SimulateArgs {
    #[command(flatten)]
    args: SceneArgs,
    /// Mesh formats to write, comma separated: stl, obj, ply.
    #[arg(long, value_delimiter = ',', default_value = "stl", value_parser = ["stl", "obj", "ply"])]
    mesh: Vec<String>,
}

/// `twinmill simulate`.
pub fn exec(a: SimulateArgs) -> ExitCode {
    let (scene, program) = match load(&a.args, "simulate", &[]) {
        Ok(Loaded::Serial(s, p)) => (*s, p),
        Ok(Loaded::Hexapod(path)) => return fail(format!("{}: a hexapod scene", path.display())),
        Err(code) => return code,
    };
    let formats: Vec<MeshFormat> = a
        .mesh
        .iter()
        .map(|f| match f.as_str() {
            "obj" => MeshFormat::Obj,
            "ply" => MeshFormat::Ply,
            _ => MeshFormat::Stl,
        })
        .collect();
    let sim = match simulate(&scene, &program, &bars(a.args.json)) {
        Ok(s) => s,
        Err(e) => return fail(e),
    };
    let dir = a.args.out.join(format!("{}-simulate", scene.name));
    if let Err(e) = write_simulation(&sim, &formats, &dir) {
        return fail(e);
    }
    let names: Vec<&str> = ["report.json", "part.png", "report.html"]
        .into_iter()
        .chain(sim.deviation_png.as_ref().map(|_| "deviation.png"))
        .chain(formats.iter().map(|f| f.file_name()))
        .collect();
    print_out(
        || {
            format!(
                "{}wrote         {}/{{{}}}\n",
                sim.report.summary(),
                dir.display(),
                names.join(", ")
            )
        },
        a.args
            .json
            .then(|| serde_json::to_string_pretty(&sim.report)),
    )
}
