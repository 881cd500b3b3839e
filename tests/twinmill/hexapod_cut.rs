//! Cutting on the hexapod: the step experiment's faces against an independent derivation
//! of `FK_actual(IK_nominal)` written out here (strut lengths, Newton on central-difference
//! Jacobians, the flat end mill's bottom disc), the table axes, the sweep's bounds, and bad
//! input through the command line.

use super::Sandbox;
use nalgebra::{Matrix3, Matrix6, Vector6};
use std::path::{Path, PathBuf};
use twinmill::cutting::stock::TriDexel;
use twinmill::math::{Real, Vector3};
use twinmill::pipeline::machine_part;
use twinmill::progress::NoProgress;
use twinmill::scene::{HexapodScene, Machine, MemoryBudget, Scene, SceneError};

pub(super) fn scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name)
}

// ---------------------------------------------------------------------------------------
// The oracle: a hexapod written out from its definition (L_i = |t + R·(a_i − o) − b_i|,
// R = Rz(c)·Ry(b)·Rx(a), readings s_i = L_i − l0_i), independent of the library's
// kinematics and sweep.

pub(super) struct Oracle {
    base: [Vector3; 6],
    platform: [Vector3; 6],
    l0: [Real; 6],
    tool: Vector3,
}

pub(super) fn rpy(a: Real, b: Real, c: Real) -> Matrix3<Real> {
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, a.cos(), -a.sin(), 0.0, a.sin(), a.cos());
    let ry = Matrix3::new(b.cos(), 0.0, b.sin(), 0.0, 1.0, 0.0, -b.sin(), 0.0, b.cos());
    let rz = Matrix3::new(c.cos(), -c.sin(), 0.0, c.sin(), c.cos(), 0.0, 0.0, 0.0, 1.0);
    rz * ry * rx
}

impl Oracle {
    /// From the 42 parameters in the documented order (b_i, a_i, l0_i) and the tool offset.
    pub(super) fn new(p: &[Real; 42], tool: Vector3) -> Self {
        Self {
            base: std::array::from_fn(|i| Vector3::new(p[3 * i], p[3 * i + 1], p[3 * i + 2])),
            platform: std::array::from_fn(|i| {
                Vector3::new(p[18 + 3 * i], p[19 + 3 * i], p[20 + 3 * i])
            }),
            l0: std::array::from_fn(|i| p[36 + i]),
            tool,
        }
    }

    /// Readings at the pose (x, y, z mm; a, b, c rad).
    pub(super) fn readings(&self, q: &Vector6<Real>) -> Vector6<Real> {
        let r = rpy(q[3], q[4], q[5]);
        let t = Vector3::new(q[0], q[1], q[2]);
        Vector6::from_fn(|i, _| {
            (t + r * (self.platform[i] - self.tool) - self.base[i]).norm() - self.l0[i]
        })
    }

    /// The pose whose readings are `s`, by Newton from `near` with a central-difference
    /// Jacobian.
    pub(super) fn pose_of(&self, s: &Vector6<Real>, near: &Vector6<Real>) -> Vector6<Real> {
        let mut q = *near;
        for _ in 0..50 {
            let f = self.readings(&q) - s;
            if f.amax() < 1e-12 {
                break;
            }
            let mut j = Matrix6::zeros();
            for k in 0..6 {
                let h = if k < 3 { 1e-4 } else { 1e-7 };
                let mut qp = q;
                let mut qm = q;
                qp[k] += h;
                qm[k] -= h;
                j.set_column(k, &((self.readings(&qp) - self.readings(&qm)) / (2.0 * h)));
            }
            q -= j.lu().solve(&f).expect("not singular");
        }
        q
    }
}

/// The machine's pose for a command (mm, degrees): the readings of the controller (`nominal`
/// here, or calibrated parameters), solved on the actual machine.
pub(super) fn reached(nominal: &Oracle, actual: &Oracle, cmd: [Real; 6]) -> Vector6<Real> {
    let q = Vector6::new(
        cmd[0],
        cmd[1],
        cmd[2],
        cmd[3].to_radians(),
        cmd[4].to_radians(),
        cmd[5].to_radians(),
    );
    actual.pose_of(&nominal.readings(&q), &q)
}

