//! `report.html` in a real browser: headless Chromium opens the page from disk
//! (`tools/browser_check.py`, the DevTools protocol over a pipe), waits for the 3-D view's
//! first frame, takes a screenshot, and the tests check what a person would see — the view
//! drawn, the two halves of the stepped face in the deviation colours the page's legend
//! gives them — and what they would not: no console error, no request beyond the page
//! itself and the module URLs it makes of its own embedded scripts.
//!
//! Chromium is Debian's `chromium` (`.ci/run` installs it); `TWINMILL_CHROMIUM` names
//! another binary. Without Chromium or Python 3 a test is skipped with the reason — but
//! under CI (`CI` set) it fails, unless `.ci/run` found that Chromium cannot be installed
//! there (`TWINMILL_NO_CHROMIUM`, the reason). `TWINMILL_UPDATE_SCREENSHOT=1` copies the
//! built-in scene's screenshot to `docs/images/report-html.png`.

use crate::{Sandbox, builtin};
use image::RgbImage;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "../../benches/support/p1.rs"]
mod p1;

/// Largest page (bytes).
const MAX_PAGE: u64 = 10 * 1024 * 1024;
/// Longest time from navigation to the first frame (ms).
const MAX_READY_MS: f64 = 5000.0;

fn on_path(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// Chromium and Python 3, or the reason they are missing. Under CI a missing one fails.
#[expect(clippy::print_stderr, reason = "a skipped test says why")]
fn browser() -> Option<(PathBuf, PathBuf)> {
    let chromium = std::env::var_os("TWINMILL_CHROMIUM")
        .map(PathBuf::from)
        .or_else(|| on_path("chromium"))
        .or_else(|| on_path("chromium-browser"));
    let python = on_path("python3");
    match (chromium, python) {
        (Some(c), Some(p)) => Some((c, p)),
        (c, _) => {
            let missing = if c.is_none() {
                "Chromium (apt-get install chromium)"
            } else {
                "python3"
            };
            let cannot = std::env::var("TWINMILL_NO_CHROMIUM").ok();
            assert!(
                std::env::var_os("CI").is_none() || cannot.is_some(),
                "{missing} is missing: .ci/run installs it"
            );
            eprintln!(
                "skipped: {missing} is missing ({})",
                cannot.unwrap_or_else(|| "install it, or run .ci/run, which does".into())
            );
            None
        }
    }
}

/// What the browser saw: the driver's JSON and the screenshot.
struct Seen {
    json: Value,
    shot: RgbImage,
}

/// Opens `page` in headless Chromium, evaluates `probe` once the view is drawn.
fn open(page: &Path, probe: &str, browser: &(PathBuf, PathBuf)) -> Seen {
    let shot = page.with_extension("png");
    let tool = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/browser_check.py");
    let out = Command::new(&browser.1)
        .arg(tool)
        .arg(page)
        .args(["--screenshot", shot.to_str().expect("utf-8 path")])
        .args([
            "--probe",
            probe,
            "--width",
            "1280",
            "--height",
            "1200",
            "--timeout",
            "30",
        ])
        .arg("--chromium")
        .arg(&browser.0)
        .output()
        .expect("the browser driver runs");
    let json: Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "driver output is not JSON ({e}): {}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    });
    assert!(out.status.success(), "the page never got ready: {json:#}");
    let shot = image::open(&shot).expect("screenshot").to_rgb8();
    Seen { json, shot }
}

/// The checks every page must pass: drawn within the time, no console error or exception,
/// nothing requested beyond the page and its own module URLs.
fn check_clean(seen: &Seen, page: &Path) {
    let j = &seen.json;
    let ready = j["ready_ms"].as_f64().expect("ready");
    assert!(ready < MAX_READY_MS, "first frame after {ready} ms");
    let errors: Vec<&Value> = j["console"]
        .as_array()
        .expect("console")
        .iter()
        .filter(|m| m["level"] == "error")
        .collect();
    assert!(errors.is_empty(), "console errors: {errors:?}");
    assert_eq!(j["exceptions"].as_array().map(Vec::len), Some(0), "{j:#}");
    let own = j["page"].as_str().expect("page URL");
    for r in j["requests"].as_array().expect("requests") {
        let r = r.as_str().unwrap_or_default();
        assert!(
            r == own || r.starts_with("blob:") || r.starts_with("data:"),
            "network request: {r}"
        );
    }
    let size = std::fs::metadata(page).expect("page").len();
    assert!(size <= MAX_PAGE, "page is {size} bytes");
}

/// The canvas's rectangle in the screenshot (px), clipped to it.
fn canvas(seen: &Seen) -> (u32, u32, u32, u32) {
    let c = &seen.json["probe"]["canvas"];
    let f = |i: usize| c[i].as_f64().expect("canvas rect").round().max(0.0) as u32;
    let (x, y) = (f(0), f(1));
    let w = f(2).min(seen.shot.width().saturating_sub(x));
    let h = f(3).min(seen.shot.height().saturating_sub(y));
    (x, y, w, h)
}

/// The view is not blank: much of the canvas is not background white, in many colours.
fn check_drawn(seen: &Seen) {
    let (x0, y0, w, h) = canvas(seen);
    assert!(w > 200 && h > 200, "canvas {w} × {h} on screen");
    let mut inked = 0u64;
    let mut colours = std::collections::HashSet::new();
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            let p = seen.shot.get_pixel(x, y).0;
            if p.iter().any(|&c| c < 225) {
                inked += 1;
                colours.insert(p.map(|c| c / 8));
            }
        }
    }
    let share = inked as f64 / f64::from(w * h);
    assert!(
        share > 0.05,
        "only {:.1} % of the canvas drawn",
        share * 100.0
    );
    assert!(colours.len() > 20, "{} colours", colours.len());
}

