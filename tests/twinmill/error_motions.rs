//! Error motions, reversal, location and squareness: machines with them cut faces where an
//! independent derivation puts them, the ISO names map onto the chain as their geometry says,
//! and bad `[error_motions]` fail with file:line:column.

use crate::{Sandbox, builtin};
use twinmill::cutting::stock::TriDexel;
use twinmill::machine::error_motion::{Direction, Directions};
use twinmill::math::{Point3, Real};
use twinmill::nc::{AxisLetter, AxisValues};
use twinmill::pipeline::machine_part;
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

/// A 3-axis machine (X, Y, Z from the workpiece), a flat Ø6 end mill 20 long, a
/// 60 × 40 × 20 block, with `extra` sections and `program`.
fn xyz_scene(sb: &Sandbox, extra: &str, program: &str) -> Scene {
    let text = format!(
        "program = \"p.ngc\"\n\
         [machine]\n\
         axes = [\n\
           {{ name = \"X\", kind = \"linear\", direction = [1, 0, 0] }},\n\
           {{ name = \"Y\", kind = \"linear\", direction = [0, 1, 0] }},\n\
           {{ name = \"Z\", kind = \"linear\", direction = [0, 0, 1] }},\n\
         ]\n\
         home = {{ X = 0, Y = 0, Z = 50 }}\n\
         [tool]\nkind = \"flat\"\ndiameter_mm = 6.0\nlength_mm = 20.0\n\
         [stock]\nmin = [0.0, 0.0, 0.0]\nmax = [60.0, 40.0, 20.0]\npitch_mm = 0.25\n\
         {extra}\n"
    );
    sb.write("s.toml", text.as_bytes());
    sb.write("p.ngc", program.as_bytes());
    Scene::load(&sb.dir.join("s.toml")).expect("scene loads")
}

fn cut(scene: &Scene) -> TriDexel {
    let program = scene.load_program().expect("program");
    machine_part(scene, &program, &NoProgress)
        .expect("sweep")
        .stock
}

/// The crossings of the x rays cut by NC `line` with x in `(x_lo, x_hi)`, y and z inside
/// the given ranges: the points of one flank.
fn flank_points(
    stock: &TriDexel,
    line: u32,
    (x_lo, x_hi): (Real, Real),
    (y_lo, y_hi): (Real, Real),
    (z_lo, z_hi): (Real, Real),
) -> Vec<Point3> {
    let mut out = Vec::new();
    stock.grids()[0].for_each_crossing(|p, c| {
        if c.line == line
            && p.x > x_lo
            && p.x < x_hi
            && p.y > y_lo
            && p.y < y_hi
            && p.z > z_lo
            && p.z < z_hi
        {
            out.push(p);
        }
    });
    out
}

/// A slot along +Y at X = 20 (line 5), after X moved in +: its +x flank.
const SLOT_Y: &str = "G21 G90 G17\nG0 Z30\nG0 X20 Y-10\nG0 Z10\nG1 Y50 F600\nG0 Z30\nM30\n";

/// A positioning polynomial EXX and a constant pitch EBX: the +x flank of a slot cut along
/// Y at X = x0 is the tilted plane x = x0 + EXX(x0) + R/cos β + z·tan β (the tool's side
/// turned by Ry(β) about the X carriage's origin, z = 0 of W: the Abbe lever is the
/// height z), derived here from the definition Err = Trans(EXX, 0, 0)·Ry(EBX).
#[test]
fn positioning_and_pitch_put_the_flank_where_the_abbe_lever_says() {
    let sb = Sandbox::new("em-abbe");
    let (c0, c1, beta): (Real, Real, Real) = (0.01, 2e-4, 2e-4);
    let scene = xyz_scene(
        &sb,
        &format!(
            "[error_motions]\nEXX = {{ polynomial = [{c0}, {c1}] }}\nEBX = {{ polynomial = [{beta}] }}\n"
        ),
        SLOT_Y,
    );
    let stock = cut(&scene);
    let pts = flank_points(&stock, 5, (21.0, 25.0), (2.0, 38.0), (10.5, 19.5));
    assert!(pts.len() > 500, "{} points", pts.len());
    let (x0, r) = (20.0, 3.0);
    let exx = c0 + c1 * x0;
    let mut worst: Real = 0.0;
    for p in &pts {
        let want = x0 + exx + r / beta.cos() + p.z * beta.tan();
        worst = worst.max((p.x - want).abs());
    }
    assert!(worst < 5e-4, "worst {worst} mm");
    // The effect itself is far above the tolerance: 14 µm of EXX, 2–4 µm of Abbe error.
    assert!(exx + 10.0 * beta > 0.015);
}

