//! Unit tests of the interpreter through its public entry points.

use super::*;
use proptest::prelude::*;

fn run(text: &str) -> Result<Program, NcError> {
    parse_program(text, Path::new("t.ngc"), AxisValues::default())
}

fn ends(text: &str) -> Vec<[Real; 6]> {
    run(text)
        .expect("runs")
        .moves
        .iter()
        .map(|m| m.end.to_array())
        .collect()
}

fn near(a: Real, b: Real) -> bool {
    (a - b).abs() < 1e-9
}

#[test]
fn g0_g1_in_mm() {
    let p = run("G21 G90 G0 X10 Y5\nG1 X20 F100\nM2\n").expect("runs");
    assert_eq!(p.moves.len(), 2);
    assert_eq!(p.moves[1].end.get(AxisLetter::X), 20.0);
    assert_eq!(p.moves[1].feed_mm_per_min, Some(100.0));
    assert_eq!(p.ended_by, Some(3));
}

#[test]
fn inch_lengths_scale_and_angles_do_not() {
    let e = ends("G20 G0 X1 A90\nM2\n");
    assert!(near(e[0][0], 25.4));
    assert!(near(e[0][3], 90.0));
}

#[test]
fn incremental_and_g92_offsets() {
    // G92 X0 at X10 makes program X5 machine X15
    let e = ends("G0 X10\nG92 X0\nG0 X5\nG91 G0 X1\nM2\n");
    assert!(near(e[1][0], 15.0));
    assert!(near(e[2][0], 16.0));
}

#[test]
fn work_offsets_and_rotation() {
    // G55 at (100, 0) rotated 90°: program (10, 0) is machine (100, 10)
    let e = ends("G10 L2 P2 X100 R90\nG55 G0 X10 Y0\nM2\n");
    assert!(near(e[0][0], 100.0) && near(e[0][1], 10.0), "{e:?}");
}

#[test]
fn arcs_carry_centre_direction_and_sweep() {
    let p = run("G0 X10 Y0\nG3 X0 Y10 I-10 J0 F100\nG2 X10 Y0 R10\nM2\n").expect("runs");
    let MoveKind::Arc(a) = p.moves[1].kind else {
        panic!("arc expected")
    };
    assert!(near(a.center.x, 0.0) && near(a.center.y, 0.0));
    assert_eq!(a.rotation, 1);
    assert!(near(a.sweep_deg, 90.0));
    assert!(near(a.radius, 10.0));
    // the point half way along is on the circle at 45°
    let mid = p.moves[1].point_at(0.5).to_array();
    let h = 10.0 / 2f64.sqrt();
    assert!(near(mid[0], h) && near(mid[1], h), "{mid:?}");
    let MoveKind::Arc(b) = p.moves[2].kind else {
        panic!("arc expected")
    };
    // R10 clockwise from (0,10) to (10,0): the short arc about the origin
    assert!(near(b.center.x, 0.0) && near(b.center.y, 0.0), "{b:?}");
    assert!(near(b.sweep_deg, -90.0));
}

#[test]
fn full_circle_and_helix_turns() {
    let p = run("G0 X5\nG2 X5 Y0 Z-2 I-5 J0 P2 F100\nM2\n").expect("runs");
    let MoveKind::Arc(a) = p.moves[1].kind else {
        panic!("arc expected")
    };
    assert_eq!(a.rotation, -2);
    assert!(near(a.sweep_deg, -720.0));
    let chords: Vec<Move> = p.moves[1].chords(0.01).collect();
    // sagitta 0.01 on r = 5: step 2·acos(1 − 0.002) ≈ 0.1265 rad → ≥ 99 chords over 4π
    assert!(chords.len() >= 99, "{}", chords.len());
    assert_eq!(chords.last().expect("chords").end, p.moves[1].end);
}

#[test]
fn canned_cycle_g81_g99_retracts_to_r() {
    let e = ends("G0 X0 Y0 Z10\nG99 G81 X5 Y5 Z-3 R2 F100\nX10\nG80\nM2\n");
    // hole 1: xy at 10, down to R, feed to -3, back to R; hole 2 from R
    let z: Vec<Real> = e.iter().map(|p| p[2]).collect();
    assert_eq!(z, vec![10.0, 10.0, 2.0, -3.0, 2.0, 2.0, -3.0, 2.0]);
}

