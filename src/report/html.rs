//! `report.html`: one self-contained page per command — the summary the CLI prints, tables,
//! SVG plots, every number of the JSON report, and a 3-D view (orbit, zoom, pick) of the
//! scene's geometry as an embedded GLB drawn by three.js.
//!
//! The page loads nothing: three.js (vendored in `assets/three/`, MIT, see its README) and
//! the viewer (`assets/report/viewer.js`) are embedded as text, the geometry as base64.
//! A few lines of inline script make a module URL of each embedded file with its import
//! specifiers rewritten to the other files' URLs (the vendored files import `'three'`,
//! `./three.core.min.js` and `../utils/BufferGeometryUtils.js`), then import the viewer.
//! The viewer sets `window.twinmillReady` once the first frame is drawn and offers
//! `window.twinmill` (project a point to the screen, show or hide a layer) for the browser
//! test. In a browser without WebGL 2 (turned off, no graphics driver) the loader says so
//! in the view's place and shows the part there as a picture (`part.png`, embedded when the
//! page has a part), as it does when the view fails to start; `window.twinmillReady` then
//! has `webgl: false`.
//!
//! **Invariant:** everything the page shows is escaped text or data this module wrote; the
//! same input gives the same bytes (no dates, no random identifiers).

use crate::report::render::diverging_colour;
use base64::Engine as _;
use serde_json::Value;
use std::fmt::Write as _;

/// three.js's version, as vendored in `assets/three/`.
pub const THREE_VERSION: &str = "0.181.2";

/// The embedded modules: element id, text.
const MODULES: [(&str, &str); 5] = [
    (
        "three-core",
        include_str!("../../assets/three/three.core.min.js"),
    ),
    (
        "three-module",
        include_str!("../../assets/three/three.module.min.js"),
    ),
    (
        "three-bgu",
        include_str!("../../assets/three/BufferGeometryUtils.js"),
    ),
    (
        "three-orbit",
        include_str!("../../assets/three/OrbitControls.js"),
    ),
    (
        "three-gltf",
        include_str!("../../assets/three/GLTFLoader.js"),
    ),
];
const VIEWER: &str = include_str!("../../assets/report/viewer.js");
const THREE_LICENSE: &str = include_str!("../../assets/three/LICENSE");

/// Turns the embedded modules into module URLs with their imports rewritten, then starts
/// the viewer. Kept in step with the specifiers the vendored files use (checked by a test).
const LOADER: &str = r#"(function () {
  const text = id => document.getElementById(id).textContent;
  const url = s => URL.createObjectURL(new Blob([s], { type: 'text/javascript' }));
  const swap = (s, from, to) => s.split(from).join(JSON.stringify(to));
  // Without the 3-D view: say why in its place and show the part as a picture there
  // (part.png, embedded), then tell a waiting test (twinmillReady with webgl: false).
  const instead = (why, error) => {
    const box = document.getElementById('view');
    const v = document.getElementById('view-status');
    const pic = document.getElementById('twinmill-picture');
    const done = picture => {
      window.twinmillReady = { ms: performance.now(), webgl: false, picture, error };
    };
    if (box) {
      for (const c of box.querySelectorAll('canvas')) c.remove();
      box.classList.add('picture');
    }
    if (v) v.textContent = why + (pic ? ' The part is shown below as a picture instead.' : '');
    if (!box || !pic) { done(false); return; }
    const img = new Image();
    img.id = 'view-picture';
    img.alt = 'the cut part (part.png)';
    img.onload = () => done(true);
    img.onerror = () => done(false);
    img.src = 'data:image/png;base64,' + pic.textContent.trim();
    box.append(img);
  };
  const fail = e => {
    window.twinmillError = String(e && e.stack || e);
    console.error(e);
    instead('The 3-D view could not start: ' + e + '.', String(e));
  };
  // three.js draws with WebGL 2; a browser without it (turned off, no graphics driver, some
  // remote desktops and virtual machines) is told so in words.
  const gl = (() => {
    try { return document.createElement('canvas').getContext('webgl2'); } catch (e) { return null; }
  })();
  if (!gl) {
    instead('This browser has no WebGL, which the 3-D view needs: WebGL 2 is turned off ' +
            'here, or there is no graphics driver for it.', null);
    return;
  }
  const lose = gl.getExtension('WEBGL_lose_context');
  if (lose) lose.loseContext();
  try {
    const core = url(text('three-core'));
    const three = url(swap(text('three-module'), '"./three.core.min.js"', core));
    const bgu = url(swap(text('three-bgu'), "'three'", three));
    const orbit = url(swap(text('three-orbit'), "'three'", three));
    const gltf = url(swap(swap(text('three-gltf'), "'three'", three),
                          "'../utils/BufferGeometryUtils.js'", bgu));
    let app = text('twinmill-viewer');
    app = swap(app, "'three/addons/controls/OrbitControls.js'", orbit);
    app = swap(app, "'three/addons/loaders/GLTFLoader.js'", gltf);
    app = swap(app, "'three'", three);
    import(url(app)).catch(fail);
  } catch (e) { fail(e); }
})();"#;

