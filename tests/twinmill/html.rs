//! `report.html` in a real browser: headless Chromium opens the page from disk
//! (`tools/browser_check.py`, the DevTools protocol over a pipe), waits for the 3-D view's
//! first frame, takes a screenshot, and the tests check what a person would see — the view
//! drawn, the two halves of the stepped face in the deviation colours the page's legend
//! gives them — and what they would not: no console error, no request beyond the page
//! itself and the module URLs it makes of its own embedded scripts.
//!
//! The page without WebGL is opened the same way in a Chromium started without it, where
//! it must say so and show the part as a picture.
//!
//! Chromium is Debian's `chromium` (`.ci/run` installs it); `TWINMILL_CHROMIUM` names
//! another binary. Without Chromium or Python 3 a test is skipped with the reason — but
//! under CI (`CI` set; `.ci/run` sets it) it fails. `TWINMILL_UPDATE_SCREENSHOT=1` copies
//! the built-in scene's screenshot to `docs/images/report-html.png`.

use crate::{Sandbox, builtin, files_in};
use image::RgbImage;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "../../benches/support/p1.rs"]
pub(crate) mod p1;

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

/// Chromium and Python 3, or the reason they are missing. Under CI (`CI` set, as `.ci/run`
/// sets it) a missing one fails the test: CI installs both or stops.
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
            assert!(
                std::env::var_os("CI").is_none(),
                "{missing} is missing: under CI the browser tests must run (.ci/run installs it)"
            );
            eprintln!("skipped: {missing} is missing (install it, or run .ci/run, which does)");
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
    open_with(page, probe, browser, &[])
}