#[test]
fn subroutines_with_arguments_and_loops() {
    let text = "o<sq> sub\nG1 X#1 F100\no<sq> endsub\n#2 = 0\no10 while [#2 LT 3]\n#2 = [#2 + 1]\no<sq> call [#2 * 2]\no10 endwhile\nM2\n";
    let e = ends(text);
    let x: Vec<Real> = e.iter().map(|p| p[0]).collect();
    assert_eq!(x, vec![2.0, 4.0, 6.0]);
}

#[test]
fn errors_name_line_column_and_word() {
    let err = run("G0 X1\nG1 X2\nM2\n").unwrap_err();
    let d = &err.diagnostics[0];
    assert_eq!((d.line, d.column, d.word.as_str()), (2, 1, "G1"));
    assert!(d.message.contains("zero feed rate"), "{}", d.message);
    assert!(err.to_string().contains("t.ngc:2:1: \"G1\""), "{err}");
}

#[test]
fn exponent_notation_is_a_stray_e_word() {
    // RS274/NGC numbers have no exponent: `X1e999` is X1 and an E word nothing uses.
    let err = run("G21 G90\nG1 X1e999 F600\nM2\n").unwrap_err();
    let d = &err.diagnostics[0];
    assert_eq!((d.line, d.column), (2, 6), "{err}");
    assert!(d.word.to_ascii_uppercase().starts_with('E'), "{err}");
    assert!(d.message.contains("E word with no G76"), "{}", d.message);
}

#[test]
fn all_syntax_errors_after_the_stop_are_reported() {
    let err = run("G0 X1\nG0 X[1\nG0 Q$\nG1 X1 X2\nM2\n").unwrap_err();
    let lines: Vec<usize> = err.diagnostics.iter().map(|d| d.line).collect();
    assert_eq!(lines, vec![2, 3, 4]);
}

#[test]
fn program_without_end_is_rejected_at_the_last_line() {
    let err = run("G0 X1\nG0 X2\n").unwrap_err();
    assert_eq!(err.diagnostics[0].line, 2);
}