/// A straightness EXY (periodic, a screw's pitch) while Y moves: the slot's flank follows
/// it; the expected flank at each ray is the envelope of the tool's circles along the
/// curved path, maximised here by brute force over the path.
#[test]
fn straightness_while_moving_is_swept_exactly() {
    let sb = Sandbox::new("em-straight");
    let (amp, pitch, phase): (Real, Real, Real) = (0.003, 5.0, 30.0);
    let scene = xyz_scene(
        &sb,
        &format!(
            "[error_motions]\nEXY = {{ periodic = [{{ amplitude = {amp}, period = {pitch}, phase_deg = {phase} }}] }}\n"
        ),
        SLOT_Y,
    );
    let stock = cut(&scene);
    let pts = flank_points(&stock, 5, (21.0, 25.0), (2.0, 38.0), (10.5, 19.5));
    assert!(pts.len() > 500, "{} points", pts.len());
    let e = |y: Real| amp * (std::f64::consts::TAU * y / pitch + phase.to_radians()).sin();
    let r = 3.0;
    // The flank at height z along the ray at y: max over the tool centre (20 + e(y'), y')
    // of the circle's x at y.
    let envelope = |y: Real| {
        let n = 6000;
        let mut best = Real::NEG_INFINITY;
        for k in 0..=n {
            let yc = y - r + 2.0 * r * k as Real / n as Real;
            let dy = y - yc;
            if dy.abs() <= r {
                best = best.max(20.0 + e(yc) + (r * r - dy * dy).sqrt());
            }
        }
        // Refine around the best sample: the tool centre near y.
        let (mut lo, mut hi) = (y - 0.01, y + 0.01);
        let f = |yc: Real| 20.0 + e(yc) + (r * r - (y - yc) * (y - yc)).max(0.0).sqrt();
        for _ in 0..100 {
            let (a, b) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
            if f(a) < f(b) {
                lo = a;
            } else {
                hi = b;
            }
        }
        best.max(f(0.5 * (lo + hi)))
    };
    let mut worst: Real = 0.0;
    let mut spread = (Real::INFINITY, Real::NEG_INFINITY);
    for p in pts.iter().step_by(7) {
        let want = envelope(p.y);
        worst = worst.max((p.x - want).abs());
        spread = (spread.0.min(p.x), spread.1.max(p.x));
    }
    assert!(worst < 5e-4, "worst {worst} mm");
    // The flank really waves by the straightness (±3 µm).
    assert!(spread.1 - spread.0 > 0.005, "spread {spread:?}");
}

/// Reversal: a slot at X = 10 reached moving +X and one at X = 40 reached moving −X: their
/// flanks sit at 10 + B/2 + R and 40 − B/2 + R (B = x̄↑ − x̄↓ split ±B/2).
#[test]
fn reversal_shifts_faces_approached_from_opposite_sides() {
    let sb = Sandbox::new("em-reversal");
    let b = -0.004;
    let program = "G21 G90 G17\nG0 Z30\nG0 X10 Y-10\nG0 Z10\nG1 Y50 F600\nG0 Z30\n\
                   G0 X45\nG0 X40\nG0 Z10\nG1 Y-10 F600\nG0 Z30\nM30\n";
    let scene = xyz_scene(&sb, &format!("[reversal]\nX = {b}\n"), program);
    let stock = cut(&scene);
    let r = 3.0;
    for (line, x_cmd, want) in [
        (5, 10.0, 10.0 + b / 2.0 + r),
        (10, 40.0, 40.0 - b / 2.0 + r),
    ] {
        let pts = flank_points(
            &stock,
            line,
            (x_cmd + 1.0, x_cmd + 5.0),
            (2.0, 38.0),
            (10.5, 19.5),
        );
        assert!(pts.len() > 500, "line {line}: {} points", pts.len());
        let worst = pts.iter().map(|p| (p.x - want).abs()).fold(0.0, Real::max);
        assert!(worst < 5e-4, "line {line}: worst {worst} mm");
    }
    // The chain's static poses say the same.
    let q = AxisValues::default().with(AxisLetter::X, 10.0);
    let up = scene.chain().tool_point(&q, &Directions::default());
    let down = scene.chain().tool_point(
        &q,
        &Directions::default().with(AxisLetter::X, Direction::Negative),
    );
    assert!(((up.x - down.x) - b).abs() < 1e-12);
}