/// [`open`] with more arguments for the driver (`--no-webgl`).
fn open_with(page: &Path, probe: &str, browser: &(PathBuf, PathBuf), extra: &[&str]) -> Seen {
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
        .args(extra)
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

/// In a browser without WebGL (Chromium with `--disable-gpu --disable-webgl`, as on a remote
/// desktop or in some virtual machines) the page says so in words where the 3-D view would
/// be and shows the part there as a picture: the same PNG as `part.png`, drawn on screen.
#[test]
fn html_report_without_webgl_says_so_and_shows_the_part_as_a_picture() {
    let Some(browser) = browser() else { return };
    let sb = Sandbox::new("html-no-webgl");
    sb.write("s.toml", builtin("mdx50-step.toml").as_bytes());
    sb.write("mdx50-step.ngc", builtin("mdx50-step.ngc").as_bytes());
    let (code, _, stderr) = sb.run(&["simulate", "s.toml"]);
    assert_eq!(code, 0, "{stderr}");
    let dir = sb.dir.join("out/mdx50-step-simulate");
    let page = dir.join("report.html");
    let probe = "(() => { const i = document.getElementById('view-picture'); \
        if (i) i.scrollIntoView({block: 'start'}); \
        const r = i ? i.getBoundingClientRect() : null; \
        return {status: document.getElementById('view-status').textContent, \
                canvases: document.querySelectorAll('#view canvas').length, \
                picture: i && {rect: [r.left, r.top, r.width, r.height], \
                               natural: [i.naturalWidth, i.naturalHeight], src: i.src}}; })()";
    let seen = open_with(&page, probe, &browser, &["--no-webgl"]);
    let j = &seen.json;
    assert_eq!(j["ready"]["webgl"], false, "{:#}", j["ready"]);
    assert_eq!(j["ready"]["picture"], true, "{:#}", j["ready"]);
    // Nothing failed: no error, no exception, no request; the old failure is gone.
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
        assert!(r == own || r.starts_with("data:"), "request: {r}");
    }
    let p = &j["probe"];
    let status = p["status"].as_str().expect("status text");
    assert!(
        status.starts_with("This browser has no WebGL") && status.contains("as a picture"),
        "{status}"
    );
    assert!(!status.contains("could not start"), "{status}");
    assert_eq!(p["canvases"], 0, "no 3-D canvas left on the page");
    // The picture is part.png, byte for byte, at its own size.
    let png = std::fs::read(dir.join("part.png")).expect("part.png");
    let src = p["picture"]["src"].as_str().expect("a picture in the view");
    let b64 = src
        .strip_prefix("data:image/png;base64,")
        .expect("an embedded PNG");
    use base64::Engine as _;
    let embedded = base64::engine::general_purpose::STANDARD
        .decode(b64)
        .expect("base64");
    assert!(embedded == png, "the picture is not part.png");
    let want = image::load_from_memory(&png).expect("part.png").to_rgb8();
    let natural = &p["picture"]["natural"];
    assert_eq!(natural[0], want.width(), "{natural}");
    assert_eq!(natural[1], want.height(), "{natural}");
    // What is on screen is that picture: the screenshot, where the image is, against
    // part.png sampled at the same places (the picture may be scaled to the page's width).
    let rect = &p["picture"]["rect"];
    let f = |i: usize| rect[i].as_f64().expect("rect");
    let (x0, y0, w, h) = (f(0), f(1), f(2), f(3));
    assert!(w > 600.0 && h > 400.0, "picture shown {w} × {h}");
    let (sw, sh) = (f64::from(seen.shot.width()), f64::from(seen.shot.height()));
    let (mut diff, mut n, mut inked) = (0.0, 0u64, 0u64);
    for gy in 0..60 {
        for gx in 0..80 {
            let (u, v) = ((f64::from(gx) + 0.5) / 80.0, (f64::from(gy) + 0.5) / 60.0);
            let (sx, sy) = (x0 + u * w, y0 + v * h);
            if sx < 0.0 || sy < 0.0 || sx >= sw || sy >= sh {
                continue;
            }
            let a = seen.shot.get_pixel(sx as u32, sy as u32).0;
            let b = want
                .get_pixel(
                    (u * f64::from(want.width())) as u32,
                    (v * f64::from(want.height())) as u32,
                )
                .0;
            diff += (0..3)
                .map(|k| (f64::from(a[k]) - f64::from(b[k])).abs())
                .sum::<f64>()
                / 3.0;
            n += 1;
            if b.iter().any(|&c| c < 225) {
                inked += 1;
            }
        }
    }
    assert!(n > 4000, "only {n} samples of the picture on screen");
    assert!(inked * 20 > n, "part.png is blank: {inked} of {n} inked");
    let mean = diff / n as f64;
    assert!(
        mean < 12.0,
        "the screen differs from part.png by {mean:.1} per channel"
    );
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

// ---------------------------------------------------------------------------------------
// The instruments' and evaluations' pages: every command that measures or evaluates writes
// a page holding every number its JSON output has.

/// The numbers of a JSON text, each as it is written there.
fn json_numbers(text: &str) -> Vec<String> {
    text.split(|c: char| !(c.is_ascii_digit() || "+-.eE".contains(c)))
        .filter(|t| t.parse::<f64>().is_ok())
        .map(String::from)
        .collect()
}

/// Every number of `json` (a command's `--json` output) and every string value of
/// `names` (JSON pointers to arrays of names) appear on `page`.
fn page_holds(page: &Path, json: &str, names: &[&str]) -> String {
    let html = std::fs::read_to_string(page).expect("page written");
    assert!(html.starts_with("<!DOCTYPE html>"), "{}", page.display());
    let tokens: std::collections::HashSet<&str> = html
        .split(|c: char| !(c.is_ascii_digit() || "+-.eE".contains(c)))
        .collect();
    let numbers = json_numbers(json);
    assert!(!numbers.is_empty());
    for n in &numbers {
        assert!(
            tokens.contains(n.as_str()) || html.contains(n.as_str()),
            "{n} of the JSON output is not on {}",
            page.display()
        );
    }
    let v: Value = serde_json::from_str(json).expect("JSON output");
    for p in names {
        for n in v.pointer(p).and_then(Value::as_array).expect(p) {
            let n = n.as_str().expect("a name");
            assert!(html.contains(n), "{p}: {n} is not on {}", page.display());
        }
    }
    // Self-contained: no script, style or image is fetched from anywhere.
    for bad in ["src=\"http", "href=\"http", "url(http", "<link"] {
        assert!(!html.contains(bad), "{bad} on {}", page.display());
    }
    html
}

/// Runs `args`, a command that prints its JSON and writes the page `page` (in the
/// sandbox): it succeeds, and the page holds every number of the JSON and the names at
/// `names` ([`page_holds`]). The page and the JSON.
fn command_page(sb: &Sandbox, args: &[&str], page: &str, names: &[&str]) -> (String, String) {
    let (code, stdout, stderr) = sb.run(args);
    assert_eq!(code, 0, "{args:?}: {stderr}");
    (page_holds(&sb.dir.join(page), &stdout, names), stdout)
}

/// `measure SCENE --instrument laser` along X over ±20 mm at 0.3 µm noise, and `extra`.
fn measure_laser(sb: &Sandbox, scene: &str, extra: &[&str]) -> (i32, String, String) {
    let mut args = vec![
        "measure",
        scene,
        "--instrument",
        "laser",
        "--axis",
        "X",
        "--from",
        "-20",
        "--to",
        "20",
        "--noise",
        "0.3",
    ];
    args.extend(extra);
    sb.run(&args)
}

fn scene_file(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name)
        .display()
        .to_string()
}

