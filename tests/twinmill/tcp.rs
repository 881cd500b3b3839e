//! Tool-centre-point programs (`[machine] controller = "tcp"`): a TCP program cuts the part
//! its joint equivalent cuts, a move turning a rotary axis keeps the tip on its line, and
//! `correct` writes a TCP program that cuts the corrected part. The joint equivalents come
//! from a small inverse kinematics of each nominal chain written out here (rotations and
//! offsets of the scene's comments), not from the crate's chain.

use nalgebra::{Matrix3, Vector3};
use std::path::Path;
use twinmill::cutting::stock::TriDexel;
use twinmill::cutting::sweep::{SweepOptions, sweep_program};
use twinmill::math::Real;
use twinmill::nc::{AxisLetter, Move};
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

fn rx(t: Real) -> Matrix3<Real> {
    let (s, c) = t.to_radians().sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

fn rz(t: Real) -> Matrix3<Real> {
    let (s, c) = t.to_radians().sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// The documented bound on the tip's distance from its TCP path (docs/nc.md): 0.1 µm.
const TCP_PATH_BOUND_MM: Real = 1e-4;

/// Axis values in the order X Y Z A B C.
type Q = [Real; 6];

/// The nominal tool tip of a scene's machine in the workpiece frame, and its inverse: the
/// linear axes that put the tip at `p` at the rotary values of `q`.
struct Kinematics {
    tip: fn(&Q) -> Vector3<Real>,
    linear: fn(&Vector3<Real>, &Q) -> Vector3<Real>,
    /// The machine's rotary letters, as the program writes them.
    rotary: &'static [(usize, char)],
}

/// `scenes/head-table.toml`: `RotZ(c)·T(x, y, z)·[RotY(b) about (0, 0, 150)]`: the tip at
/// `RotZ(c)·(x − 150 sin b, y, z + 150 − 150 cos b)`.
const HEAD_TABLE: Kinematics = Kinematics {
    tip: |q| {
        let b = q[4].to_radians();
        rz(q[5]) * Vector3::new(q[0] - 150.0 * b.sin(), q[1], q[2] + 150.0 - 150.0 * b.cos())
    },
    linear: |p, q| {
        let b = q[4].to_radians();
        let v = rz(-q[5]) * p;
        Vector3::new(v.x + 150.0 * b.sin(), v.y, v.z - 150.0 + 150.0 * b.cos())
    },
    rotary: &[(4, 'B'), (5, 'C')],
};

/// `scenes/trunnion-ac.toml`: `RotZ(c)·[RotX(a) about (0, 0, −50)]·T(x, y, z)`.
const TRUNNION: Kinematics = Kinematics {
    tip: |q| {
        let o = Vector3::new(0.0, 0.0, -50.0);
        rz(q[5]) * (rx(q[3]) * (Vector3::new(q[0], q[1], q[2]) - o) + o)
    },
    linear: |p, q| {
        let o = Vector3::new(0.0, 0.0, -50.0);
        rx(-q[3]) * (rz(-q[5]) * p - o) + o
    },
    rotary: &[(3, 'A'), (5, 'C')],
};

/// The distance (mm) of `p` from the polyline through the tips (X Y Z) of `path`.
fn off_path(path: &[Q], p: &Vector3<Real>) -> Real {
    path.windows(2)
        .map(|w| {
            let (a, e) = (
                Vector3::new(w[0][0], w[0][1], w[0][2]),
                Vector3::new(w[1][0], w[1][1], w[1][2]),
            );
            let d = e - a;
            let t = if d.norm() > 0.0 {
                ((p - a).dot(&d) / d.norm_squared()).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (a + d * t - p).norm()
        })
        .fold(Real::INFINITY, Real::min)
}

/// One block: rapid or feed, and the TCP target (tip X Y Z in the workpiece frame, A B C).
type Block = (bool, Q);

fn word(k: &Kinematics, q: &Q) -> String {
    let mut s = format!("X{:.9} Y{:.9} Z{:.9}", q[0], q[1], q[2]);
    for (i, c) in k.rotary {
        s.push_str(&format!(" {c}{:.9}", q[*i]));
    }
    s
}

fn g(rapid: bool) -> &'static str {
    if rapid { "G0" } else { "G1" }
}

/// The blocks as a TCP program, from the tip at home (0, 0, 120).
fn tcp_text(k: &Kinematics, blocks: &[Block]) -> String {
    let mut s = String::from("%\nG21 G90 G94 F600\n");
    for (rapid, q) in blocks {
        s.push_str(&format!("{} {}\n", g(*rapid), word(k, q)));
    }
    s.push_str("M30\n%\n");
    s
}

/// The same blocks as a joint program: every end solved by the hand inverse kinematics; a
/// block that turns a rotary axis split into `parts` joint moves through solved points.
fn joint_text(k: &Kinematics, blocks: &[Block], parts: usize) -> String {
    let joint = |p: &Q| {
        let v = (k.linear)(&Vector3::new(p[0], p[1], p[2]), p);
        let mut q = *p;
        q[..3].copy_from_slice(v.as_slice());
        q
    };
    let mut s = String::from("%\nG21 G90 G94 F600\n");
    let mut at: Q = [0.0, 0.0, 120.0, 0.0, 0.0, 0.0];
    for (rapid, q) in blocks {
        let n = if (3..6).any(|i| q[i] != at[i]) {
            parts
        } else {
            1
        };
        for j in 1..=n {
            let t = j as Real / n as Real;
            let p: Q = std::array::from_fn(|i| at[i] + (q[i] - at[i]) * t);
            s.push_str(&format!("{} {}\n", g(*rapid), word(k, &joint(&p))));
        }
        at = *q;
    }
    s.push_str("M30\n%\n");
    s
}

fn load(file: &str, tcp: bool) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(file);
    let text = std::fs::read_to_string(&path).expect("scene");
    let text = if tcp {
        text.replacen("[machine]\n", "[machine]\ncontroller = \"tcp\"\n", 1)
    } else {
        text
    };
    Scene::parse(&text, &path).expect("loads")
}

/// The moves swept on the scene's machine (the rotary sub-steps bounded at 0.01 µm), on a
/// 0.4 mm grid.
fn cut(s: &Scene, chain: &twinmill::machine::chain::Chain, moves: &[Move]) -> TriDexel {
    let mut stock = TriDexel::new_box(s.stock_box, 0.4, 4e9).expect("fits");
    let opts = SweepOptions {
        rotary_step_bound_mm: 1e-5,
    };
    sweep_program(&mut stock, chain, &s.tool, moves, &opts, &NoProgress).expect("sweeps");
    stock
}

/// The two parts compared ray by ray: the largest distance between crossings of cut surfaces
/// (along the surface normal, to first order, on rays at most 60° off it), the crossings
/// compared, and the rays whose crossings differ in number or direction (an edge across the
/// ray). X and Y rays below `z_min` are left out: there a tilted flat end's rim sweeps a
/// surface the rays meet at grazing incidence while the crossing carries the flank's normal,
/// so the first-order distance does not hold.
fn compare(a: &TriDexel, b: &TriDexel, z_min: Real) -> (Real, usize, usize) {
    let (mut worst, mut compared, mut unmatched): (Real, usize, usize) = (0.0, 0, 0);
    for (g, h) in a.grids().iter().zip(b.grids()) {
        let (nu, nv) = g.dims();
        assert_eq!(h.dims(), (nu, nv));
        let axis = g.axis();
        for iv in 0..nv {
            for iu in 0..nu {
                let (x, y) = (g.ray(iu, iv), h.ray(iu, iv));
                let crossings = |r: &[twinmill::cutting::stock::Segment]| {
                    r.iter().flat_map(|s| [s.lo, s.hi]).collect::<Vec<_>>()
                };
                let (cx, cy) = (crossings(x), crossings(y));
                if cx.iter().chain(&cy).all(|c| c.line == 0)
                    || (axis < 2 && g.ray_origin(iu, iv).z < z_min)
                {
                    continue;
                }
                if cx.len() != cy.len()
                    || cx
                        .iter()
                        .zip(&cy)
                        .any(|(p, q)| p.normal().dot(&q.normal()) < 0.9)
                {
                    unmatched += 1;
                    continue;
                }
                for (p, q) in cx.iter().zip(&cy) {
                    let n = q.normal()[axis].abs();
                    if (p.line == 0 && q.line == 0) || n < 0.5 {
                        continue;
                    }
                    compared += 1;
                    worst = worst.max((p.t - q.t).abs() * n);
                }
            }
        }
    }
    (worst, compared, unmatched)
}

/// Side cuts at two C angles, a 3+2 chamfer with the tool tilted, all on the workpiece's
/// faces as a TCP program writes them (40 mm cube, sides at ±20, D6 tool).
fn head_table_3_2() -> Vec<Block> {
    vec![
        (true, [-30.0, -22.6, 120.0, 0.0, 0.0, 0.0]),
        (true, [-30.0, -22.6, 20.0, 0.0, 0.0, 0.0]),
        (false, [30.0, -22.6, 20.0, 0.0, 0.0, 0.0]),
        (true, [30.0, -22.6, 120.0, 0.0, 0.0, 0.0]),
        (true, [22.6, -30.0, 120.0, 0.0, 0.0, 90.0]),
        (true, [22.6, -30.0, 20.0, 0.0, 0.0, 90.0]),
        (false, [22.6, 30.0, 20.0, 0.0, 0.0, 90.0]),
        (true, [22.6, 30.0, 120.0, 0.0, 0.0, 90.0]),
        // B = 30 at C = 180: the tool leans towards −X; the −X top edge.
        (true, [-21.0, 30.0, 120.0, 0.0, 30.0, 180.0]),
        (true, [-21.0, 30.0, 37.0, 0.0, 30.0, 180.0]),
        (false, [-21.0, -30.0, 37.0, 0.0, 30.0, 180.0]),
        (true, [-21.0, -30.0, 120.0, 0.0, 30.0, 180.0]),
    ]
}

/// A groove across the top with B and C turning while the tip runs straight, then one with
/// C alone turning through 90°.
fn head_table_simultaneous() -> Vec<Block> {
    // Values off the 0.4 mm grid's rays (± the tool radius): no ray grazes an end position
    // or a flat end's floor.
    vec![
        (true, [-10.13, -9.93, 120.0, 0.0, 0.0, 0.0]),
        (true, [-10.13, -9.93, 36.07, 0.0, 0.0, 0.0]),
        (false, [10.17, 9.87, 36.07, 0.0, 10.0, 60.0]),
        (true, [10.17, 9.87, 120.0, 0.0, 10.0, 60.0]),
        (true, [-12.03, 8.11, 120.0, 0.0, 0.0, 0.0]),
        (true, [-12.03, 8.11, 37.13, 0.0, 0.0, 0.0]),
        (false, [6.07, -10.13, 37.13, 0.0, 0.0, 90.0]),
        (true, [6.07, -10.13, 120.0, 0.0, 0.0, 90.0]),
    ]
}

fn trunnion_blocks() -> Vec<Block> {
    vec![
        (true, [-30.0, -22.6, 120.0, 0.0, 0.0, 0.0]),
        (true, [-30.0, -22.6, 20.0, 0.0, 0.0, 0.0]),
        (false, [30.0, -22.6, 20.0, 0.0, 0.0, 0.0]),
        (true, [30.0, -22.6, 120.0, 0.0, 0.0, 0.0]),
        (true, [30.0, 22.6, 120.0, 0.0, 0.0, 90.0]),
        (true, [30.0, 22.6, 20.0, 0.0, 0.0, 90.0]),
        (false, [-30.0, 22.6, 20.0, 0.0, 0.0, 90.0]),
        (true, [-30.0, 22.6, 120.0, 0.0, 0.0, 90.0]),
        // A = 30 at C = 0: the tool leans towards −Y; the −Y top edge.
        (true, [-30.0, -21.0, 120.0, 30.0, 0.0, 0.0]),
        (true, [-30.0, -21.0, 37.0, 30.0, 0.0, 0.0]),
        (false, [30.0, -21.0, 37.0, 30.0, 0.0, 0.0]),
        (true, [30.0, -21.0, 120.0, 30.0, 0.0, 0.0]),
        // A and C turning while the tip runs straight across the top.
        (true, [-10.13, 0.07, 120.0, 0.0, 0.0, 0.0]),
        (true, [-10.13, 0.07, 36.0, 0.0, 0.0, 0.0]),
        (false, [10.17, 5.11, 35.0, 15.0, 0.0, 45.0]),
        (true, [10.17, 5.11, 120.0, 15.0, 0.0, 45.0]),
    ]
}

/// A TCP program and its hand-solved joint equivalent cut the same part on the nominal
/// machine, to the TCP bound (0.1 µm) and the sweeps' own.
fn same_part(file: &str, k: &Kinematics, blocks: &[Block]) {
    let (tcp, joint) = (load(file, true), load(file, false));
    let pt = tcp
        .program_from_text(&tcp_text(k, blocks))
        .expect("TCP parses");
    let pj = joint
        .program_from_text(&joint_text(k, blocks, 400))
        .expect("joint parses");
    let nominal = joint.chain().nominal();
    let (a, b) = (
        cut(&tcp, &nominal, &pt.moves),
        cut(&joint, &nominal, &pj.moves),
    );
    let (worst, compared, unmatched) = compare(&a, &b, Real::NEG_INFINITY);
    assert!(compared > 2000, "{file}: {compared} crossings compared");
    assert!(
        unmatched * 20 < compared,
        "{file}: {unmatched} rays unmatched of {compared}"
    );
    // Each path within the TCP bound of the TCP path (the hand one's 400 parts: < 0.02 µm),
    // each sweep of a move turning a rotary axis within 0.1 µm of its swept surface (the
    // envelope's bound, docs/limits.md).
    let bound = TCP_PATH_BOUND_MM + 2.0 * 1e-4 + 2e-5;
    assert!(
        worst <= bound,
        "{file}: the TCP part is {worst} mm off the joint one (bound {bound})"
    );
    // The TCP program is not the joint one read as joint values.
    let as_joint = joint
        .program_from_text(&tcp_text(k, blocks))
        .expect("parses");
    let (off, _, _) = compare(
        &cut(&joint, &nominal, &as_joint.moves),
        &b,
        Real::NEG_INFINITY,
    );
    assert!(off > 0.1, "{file}: read as joint values only {off} mm off");
}

#[test]
fn a_tcp_program_cuts_the_part_of_its_joint_equivalent() {
    let mut head = head_table_3_2();
    head.extend(head_table_simultaneous());
    same_part("head-table.toml", &HEAD_TABLE, &head);
    same_part("trunnion-ac.toml", &TRUNNION, &trunnion_blocks());
}

#[test]
fn a_tcp_move_turning_c_keeps_the_tip_on_its_line() {
    let s = load("head-table.toml", true);
    let blocks = head_table_simultaneous();
    let program = s
        .program_from_text(&tcp_text(&HEAD_TABLE, &blocks))
        .expect("parses");
    // Line 5 of the text is the third block: B 0 → 10 and C 0 → 60 while the tip runs across
    // the top; line 9: C 0 → 90 alone.
    for (line, from, to) in [(5, blocks[1].1, blocks[2].1), (9, blocks[5].1, blocks[6].1)] {
        let moves: Vec<&Move> = program.moves.iter().filter(|m| m.line == line).collect();
        assert!(moves.len() > 20, "line {line}: {} joint moves", moves.len());
        let mut worst: Real = 0.0;
        for m in &moves {
            for i in 0..=16 {
                let t = i as Real / 16.0;
                let q: Q = std::array::from_fn(|k| {
                    let l = AxisLetter::ALL[k];
                    m.start.get(l) + (m.end.get(l) - m.start.get(l)) * t
                });
                // The move's parameter from C (linear in it on both paths).
                let s = q[5] / to[5];
                let want = Vector3::new(
                    from[0] + (to[0] - from[0]) * s,
                    from[1] + (to[1] - from[1]) * s,
                    from[2] + (to[2] - from[2]) * s,
                );
                assert!((q[4] - to[4] * s).abs() < 1e-9, "B follows C");
                worst = worst.max(((HEAD_TABLE.tip)(&q) - want).norm());
            }
        }
        assert!(
            worst <= TCP_PATH_BOUND_MM,
            "line {line}: the tip is {worst} mm off its line"
        );
        assert!(
            worst > 1e-7,
            "line {line}: {worst} (the check sees the chords)"
        );
    }
}

/// `correct` of a TCP program on the head-table scene (C and B lines offset and tilted, X
/// and Y out of square): the corrected part within 1 µm of the nominal one on the twin, and
/// the written program, read back as a TCP program and cut on the deviated machine, cuts it.
fn corrected_in_tcp(blocks: &[Block], z_min: Real) {
    use twinmill::calibration::correct::write_gcode;
    let s = load("head-table.toml", true);
    let text = tcp_text(&HEAD_TABLE, blocks);
    let program = s.program_from_text(&text).expect("parses");
    let out =
        twinmill::pipeline::correct(&s, &program, s.chain(), 1e-3, &NoProgress).expect("corrects");
    let last = out.report.iterations.last().expect("a pass");
    let nominal_part = cut(&s, &s.chain().nominal(), &program.moves);
    let given = compare(&cut(&s, s.chain(), &program.moves), &nominal_part, z_min).0;
    assert!(given > 0.01, "the program as given is only {given} mm off");
    let mut written = Vec::new();
    write_gcode(&out.corrected, &out.header, &mut written).expect("writes");
    let written = String::from_utf8(written).expect("utf-8");
    assert!(written.contains("tool-centre-point program"), "{written}");
    let again = s
        .program_from_text(&written)
        .expect("the corrected program parses");
    let (worst, compared, unmatched) =
        compare(&cut(&s, s.chain(), &again.moves), &nominal_part, z_min);
    assert!(
        compared > 1000 && unmatched * 20 < compared,
        "{unmatched} rays unmatched of {compared}"
    );
    assert!(
        worst <= 1e-3,
        "re-read in TCP mode, the corrected program cuts {worst} mm off ({} on the twin's pass)",
        last.part.max_mm
    );
    // Its values are tip coordinates: each block end, through the hand kinematics of the
    // nominal chain, is within the corrections (< 0.1 mm) of its written X Y Z.
    for b in &out.corrected.blocks {
        let q: Q = std::array::from_fn(|k| b.end.get(AxisLetter::ALL[k]));
        let joint = (HEAD_TABLE.linear)(&Vector3::new(q[0], q[1], q[2]), &q);
        let mut qj = q;
        qj[..3].copy_from_slice(joint.as_slice());
        assert!(((HEAD_TABLE.tip)(&qj) - Vector3::new(q[0], q[1], q[2])).norm() < 1e-9);
    }
    // … and they lie on the programmed TCP path (within the corrections, < 0.1 mm): the tip,
    // not the joint values (75 mm off at B = 30).
    let mut path: Vec<Q> = vec![[0.0, 0.0, 120.0, 0.0, 0.0, 0.0]];
    path.extend(blocks.iter().map(|b| b.1));
    for b in out.corrected.blocks.iter().filter(|b| b.source.is_some()) {
        let p = Vector3::new(
            b.end.get(AxisLetter::X),
            b.end.get(AxisLetter::Y),
            b.end.get(AxisLetter::Z),
        );
        let off = off_path(&path, &p);
        assert!(off < 0.1, "block end {p:?} is {off} mm off the TCP path");
    }
}

#[test]
fn correct_writes_a_3_2_tcp_program_that_cuts_the_corrected_part() {
    corrected_in_tcp(&head_table_3_2(), Real::NEG_INFINITY);
}

#[test]
fn correct_writes_a_simultaneous_tcp_program_that_cuts_the_corrected_part() {
    // The tilted groove's rim dips below its tip's 36 mm.
    corrected_in_tcp(&head_table_simultaneous(), 36.0);
}

#[test]
fn tcp_is_refused_without_rotary_axes_and_on_a_hexapod() {
    for (file, key) in [
        ("xyz-pocket.toml", "needs a rotary axis"),
        ("hexapod-step.toml", "applies to serial machines"),
        ("head-table.toml", "must be \"joint\" or \"tcp\""),
    ] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenes")
            .join(file);
        let text = std::fs::read_to_string(&path).expect("scene");
        let value = if file == "head-table.toml" {
            "rtcp"
        } else {
            "tcp"
        };
        let text = text.replacen(
            "[machine]\n",
            &format!("[machine]\ncontroller = \"{value}\"\n"),
            1,
        );
        let line = text
            .lines()
            .position(|l| l.starts_with("controller"))
            .expect("added")
            + 1;
        let err = if text.contains("kind = \"hexapod\"") {
            Scene::parse_hexapod_cut(&text, &path, &twinmill::scene::MemoryBudget::installed())
                .expect_err("refused")
                .to_string()
        } else {
            Scene::parse(&text, &path).expect_err("refused").to_string()
        };
        assert!(err.contains(key), "{file}: {err}");
        assert!(err.contains(&format!("{file}:{line}:14")), "{file}: {err}");
        assert_eq!(err.lines().count(), 1, "{err}");
    }
}