/// The location of a C table's line: EY0C = 0.05 moves the line by 0.05 in Y, so a table
/// point under a fixed tool position turned 180° about C moves 0.1 in Y relative to the
/// nominal machine (and not at all at 0°, up to the workpiece zero).
#[test]
fn rotary_location_moves_the_line() {
    let sb = Sandbox::new("em-location");
    let text = "program = \"p.ngc\"\n\
        [machine]\n\
        axes = [\n\
          { name = \"C\", kind = \"rotary\", direction = [0, 0, 1] },\n\
          { name = \"X\", kind = \"linear\", direction = [1, 0, 0] },\n\
          { name = \"Y\", kind = \"linear\", direction = [0, 1, 0] },\n\
          { name = \"Z\", kind = \"linear\", direction = [0, 0, 1] },\n\
        ]\n\
        [deviations]\nEY0C = 0.05\nEX0C = -0.02\n\
        [tool]\nkind = \"flat\"\ndiameter_mm = 6.0\nlength_mm = 20.0\n\
        [stock]\nmin = [0.0, 0.0, 0.0]\nmax = [10.0, 10.0, 10.0]\npitch_mm = 0.5\n";
    sb.write("s.toml", text.as_bytes());
    sb.write("p.ngc", b"G0 X0\nM30\n");
    let scene = Scene::load(&sb.dir.join("s.toml")).expect("scene");
    let nominal = scene.chain().nominal();
    let d = Directions::default();
    let at = |c: Real| {
        let q = AxisValues::default()
            .with(AxisLetter::X, 12.0)
            .with(AxisLetter::Y, -7.0)
            .with(AxisLetter::Z, 3.0)
            .with(AxisLetter::C, c);
        scene.chain().tool_point(&q, &d) - nominal.tool_point(&q, &d)
    };
    let moved = at(180.0) - at(0.0);
    assert!((moved.y - 0.1).abs() < 1e-12, "{moved}");
    assert!((moved.x - -0.04).abs() < 1e-12, "{moved}");
    assert!(moved.z.abs() < 1e-12, "{moved}");
    // At 90° the line offset (ex, ey) turns the point by (ex − ey, ex + ey) − (0, 0)…
    // o − Rz(90°)·o = (ex + ey, ey − ex).
    let m90 = at(90.0) - at(0.0);
    assert!((m90.x - (-0.02 + 0.05)).abs() < 1e-12, "{m90}");
    assert!((m90.y - (0.05 + 0.02)).abs() < 1e-12, "{m90}");
}

/// Squareness EC(0X)Y: Y's motion turned about +Z by the value, X the reference, the tool's
/// orientation unchanged.
#[test]
fn squareness_turns_one_axis_against_its_reference() {
    let sb = Sandbox::new("em-square");
    let eps: Real = 1e-4;
    let scene = xyz_scene(
        &sb,
        &format!("[deviations]\n\"EC(0X)Y\" = {eps}\nEB0XZ = {eps}\n"),
        "G0 X0\nM30\n",
    );
    let d = Directions::default();
    let p = |x: Real, y: Real, z: Real| {
        let q = AxisValues::default()
            .with(AxisLetter::X, x)
            .with(AxisLetter::Y, y)
            .with(AxisLetter::Z, z);
        scene.chain().tool_point(&q, &d)
    };
    let l = 100.0;
    let along_x = p(l, 0.0, 0.0) - p(0.0, 0.0, 0.0);
    assert!((along_x - twinmill::math::Vector3::new(l, 0.0, 0.0)).norm() < 1e-12);
    let along_y = p(0.0, l, 0.0) - p(0.0, 0.0, 0.0);
    let want_y = twinmill::math::Vector3::new(-l * eps.sin(), l * eps.cos(), 0.0);
    assert!((along_y - want_y).norm() < 1e-12, "{along_y}");
    // EB(0X)Z: Z turned about +Y: +Z moves toward +X.
    let along_z = p(0.0, 0.0, l) - p(0.0, 0.0, 0.0);
    let want_z = twinmill::math::Vector3::new(l * eps.sin(), 0.0, l * eps.cos());
    assert!((along_z - want_z).norm() < 1e-12, "{along_z}");
    let q = AxisValues::default().with(AxisLetter::Y, 30.0);
    let rot = scene.chain().w_from_t(&q).rotation;
    assert!(rot.angle() < 1e-15);
}

/// Bad `[error_motions]` and `[reversal]` entries fail with file:line:column, never a panic.
#[test]
fn bad_error_motions_name_file_line_and_column() {
    let sb = Sandbox::new("em-bad");
    let base = builtin("xyz-pocket.toml");
    sb.write("xyz-pocket.ngc", builtin("xyz-pocket.ngc").as_bytes());
    let cases = [
        (
            "[error_motions]\nEXX = { table = { q = [0, 20, 10], values = [0, 1e-3, 0] } }\n",
            "increase strictly",
        ),
        (
            "[error_motions]\nEXX = { polynomial = [0, nan] }\n",
            "finite",
        ),
        (
            "[error_motions]\nEQX = { polynomial = [0] }\n",
            "unknown error motion",
        ),
        (
            "[error_motions]\nEXA = { polynomial = [0] }\n",
            "does not have",
        ),
        ("[reversal]\nA = 0.001\n", "does not have"),
        (
            "[error_motions]\nEXX = { periodic = [{ amplitude = 1e-3, period = 0 }] }\n",
            "period",
        ),
        ("[error_motions]\nEXX = {}\n", "needs a table"),
        ("[deviations]\nEY0A = 0.05\n", "does not have"),
        ("[deviations]\nEQ0A = 0.05\n", "unknown location"),
        (
            "[error_motions]\nEXX = { table = { q = [0, 1], values = [0] } }\n",
            "positions but",
        ),
    ];
    for (extra, want) in cases {
        let text = format!("{base}\n{extra}");
        sb.write("s.toml", text.as_bytes());
        let err = Scene::load(&sb.dir.join("s.toml"))
            .expect_err(extra)
            .to_string();
        let line = base.lines().count() + 3;
        assert!(err.contains(want), "{extra}: {err}");
        assert!(
            err.contains(&format!("s.toml:{line}:")),
            "{extra}: want line {line}: {err}"
        );
    }
}
