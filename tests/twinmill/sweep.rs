//! One sweep driver: the checked sweep of `simulate` removes exactly what the sweep
//! removes, and the sweep report states the chord sagitta of arcs.

use crate::{Sandbox, builtin};
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::sweep_program;
use twinmill::math::{Point3, Real};
use twinmill::nc::{AxisLetter, AxisValues, Move, MoveKind};
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

/// Every crossing of a stock (point, then its stored data), in grid order.
fn all_crossings(s: &TriDexel) -> Vec<(Point3, twinmill::cutting::stock::Crossing)> {
    let mut out = Vec::new();
    for g in s.grids() {
        g.for_each_crossing(|p, c| out.push((p, *c)));
    }
    out
}

/// The MDX-50 scene with `program` and the tri-dexel at `pitch`, loaded from a sandbox.
fn mdx50_with(sb: &Sandbox, program: &str, pitch: &str, tool: Option<&str>) -> Scene {
    let mut text = builtin("mdx50-step.toml")
        .replace("program = \"mdx50-step.ngc\"", "program = \"p.ngc\"")
        .replace("pitch_mm = 0.1 ", &format!("pitch_mm = {pitch} "));
    if let Some(t) = tool {
        text = text.replace("kind = \"flat\"         # flat | ball", t);
    }
    sb.write("s.toml", text.as_bytes());
    sb.write("p.ngc", program.as_bytes());
    Scene::load(&sb.dir.join("s.toml")).expect("scene")
}

/// Whether two stocks' crossings (`all_crossings`) are the same: the same rays, each
/// crossing's point within 1e-7 mm (the envelope's bound) with the same NC line, and its
/// normal within 1e-6 rad (an `f32` normal rounds to 6e-8 rad).
fn same_crossings(
    a: &[(Point3, twinmill::cutting::stock::Crossing)],
    b: &[(Point3, twinmill::cutting::stock::Crossing)],
) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|((p, c), (q, d))| {
            let (n, m) = (c.normal(), d.normal());
            (p - q).norm() <= 1e-7 && c.line == d.line && n.angle(&m) <= 1e-6
        })
}

/// Cutting while A turns, arcs, a collinear run split in three, rapids through material and
/// a holder that dips into the stock: the checked sweep's stock (every move cut in program
/// order, the holder checked after each) equals the plain sweep's (envelope moves cut 16 at
/// a time, each ray through the latest first): every crossing's point, normal and NC line,
/// the points within the envelope's 1e-7 mm and the normals within 1e-6 rad (a ray's end on
/// a face that stays put through a move is the same point, found at another pose of it
/// when the material it meets differs), with the same sweep report, for a flat end mill
/// (rotary moves cut by the envelope) and a bull-nose (cut in sub-steps); and one or two
/// threads give the same events and stock bit for bit.
#[test]
fn checked_sweep_removes_exactly_what_the_sweep_removes() {
    use twinmill::cutting::collide::{Holder, HolderSection, sweep_with_checks};
    let program = "G21 G90 G17\nG0 Z60 A0\nG0 X-30 Y-25\nG0 Z5\n\
        G1 X-10 F600\nG1 X0\nG1 X10\n\
        G3 X20 Y-15 I0 J10\nG3 X10 Y-5 I-10 J0\n\
        G1 Z2\nG1 A30 F600\nG1 X-10 A45\nG0 A60\nG0 X-25 Y-20\n\
        G1 Y-10 Z0\nG0 Z60\nG0 A0\nM30\n";
    let holder = Holder::try_sections(
        4.0,
        10.0,
        &[
            HolderSection {
                length: 3.0,
                radius_bottom: 8.0,
                radius_top: 12.0,
            },
            HolderSection {
                length: 5.0,
                radius_bottom: 15.0,
                radius_top: 15.0,
            },
        ],
    )
    .expect("holder");
    for (tag, tool, bound) in [
        ("flat", None, 1e-4),
        (
            "bull",
            Some("kind = \"bull_nose\"\ncorner_radius_mm = 1.0"),
            2e-2,
        ),
    ] {
        let sb = Sandbox::new(&format!("one-driver-{tag}"));
        let mut s = mdx50_with(&sb, program, "0.6", tool);
        s.sweep.rotary_step_bound_mm = bound;
        let prog = s.load_program().expect("program");
        assert!(
            prog.moves
                .iter()
                .any(|m| matches!(m.kind, MoveKind::Arc(_))),
            "the program has arcs"
        );
        let mut plain = twinmill::pipeline::make_stock(&s).expect("stock");
        let v0 = plain.volume();
        let rep = sweep_program(
            &mut plain,
            s.chain(),
            &s.tool,
            &prog.moves,
            &s.sweep,
            &NoProgress,
        )
        .expect("sweep");
        assert!(rep.rotary_moves >= 3 && rep.cutting_moves >= 6, "{rep:?}");
        assert!(plain.volume() < v0 - 100.0, "the program cuts");
        let checked = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| {
                let mut stock = twinmill::pipeline::make_stock(&s).expect("stock");
                let r = sweep_with_checks(
                    &mut stock,
                    s.chain(),
                    &s.tool,
                    Some(&holder),
                    &[],
                    &prog.moves,
                    &s.sweep,
                    &NoProgress,
                )
                .expect("checked sweep");
                (stock, r)
            })
        };
        let (stock, r) = checked(1);
        assert_eq!(r.sweep, rep, "{tag}: same sweep report");
        let want = all_crossings(&plain);
        assert!(
            same_crossings(&all_crossings(&stock), &want),
            "{tag}: the checked sweep's stock differs from the sweep's"
        );
        // Rapids through material (G0 A60 and G0 X-25 Y-20 at Z2 inside the blank) are seen.
        assert!(
            r.events
                .iter()
                .any(|e| e.kind == twinmill::cutting::collide::EventKind::RapidThroughMaterial),
            "{tag}: {:?}",
            r.events
        );
        assert!(r.check_error_bound_mm > 0.0 && r.check_error_bound_mm <= bound.max(1e-3));
        let (stock2, r2) = checked(2);
        assert_eq!(r2, r, "{tag}: events depend on the thread count");
        assert!(
            all_crossings(&stock2) == all_crossings(&stock),
            "{tag}: 2 threads"
        );
    }
}

