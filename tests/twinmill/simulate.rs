//! `simulate` on scenes with cylinder and mesh stock, fixtures, holders and a design model,
//! and its refusal of bad tools, stocks, meshes and numbers.

use crate::solids_collisions_deviation;
use crate::{Sandbox, builtin, files_in, obj};
use std::path::Path;
use twinmill::cutting::sweep::sweep_program;
use twinmill::math::{Point3, Real};
use twinmill::progress::NoProgress;
use twinmill::scene::Scene;

/// A three-axis scene (X, Y, Z; the tool tip at W = (x, y, z)) with `tool`, `stock` and
/// `extra` TOML; the program is `p.ngc`. No scanner and no faces: `simulate` needs neither.
fn xyz_scene(tool: &str, stock: &str, extra: &str) -> String {
    format!(
        r#"name = "t"
program = "p.ngc"

[machine]
axes = [
  {{ name = "X", kind = "linear", direction = [1, 0, 0] }},
  {{ name = "Y", kind = "linear", direction = [0, 1, 0] }},
  {{ name = "Z", kind = "linear", direction = [0, 0, 1] }},
]
home = {{ X = -20, Y = 0, Z = 60 }}

[tool]
{tool}

[stock]
{stock}

{extra}
"#
    )
}

const FLAT6: &str = "kind = \"flat\"\ndiameter_mm = 6.0\nlength_mm = 20.0";

/// OBJ text of the box [min, max].
fn box_obj(min: [Real; 3], max: [Real; 3]) -> String {
    let v: Vec<[Real; 3]> = (0..8)
        .map(|k| {
            [
                if k & 1 == 0 { min[0] } else { max[0] },
                if k & 2 == 0 { min[1] } else { max[1] },
                if k & 4 == 0 { min[2] } else { max[2] },
            ]
        })
        .collect();
    // Outward, counter-clockwise seen from outside.
    let t = [
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ];
    obj(&v, &t)
}

/// Runs `twinmill simulate` on a scene with the given files; returns the exit code, the
/// report (if it printed one) and stderr.
fn simulate_in(
    sb: &Sandbox,
    scene: &str,
    program: &str,
    files: &[(&str, &str)],
) -> (i32, serde_json::Value, String) {
    sb.write("s.toml", scene.as_bytes());
    sb.write("p.ngc", program.as_bytes());
    for (name, text) in files {
        sb.write(name, text.as_bytes());
    }
    let (code, stdout, stderr) = sb.run(&["simulate", "s.toml", "--json"]);
    let report = serde_json::from_str(&stdout).unwrap_or(serde_json::Value::Null);
    (code, report, stderr)
}

/// Upper bound on the dexel error of a convex body's volume (area `s`, diameter `diam`) at
/// ray spacing `h`: the outer parallel shell at half a cell diagonal ρ = h/√2 (Steiner,
/// with the integral mean curvature at most 2π·diameter).
fn convex_shell_bound(s: Real, diam: Real, h: Real) -> Real {
    let r = h / 2f64.sqrt();
    s * r + 2.0 * std::f64::consts::PI * diam * r * r + 4.0 * std::f64::consts::PI / 3.0 * r * r * r
}

/// Distance from (x, y) to the rectangle [x0, x1] × [y0, y1] (0 inside).
fn rect_distance(x: Real, y: Real, [x0, x1, y0, y1]: [Real; 4]) -> Real {
    let dx = (x0 - x).max(x - x1).max(0.0);
    let dy = (y0 - y).max(y - y1).max(0.0);
    dx.hypot(dy)
}