/// The lowest height the bottom disc (radius `r`) of a flat end mill reaches over the
/// point (x0, y0) while its tip is commanded along x from `xs` to `xe` at (y, z) with the
/// angles `abc`: the disc's plane at (x0, y0), wherever that point lies within the disc,
/// minimised over poses sampled 1 µm apart near it.
pub(super) fn face_height(
    nominal: &Oracle,
    actual: &Oracle,
    (xs, xe): (Real, Real),
    (y, z): (Real, Real),
    abc: [Real; 3],
    r: Real,
    (x0, y0): (Real, Real),
) -> Real {
    let (lo, hi) = (
        (x0 - r - 0.5).max(xs.min(xe)),
        (x0 + r + 0.5).min(xs.max(xe)),
    );
    let n = ((hi - lo) / 1e-3).ceil() as usize;
    let mut best = Real::INFINITY;
    for k in 0..=n {
        let x = lo + (hi - lo) * k as Real / n as Real;
        let p = reached(nominal, actual, [x, y, z, abc[0], abc[1], abc[2]]);
        let axis = rpy(p[3], p[4], p[5]) * Vector3::z();
        let tip = Vector3::new(p[0], p[1], p[2]);
        let h = tip.z - (axis.x * (x0 - tip.x) + axis.y * (y0 - tip.y)) / axis.z;
        if (Vector3::new(x0, y0, h) - tip).norm() <= r {
            best = best.min(h);
        }
    }
    best
}

/// The top of the material along the z ray nearest (x, y): its exact (x, y) and height.
pub(super) fn z_top(stock: &TriDexel, x: Real, y: Real) -> (Real, Real, Real) {
    let g = &stock.grids()[2];
    let o = g.ray_origin(0, 0);
    let (du, dv) = g.pitches();
    let (iu, iv) = (
        ((x - o.x) / du).round() as usize,
        ((y - o.y) / dv).round() as usize,
    );
    let p = g.ray_origin(iu, iv);
    let top = g.ray(iu, iv).last().expect("material on the ray").hi.t;
    (p.x, p.y, top)
}

pub(super) fn load(path: &Path) -> (Scene, HexapodScene) {
    let scene = Scene::load_hexapod_cut(path, &MemoryBudget::installed()).expect("scene loads");
    let hex = HexapodScene::load(path).expect("hexapod loads");
    (scene, hex)
}

#[test]
fn hexapod_step_faces_match_the_independent_fk_derivation() {
    let (scene, hex) = load(&scene_path("hexapod-step.toml"));
    let program = scene.load_program().expect("program parses");
    let part = machine_part(&scene, &program, &NoProgress).expect("the hexapod cuts");
    let s = &part.sweep;
    assert!(s.error_bound_mm <= 1e-4, "{s:?}");
    // The strut's offset bends the straight moves and moves the tip off its command.
    assert!(s.tip_error_mm.expect("pose source") > 0.01, "{s:?}");
    assert!(s.path_bow_mm.expect("pose source") > 0.0, "{s:?}");
    assert!(s.curved_moves > 0 && s.rotary_moves > 0, "{s:?}");

    let nominal = Oracle::new(&hex.nominal.parameters(), hex.nominal.tool_offset());
    let actual = Oracle::new(&hex.actual.parameters(), hex.actual.tool_offset());
    let r = scene.tool.radius();
    // Face A: the pass from x = −90 to −4 at c = −20°; face B: from 90 to 4 at c = +20°.
    let (xa, ya, za) = z_top(&part.stock, -30.0, 0.0);
    let (xb, yb, zb) = z_top(&part.stock, 30.0, 0.0);
    let oa = face_height(
        &nominal,
        &actual,
        (-90.0, -4.0),
        (0.0, 159.0),
        [0.0, 0.0, -20.0],
        r,
        (xa, ya),
    );
    let ob = face_height(
        &nominal,
        &actual,
        (90.0, 4.0),
        (0.0, 159.0),
        [0.0, 0.0, 20.0],
        r,
        (xb, yb),
    );
    assert!((za - oa).abs() <= 0.5e-3, "face A {za} vs {oa}");
    assert!((zb - ob).abs() <= 0.5e-3, "face B {zb} vs {ob}");
    let (step, predicted) = (zb - za, ob - oa);
    assert!(
        (step - predicted).abs() <= 0.5e-3,
        "step {step} vs {predicted}"
    );
    // The step is the deviation's, not rounding: tens of µm, and the faces are off their
    // commanded height.
    assert!(predicted.abs() > 0.01, "{predicted}");
    assert!((oa - 159.0).abs() > 0.01, "{oa}");
}

