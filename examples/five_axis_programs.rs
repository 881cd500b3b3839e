//! Writes the NC programs of the simultaneous 5-axis scenes in `benches/data/` (the programs
//! of `benches/support/five_axis.rs`): `cargo run --release --example five_axis_programs`
//! (`-- --check` compares instead of writing, exit 1 if a file differs).
//!
//! - `trunnion-side-cut.ngc`: the side cut's 7,200 moves (ten turns of C);
//! - `trunnion-blade.ngc`: the blade-like path's first 1,440 moves (one turn), ball Ø6;
//! - `hexapod-side-cut.ngc`: the hexapod side cut's 720 moves (one turn).

#![allow(clippy::print_stdout, reason = "an example reports on the terminal")]

use std::path::Path;
use twinmill::nc::AxisLetter;
use twinmill::scene::Scene;
use twinmill::{machine, math, nc};

#[path = "../benches/support/five_axis.rs"]
mod five_axis;

fn main() -> std::process::ExitCode {
    let check = std::env::args().any(|a| a == "--check");
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/data");
    let trunnion =
        Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/trunnion-ac.toml"))
            .expect("the trunnion scene loads");
    use AxisLetter::{A, B, C, X, Y, Z};
    let files = [
        (
            "trunnion-side-cut.ngc",
            five_axis::nc_text(
                &five_axis::side_cut(7200),
                &[X, Y, Z, A, C],
                120.0,
                "side cut: C 0.5 deg a move, Z down 36 mm over 7,200 moves, A +-8 deg three times a turn",
            ),
        ),
        (
            "trunnion-blade.ngc",
            five_axis::nc_text(
                &five_axis::blade(&trunnion.chain().nominal(), 3.0, 1440),
                &[X, Y, Z, A, C],
                120.0,
                "blade-like finishing, ball D6: C 0.25 deg a move, A +-5 deg twice a turn, 0.2 mm deep",
            ),
        ),
        (
            "hexapod-side-cut.ngc",
            five_axis::nc_text(
                &five_axis::hexapod_side(720),
                &[X, Y, Z, A, B, C],
                200.0,
                "hexapod side cut: 0.5 deg a move at radius 21 mm, 3.6 mm down a turn, A +-8 deg",
            ),
        ),
    ];
    let mut same = true;
    for (name, text) in files {
        let path = dir.join(name);
        if check {
            let old = std::fs::read_to_string(&path).unwrap_or_default();
            let ok = old == text;
            same &= ok;
            println!("{name}: {}", if ok { "same" } else { "DIFFERS" });
        } else {
            std::fs::write(&path, text).expect("writes the program");
            println!("wrote {}", path.display());
        }
    }
    if same {
        std::process::ExitCode::SUCCESS
    } else {
        std::process::ExitCode::FAILURE
    }
}