/// Mean colour of the 7 × 7 pixels around a page point.
fn colour_at(seen: &Seen, p: &Value) -> [f64; 3] {
    let (x, y) = (
        p[0].as_f64().expect("x").round() as i64,
        p[1].as_f64().expect("y").round() as i64,
    );
    let mut sum = [0.0; 3];
    for dy in -3..=3 {
        for dx in -3..=3 {
            let px = seen.shot.get_pixel((x + dx) as u32, (y + dy) as u32).0;
            for k in 0..3 {
                sum[k] += f64::from(px[k]) / 49.0;
            }
        }
    }
    sum
}

#[test]
fn html_report_of_run_renders_the_step_in_deviation_colours_in_chromium() {
    let Some(browser) = browser() else { return };
    let sb = Sandbox::new("html-run");
    sb.write("s.toml", builtin("mdx50-step.toml").as_bytes());
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let (code, stdout, stderr) = sb.run(&["run", "s.toml"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("report.html"), "{stdout}");
    let dir = sb.dir.join("out/mdx50-step");
    let report: Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).expect("json"))
            .expect("report");
    // Where the two halves of the face are: the fitted faces' centroids.
    let centroids: Vec<String> = report["faces"]
        .as_array()
        .expect("faces")
        .iter()
        .map(|f| format!("twinmill.project({})", f["centroid_mm"]))
        .collect();
    let probe = format!(
        "({{canvas: twinmill.canvas(), faces: [{}]}})",
        centroids.join(", ")
    );
    let page = dir.join("report.html");
    let seen = open(&page, &probe, &browser);
    check_clean(&seen, &page);
    check_drawn(&seen);
    // The face cut at A = 0° lies 0.5 mm outside the nominal part (material left: red), the
    // one cut at A = 180° 0.5 mm inside it (a gouge: blue).
    let faces = &seen.json["probe"]["faces"];
    let (a0, a180) = (colour_at(&seen, &faces[0]), colour_at(&seen, &faces[1]));
    assert!(a0[0] > a0[2] + 60.0, "A0 face not red: {a0:?}");
    assert!(a180[2] > a180[0] + 60.0, "A180 face not blue: {a180:?}");
    // Every number and name of report.json is on the page, as report.json writes it.
    let html = std::fs::read_to_string(&page).expect("page");
    let text = std::fs::read_to_string(dir.join("report.json")).expect("json");
    let numbers: Vec<&str> = text
        .split(|c: char| !(c.is_ascii_digit() || "+-.eE".contains(c)))
        .filter(|t| t.parse::<f64>().is_ok())
        .collect();
    assert!(numbers.len() > 50, "{}", numbers.len());
    for n in numbers {
        assert!(html.contains(n), "{n} of report.json is not on the page");
    }
    for n in report["not_identified"].as_array().expect("names") {
        assert!(html.contains(n.as_str().expect("name")), "{n}");
    }
    if std::env::var_os("TWINMILL_UPDATE_SCREENSHOT").is_some() {
        let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/images/report-html.png");
        std::fs::copy(page.with_extension("png"), docs).expect("screenshot copied");
    }
}