#[test]
fn a_perfect_hexapod_cuts_the_commanded_faces() {
    let text = std::fs::read_to_string(scene_path("hexapod-step.toml")).expect("scene");
    let text = text.replace("l0_1 = 0.1", "");
    let sb = Sandbox::new("hexapod-perfect");
    let path = sb.write("hexapod-step.toml", text.as_bytes());
    sb.write(
        "hexapod-step.ngc",
        &std::fs::read(scene_path("hexapod-step.ngc")).expect("program"),
    );
    let (scene, _) = load(&path);
    let program = scene.load_program().expect("program parses");
    let part = machine_part(&scene, &program, &NoProgress).expect("cuts");
    for x in [-30.0, 30.0] {
        let (_, _, z) = z_top(&part.stock, x, 0.0);
        assert!((z - 159.0).abs() < 1e-6, "{x}: {z}");
    }
    assert!(part.sweep.tip_error_mm.expect("pose source") < 1e-6);
    // Straight moves at fixed angles are exact translations: no curved moves.
    assert_eq!(part.sweep.curved_moves, 0, "{:?}", part.sweep);
}

/// A C table turning the part on the step scene's machine: the table's axis tilted by
/// `alpha_CS` about x. Faces cut at C = 0 and C = 180 with the platform level against the
/// table turned by the exact rotation written out here.
#[test]
fn a_table_axis_turns_the_part_and_its_tilt_shows_between_the_faces() {
    let text = std::fs::read_to_string(scene_path("hexapod-step.toml")).expect("scene");
    let alpha: Real = 2e-4;
    let text = text
        .replace("l0_1 = 0.1", &format!("l0_1 = 0.1\nalpha_CS = {alpha}"))
        .replace(
            "[tool]",
            "[table_axes]\naxes = [{ name = \"C\", direction = [0.0, 0.0, 1.0] }]\n\n[tool]",
        )
        .replace(
            "min = [-60.0, -20.0, 140.0]\nmax = [60.0, 20.0, 160.0]",
            "min = [-40.0, -40.0, 140.0]\nmax = [40.0, 40.0, 160.0]",
        );
    let sb = Sandbox::new("hexapod-table");
    let path = sb.write("hexapod-table.toml", text.as_bytes());
    // One pass along x at y = 20 (machine frame) at C = 0, and again at C = 180: the second
    // cuts the other side of the part.
    sb.write(
        "hexapod-step.ngc",
        b"G21 G90\nG0 X-70 Y20 Z200 A0 B0 C0\nG0 Z159\nG1 X70 F600\nG0 Z200\nG0 C180\nG0 X-70\nG0 Z159\nG1 X70\nG0 Z200\nM2\n",
    );
    let (scene, hex) = load(&path);
    let Machine::Hexapod(h) = &scene.machine else {
        panic!("a hexapod")
    };
    assert!(h.twin.table.is_some());
    let program = scene.load_program().expect("program parses");
    let part = machine_part(&scene, &program, &NoProgress).expect("cuts");
    let nominal = Oracle::new(&hex.nominal.parameters(), hex.nominal.tool_offset());
    let actual = Oracle::new(&hex.actual.parameters(), hex.actual.tool_offset());
    let r = scene.tool.radius();
    // The chain from the part frame W to the base frame: the C rotation, then its joint's
    // deviation Rx(alpha): p_W = Rz(C)·Rx(alpha)·p_base.
    let w_from_base = |c: Real| rpy(0.0, 0.0, c.to_radians()) * rpy(alpha, 0.0, 0.0);
    // The pass at y = 20 (base frame) cuts the face at y_W ≈ +20 at C = 0 and at y_W ≈ −20
    // at C = 180: points across each face, each against the oracle.
    let mut tilt_seen: Real = 0.0;
    for (c, y_face) in [(0.0, 20.0), (180.0, -20.0)] {
        for (dx, dy) in [
            (-20.0, -5.0),
            (-20.0, 5.0),
            (0.0, 0.0),
            (20.0, -5.0),
            (20.0, 5.0),
        ] {
            let (x, y, z) = z_top(&part.stock, dx, y_face + dy);
            // The W ray's point in the base frame, the disc's lowest height over it there,
            // and that height back in W (the ray is tilted by alpha in the base frame: the
            // µm between the guess and the surface move it by alpha·µm, far below 1 nm).
            let rot = w_from_base(c);
            let p_base = rot.transpose() * Vector3::new(x, y, z);
            let h = face_height(
                &nominal,
                &actual,
                (-70.0, 70.0),
                (20.0, 159.0),
                [0.0, 0.0, 0.0],
                r,
                (p_base.x, p_base.y),
            );
            let zw = (rot * Vector3::new(p_base.x, p_base.y, h)).z;
            assert!((z - zw).abs() <= 0.5e-3, "C{c} at ({x}, {y}): {z} vs {zw}");
            // What the table's tilt adds: the height the platform alone cuts there.
            tilt_seen = tilt_seen.max((z - h).abs());
        }
    }
    // alpha · 25 mm = 5 µm at the far edge: the table's deviation shows.
    assert!(tilt_seen > 3e-3, "{tilt_seen}");
}