const STYLE: &str = r#"
body { font: 14px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 1200px; padding: 0 16px 48px; color: #1a1a1a; }
h1 { font-size: 22px; margin: 20px 0 4px; } h2 { font-size: 17px; margin: 28px 0 8px; border-bottom: 1px solid #ddd; }
pre { background: #f6f6f6; padding: 10px 12px; overflow-x: auto; font-size: 13px; }
table { border-collapse: collapse; margin: 6px 0 12px; } td, th { border: 1px solid #ddd; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #f2f2f2; } td.n { text-align: right; font-variant-numeric: tabular-nums; }
#view { position: relative; height: 560px; border: 1px solid #ccc; background: #fff; }
#view canvas { display: block; }
#legend { position: absolute; right: 10px; top: 10px; max-width: 180px; background: rgba(255,255,255,.9); padding: 6px 8px; font-size: 12px; border: 1px solid #ddd; }
#legend .bar { width: 18px; height: 200px; display: inline-block; vertical-align: top; margin-top: 10px; }
#legend .ticks { display: inline-block; height: 200px; position: relative; width: 64px; margin-left: 4px; margin-top: 10px; }
#legend .ticks span { position: absolute; left: 0; transform: translateY(-50%); }
#layers { position: absolute; left: 10px; top: 10px; background: rgba(255,255,255,.9); padding: 6px 8px; font-size: 12px; border: 1px solid #ddd; }
#pick:empty { display: none; }
#pick { position: absolute; left: 10px; bottom: 10px; background: rgba(255,255,255,.92); padding: 4px 8px; font-size: 12px; border: 1px solid #ddd; min-height: 1em; }
#view-status { position: absolute; left: 50%; top: 45%; transform: translate(-50%, -50%); color: #666; }
#view.picture { height: auto; }
#view.picture #view-status { position: static; transform: none; padding: 8px 10px; color: #1a1a1a; background: #fff4e5; border-bottom: 1px solid #ddd; }
#view.picture #legend, #view.picture #layers, #view.picture #pick { display: none; }
#view-picture { display: block; max-width: 100%; height: auto; margin: 0 auto; }
.marker { position: absolute; font-size: 11px; color: #b2182b; background: rgba(255,255,255,.85); padding: 0 3px; pointer-events: none; white-space: nowrap; }
.plot svg { max-width: 100%; height: auto; } figure { margin: 12px 0; } figcaption { color: #555; font-size: 13px; }
.note { color: #555; font-size: 13px; }
"#;

/// A table with a heading.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Section {
    /// Heading.
    pub heading: String,
    /// A sentence or two above the table.
    pub intro: String,
    /// Column titles.
    pub columns: Vec<String>,
    /// Rows of cells (text; cells that parse as numbers are right-aligned).
    pub rows: Vec<Vec<String>>,
}

/// A plot.
#[derive(Clone, Debug, PartialEq)]
pub struct Plot {
    /// Caption.
    pub caption: String,
    /// The SVG document.
    pub svg: String,
}

/// A colour legend of the diverging map, ±range.
#[derive(Clone, Debug, PartialEq)]
pub struct Legend {
    /// What the colours mean.
    pub title: String,
    /// ±range (mm).
    pub range_mm: f64,
}

/// A labelled point in the 3-D view (a collision and its NC line).
#[derive(Clone, Debug, PartialEq)]
pub struct Marker {
    /// Position (mm, W).
    pub position: [f64; 3],
    /// Label.
    pub label: String,
}

/// The 3-D view: a GLB whose meshes are named `part`, `cloud` and `plane …` (the viewer
/// gives each its material), a legend, markers, the initial view direction.
#[derive(Clone, Debug, PartialEq)]
pub struct View3d {
    /// The geometry.
    pub glb: Vec<u8>,
    /// The part's colours.
    pub legend: Option<Legend>,
    /// Labelled points.
    pub markers: Vec<Marker>,
    /// From the scene towards the eye.
    pub eye: [f64; 3],
    /// The screen's up.
    pub up: [f64; 3],
    /// Layers shown at first (by mesh name prefix); the others start hidden.
    pub shown: Vec<String>,
    /// Sentences under the view (what the geometry is, how it was simplified).
    pub notes: Vec<String>,
    /// The part as a picture (PNG, `part.png`), shown in the view's place when the browser
    /// cannot draw it (no WebGL 2, or the view failed to start).
    pub picture: Option<Vec<u8>>,
}

/// A page.
#[derive(Clone, Debug, PartialEq)]
pub struct Page {
    /// Title (`twinmill run: mdx50-step`).
    pub title: String,
    /// The summary the CLI prints.
    pub summary: String,
    /// The 3-D view, if the command has geometry.
    pub view: Option<View3d>,
    /// Tables.
    pub sections: Vec<Section>,
    /// Plots.
    pub plots: Vec<Plot>,
    /// The JSON report, shown in full at the end.
    pub report: Value,
}

/// Escapes text for HTML content and attribute values.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// JSON safe inside a `<script>` element.
fn script_json(v: &Value) -> String {
    v.to_string().replace('<', "\\u003c")
}

fn is_number(s: &str) -> bool {
    let t = s.trim().trim_start_matches(['+', '±']);
    !t.is_empty()
        && t.split_whitespace()
            .next()
            .is_some_and(|w| w.parse::<f64>().is_ok())
}

fn table(out: &mut String, columns: &[String], rows: &[Vec<String>]) {
    out.push_str("<table>");
    if !columns.is_empty() {
        out.push_str("<tr>");
        for c in columns {
            let _ = write!(out, "<th>{}</th>", escape(c));
        }
        out.push_str("</tr>");
    }
    for r in rows {
        out.push_str("<tr>");
        for c in r {
            let class = if is_number(c) { " class=\"n\"" } else { "" };
            let _ = write!(out, "<td{class}>{}</td>", escape(c));
        }
        out.push_str("</tr>");
    }
    out.push_str("</table>\n");
}

/// A JSON value as nested tables: every number as serde_json writes it (shortest form that
/// reads back to the same f64).
fn json_html(out: &mut String, v: &Value) {
    match v {
        Value::Object(m) if m.is_empty() => out.push_str("{}"),
        Value::Object(m) => {
            out.push_str("<table>");
            for (k, x) in m {
                let _ = write!(out, "<tr><th>{}</th><td>", escape(k));
                json_html(out, x);
                out.push_str("</td></tr>");
            }
            out.push_str("</table>");
        }
        Value::Array(a) if a.is_empty() => out.push_str("[]"),
        Value::Array(a) if a.iter().all(|x| !x.is_object() && !x.is_array()) => {
            let items: Vec<String> = a.iter().map(|x| escape(&scalar(x))).collect();
            out.push_str(&items.join(", "));
        }
        Value::Array(a) => {
            out.push_str("<table>");
            for (i, x) in a.iter().enumerate() {
                let _ = write!(out, "<tr><th>{i}</th><td>");
                json_html(out, x);
                out.push_str("</td></tr>");
            }
            out.push_str("</table>");
        }
        x => out.push_str(&escape(&scalar(x))),
    }
}

fn scalar(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Null => "null (not a number)".into(),
        x => x.to_string(),
    }
}

/// The legend's colour stops as a CSS gradient, bottom (−range) to top.
fn gradient() -> String {
    let stops: Vec<String> = (0..=10)
        .map(|k| {
            let c = diverging_colour(-1.0 + 0.2 * f64::from(k));
            format!("rgb({},{},{})", c[0], c[1], c[2])
        })
        .collect();
    format!("linear-gradient(to top, {})", stops.join(", "))
}

fn legend_html(out: &mut String, l: &Legend) {
    let (unit, scale) = if l.range_mm >= 1.0 {
        ("mm", 1.0)
    } else {
        ("µm", 1000.0)
    };
    let _ = write!(
        out,
        "<div id=\"legend\"><div>{} ({unit})</div><div class=\"bar\" style=\"background: {}\"></div><div class=\"ticks\">",
        escape(&l.title),
        gradient()
    );
    for f in [1.0, 0.5, 0.0, -0.5, -1.0] {
        let v = f * l.range_mm * scale;
        let label = if f == 0.0 {
            "0".to_string()
        } else {
            format!("{v:+}")
        };
        let _ = write!(
            out,
            "<span style=\"top: {}%\">{}</span>",
            (1.0 - f) * 50.0,
            escape(&label)
        );
    }
    out.push_str("</div></div>");
}

/// Appends `bytes` to the page as a plain-text script block `id`, base64-encoded straight
/// into it (no second copy of the text).
fn embed_base64(out: &mut String, id: &str, bytes: &[u8]) {
    let _ = write!(out, "<script type=\"text/plain\" id=\"{id}\">");
    base64::engine::general_purpose::STANDARD.encode_string(bytes, out);
    out.push_str("</script>\n");
}

/// The page as HTML.
pub fn render_page(page: &Page) -> String {
    let mut out =
        String::with_capacity(page.view.as_ref().map_or(0, |v| v.glb.len() * 4 / 3) + 1_200_000);
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; script-src 'unsafe-inline' blob:; style-src 'unsafe-inline'; img-src data: blob:; connect-src data: blob:\">\
         <title>{}</title><style>{STYLE}</style></head><body>\n<h1>{}</h1>\n",
        escape(&page.title),
        escape(&page.title)
    );
    out.push_str("<h2>Summary</h2>\n<pre>");
    out.push_str(&escape(&page.summary));
    out.push_str("</pre>\n");
    if let Some(v) = &page.view {
        out.push_str("<h2>3-D view</h2>\n<p class=\"note\">Drag to orbit, scroll to zoom, right-drag to pan, click a point for its position and value.</p>\n<div id=\"view\"><div id=\"view-status\">loading the 3-D view…</div>");
        if let Some(l) = &v.legend {
            legend_html(&mut out, l);
        }
        out.push_str("<div id=\"layers\"></div><div id=\"pick\"></div></div>\n");
        for n in &v.notes {
            let _ = writeln!(out, "<p class=\"note\">{}</p>", escape(n));
        }
        let meta = serde_json::json!({
            "eye": v.eye,
            "up": v.up,
            "shown": v.shown,
            "markers": v.markers.iter().map(|m| serde_json::json!({"position": m.position, "label": m.label})).collect::<Vec<_>>(),
            "legend": v.legend.as_ref().map(|l| serde_json::json!({"title": l.title, "range_mm": l.range_mm})),
        });
        let _ = writeln!(
            out,
            "<script type=\"application/json\" id=\"twinmill-view\">{}</script>",
            script_json(&meta)
        );
        embed_base64(&mut out, "twinmill-glb", &v.glb);
        if let Some(png) = &v.picture {
            embed_base64(&mut out, "twinmill-picture", png);
        }
    }
    for s in &page.sections {
        let _ = writeln!(out, "<h2>{}</h2>", escape(&s.heading));
        if !s.intro.is_empty() {
            let _ = writeln!(out, "<p>{}</p>", escape(&s.intro));
        }
        table(&mut out, &s.columns, &s.rows);
    }
    if !page.plots.is_empty() {
        out.push_str("<h2>Plots</h2>\n");
        for p in &page.plots {
            // The SVG is plotters' output: markup this crate produced, embedded as is.
            let _ = writeln!(
                out,
                "<figure class=\"plot\">{}<figcaption>{}</figcaption></figure>",
                p.svg,
                escape(&p.caption)
            );
        }
    }
    out.push_str(
        "<h2>Every number of the JSON report</h2>\n<details open><summary>report</summary>\n",
    );
    json_html(&mut out, &page.report);
    out.push_str("\n</details>\n");
    if page.view.is_some() {
        let _ = writeln!(
            out,
            "<h2>About this page</h2><p class=\"note\">The 3-D view is drawn by three.js {THREE_VERSION} (MIT licence, below), embedded in this file with the geometry: the page loads nothing from anywhere.</p><details><summary>three.js licence</summary><pre>{}</pre></details>",
            escape(THREE_LICENSE)
        );
        for (id, text) in MODULES {
            let _ = writeln!(
                out,
                "<script type=\"text/plain\" id=\"{id}\">{text}</script>"
            );
        }
        let _ = writeln!(
            out,
            "<script type=\"text/plain\" id=\"twinmill-viewer\">{VIEWER}</script>"
        );
        let _ = writeln!(out, "<script>{LOADER}</script>");
    }
    out.push_str("</body></html>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_scripts_cannot_end_their_element_and_import_what_the_loader_rewrites() {
        for (id, text) in MODULES.iter().chain([&("twinmill-viewer", VIEWER)]) {
            let lower = text.to_lowercase();
            assert!(!lower.contains("</script"), "{id}");
            assert!(!lower.contains("<!--"), "{id}");
        }
        let m = |id: &str| MODULES.iter().find(|(i, _)| *i == id).unwrap().1;
        assert!(m("three-module").contains("\"./three.core.min.js\""));
        assert!(!m("three-core").contains(" from\"") && !m("three-core").contains("import\""));
        for id in ["three-bgu", "three-orbit", "three-gltf"] {
            assert!(m(id).contains("} from 'three';"), "{id}");
        }
        assert!(m("three-gltf").contains("'../utils/BufferGeometryUtils.js'"));
        // Every import of every file is one the loader rewrites.
        let allowed = [
            "three",
            "./three.core.min.js",
            "../utils/BufferGeometryUtils.js",
            "three/addons/controls/OrbitControls.js",
            "three/addons/loaders/GLTFLoader.js",
        ];
        for (id, text) in MODULES.iter().chain([&("twinmill-viewer", VIEWER)]) {
            for spec in specifiers(text) {
                assert!(allowed.contains(&spec.as_str()), "{id} imports {spec}");
            }
        }
    }

    /// The module specifiers of `from '…'`, `from"…"` and `import '…'` in a script, outside
    /// comment lines.
    fn specifiers(text: &str) -> Vec<String> {
        let mut out = Vec::new();
        let code = text.lines().filter(|l| {
            let t = l.trim_start();
            !(t.starts_with('*') || t.starts_with("//") || t.starts_with("/*"))
        });
        for line in code {
            for key in ["from", "import"] {
                for (i, _) in line.match_indices(key) {
                    let rest = line[i + key.len()..].trim_start_matches(' ');
                    let Some(q) = rest.chars().next().filter(|c| *c == '\'' || *c == '"') else {
                        continue;
                    };
                    if let Some(end) = rest[1..].find(q) {
                        let spec = &rest[1..1 + end];
                        if spec.ends_with(".js") || spec == "three" {
                            out.push(spec.to_string());
                        }
                    }
                }
            }
        }
        out
    }

    fn page() -> Page {
        Page {
            title: "twinmill run: <x>".into(),
            summary: "a & b".into(),
            view: Some(View3d {
                glb: vec![1, 2, 3],
                legend: Some(Legend {
                    title: "deviation".into(),
                    range_mm: 0.5,
                }),
                markers: vec![Marker {
                    position: [0.0, 1.0, 2.0],
                    label: "line 9 </script>".into(),
                }],
                eye: [0.0, -1.0, 0.0],
                up: [0.0, 0.0, 1.0],
                shown: vec!["part".into()],
                notes: vec!["display mesh".into()],
                picture: Some(vec![0x89, b'P', b'N', b'G']),
            }),
            sections: vec![Section {
                heading: "Identified".into(),
                intro: String::new(),
                columns: vec!["name".into(), "value".into()],
                rows: vec![vec!["dy_AY".into(), "-0.5002".into()]],
            }],
            plots: vec![],
            report: serde_json::json!({"step_mm": 1.0004329174689666, "names": ["a<b"], "none": null}),
        }
    }

    #[test]
    fn the_page_escapes_text_and_shows_every_number() {
        let html = render_page(&page());
        assert!(html.contains("twinmill run: &lt;x&gt;"));
        assert!(html.contains("a &amp; b"));
        assert!(html.contains("1.0004329174689666"));
        assert!(html.contains("a&lt;b"));
        assert!(html.contains("line 9 \\u003c/script>"));
        assert!(html.contains("<td class=\"n\">-0.5002</td>"));
        // One </script> per script element: nothing inside ends one early.
        assert_eq!(
            html.matches("</script>").count(),
            html.matches("<script").count()
        );
        assert_eq!(html, render_page(&page()));
    }
}