#[test]
fn a_three_axis_scene_of_machine_tool_stock_and_program_is_complete_for_simulate() {
    // The built-in pocket scene has nothing but the program, [machine], [tool] and [stock].
    let text = builtin("xyz-pocket.toml");
    let table: toml::Table = toml::from_str(&text).expect("TOML");
    let keys: Vec<&str> = table.keys().map(String::as_str).collect();
    assert_eq!(keys, ["machine", "program", "stock", "tool"], "{keys:?}");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/xyz-pocket.toml");
    let scene = Scene::load(&path).expect("scene");
    assert_eq!(
        scene.name, "xyz-pocket",
        "the name defaults to the file's stem"
    );
    assert!(scene.scanner.is_none() && scene.faces.is_empty());

    // The tool centre covers R = [15, 45] × [12, 28] at z = 15 (rows 4 mm apart and the
    // contour of R, Ø6): the pocket is R grown by 3 mm, 5 mm deep in the 20 mm block. Every
    // z ray strictly inside it ends at the floor, every ray outside at the top — exactly,
    // since dexels store exact crossings.
    let program = scene.load_program().expect("program");
    let part = twinmill::pipeline::machine_part(&scene, &program, &NoProgress).expect("cut");
    let r_path = [15.0, 45.0, 12.0, 28.0];
    let (floor, top, radius) = (15.0, 20.0, 3.0);
    let grid = &part.stock.grids()[2];
    assert_eq!(grid.axis(), 2);
    let (nu, nv) = grid.dims();
    let (mut inside, mut outside) = (0, 0);
    for iu in 0..nu {
        for iv in 0..nv {
            let o = grid.ray_origin(iu, iv);
            let d = rect_distance(o.x, o.y, r_path) - radius;
            let ray = grid.ray(iu, iv);
            let highest = ray
                .iter()
                .map(|s| s.hi.t)
                .fold(Real::NEG_INFINITY, Real::max);
            if d < -1e-6 {
                inside += 1;
                assert!((highest - floor).abs() < 1e-9, "ray at {o}: top {highest}");
            } else if d > 1e-6 {
                outside += 1;
                assert!((highest - top).abs() < 1e-9, "ray at {o}: top {highest}");
            }
        }
    }
    assert!(
        inside > 70_000 && outside > 100_000,
        "{inside} in, {outside} out"
    );

    // Through the CLI: `simulate` works, removing the pocket's volume within the dexel
    // bound of a convex body; `run`, `scan`, `identify` and `design` each fail with one line
    // naming what they need, and write nothing.
    let sb = Sandbox::new("xyz-pocket");
    sb.write("pocket.toml", text.as_bytes());
    sb.write("xyz-pocket.ngc", builtin("xyz-pocket.ngc").as_bytes());
    let (code, stdout, stderr) = sb.run(&["simulate", "pocket.toml", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("report");
    let (w, h) = (r_path[1] - r_path[0], r_path[3] - r_path[2]);
    let area =
        (w + 2.0 * radius) * (h + 2.0 * radius) - (4.0 - std::f64::consts::PI) * radius * radius;
    let depth = top - floor;
    let exact = area * depth;
    let perimeter = 2.0 * (w + h) + 2.0 * std::f64::consts::PI * radius;
    let diam = ((w + 2.0 * radius).powi(2) + (h + 2.0 * radius).powi(2) + depth * depth).sqrt();
    let bound = convex_shell_bound(2.0 * area + perimeter * depth, diam, scene.pitch_mm);
    let removed = report["stock"]["removed_mm3"].as_f64().expect("number");
    assert!(
        (removed - exact).abs() < bound,
        "removed {removed}, exact {exact}, bound {bound}"
    );
    assert_eq!(report["collisions"].as_array().map(Vec::len), Some(0));
    for (args, needs) in [
        (
            &["run", "pocket.toml"][..],
            &["run needs [scanner]", "[identify] faces"][..],
        ),
        (&["scan", "pocket.toml"][..], &["scan needs [scanner]"][..]),
        (
            &["identify", "pocket.toml"][..],
            &["identify needs [identify] parameters", "[scanner]"][..],
        ),
        (
            &["design", "pocket.toml", "--params", "dy_XY"][..],
            &["design needs [scanner]"][..],
        ),
    ] {
        let listing = || {
            let mut f = files_in(&sb.dir.join("out"));
            f.sort();
            f
        };
        let before = listing();
        let (code, stdout, stderr) = sb.run(args);
        assert_ne!(code, 0, "{args:?} should fail");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains("pocket.toml: "), "{args:?}: {stderr}");
        for n in needs {
            assert!(stderr.contains(n), "{args:?}: '{n}' not in {stderr}");
        }
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
        assert_eq!(listing(), before, "{args:?} wrote files");
    }
    // `correct` needs no faces: it measures the path and the whole part, and says that no
    // face was measured instead of giving a number.
    let (code, stdout, stderr) = sb.run(&["correct", "pocket.toml", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("report");
    let last = report["iterations"]
        .as_array()
        .and_then(|i| i.last())
        .expect("a pass");
    assert!(last["predicted_error_mm"].is_null(), "{last}");
    assert!(
        last["path"]["max_mm"].as_f64().is_some_and(|m| m < 1e-9),
        "{last}"
    );
}

#[test]
fn simulate_cylinder_stock_removes_the_analytic_volume() {
    let sb = Sandbox::new("sim-cylinder");
    let (r, len, pitch, z_cut, half) = (10.0_f64, 40.0_f64, 0.2_f64, 7.0_f64, 3.0_f64);
    let stock = format!(
        "kind = \"cylinder\"\nends = [[0.0, 0.0, 0.0], [{len}, 0.0, 0.0]]\nradius_mm = {r}\npitch_mm = {pitch}"
    );
    // A flat Ø6 end mill at z = 7 along the whole bar, entering and leaving in the air.
    let program = "G21 G90\nG0 X-10 Y0 Z60\nG0 Z7\nG1 X50 F600\nG0 Z60\nM30\n";
    let (code, report, stderr) = simulate_in(&sb, &xyz_scene(FLAT6, &stock, ""), program, &[]);
    assert_eq!(code, 0, "{stderr}");
    // Removed: the bar's section cut by z ≥ 7, |y| ≤ 3, times its length:
    // A = ∫_{−3}^{3} (√(r² − y²) − 7) dy = [y/2·√(r² − y²) + r²/2·asin(y/r)]_{−3}^{3} − 6·7.
    let area = half * (r * r - half * half).sqrt() + r * r * (half / r).asin() - 2.0 * half * z_cut;
    let exact = len * area;
    // The removed region is convex: its dexel volume is within the parallel-shell bound.
    // Section perimeter: the floor (6), two sides up to the arc, the arc.
    let side = (r * r - half * half).sqrt() - z_cut;
    let perimeter = 2.0 * half + 2.0 * side + 2.0 * r * (half / r).asin();
    let s = 2.0 * area + len * perimeter;
    let diam = (len * len + 4.0 * half * half + (r - z_cut) * (r - z_cut)).sqrt();
    let bound = convex_shell_bound(s, diam, pitch);
    let removed = report["stock"]["removed_mm3"].as_f64().expect("number");
    assert!(
        (removed - exact).abs() < bound,
        "removed {removed}, exact {exact}, bound {bound}"
    );
    // And the bar itself: π r² L within its own bound.
    let total = removed + report["stock"]["volume_mm3"].as_f64().expect("number");
    let bar = std::f64::consts::PI * r * r * len;
    let bar_bound = convex_shell_bound(
        2.0 * std::f64::consts::PI * r * (r + len),
        (len * len + 4.0 * r * r).sqrt(),
        pitch,
    );
    assert!(
        (total - bar).abs() < bar_bound,
        "{total} vs {bar} ± {bar_bound}"
    );
    assert_eq!(report["collisions"].as_array().map(Vec::len), Some(0));
    assert!(report["deviation"].is_null());
}

#[test]
fn simulate_reports_a_fixture_hit_at_its_line() {
    let sb = Sandbox::new("sim-fixture");
    let stock = "min = [0.0, -10.0, 0.0]\nmax = [40.0, 10.0, 10.0]\npitch_mm = 0.25";
    let extra = "[[fixtures]]\nname = \"clamp\"\nfile = \"clamp.obj\"\nposition = [45.0, 0.0, 0.0]";
    // The clamp is [45, 55] × [−5, 5] × [0, 20] once placed; line 4 cuts along the stock
    // at z = 5 and runs on into it: the Ø6 tool touches x = 45 with its tip at x = 42.
    let program = "G21 G90\nG0 X-10 Y0 Z60\nG0 Z5\nG1 X60 F600\nG0 Z60\nM30\n";
    let clamp = box_obj([0.0, -5.0, 0.0], [10.0, 5.0, 20.0]);
    let (code, report, stderr) = simulate_in(
        &sb,
        &xyz_scene(FLAT6, stock, extra),
        program,
        &[("clamp.obj", &clamp)],
    );
    assert_eq!(code, 0, "{stderr}");
    let events = report["collisions"].as_array().expect("list");
    assert_eq!(events.len(), 1, "{events:?}");
    let e = &events[0];
    assert_eq!(e["kind"], "fixture_hit");
    assert_eq!(e["fixture"], "clamp");
    assert_eq!(e["part"], "tool");
    assert_eq!(e["line"], 4);
    let p: Vec<Real> = e["point_mm"]
        .as_array()
        .expect("point")
        .iter()
        .map(|c| c.as_f64().expect("number"))
        .collect();
    assert!(
        (p[0] - 45.0).abs() < 1e-6 && p[1].abs() <= 3.0 + 1e-9 && (5.0..=25.0).contains(&p[2]),
        "{p:?}"
    );
    // Travel after first contact: from x = 42 to 60.
    assert!(
        (e["depth_mm"].as_f64().expect("number") - 18.0).abs() < 1e-6,
        "{e}"
    );
    // The cut itself is unchanged by the checks: a 6 × 5 slot through the 40 mm stock.
    let removed = report["stock"]["removed_mm3"].as_f64().expect("number");
    assert!((removed - 40.0 * 6.0 * 5.0).abs() < 1e-6, "{removed}");
}

#[test]
fn simulate_checks_a_holder_given_as_sections() {
    let sb = Sandbox::new("sim-holder-sections");
    let stock = "min = [0.0, -10.0, 0.0]\nmax = [40.0, 10.0, 10.0]\npitch_mm = 0.25";
    // The tip feeds at z = −20 along y: the flutes (20 mm) end at the stock's bottom, the
    // shank (Ø10 × 6) runs through it from z = 0 to 6, the holder's conical section (radius
    // 8 at z = 6 to 20 at z = 16) dips 4 mm in below the top at z = 10.
    let program = "G21 G90\nG0 X20 Y30 Z-20\nG1 Y-30 F600\nG0 Z60\nM30\n";
    let tool = format!(
        "{FLAT6}\nshank_diameter_mm = 10.0\nshank_length_mm = 6.0\nholder_sections = [{{ length_mm = 10.0, radius_bottom_mm = 8.0, radius_top_mm = 20.0 }}, {{ length_mm = 30.0, radius_bottom_mm = 20.0, radius_top_mm = 20.0 }}]"
    );
    let (code, report, stderr) = simulate_in(&sb, &xyz_scene(&tool, stock, ""), program, &[]);
    assert_eq!(code, 0, "{stderr}");
    let events = report["collisions"].as_array().expect("list");
    let find = |kind: &str| {
        events
            .iter()
            .find(|e| e["kind"] == kind)
            .unwrap_or_else(|| panic!("no {kind} in {events:?}"))
    };
    let (shank, holder) = (find("shank_in_stock"), find("holder_in_stock"));
    assert_eq!(
        (shank["line"].as_i64(), holder["line"].as_i64()),
        (Some(3), Some(3))
    );
    // Depths along z: the shank the whole 6 mm it spans inside, the cone from 6 to 10.
    let depth = |e: &serde_json::Value| e["depth_mm"].as_f64().expect("number");
    assert!((depth(shank) - 6.0).abs() < 1e-6, "{shank}");
    assert!((depth(holder) - 4.0).abs() < 1e-6, "{holder}");
    // The holder's first contact lies on the cone: radius 8 + 1.2·(z − 6) about the tool axis
    // (x = 20), within a dexel spacing.
    let p: Vec<Real> = (0..3)
        .map(|k| holder["point_mm"][k].as_f64().expect("number"))
        .collect();
    assert!((6.0 - 1e-6..=10.0 + 1e-6).contains(&p[2]), "{p:?}");
    let r_at = 8.0 + 1.2 * (p[2] - 6.0);
    assert!((p[0] - 20.0).abs() <= r_at + 0.25, "{p:?}");
}

#[test]
fn simulate_reports_a_rapid_through_material_and_a_holder_in_the_stock() {
    let sb = Sandbox::new("sim-rapid");
    let stock = "min = [0.0, -10.0, 0.0]\nmax = [40.0, 10.0, 10.0]\npitch_mm = 0.25";
    // Line 3 rapids through the stock at z = 5. Line 5 feeds at z = −12, so the flutes
    // (20 mm) end 2 mm below the top of the stock at z = 8 and the shank (Ø10) dips 2 mm in.
    let program = "G21 G90\nG0 X-10 Y0 Z5\nG0 X60\nG0 X20 Y30 Z-12\nG1 Y-30 F600\nG0 Z60\nM30\n";
    let tool = format!(
        "{FLAT6}\nshank_diameter_mm = 10.0\nshank_length_mm = 30.0\nholder_diameter_mm = 40.0\nholder_length_mm = 50.0"
    );
    let (code, report, stderr) = simulate_in(&sb, &xyz_scene(&tool, stock, ""), program, &[]);
    assert_eq!(code, 0, "{stderr}");
    let events = report["collisions"].as_array().expect("list");
    let kinds: Vec<(String, i64)> = events
        .iter()
        .map(|e| {
            (
                e["kind"].as_str().unwrap_or("").to_string(),
                e["line"].as_i64().unwrap_or(0),
            )
        })
        .collect();
    assert_eq!(
        kinds,
        [
            ("rapid_through_material".to_string(), 3),
            ("shank_in_stock".to_string(), 5)
        ],
        "{events:?}"
    );
    // The rapid's first contact is on the stock's face x = 0 (to a dexel spacing); the
    // deepest overlap is along z: from the tip at z = 5 to the top at z = 10.
    let rapid = &events[0];
    let x = rapid["point_mm"][0].as_f64().expect("number");
    assert!(x.abs() <= 0.25 + 1e-3, "{rapid}");
    assert!(
        (rapid["depth_mm"].as_f64().expect("number") - 5.0).abs() < 1e-6,
        "{rapid}"
    );
    // The shank's overlap: 2 mm deep (tip at −12, flutes 20 mm, shank from z = 8 to 10).
    let shank = &events[1];
    assert!(
        (shank["depth_mm"].as_f64().expect("number") - 2.0).abs() < 1e-6,
        "{shank}"
    );
    assert_eq!(shank["part"], "shank");
}

#[test]
fn simulate_mesh_stock_cuts_like_the_box_it_describes() {
    let sb = Sandbox::new("sim-mesh-stock");
    // The box [−20, 20] × [−5, 5] × [−10, 10] turned 90° about x ((x, y, z) ↦ (x, −z, y))
    // and moved by (20, 0, 5) is the stock [0, 40] × [−10, 10] × [0, 10].
    let blank = box_obj([-20.0, -5.0, -10.0], [20.0, 5.0, 10.0]);
    let stock = "kind = \"mesh\"\nfile = \"blank.obj\"\nposition = [20.0, 0.0, 5.0]\nrotation_deg = [90.0, 0.0, 0.0]\npitch_mm = 0.25";
    let program = "G21 G90\nG0 X-10 Y0 Z60\nG0 Z5\nG1 X50 F600\nG0 Z60\nM30\n";
    let (code, report, stderr) = simulate_in(
        &sb,
        &xyz_scene(FLAT6, stock, ""),
        program,
        &[("blank.obj", &blank)],
    );
    assert_eq!(code, 0, "{stderr}");
    // A 6 × 5 slot through the 40 mm length; the blank is 40 × 20 × 10.
    let removed = report["stock"]["removed_mm3"].as_f64().expect("number");
    let left = report["stock"]["volume_mm3"].as_f64().expect("number");
    assert!((removed - 40.0 * 6.0 * 5.0).abs() < 1e-6, "{removed}");
    assert!(
        (removed + left - 40.0 * 20.0 * 10.0).abs() < 1e-6,
        "{}",
        removed + left
    );
}

/// Signed distance of a point on the cut slot part to the slot design with floor
/// `design_floor` (≤ the part's floor 14): inside the design's slot void the distance to its
/// floor or nearer wall, else 0 (the part's other faces lie on the design's).
fn slot_distance(p: &Point3, design_floor: Real) -> Real {
    if p.y > 12.0 && p.y < 18.0 && p.z > design_floor && p.z < 20.0 {
        (p.z - design_floor).min(p.y - 12.0).min(18.0 - p.y)
    } else {
        0.0
    }
}

#[test]
fn simulate_maps_the_deviation_from_a_design_mesh() {
    let pitch = 0.25;
    let stock = format!("min = [0.0, 0.0, 0.0]\nmax = [40.0, 30.0, 20.0]\npitch_mm = {pitch}");
    // A Ø6 flat end mill cuts the slot y 12..18, floor z = 14, straight through along x.
    let program = "G21 G90\nG0 X-10 Y15 Z60\nG0 Z14\nG1 X50 F600\nG0 Z60\nM30\n";
    for (tag, design_floor) in [("exact", 14.0), ("offset", 13.9)] {
        let sb = Sandbox::new(&format!("sim-design-{tag}"));
        let design = solids_collisions_deviation::slot_design_obj(design_floor);
        let scene = xyz_scene(FLAT6, &stock, "[design]\nfile = \"design.obj\"");
        let (code, report, stderr) = simulate_in(&sb, &scene, program, &[("design.obj", &design)]);
        assert_eq!(code, 0, "{stderr}");
        let d = &report["deviation"];
        let (max, min, rms) = (
            d["max_mm"].as_f64().expect("max"),
            d["min_mm"].as_f64().expect("min"),
            d["rms_mm"].as_f64().expect("rms"),
        );
        // The same part, cut through the library; the distances from the analytic design.
        let s = Scene::load(&sb.dir.join("s.toml")).expect("scene");
        let prog = s.load_program().expect("program");
        let mut stock = twinmill::pipeline::make_stock(&s).expect("stock");
        sweep_program(
            &mut stock,
            s.chain(),
            &s.tool,
            &prog.moves,
            &s.sweep,
            &NoProgress,
        )
        .expect("sweep");
        let mut dist = Vec::new();
        for g in stock.grids() {
            g.for_each_crossing(|p, _| dist.push(slot_distance(&p, design_floor)));
        }
        assert_eq!(d["points"].as_u64(), Some(dist.len() as u64));
        let want_max = dist.iter().copied().fold(Real::NEG_INFINITY, Real::max);
        let want_rms = (dist.iter().map(|x| x * x).sum::<Real>() / dist.len() as Real).sqrt();
        assert!(
            (max - want_max).abs() < 1e-9,
            "{tag}: max {max} vs {want_max}"
        );
        assert!(
            (rms - want_rms).abs() < 1e-9,
            "{tag}: rms {rms} vs {want_rms}"
        );
        assert!(min > -1e-9, "{tag}: no gouge expected, min {min}");
        assert!(
            (want_max - (14.0 - design_floor)).abs() < 1e-9,
            "{tag}: {want_max}"
        );
        let png =
            std::fs::read(sb.dir.join("out/t-simulate/deviation.png")).expect("deviation.png");
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    }
}

/// Without a design the part is coloured by its deviation from the nominal part, and the
/// report carries the numbers: a spindle 20 µm low (dz_ZS) cuts the slot's floor 20 µm deep
/// and leaves every other surface where the nominal machine does (a vertical shift moves
/// the slot's walls along themselves), so the deviation is −20 µm on the floor (line 4),
/// 0 elsewhere: min −0.02 mm on the floor, max 0, and over the part's surface mean
/// −0.02·A_floor/A and RMS 0.02·√(A_floor/A), the areas written out from the geometry.
#[test]
fn simulate_reports_the_deviation_from_the_nominal_part_it_colours() {
    let sb = Sandbox::new("sim-nominal-deviation");
    let stock = "min = [0.0, 0.0, 0.0]\nmax = [40.0, 30.0, 20.0]\npitch_mm = 0.25";
    // A Ø6 flat end mill cuts the slot y 12..18, floor z = 14, straight through along x.
    let program = "G21 G90\nG0 X-10 Y15 Z60\nG0 Z14\nG1 X50 F600\nG0 Z60\nM30\n";
    let dz: Real = -0.02;
    let scene = xyz_scene(FLAT6, stock, &format!("[deviations]\ndz_ZS = {dz}"));
    let (code, report, stderr) = simulate_in(&sb, &scene, program, &[]);
    assert_eq!(code, 0, "{stderr}");
    let d = &report["deviation"];
    assert_eq!(d["from"], "nominal part", "{d}");
    let f = |k: &str| d[k].as_f64().unwrap_or_else(|| panic!("{k} in {d}"));
    // The part's surface: the box, less the slot's opening and the notches in its two end
    // faces, plus the slot's walls and floor (depth 6 + 0.02).
    let depth = 6.0 - dz;
    let floor = 40.0 * 6.0;
    let area = 2.0 * (40.0 * 30.0 + 40.0 * 20.0 + 30.0 * 20.0) - floor - 2.0 * 6.0 * depth
        + 2.0 * 40.0 * depth
        + floor;
    let (mean, rms) = (dz * floor / area, dz.abs() * (floor / area).sqrt());
    assert!((f("min_mm") - dz).abs() < 1e-6, "{d}");
    assert!(f("max_mm").abs() < 1e-6, "{d}");
    // The slivers where a wall runs 20 µm below the nominal floor: 0.1 % of the area.
    assert!(
        (f("mean_mm") - mean).abs() < 0.02 * mean.abs(),
        "{d} vs {mean}"
    );
    assert!((f("rms_mm") - rms).abs() < 0.02 * rms, "{d} vs {rms}");
    // Where: on the floor, cut by line 4.
    let at = &d["at_min"];
    let (y, z) = (at[1].as_f64().expect("y"), at[2].as_f64().expect("z"));
    assert!(
        (z - (14.0 + dz)).abs() < 1e-6 && (12.0..=18.0).contains(&y),
        "{at}"
    );
    assert_eq!(d["line_at_min"], 4, "{d}");
    // The summary line and the page say the same.
    let (code, stdout, _) = sb.run(&["simulate", "s.toml"]);
    assert_eq!(code, 0);
    let line = stdout
        .lines()
        .find(|l| l.starts_with("deviation"))
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(
        line.contains("min -0.0200 mm") && line.contains("line 4") && line.contains("nominal part"),
        "{line}"
    );
    let page = std::fs::read_to_string(sb.dir.join("out/t-simulate/report.html")).expect("page");
    assert!(page.contains("Deviation from the nominal part") && page.contains("NC line 4"));
}

/// Runs `simulate` on a broken scene or program and checks the failure is clean: non-zero
/// exit, one line naming what is expected, nothing written.
fn check_bad_simulate(
    name: &str,
    scene: &str,
    program: &str,
    files: &[(&str, &str)],
    expect: &[&str],
) {
    let sb = Sandbox::new(&format!("bad-sim-{name}"));
    let (code, report, stderr) = simulate_in(&sb, scene, program, files);
    assert_ne!(code, 0, "{name}: should fail");
    assert!(report.is_null(), "{name}: printed a report");
    assert!(!stderr.contains("panicked"), "{name}: panicked: {stderr}");
    assert_eq!(
        stderr.trim_end().lines().count(),
        1,
        "{name}: one line expected: {stderr}"
    );
    for e in expect {
        assert!(stderr.contains(e), "{name}: '{e}' not in: {stderr}");
    }
    let leftovers: Vec<_> = std::fs::read_dir(sb.dir.join("out"))
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    assert!(leftovers.is_empty(), "{name}: left {leftovers:?}");
}

#[test]
fn simulate_refuses_bad_tools_stocks_meshes_and_numbers() {
    let stock = "min = [0.0, -10.0, 0.0]\nmax = [40.0, 10.0, 10.0]\npitch_mm = 0.25";
    let program = "G21 G90\nG0 X-10 Y0 Z5\nG1 X50 F600\nM30\n";
    let bad_tool = |name: &str, tool: &str, expect: &[&str]| {
        check_bad_simulate(name, &xyz_scene(tool, stock, ""), program, &[], expect);
    };
    for d in ["0.0", "-6.0", "nan"] {
        bad_tool(
            &format!("diameter{d}"),
            &FLAT6.replace("6.0", d),
            &["s.toml:", "diameter_mm must be"],
        );
    }
    bad_tool(
        "corner-radius",
        "kind = \"bull_nose\"\ndiameter_mm = 6.0\ncorner_radius_mm = 3.5\nlength_mm = 20.0",
        &["s.toml:", "corner"],
    );
    bad_tool(
        "holder-incomplete",
        &format!("{FLAT6}\nshank_diameter_mm = 6.0"),
        &["s.toml:", "tool.shank_length_mm is missing"],
    );
    // Holder sections: every bad value names its section and field.
    let shank = "shank_diameter_mm = 6.0\nshank_length_mm = 10.0";
    let sec = |a: &str, b: &str| {
        format!(
            "holder_sections = [{{ length_mm = 10.0, radius_bottom_mm = 8.0, radius_top_mm = 12.0 }}, {{ length_mm = {a}, radius_bottom_mm = 15.0, radius_top_mm = {b} }}]"
        )
    };
    for (tag, a, b, field) in [
        (
            "len0",
            "0.0",
            "15.0",
            "tool.holder_sections[1].length_mm must be positive",
        ),
        (
            "rneg",
            "20.0",
            "-1.0",
            "tool.holder_sections[1].radius_top_mm must be positive",
        ),
        (
            "rnan",
            "20.0",
            "nan",
            "tool.holder_sections[1].radius_top_mm",
        ),
    ] {
        bad_tool(
            &format!("holder-section-{tag}"),
            &format!("{FLAT6}\n{shank}\n{}", sec(a, b)),
            &["s.toml:", field],
        );
    }
    bad_tool(
        "holder-sections-and-cylinder",
        &format!(
            "{FLAT6}\n{shank}\nholder_diameter_mm = 40.0\n{}",
            sec("20.0", "15.0")
        ),
        &[
            "s.toml:",
            "tool.holder_diameter_mm and tool.holder_sections both describe the holder",
        ],
    );
    bad_tool(
        "holder-sections-no-shank",
        &format!("{FLAT6}\n{}", sec("20.0", "15.0")),
        &["s.toml:", "tool.shank_diameter_mm is missing"],
    );
    bad_tool(
        "holder-sections-empty",
        &format!("{FLAT6}\n{shank}\nholder_sections = []"),
        &["s.toml:", "tool.holder_sections is empty"],
    );
    // A pitch whose tri-dexel cannot fit: the error names the scene key and a pitch that fits.
    check_bad_simulate(
        "pitch",
        &xyz_scene(FLAT6, &stock.replace("0.25", "0.00001"), ""),
        program,
        &[],
        &[
            "s.toml:",
            "stock.pitch_mm",
            "MiB",
            "use a pitch of at least",
        ],
    );
    // A mesh with a hole: the cube without its last triangle.
    let cube = box_obj([0.0; 3], [10.0; 3]);
    let open: String = cube
        .lines()
        .take(8 + 11)
        .map(|l| format!("{l}\n"))
        .collect();
    let mesh_stock = "kind = \"mesh\"\nfile = \"open.obj\"\npitch_mm = 0.25";
    check_bad_simulate(
        "open-stock",
        &xyz_scene(FLAT6, mesh_stock, ""),
        program,
        &[("open.obj", &open)],
        &[
            "s.toml:",
            "stock.file",
            "open.obj",
            "not a closed",
            "for example edge",
            "used by one triangle only",
        ],
    );
    check_bad_simulate(
        "open-fixture",
        &xyz_scene(FLAT6, stock, "[[fixtures]]\nfile = \"open.obj\""),
        program,
        &[("open.obj", &open)],
        &[
            "s.toml:",
            "fixtures[0].file",
            "open.obj",
            "for example edge",
        ],
    );
    check_bad_simulate(
        "open-design",
        &xyz_scene(FLAT6, stock, "[design]\nfile = \"open.obj\""),
        program,
        &[("open.obj", &open)],
        &["s.toml:", "design.file", "open.obj", "for example edge"],
    );
    check_bad_simulate(
        "missing-mesh",
        &xyz_scene(FLAT6, stock, "[design]\nfile = \"nowhere.stl\""),
        program,
        &[],
        &["s.toml:", "design.file", "nowhere.stl", "cannot read"],
    );
    let nan_vertex = cube.replacen("v 0.0 0.0 0.0", "v nan 0.0 0.0", 1);
    check_bad_simulate(
        "nan-vertex",
        &xyz_scene(FLAT6, mesh_stock.replace("open", "nan").as_str(), ""),
        program,
        &[("nan.obj", &nan_vertex)],
        &["s.toml:", "nan.obj:1", "not finite"],
    );
    // Non-finite numbers in the scene.
    check_bad_simulate(
        "nan-stock",
        &xyz_scene(FLAT6, &stock.replace("min = [0.0", "min = [nan"), ""),
        program,
        &[],
        &["s.toml:", "stock.min must have finite components"],
    );
    check_bad_simulate(
        "inf-cylinder",
        &xyz_scene(
            FLAT6,
            "kind = \"cylinder\"\nends = [[0.0, 0.0, 0.0], [inf, 0.0, 0.0]]\nradius_mm = 5.0\npitch_mm = 0.25",
            "",
        ),
        program,
        &[],
        &["s.toml:", "stock.ends must have finite components"],
    );
    check_bad_simulate(
        "nan-fixture-position",
        &xyz_scene(
            FLAT6,
            stock,
            "[[fixtures]]\nfile = \"c.obj\"\nposition = [0.0, nan, 0.0]",
        ),
        program,
        &[("c.obj", &cube)],
        &[
            "s.toml:",
            "fixtures[0].position must have finite components",
        ],
    );
    check_bad_simulate(
        "box-key-on-cylinder",
        &xyz_scene(
            FLAT6,
            &format!("kind = \"cylinder\"\nradius_mm = 5.0\n{stock}"),
            "",
        ),
        program,
        &[],
        &["s.toml:", "stock.min does not apply to a 'cylinder' stock"],
    );
    // Non-finite numbers in the NC program.
    let scene = xyz_scene(FLAT6, stock, "");
    check_bad_simulate(
        "nc-overflow",
        &scene,
        "G21 G90\n#1 = [10 ** 400]\nG1 X#1 F600\nM30\n",
        &[],
        &["p.ngc:3:", "out of range"],
    );
    check_bad_simulate(
        "nc-divide-by-zero",
        &scene,
        "G21 G90\nG1 X[1/0] F600\nM30\n",
        &[],
        &["p.ngc:2:", "divide by zero"],
    );
}

#[test]
fn simulate_meshes_the_p1_pocket_adaptively_small_closed_and_within_its_bound() {
    use crate::html::p1;
    // The built-in scene is benchmark P1 as text: the same program the benches cut.
    assert_eq!(builtin("p1-pocket.ngc"), p1::gcode());
    let sb = Sandbox::new("simulate-p1");
    sb.write("p1-pocket.toml", builtin("p1-pocket.toml").as_bytes());
    sb.write("p1-pocket.ngc", builtin("p1-pocket.ngc").as_bytes());
    let (code, stdout, stderr) = sb.run(&["simulate", "p1-pocket.toml", "--json"]);
    assert_eq!(code, 0, "{stderr}");
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("--json prints it");
    let mesh = &r["mesh"];
    // One closed surface with no handle.
    assert_eq!(mesh["euler_characteristic"].as_i64(), Some(2));
    // The pocket is flat-bottomed with vertical walls: removed volume 1.5 mm × the area of
    // the 3 mm offset of the path (docs/benchmarks.md). The mesh's flat faces and sharp
    // edges are exact; its only approximation is within the stated bound over the walls.
    let removed = 100.0 * 100.0 * 20.0 - mesh["volume_mm3"].as_f64().expect("number");
    let truth = 1.5 * p1::offset_area(3.0);
    let bound = mesh["bound_mm"].as_f64().expect("number");
    assert!(bound <= 0.005, "{bound}");
    let walls = 1.5 * 4.0 * 86.0 * 2.0;
    assert!(
        (removed - truth).abs() <= bound * walls,
        "{removed} vs {truth}"
    );
    // Few triangles: part.stl far below the dexel-resolution 1.1 GB.
    let stl = std::fs::metadata(sb.dir.join("out/p1-pocket-simulate/part.stl"))
        .expect("part.stl")
        .len();
    let triangles = mesh["triangles"].as_u64().expect("number");
    assert_eq!(stl, 84 + 50 * triangles);
    assert!(stl <= 30 * 1024 * 1024, "{stl} bytes");
    assert!(triangles < 100_000, "{triangles}");
    assert!(mesh["planar_regions"].as_u64().expect("number") > 1000);
}

#[test]
fn simulate_colours_the_slot_by_the_spindles_offset_without_sweeping_it_twice() {
    // A slot cut with the spindle 20 µm (then 50 µm) low: its floor lies that far below the
    // nominal part's, its walls and the stock's faces on it. The colours come from the
    // program on the nominal machine read near the cut part (no second sweep), against the
    // stock's own surface: a box, and the same box as a closed mesh of twelve triangles (the
    // mesh's nearest triangle, inside by its pseudo-normals).
    let sb = Sandbox::new("sim-nominal-path");
    let boxed = "min = [0.0, 0.0, 0.0]\nmax = [40.0, 30.0, 20.0]\npitch_mm = 0.25";
    let meshed = "kind = \"mesh\"\nfile = \"blank.obj\"\npitch_mm = 0.25";
    let program = "G21 G90\nG0 X-10 Y15 Z60\nG0 Z14\nG1 X50 F600\nG0 Z60\nM30\n";
    sb.write("p.ngc", program.as_bytes());
    sb.write(
        "blank.obj",
        box_obj([0.0, 0.0, 0.0], [40.0, 30.0, 20.0]).as_bytes(),
    );
    for (stock, dz) in [
        (boxed, -0.02),
        (boxed, -0.05),
        (meshed, -0.02),
        (meshed, -0.05),
    ] {
        let scene = xyz_scene(FLAT6, stock, &format!("[deviations]\ndz_ZS = {dz}"));
        sb.write("s.toml", scene.as_bytes());
        let (code, out, stderr) = sb.run(&["simulate", "s.toml", "--json"]);
        assert_eq!(code, 0, "{stderr}");
        let r: serde_json::Value = serde_json::from_str(&out).expect("report");
        let d = &r["deviation"];
        assert_eq!(d["from"], "nominal part", "{stock}: {d}");
        let (min, max) = (
            d["min_mm"].as_f64().expect("min"),
            d["max_mm"].as_f64().expect("max"),
        );
        assert!((min - dz).abs() < 1e-6, "{stock} {dz}: {d}");
        assert!(max.abs() < 1e-6, "{stock} {dz}: {d}");
        assert_eq!(d["line_at_min"], 4, "{stock}: {d}");
    }
}