#[test]
fn cli_simulates_a_hexapod_and_refuses_bad_input_with_the_nc_line() {
    let sb = Sandbox::new("hexapod-cut-cli");
    let scene = std::fs::read_to_string(scene_path("hexapod-step.toml")).expect("scene");
    let program = std::fs::read_to_string(scene_path("hexapod-step.ngc")).expect("program");
    sb.write("hexapod-step.toml", scene.as_bytes());
    sb.write("hexapod-step.ngc", program.as_bytes());
    let (code, out, err) = sb.run(&["simulate", "hexapod-step.toml", "--out", "out"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("hexapod       tip off its command"), "{out}");
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(sb.dir.join("out/hexapod-step-simulate/report.json"))
            .expect("report"),
    )
    .expect("json");
    let tip = report["sweep"]["tip_error_mm"].as_f64().expect("tip error");
    let bow = report["sweep"]["path_bow_mm"].as_f64().expect("bow");
    assert!(tip > 0.01 && bow > 0.0, "{report}");
    std::fs::remove_dir_all(sb.dir.join("out")).expect("clean");

    // Programs the machine cannot follow: a strut beyond its stroke (far below the table
    // reach), the platform tilted past its joint cones; each names the NC line.
    for (bad, line) in [
        (
            program.replace("G0 Z159\nG1 X4", "G0 Z159\nG1 X4 Z-600"),
            11,
        ),
        (program.replace("G0 X90 C20", "G0 X90 A80"), 9),
    ] {
        sb.write("bad.ngc", bad.as_bytes());
        sb.write(
            "bad.toml",
            scene
                .replace("hexapod-step.ngc", "bad.ngc")
                .replace("name = \"hexapod-step\"", "name = \"bad\"")
                .as_bytes(),
        );
        let (code, out, err) = sb.run(&["simulate", "bad.toml", "--out", "out"]);
        assert_ne!(code, 0);
        assert!(out.is_empty(), "{out}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains(&format!("bad.ngc:{line}")), "{err}");
        assert!(err.contains("cannot follow the move"), "{err}");
        assert!(!sb.dir.join("out").exists());
    }

    // Malformed hexapod scenes that cut: what a hexapod cannot take, named at its line.
    for (bad, what) in [
        (
            scene.replace(
                "[tool]",
                "[error_motions]\nEXX = { polynomial = [0.0, 1e-5] }\n\n[tool]",
            ),
            "[error_motions] does not apply to a hexapod scene",
        ),
        (
            scene.replace(
                "length_mm = 40.0",
                "length_mm = 40.0\nholder_diameter_mm = 40.0",
            ),
            "collision checks are not run on a hexapod",
        ),
        (
            scene.replace(
                "[tool]",
                "[table_axes]\naxes = [{ name = \"X\", direction = [0.0, 0.0, 1.0] }]\n\n[tool]",
            ),
            "a table axis is rotary",
        ),
        (
            scene.replace("pitch_mm = 0.5", "pitch_mm = nan"),
            "pitch_mm",
        ),
    ] {
        sb.write("bad.toml", bad.as_bytes());
        let (code, out, err) = sb.run(&["simulate", "bad.toml", "--out", "out"]);
        assert_ne!(code, 0);
        assert!(out.is_empty(), "{out}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains("bad.toml:"), "{err}");
        assert!(err.contains(what), "{err}");
        assert!(!sb.dir.join("out").exists());
    }
}

/// One reader for both machine kinds: a hexapod scene that cuts takes `[report] view` as a
/// serial scene does (the hexapod verbs read the same file), its machine is the hexapod
/// variant with the twin the hexapod verbs get, and a bad view is refused at its line and
/// column with the serial scene's message.
#[test]
fn a_hexapod_scene_takes_report_view_like_a_serial_one() {
    let path = scene_path("hexapod-step.toml");
    let text = std::fs::read_to_string(&path).expect("scene");
    let budget = MemoryBudget::installed();
    let with_view = format!("{text}\n[report]\nview = \"+x\"\n");
    let scene = Scene::parse_hexapod_cut(&with_view, &path, &budget).expect("[report] accepted");
    // "+x": the eye on the +x axis, looking back at the part.
    let v = scene.view.expect("a view").into_inner();
    assert!((v - Vector3::x()).norm() < 1e-15, "{v:?}");
    assert!(
        Scene::parse_hexapod_cut(&text, &path, &budget)
            .expect("loads")
            .view
            .is_none(),
        "no [report]: the default view"
    );
    // The hexapod verbs read the same file, and see the same machine.
    let hex = HexapodScene::parse(&with_view, &path).expect("the hexapod verbs accept [report]");
    let Machine::Hexapod(h) = &scene.machine else {
        panic!("a hexapod scene's machine is the hexapod variant")
    };
    assert_eq!(h.twin, hex.twin());
    assert_eq!(h.injected, hex.injected);
    // A bad view: three lines below the end of the text (a blank line, `[report]`, the
    // key), at column 8 (after `view = `), with the message a serial scene gives.
    let bad_view = "\n[report]\nview = \"+w\"\n";
    let (line, column, message) =
        match Scene::parse_hexapod_cut(&format!("{text}{bad_view}"), &path, &budget) {
            Err(SceneError::Invalid {
                line,
                column,
                message,
                ..
            }) => (line, column, message),
            other => panic!("expected a located error, got {:?}", other.map(|s| s.name)),
        };
    assert_eq!((line, column), (text.lines().count() + 3, 8), "{message}");
    let serial_path = scene_path("xyz-pocket.toml");
    let serial = std::fs::read_to_string(&serial_path).expect("serial scene");
    match Scene::parse_with(&format!("{serial}{bad_view}"), &serial_path, &budget) {
        Err(SceneError::Invalid { message: m, .. }) => assert_eq!(m, message),
        other => panic!("expected a located error, got {:?}", other.map(|s| s.name)),
    }
}

/// `simulate` on a hexapod scene with `[report] view`: it runs, cuts the same part as
/// without the section (the view changes the pictures, not the physics), and the picture
/// looks from the asked direction — a different image from the default view, which looks
/// along the machined faces' normals.
#[test]
fn a_hexapod_scene_with_report_view_simulates() {
    let sb = Sandbox::new("hexapod-report-view");
    let scene = std::fs::read_to_string(scene_path("hexapod-step.toml")).expect("scene");
    let program = std::fs::read_to_string(scene_path("hexapod-step.ngc")).expect("program");
    sb.write("hexapod-step.ngc", program.as_bytes());
    sb.write(
        "plain.toml",
        scene
            .replace("name = \"hexapod-step\"", "name = \"plain\"")
            .as_bytes(),
    );
    sb.write(
        "viewed.toml",
        format!(
            "{}\n[report]\nview = \"-y\"\n",
            scene.replace("name = \"hexapod-step\"", "name = \"viewed\"")
        )
        .as_bytes(),
    );
    let mut made = Vec::new();
    for name in ["plain", "viewed"] {
        let (code, _, err) = sb.run(&["simulate", &format!("{name}.toml"), "--out", "out"]);
        assert_eq!(code, 0, "{name}: {err}");
        let dir = sb.dir.join(format!("out/{name}-simulate"));
        let report: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("report.json")).expect("report"),
        )
        .expect("json");
        let png = std::fs::read(dir.join("part.png")).expect("part.png");
        made.push((report, png));
    }
    let (plain, viewed) = (&made[0], &made[1]);
    for key in ["stock", "mesh", "deviation"] {
        assert_eq!(
            plain.0[key], viewed.0[key],
            "{key}: the view changed the part"
        );
    }
    assert_eq!(
        plain.0["sweep"]["tip_error_mm"],
        viewed.0["sweep"]["tip_error_mm"]
    );
    assert_ne!(
        plain.1, viewed.1,
        "[report] view did not change the picture"
    );
}