/// The TCP targets of a program's text (absolute, every block naming the axes it moves):
/// the tip X Y Z and A B C of every G0/G1 block end, from home (tip at (0, 0, 120)).
fn tcp_targets(text: &str) -> Vec<Q> {
    let mut at: Q = [0.0, 0.0, 120.0, 0.0, 0.0, 0.0];
    let mut out = vec![at];
    for line in text.lines() {
        let code = line.split('(').next().unwrap_or("");
        let words: Vec<&str> = code.split_whitespace().collect();
        if !words.iter().any(|w| *w == "G0" || *w == "G1") {
            continue;
        }
        for w in &words {
            let (l, v) = w.split_at(1);
            if let Some(k) = "XYZABC".find(l) {
                at[k] = v.parse().expect("a number");
            }
        }
        out.push(at);
    }
    out
}

/// `twinmill correct scenes/head-table-tcp.toml` through the command line: it writes a TCP
/// program (tip coordinates: every block end within the corrections of the source's tip
/// path, not on the joint values), whose verification on the twin puts path and part within
/// 1 µm; read back as a TCP program and cut here on the deviated machine it leaves the
/// nominal part within 1 µm, where the program as given misses by tens of µm.
#[test]
fn correct_of_the_tcp_scene_writes_a_tcp_program_within_a_micrometre() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/head-table-tcp.toml");
    let sb = super::Sandbox::new("tcp-scene-correct");
    let (code, out, err) = sb.run(&["correct", path.to_str().expect("utf-8"), "--out", "out"]);
    assert_eq!(code, 0, "{out}\n{err}");
    let written =
        std::fs::read_to_string(sb.dir.join("out/head-table-tcp-corrected.ngc")).expect("written");
    assert!(written.contains("tool-centre-point program"), "{written}");
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(sb.dir.join("out/head-table-tcp-correct.json")).expect("json"),
    )
    .expect("parses");
    let last = report["iterations"]
        .as_array()
        .and_then(|v| v.last().cloned())
        .expect("a pass");
    for what in ["path", "part"] {
        let v = last[what]["max_mm"].as_f64().expect("number");
        assert!(v < 1e-3, "{what} {v} mm");
    }

    let s = Scene::load(&path).expect("scene");
    let source = std::fs::read_to_string(path.with_extension("ngc")).expect("program");
    let targets = tcp_targets(&source);
    // Every written block end lies on the source's TCP path within the corrections.
    let mut ends = tcp_targets(&written);
    ends.remove(0);
    assert!(ends.len() > targets.len(), "{} blocks", ends.len());
    for q in &ends {
        let p = Vector3::new(q[0], q[1], q[2]);
        let off = off_path(&targets, &p);
        assert!(off < 0.1, "block end {q:?} is {off} mm off the TCP path");
    }
    let program = s.load_program().expect("parses");
    let nominal_part = cut(&s, &s.chain().nominal(), &program.moves);
    // The tilted groove's rim dips below its tip's 36 mm (see compare).
    let z_min = 36.0;
    let given = compare(&cut(&s, s.chain(), &program.moves), &nominal_part, z_min).0;
    assert!(given > 0.01, "the program as given is only {given} mm off");
    let again = s
        .program_from_text(&written)
        .expect("the corrected program parses");
    let (worst, compared, unmatched) =
        compare(&cut(&s, s.chain(), &again.moves), &nominal_part, z_min);
    assert!(
        compared > 1000 && unmatched * 20 < compared,
        "{unmatched} rays unmatched of {compared}"
    );
    assert!(
        worst <= 1e-3,
        "the corrected TCP program cuts {worst} mm off"
    );
}