#[test]
fn streaming_from_a_file_matches_text() {
    let mut text = String::new();
    synthetic::bench_program(500, &mut text);
    let dir = std::env::temp_dir().join(format!("twinmill-nc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("b.ngc");
    std::fs::write(&path, &text).expect("write");
    let a: Vec<Record> = Interpreter::from_file(&path, InterpOptions::default())
        .expect("opens")
        .map(|r| r.expect("runs"))
        .collect();
    let b: Vec<Record> = Interpreter::from_text(&text, &path, InterpOptions::default())
        .map(|r| r.expect("runs"))
        .collect();
    assert_eq!(a, b);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A move made inside a subroutine file names that file, the others the program; a lent
/// record (`next_ref`) is the record the iterator hands out.
#[test]
fn records_name_the_file_of_their_block() {
    let dir = std::env::temp_dir().join(format!("twinmill-nc-file-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let main = dir.join("main.ngc");
    std::fs::write(&main, "G21 F100\nG1 X1\no<side> call\nG1 X3\nM2\n").expect("write");
    std::fs::write(dir.join("side.ngc"), "o<side> sub\nG1 X2\no<side> endsub\n").expect("write");
    let mut interp = Interpreter::from_file(&main, InterpOptions::default()).expect("opens");
    let mut seen = Vec::new();
    while let Some(rec) = interp.next_ref() {
        let rec = rec.expect("runs").clone();
        if let RecordBody::Motion(m) = &rec.body {
            seen.push((m.end.get(AxisLetter::X), rec.line, rec.file));
        }
    }
    let names: Vec<_> = seen
        .iter()
        .map(|&(x, line, file)| {
            let name = interp
                .file_path(file)
                .and_then(|p| p.file_name())
                .expect("named");
            (x, line, name.to_string_lossy().into_owned())
        })
        .collect();
    assert_eq!(
        names,
        [
            (1.0, 2, "main.ngc".to_string()),
            (2.0, 2, "side.ngc".to_string()),
            (3.0, 4, "main.ngc".to_string()),
        ]
    );
    let by_value: Vec<Record> = Interpreter::from_file(&main, InterpOptions::default())
        .expect("opens")
        .map(|r| r.expect("runs"))
        .collect();
    let mut lent = Vec::new();
    let mut interp = Interpreter::from_file(&main, InterpOptions::default()).expect("opens");
    while let Some(rec) = interp.next_ref() {
        lent.push(rec.expect("runs").clone());
    }
    assert_eq!(by_value, lent);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Small programs covering most of the language, mutated by the property tests.
const SEEDS: &[&str] = &[
    "G21 G90 G17 F500\nG0 X0 Y0 Z5\nG1 Z-1\nG2 X10 Y0 I5 J0\nG3 X0 Y0 R5\nG91 G1 X1 Y1 A10\nG90 M2\n",
    "G20\n#1=2\no<s> sub\nG1 X[#1*2] F10\no<s> return [#1]\no<s> endsub\no<s> call [3]\no1 if [#<_value> GT 1]\nG0 Y1\no1 else\nG0 Y2\no1 endif\nM30\n",
    "G0 X0 Y0 Z10\nG98 G83 X1 Y1 Z-5 R1 Q1 F100 L2\nG80\nG10 L2 P1 X1 R30\nG54 G0 X1\nG28\nG53 G0 X0\nM2\n",
    "T1 M6\nG43 H1\nG41.1 D2 G1 X10 F100\nY10\nX0\nG40 G1 Y0\nG92 X0\nG92.1\nM2\n",
    "%\no100 repeat [3]\nG1 @5 ^[#<_x>*10] F10\no100 endrepeat\nM98 P7 L2\n%\n",
];

fn edit_strategy() -> impl Strategy<Value = (usize, u8, u8)> {
    (any::<usize>(), any::<u8>(), 0u8..4)
}

fn apply(seed: &str, edits: &[(usize, u8, u8)]) -> Vec<u8> {
    let mut b = seed.as_bytes().to_vec();
    let alphabet = b"GXYZIJKRFPQLM#[]<>()=+-*/.0123456789 \nOo@^%;";
    for &(pos, val, op) in edits {
        let p = if b.is_empty() { 0 } else { pos % (b.len() + 1) };
        let c = alphabet[val as usize % alphabet.len()];
        match op {
            0 => b.insert(p, c),
            1 if p < b.len() => {
                b.remove(p);
            }
            2 if p < b.len() => b[p] = c,
            _ => b.insert(p, val),
        }
    }
    b
}

fn exercise(bytes: &[u8]) {
    let text = String::from_utf8_lossy(bytes);
    let opts = InterpOptions {
        max_blocks: 2_000,
        tool_table: ToolTable::parse("T1 P1 Z1 D0.5\nT2 P2 Z2 D1\n", Path::new("t.tbl"))
            .expect("table"),
        ..InterpOptions::default()
    };
    for rec in Interpreter::from_text(&text, Path::new("p.ngc"), opts) {
        if rec.is_err() {
            break;
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        exercise(&bytes);
    }

    #[test]
    fn mutated_programs_never_panic(
        seed in 0..SEEDS.len(),
        edits in proptest::collection::vec(edit_strategy(), 1..16),
    ) {
        exercise(&apply(SEEDS[seed], &edits));
    }
}

#[test]
fn splines_and_threads_that_linuxcnc_would_run_for_ever_are_clean_errors() {
    // LinuxCNC loops (practically) for ever on these; twinmill stops with the line.
    let spindle = "G21 G18 G90 S500 M3\nG0 X10 Y0 Z5\n";
    let err = run(&format!("{spindle}G76 P1 Z-10 I-1 J1e-9 K1\nM2\n")).unwrap_err();
    assert_eq!(err.diagnostics[0].line, 3, "{err}");
    let err = run("G21 G17 G90 F100\nG5.2 X1 Y1 P1 L40\nX2 Y0 P1\nG5.3\nM2\n").unwrap_err();
    assert_eq!(err.diagnostics[0].line, 4, "{err}");
    // a long NURBS evaluates in time linear in its control points
    let mut text = String::from("G21 G17 G90 F100\nG5.2 X0 Y1 P1\n");
    for i in 1..20_000 {
        text.push_str(&format!("X{i} Y{} P1\n", i % 2));
    }
    text.push_str("G5.3\nM2\n");
    let moves = ends(&text);
    assert!(moves.len() > 20_000, "{}", moves.len());
}