/// The one reader refuses a `[machine] kind` it does not know before reading the machine
/// by either kind's rules, and a serial machine's key in a hexapod scene, each at the
/// value's (or key's) line and column, naming the key.
#[test]
fn an_unknown_machine_kind_and_a_serial_key_in_a_hexapod_scene_are_refused_at_their_place() {
    let path = scene_path("hexapod-step.toml");
    let hexapod = std::fs::read_to_string(&path).expect("scene");
    let serial_path = scene_path("xyz-pocket.toml");
    let serial = std::fs::read_to_string(&serial_path).expect("scene");
    let budget = MemoryBudget::installed();
    // Line and column (1-based) of the first occurrence of `needle` in `text`, plus `skip`
    // characters.
    let at = |text: &str, needle: &str, skip: usize| {
        let i = text.find(needle).expect("needle") + skip;
        let line = text[..i].matches('\n').count() + 1;
        let column = text[..i].rsplit('\n').next().expect("line").chars().count() + 1;
        (line, column)
    };
    let located = |r: Result<(), SceneError>| match r {
        Err(SceneError::Invalid {
            line,
            column,
            message,
            ..
        }) => (line, column, message),
        other => panic!("expected a located error, got {other:?}"),
    };
    let kind = "kind = \"hexapod\"";
    let nonsense_hex = hexapod.replacen(kind, "kind = \"nonsense\"", 1);
    let want = (
        at(&nonsense_hex, "kind = \"nonsense\"", 7),
        "machine.kind: got \"nonsense\", expected \"serial\" or \"hexapod\"",
    );
    for r in [
        Scene::parse_with(&nonsense_hex, &path, &budget).map(|_| ()),
        Scene::parse_hexapod_cut(&nonsense_hex, &path, &budget).map(|_| ()),
        HexapodScene::parse(&nonsense_hex, &path).map(|_| ()),
    ] {
        let (l, c, m) = located(r);
        assert_eq!(((l, c), m.as_str()), want);
    }
    // A serial scene given the kind: the same refusal, not the serial reader's.
    let nonsense_serial = serial.replacen("[machine]\n", "[machine]\nkind = \"nonsense\"\n", 1);
    let (l, c, m) = located(Scene::parse_with(&nonsense_serial, &serial_path, &budget).map(|_| ()));
    assert_eq!((l, c), at(&nonsense_serial, "kind = \"nonsense\"", 7));
    assert_eq!(m, want.1);

    // A serial machine's key in a hexapod's [machine] (`spindle`), and a serial section
    // ([reversal]) in a hexapod scene that cuts: refused at the key, which the message names.
    let spindle = hexapod.replacen(kind, "kind = \"hexapod\"\nspindle = \"S\"", 1);
    for r in [
        Scene::parse_hexapod_cut(&spindle, &path, &budget).map(|_| ()),
        HexapodScene::parse(&spindle, &path).map(|_| ()),
    ] {
        let (l, c, m) = located(r);
        assert_eq!((l, c), at(&spindle, "spindle = ", 0), "{m}");
        assert!(m.starts_with("machine.spindle: unknown key"), "{m}");
    }
    let reversal = hexapod.replacen("[tool]", "[reversal]\nX = 0.002\n\n[tool]", 1);
    let (l, c, m) = located(Scene::parse_hexapod_cut(&reversal, &path, &budget).map(|_| ()));
    assert_eq!((l, c), at(&reversal, "X = 0.002", 4), "{m}");
    assert_eq!(m, "[reversal] does not apply to a hexapod scene");
}