/// Arcs become chords: the report states their error, the largest distance of an arc point
/// from its chord, which is the sagitta r·(1 − cos(θ/2)) of the chord spanning θ; measured
/// here on points of the arc against the chords the sweep cut.
#[test]
fn sweep_report_states_the_chord_sagitta_of_arcs() {
    let sb = Sandbox::new("chord-sagitta");
    // A quarter circle of radius 10 about (10, -15) and a half circle of radius 4.
    let program = "G21 G90 G17\nG0 Z60\nG0 X10 Y-25\nG0 Z5\nG3 X20 Y-15 I0 J10 F600\n\
        G3 X12 Y-15 I-4 J0\nG0 Z60\nM30\n";
    let mut s = mdx50_with(&sb, program, "0.5", None);
    let bound = 2e-3;
    s.sweep.rotary_step_bound_mm = bound;
    let prog = s.load_program().expect("program");
    let mut stock = twinmill::pipeline::make_stock(&s).expect("stock");
    let rep = sweep_program(
        &mut stock,
        s.chain(),
        &s.tool,
        &prog.moves,
        &s.sweep,
        &NoProgress,
    )
    .expect("sweep");
    // Independently: the chords' ends in axis space and each arc's centre and radius.
    let arcs: [([Real; 2], Real, Real, Real); 2] = [
        // (centre, radius, start angle, end angle) — clockwise quarter from -90° to 0°.
        ([10.0, -15.0], 10.0, -PI_2, 0.0),
        // Counter-clockwise half from 0° to 180°.
        ([16.0, -15.0], 4.0, 0.0, std::f64::consts::PI),
    ];
    let mut worst: Real = 0.0;
    let arc_moves: Vec<&Move> = prog
        .moves
        .iter()
        .filter(|m| matches!(m.kind, MoveKind::Arc(_)))
        .collect();
    assert_eq!(arc_moves.len(), 2);
    for (m, (c, r, a0, a1)) in arc_moves.iter().zip(arcs) {
        let chords: Vec<Move> = m.chords(bound).collect();
        let xy = |q: &AxisValues| [q.get(AxisLetter::X), q.get(AxisLetter::Y)];
        let n = 20_000;
        let mut arc_worst: Real = 0.0;
        for i in 0..=n {
            let phi = a0 + (a1 - a0) * i as Real / n as Real;
            let p = [c[0] + r * phi.cos(), c[1] + r * phi.sin()];
            // Distance to the nearest chord segment.
            let d = chords
                .iter()
                .map(|ch| {
                    let (a, b) = (xy(&ch.start), xy(&ch.end));
                    let (ux, uy) = (b[0] - a[0], b[1] - a[1]);
                    let t = (((p[0] - a[0]) * ux + (p[1] - a[1]) * uy) / (ux * ux + uy * uy))
                        .clamp(0.0, 1.0);
                    (p[0] - a[0] - t * ux).hypot(p[1] - a[1] - t * uy)
                })
                .fold(Real::INFINITY, Real::min);
            arc_worst = arc_worst.max(d);
        }
        // The formula, from the chord count and the arc's angle.
        let theta = (a1 - a0).abs() / chords.len() as Real;
        let sagitta = r * (1.0 - (theta / 2.0).cos());
        assert!(
            (arc_worst - sagitta).abs() < 1e-6,
            "{arc_worst} vs {sagitta}"
        );
        worst = worst.max(sagitta);
    }
    assert!(worst <= bound && worst > bound / 4.0, "{worst}");
    assert!(
        (rep.chord_error_bound_mm - worst).abs() < 1e-12,
        "reported {} vs {worst}",
        rep.chord_error_bound_mm
    );
    assert!(rep.error_bound_mm >= rep.chord_error_bound_mm);
    assert_eq!(rep.rotary_error_bound_mm, 0.0);
}

const PI_2: Real = std::f64::consts::FRAC_PI_2;