#[test]
fn html_page_of_the_ball_bar_draws_the_polar_trace_in_chromium() {
    let Some(browser) = browser() else { return };
    let sb = Sandbox::new("html-ballbar");
    let scene = scene_file("mdx50-step.toml");
    let (code, stdout, stderr) = sb.run(&[
        "measure",
        &scene,
        "--instrument",
        "ballbar",
        "--out",
        "bb.csv",
        "--json",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let page = sb.dir.join("bb.html");
    let html = page_holds(&page, &stdout, &[]);
    assert!(!html.contains("three.js"), "no 3-D view, so no three.js");
    let probe = "(() => { const lines = [...document.querySelectorAll('figure svg polyline')]\
        .map(l => ({stroke: (l.getAttribute('stroke') || '').toUpperCase(), \
                    pts: l.getAttribute('points').trim().split(/\\s+/).map(p => p.split(',').map(Number))}))\
        .filter(l => l.pts.length > 100); \
        return {lines, shown: [...document.querySelectorAll('figure svg')].map(s => s.getBoundingClientRect().width)}; })()";
    let seen = {
        let shot = page.with_extension("png");
        let tool = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/browser_check.py");
        let out = Command::new(&browser.1)
            .arg(tool)
            .arg(&page)
            .args(["--screenshot", shot.to_str().expect("utf-8 path")])
            .args(["--ready", "document.readyState === 'complete' && 1"])
            .args(["--probe", probe, "--timeout", "30"])
            .arg("--chromium")
            .arg(&browser.0)
            .output()
            .expect("the browser driver runs");
        let json: Value = serde_json::from_slice(&out.stdout).expect("driver JSON");
        assert!(out.status.success(), "{json:#}");
        Seen {
            json,
            shot: image::open(&shot).expect("screenshot").to_rgb8(),
        }
    };
    check_clean(&seen, &page);
    let probe = &seen.json["probe"];
    assert!(
        probe["shown"][0].as_f64().expect("an SVG on the page") > 300.0,
        "{probe}"
    );
    // The nominal circle (black) and the two traces (ccw red, cw blue), as drawn.
    let lines = probe["lines"].as_array().expect("polylines");
    let points = |stroke: &str| -> Vec<(f64, f64)> {
        let l = lines
            .iter()
            .find(|l| l["stroke"] == stroke)
            .unwrap_or_else(|| panic!("no {stroke} line: {lines:?}"));
        l["pts"]
            .as_array()
            .expect("points")
            .iter()
            .map(|p| (p[0].as_f64().unwrap(), p[1].as_f64().unwrap()))
            .collect::<Vec<_>>()
    };
    let centroid = |stroke: &str| -> (f64, f64) {
        let l = lines
            .iter()
            .find(|l| l["stroke"] == stroke)
            .unwrap_or_else(|| panic!("no {stroke} line: {lines:?}"));
        let pts = l["pts"].as_array().expect("points");
        let n = pts.len() as f64;
        let s = pts.iter().fold((0.0, 0.0), |a, p| {
            (a.0 + p[0].as_f64().unwrap(), a.1 + p[1].as_f64().unwrap())
        });
        (s.0 / n, s.1 / n)
    };
    let nominal = centroid("#000000");
    // The scene moves the A axis (and the table and centre ball on it) by dy_AY = −0.5 mm:
    // the circle the tool ball runs about the commanded centre is 0.5 mm off the centre
    // ball towards +Y, so about the ball the trace's centre lies at −Y — drawn below the
    // nominal circle (SVG y runs down), in both directions, and not sideways.
    for trace in ["#B2182B", "#2166AC"] {
        let c = centroid(trace);
        assert!(
            c.1 > nominal.1 + 5.0,
            "{trace} at {c:?}, nominal {nominal:?}"
        );
        // Magnified about the nominal circle, the trace reaches further below its centre
        // than above it.
        let pts = points(trace);
        let low = pts.iter().map(|p| p.1).fold(f64::MIN, f64::max) - nominal.1;
        let high = nominal.1 - pts.iter().map(|p| p.1).fold(f64::MAX, f64::min);
        assert!(low > high + 10.0, "{trace}: {low} below, {high} above");
        assert!((c.0 - nominal.0).abs() < 3.0, "{trace} at {c:?}");
    }
    let figures: Value = serde_json::from_str(&stdout).expect("figures");
    for d in figures["directions"].as_array().expect("directions") {
        let y = d["centre_mm"][1].as_f64().expect("centre");
        assert!((y + 0.5).abs() < 1e-3, "centre y {y}");
    }
}

#[test]
fn measure_writes_a_page_with_every_number_of_its_figures() {
    let sb = Sandbox::new("html-measure");
    let mdx = scene_file("mdx50-step.toml");
    let trunnion = scene_file("trunnion-ac.toml");
    // Laser: the page beside the readings, named after them; the ISO 230-2 plot.
    let (code, stdout, stderr) = measure_laser(&sb, &mdx, &["--json"]);
    assert_eq!(code, 0, "{stderr}");
    let html = page_holds(&sb.dir.join("mdx50-step-laser.html"), &stdout, &[]);
    assert!(html.contains("ISO 230-2 figures") && html.contains("<svg"));
    assert!(sb.dir.join("mdx50-step-laser.csv").is_file());
    // Ball sensor and probe: ISO 10791-6's ranges, the identified terms with σ, what is not
    // determined, the singular values.
    for (instrument, file) in [("ball-sensor", "bs.csv"), ("probe", "pr.csv")] {
        let (code, stdout, stderr) = sb.run(&[
            "measure",
            &trunnion,
            "--instrument",
            instrument,
            "--out",
            file,
            "--json",
        ]);
        assert_eq!(code, 0, "{stderr}");
        let page = sb.dir.join(file).with_extension("html");
        let html = page_holds(
            &page,
            &stdout,
            &["/identification/not_determined", "/identification/terms"],
        );
        let v: Value = serde_json::from_str(&stdout).expect("report");
        let id = &v["identification"];
        assert!(!id["not_determined"].as_array().expect("list").is_empty());
        assert!(html.contains("Not determined") && html.contains("Identifiability"));
        for t in id["identified"].as_array().expect("identified") {
            assert!(html.contains(t["name"].as_str().expect("name")));
        }
        assert!(html.contains("ISO 10791-6"), "{instrument}");
    }
    // A page that would overwrite the readings is refused, and nothing is written.
    let (code, _, stderr) = sb.run(&[
        "measure",
        &mdx,
        "--instrument",
        "ballbar",
        "--out",
        "x.html",
    ]);
    assert_ne!(code, 0);
    assert!(
        stderr.contains("x.html") && stderr.contains("overwrite"),
        "{stderr}"
    );
    assert!(!sb.dir.join("x.html").exists());
}

#[test]
fn evaluate_writes_a_page_with_every_number_of_its_figures() {
    let sb = Sandbox::new("html-evaluate");
    let mdx = scene_file("mdx50-step.toml");
    let (code, _, stderr) = measure_laser(&sb, &mdx, &["--out", "laser.csv"]);
    assert_eq!(code, 0, "{stderr}");
    let (code, _, stderr) = sb.run(&[
        "measure",
        &mdx,
        "--instrument",
        "ballbar",
        "--noise",
        "0.2",
        "--out",
        "bb.csv",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let evaluate = [
        "evaluate",
        "iso230-2",
        "laser.csv",
        "--json",
        "--html",
        "e2.html",
    ];
    command_page(&sb, &evaluate, "e2.html", &[]);
    let (html, _) = command_page(
        &sb,
        &[
            "evaluate", "iso230-4", "bb.csv", "--radius", "100", "--json", "--html", "e4.html",
        ],
        "e4.html",
        &[],
    );
    assert!(html.contains("polyline"), "the polar plot");
    sb.write(
        "readings.csv",
        b"Lx1,Lx2,Ly1,Ly2\n3.1,3.8,3.1,3.8\n3.0,3.6,3.2,3.6\n",
    );
    let evaluate = [
        "evaluate",
        "ball-sensor",
        "readings.csv",
        "--json",
        "--html",
        "ebs.html",
    ];
    let (html, _) = command_page(&sb, &evaluate, "ebs.html", &[]);
    assert!(html.contains("Ball centres"));
    // Without --html, evaluate writes no page.
    let before = files_in(&sb.dir).len();
    let (code, _, _) = sb.run(&["evaluate", "iso230-2", "laser.csv"]);
    assert_eq!(code, 0);
    assert_eq!(files_in(&sb.dir).len(), before);
}

#[test]
fn the_hexapod_commands_write_a_page_with_every_number_of_their_output() {
    let sb = Sandbox::new("html-hexapod");
    let hex = scene_file("hexapod-machining-centre.toml");
    let ballbar = [
        "measure",
        &hex,
        "--instrument",
        "ballbar",
        "--json",
        "--html",
        "bb.html",
    ];
    let (html, _) = command_page(&sb, &ballbar, "bb.html", &[]);
    assert!(html.contains("polyline"), "the polar plot");
    // Calibration without a jig: the base frame's six rigid motions are not determined,
    // and the page says so and why, beside the parameters with σ and the spectrum.
    let calibrate = [
        "identify",
        &hex,
        "--procedure",
        "jig-free",
        "--json",
        "--html",
        "cal.html",
    ];
    let gauge = ["/run/calibration/identifiability/gauge"];
    let (html, stdout) = command_page(&sb, &calibrate, "cal.html", &gauge);
    let v: Value = serde_json::from_str(&stdout).expect("outcome");
    assert_eq!(
        v["run"]["calibration"]["identifiability"]["gauge"]
            .as_array()
            .map(Vec::len),
        Some(6),
        "a bar measures lengths only: six rigid motions of the base are free"
    );
    assert!(html.contains("Not determined (the gauge)") && html.contains("lengths only"));
    assert!(html.contains("Before and after") && html.contains("Singular values"));
    for p in v["run"]["parameters"].as_array().expect("parameters") {
        assert!(html.contains(p["name"].as_str().expect("name")));
    }
    let amplification = [
        "hexapod",
        "amplification",
        &hex,
        "--steps",
        "5",
        "--z-steps",
        "2",
        "--json",
        "--html",
        "amp.html",
    ];
    let (html, _) = command_page(&sb, &amplification, "amp.html", &[]);
    assert!(html.contains("K_p") && html.contains("<rect"), "the maps");
}

#[test]
fn a_scene_names_the_view_of_its_part() {
    let sb = Sandbox::new("html-view");
    let ngc = builtin("mdx50-step.ngc");
    sb.write("mdx50-step.ngc", ngc.as_bytes());
    let base = builtin("mdx50-step.toml");
    // A bad view: one clear error at the value, nothing written.
    sb.write(
        "bad.toml",
        format!("{base}\n[report]\nview = \"top\"\n").as_bytes(),
    );
    let (code, _, stderr) = sb.run(&["simulate", "bad.toml"]);
    assert_ne!(code, 0);
    let line = base.lines().count() + 3;
    assert!(
        stderr.contains(&format!("bad.toml:{line}:")) && stderr.contains("report view must be"),
        "{stderr}"
    );
    sb.write(
        "zero.toml",
        format!("{base}\n[report]\nview = [0, 0, 0]\n").as_bytes(),
    );
    let (code, _, stderr) = sb.run(&["simulate", "zero.toml"]);
    assert_ne!(code, 0);
    assert!(stderr.contains("no direction"), "{stderr}");
    assert!(!sb.dir.join("out").exists());
    // From +x: the page's camera looks from +x with z up (part.png is drawn from the same
    // direction).
    sb.write(
        "side.toml",
        format!("{base}\n[report]\nview = \"+x\"\n").as_bytes(),
    );
    let (code, _, stderr) = sb.run(&["simulate", "side.toml"]);
    assert_eq!(code, 0, "{stderr}");
    let html =
        std::fs::read_to_string(sb.dir.join("out/mdx50-step-simulate/report.html")).expect("page");
    let meta = html
        .split("id=\"twinmill-view\">")
        .nth(1)
        .and_then(|s| s.split("</script>").next())
        .expect("view metadata");
    let meta: Value = serde_json::from_str(meta).expect("JSON");
    assert_eq!(meta["eye"], serde_json::json!([1.0, 0.0, 0.0]), "{meta}");
    assert_eq!(meta["up"], serde_json::json!([0.0, 0.0, 1.0]), "{meta}");
}