#[test]
fn html_report_of_simulate_on_p1_renders_in_chromium() {
    let Some(browser) = browser() else { return };
    let sb = Sandbox::new("html-p1");
    sb.write("p1.ngc", p1::gcode().as_bytes());
    // P1 of docs/benchmarks.md at 0.2 mm (the benchmark's 0.05 mm would take minutes to
    // mesh here; the display mesh has the same budget either way).
    let scene = "name = \"p1\"\nprogram = \"p1.ngc\"\n\
        [machine]\nname = \"3-axis mill\"\naxes = [\n\
        { name = \"X\", kind = \"linear\", direction = [1, 0, 0] },\n\
        { name = \"Y\", kind = \"linear\", direction = [0, 1, 0] },\n\
        { name = \"Z\", kind = \"linear\", direction = [0, 0, 1] },\n]\n\
        home = { X = 10, Y = 10, Z = 25 }\n\
        [tool]\nkind = \"flat\"\ndiameter_mm = 6.0\nlength_mm = 20.0\n\
        [stock]\nmin = [0.0, 0.0, 0.0]\nmax = [100.0, 100.0, 20.0]\npitch_mm = 0.2\n";
    sb.write("p1.toml", scene.as_bytes());
    let (code, stdout, stderr) = sb.run(&["simulate", "p1.toml"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("report.html"), "{stdout}");
    let page = sb.dir.join("out/p1-simulate/report.html");
    let seen = open(&page, "({canvas: twinmill.canvas()})", &browser);
    check_clean(&seen, &page);
    check_drawn(&seen);
    assert_eq!(seen.json["ready"]["markers"], 0);
    let part = std::fs::read(sb.dir.join("out/p1-simulate/part.png")).expect("part.png");
    assert_eq!(&part[..8], b"\x89PNG\r\n\x1a\n");
}

#[test]
fn the_browser_check_sees_a_network_request_and_a_console_error() {
    // The checks above can fail: a page that asks the network for an image is caught.
    let Some(browser) = browser() else { return };
    let sb = Sandbox::new("html-network");
    let page = sb.write(
        "net.html",
        b"<!DOCTYPE html><html><body><img src=\"http://twinmill.invalid/x.png\">\
          <script>console.error('boom'); window.twinmillReady = {ms: 1};\
          window.twinmill = {canvas: () => [0, 0, 10, 10]};</script></body></html>",
    );
    let seen = open(&page, "({canvas: twinmill.canvas()})", &browser);
    let requests = seen.json["requests"].as_array().expect("requests");
    assert!(
        requests
            .iter()
            .any(|r| r == "http://twinmill.invalid/x.png"),
        "{requests:?}"
    );
    let console = seen.json["console"].as_array().expect("console");
    assert!(
        console
            .iter()
            .any(|m| m["level"] == "error" && m["text"] == "boom"),
        "{console:?}"
    );
}
