//! What a scene cuts with and cuts: `[tool]` (the cutter, its shank and holder), `[stock]`
//! (a box, a cylinder or a closed mesh, within the memory budget), `[[fixtures]]`,
//! `[design]` and `[sweep]`.

use super::Ctx;
use super::SceneError;
use super::StockShape;
use super::file::{SceneFile, StockFile, ToolFile};
use super::memory::MemoryBudget;
use crate::cutting::collide::{Fixture, Holder, HolderSection};
use crate::cutting::shape::{Cylinder, Solid};
use crate::cutting::sweep::SweepOptions;
use crate::cutting::tool::{Tool, ToolKind};
use crate::math::{Aabb, Real, Vector3, tol};
use crate::report::deviation_map::DesignModel;
use std::ops::Range;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// The cutting sections of a scene, read.
pub(super) struct Cut {
    pub tool: Tool,
    pub holder: Option<Holder>,
    pub stock_box: Aabb,
    pub stock_shape: StockShape,
    pub pitch_mm: Real,
    pub fixtures: Vec<Fixture>,
    pub design: Option<(PathBuf, DesignModel)>,
    pub sweep: SweepOptions,
}

/// Reads `[tool]`, `[stock]`, `[[fixtures]]`, `[design]` and `[sweep]`; the stock must fit in
/// `memory`. File names are relative to the scene's folder.
pub(super) fn read_cut<M>(
    ctx: &Ctx,
    file: &SceneFile<M>,
    tool_file: &ToolFile,
    stock_file: &StockFile,
    memory: &MemoryBudget,
) -> Result<Cut, SceneError> {
    let ctx = *ctx;
    let path = ctx.path;
    // Tool.
    let diameter = ctx.positive(&tool_file.diameter_mm, "diameter_mm")?;
    let length = ctx.positive(&tool_file.length_mm, "length_mm")?;
    let kind_name = tool_file.kind.get_ref().as_str();
    let extra = |field: &Option<Spanned<Real>>, name: &str, wanted: bool| match (field, wanted) {
        (Some(f), false) => Err(ctx.err(
            f.span(),
            format!("tool.{name} does not apply to a '{kind_name}' tool"),
        )),
        (None, true) => Err(ctx.err(
            tool_file.kind.span(),
            format!("a '{kind_name}' tool needs tool.{name}"),
        )),
        (Some(f), true) => Ok(Some(ctx.finite(f, name)?)),
        (None, false) => Ok(None),
    };
    let bull = kind_name == "bull_nose";
    let tapered = matches!(kind_name, "tapered_flat" | "tapered_ball");
    let corner = extra(&tool_file.corner_radius_mm, "corner_radius_mm", bull)?;
    let angle = extra(
        &tool_file.taper_half_angle_deg,
        "taper_half_angle_deg",
        tapered,
    )?;
    let made = match (kind_name, corner, angle) {
        ("flat", ..) => Tool::try_new(ToolKind::Flat, diameter, length),
        ("ball", ..) => Tool::try_new(ToolKind::Ball, diameter, length),
        ("bull_nose", Some(rc), _) => Tool::try_bull_nose(diameter, rc, length),
        ("tapered_flat", _, Some(a)) => Tool::try_tapered_flat(diameter, a, length),
        ("tapered_ball", _, Some(a)) => Tool::try_tapered_ball(diameter, a, length),
        (other, ..) => {
            return Err(ctx.err(
                tool_file.kind.span(),
                format!(
                    "tool kind must be 'flat', 'ball', 'bull_nose', 'tapered_flat' or 'tapered_ball', got '{other}'"
                ),
            ));
        }
    };
    let tool = made.map_err(|e| ctx.err(tool_file.length_mm.span(), e.to_string()))?;
    // Shank and holder.
    let t = tool_file;
    let holder_keys = [
        (&t.shank_diameter_mm, "shank_diameter_mm"),
        (&t.shank_length_mm, "shank_length_mm"),
        (&t.holder_diameter_mm, "holder_diameter_mm"),
        (&t.holder_length_mm, "holder_length_mm"),
    ];
    let holder = if let Some(secs) = &t.holder_sections {
        // The holder as sections: with the shank, without the holder cylinder's keys.
        for (given, key) in &holder_keys[2..] {
            if let Some(g) = given {
                return Err(ctx.err(
                    g.span(),
                    format!("tool.{key} and tool.holder_sections both describe the holder: give one of them"),
                ));
            }
        }
        let mut shank = [0.0; 2];
        for (k, (field, key)) in holder_keys[..2].iter().enumerate() {
            let f = field.as_ref().ok_or_else(|| {
                ctx.err(
                    secs.span(),
                    format!("tool.{key} is missing: holder_sections need shank_diameter_mm and shank_length_mm"),
                )
            })?;
            shank[k] = ctx.positive(f, &format!("tool.{key}"))?;
        }
        if secs.get_ref().is_empty() {
            return Err(ctx.err(
                secs.span(),
                "tool.holder_sections is empty: give at least one { length_mm, radius_bottom_mm, radius_top_mm }".to_string(),
            ));
        }
        let mut sections = Vec::new();
        for (i, sec) in secs.get_ref().iter().enumerate() {
            let key = |f: &str| format!("tool.holder_sections[{i}].{f}");
            sections.push(HolderSection {
                length: ctx.positive(&sec.length_mm, &key("length_mm"))?,
                radius_bottom: ctx.positive(&sec.radius_bottom_mm, &key("radius_bottom_mm"))?,
                radius_top: ctx.positive(&sec.radius_top_mm, &key("radius_top_mm"))?,
            });
        }
        let span = holder_keys[0].0.as_ref().map_or(secs.span(), |v| v.span());
        Some(
            Holder::try_sections(shank[0] / 2.0, shank[1], &sections)
                .map_err(|e| ctx.err(span, format!("tool: {e}")))?,
        )
    } else {
        match holder_keys.iter().find(|(v, _)| v.is_some()) {
            None => None,
            Some((given, _)) => {
                let span = given.as_ref().map_or(0..0, |v| v.span());
                let mut v = [0.0; 4];
                for (k, (field, key)) in holder_keys.iter().enumerate() {
                    let f = field.as_ref().ok_or_else(|| {
                        ctx.err(
                            span.clone(),
                            format!("tool.{key} is missing: a holder needs shank_diameter_mm, shank_length_mm, holder_diameter_mm and holder_length_mm"),
                        )
                    })?;
                    v[k] = ctx.positive(f, &format!("tool.{key}"))?;
                }
                Some(
                    Holder::try_new(v[0] / 2.0, v[1], v[2] / 2.0, v[3])
                        .map_err(|e| ctx.err(span, format!("tool: {e}")))?,
                )
            }
        }
    };
    // Stock.
    let dir = path.parent().unwrap_or(Path::new("."));
    let st = stock_file;
    let stock_kind = st.kind.as_ref().map_or("box", |k| k.get_ref().as_str());
    let kind_span = st.kind.as_ref().map_or(st.pitch_mm.span(), |k| k.span());
    let keys: [(&str, Option<Range<usize>>); 10] = [
        ("min", st.min.as_ref().map(|v| v.span())),
        ("max", st.max.as_ref().map(|v| v.span())),
        ("ends", st.ends.as_ref().map(|v| v.span())),
        ("base", st.base.as_ref().map(|v| v.span())),
        ("axis", st.axis.as_ref().map(|v| v.span())),
        ("length_mm", st.length_mm.as_ref().map(|v| v.span())),
        ("radius_mm", st.radius_mm.as_ref().map(|v| v.span())),
        ("file", st.file.as_ref().map(|v| v.span())),
        ("position", st.position.as_ref().map(|v| v.span())),
        ("rotation_deg", st.rotation_deg.as_ref().map(|v| v.span())),
    ];
    let allowed: &[&str] = match stock_kind {
        "box" => &["min", "max"],
        "cylinder" => &["ends", "base", "axis", "length_mm", "radius_mm"],
        "mesh" => &["file", "position", "rotation_deg"],
        other => {
            return Err(ctx.err(
                kind_span,
                format!("stock kind must be 'box', 'cylinder' or 'mesh', got '{other}'"),
            ));
        }
    };
    if let Some((key, Some(span))) = keys
        .iter()
        .find(|(k, s)| s.is_some() && !allowed.contains(k))
    {
        return Err(ctx.err(
            span.clone(),
            format!("stock.{key} does not apply to a '{stock_kind}' stock"),
        ));
    }
    let need = |v: &Option<Spanned<[Real; 3]>>, key: &str| match v {
        Some(v) => ctx.vec3(v, &format!("stock.{key}")),
        None => Err(ctx.err(
            kind_span.clone(),
            format!("a '{stock_kind}' stock needs stock.{key}"),
        )),
    };
    let (stock_box, stock_shape) = match stock_kind {
        "box" => {
            let (mn, mx) = (need(&st.min, "min")?, need(&st.max, "max")?);
            if (0..3).any(|k| mx[k] <= mn[k]) {
                return Err(ctx.err(
                    st.max.as_ref().map_or(0..0, |m| m.span()),
                    "stock.max must exceed stock.min on every axis",
                ));
            }
            let b = Aabb {
                min: mn.into(),
                max: mx.into(),
            };
            (b, StockShape::Box)
        }
        "cylinder" => {
            let radius = match &st.radius_mm {
                Some(r) => ctx.positive(r, "stock.radius_mm")?,
                None => {
                    return Err(ctx.err(kind_span, "a 'cylinder' stock needs stock.radius_mm"));
                }
            };
            let (base, axis, length, span) = match (&st.ends, &st.base) {
                (Some(e), None) => {
                    let [a, b] = *e.get_ref();
                    if !a.iter().chain(b.iter()).all(|c| c.is_finite()) {
                        return Err(ctx.err(
                            e.span(),
                            format!(
                                "stock.ends must have finite components, got {:?}",
                                e.get_ref()
                            ),
                        ));
                    }
                    if st.axis.is_some() || st.length_mm.is_some() {
                        return Err(ctx.err(
                            e.span(),
                            "stock.ends replaces stock.axis and stock.length_mm: give one or the other",
                        ));
                    }
                    let (a, b) = (Vector3::from(a), Vector3::from(b));
                    (a, b - a, (b - a).norm(), e.span())
                }
                (None, Some(b)) => {
                    let base = ctx.vec3(b, "stock.base")?;
                    let axis = need(&st.axis, "axis")?;
                    let length = match &st.length_mm {
                        Some(l) => ctx.positive(l, "stock.length_mm")?,
                        None => {
                            return Err(ctx.err(
                                kind_span,
                                "a 'cylinder' stock needs stock.length_mm with stock.base",
                            ));
                        }
                    };
                    (base, axis, length, b.span())
                }
                (Some(e), Some(_)) => {
                    return Err(ctx.err(e.span(), "give stock.ends or stock.base, not both"));
                }
                (None, None) => {
                    return Err(ctx.err(
                        kind_span,
                        "a 'cylinder' stock needs stock.ends (or stock.base, stock.axis and stock.length_mm)",
                    ));
                }
            };
            let c = Cylinder::try_new(base.into(), axis, radius, length)
                .map_err(|e| ctx.err(span, format!("stock: {e}")))?;
            (c.bounds(), StockShape::Cylinder(c))
        }
        _ => {
            let f = st
                .file
                .as_ref()
                .ok_or_else(|| ctx.err(kind_span.clone(), "a 'mesh' stock needs stock.file"))?;
            let (mesh_path, mesh) =
                ctx.mesh(dir, f, &st.position, &st.rotation_deg, "stock.file")?;
            (
                mesh.bounds(),
                StockShape::Mesh {
                    path: mesh_path,
                    mesh: Box::new(mesh),
                },
            )
        }
    };
    let pitch_mm = ctx.positive(&stock_file.pitch_mm, "pitch_mm")?;
    crate::cutting::stock::check_memory(&stock_box, pitch_mm, memory.bytes).map_err(|e| {
        ctx.err(
            stock_file.pitch_mm.span(),
            format!("stock.pitch_mm = {pitch_mm}: {e} ({})", memory.source),
        )
    })?;
    // Fixtures and design model.
    let mut fixtures: Vec<Fixture> = Vec::new();
    for (k, f) in file.fixtures.iter().enumerate() {
        let key = format!("fixtures[{k}].file");
        let (p, mesh) = ctx.mesh(dir, &f.file, &f.position, &f.rotation_deg, &key)?;
        let name = match &f.name {
            Some(n) => n.get_ref().clone(),
            None => p.file_name().map_or_else(
                || f.file.get_ref().clone(),
                |n| n.to_string_lossy().into_owned(),
            ),
        };
        let span = f.name.as_ref().map_or(f.file.span(), |n| n.span());
        if fixtures.iter().any(|g| g.name() == name) {
            return Err(ctx.err(span, format!("fixture name '{name}' given twice")));
        }
        fixtures.push(
            Fixture::try_new(&name, mesh)
                .map_err(|e| ctx.err(f.file.span(), format!("{key}: {e}")))?,
        );
    }
    let design = match &file.design {
        Some(d) => {
            if let Some(n) = &d.name {
                return Err(ctx.err(
                    n.span(),
                    "design.name does not apply (only fixtures have names)",
                ));
            }
            let (p, mesh) = ctx.mesh(dir, &d.file, &d.position, &d.rotation_deg, "design.file")?;
            let model = DesignModel::try_new(mesh).map_err(|e| {
                ctx.err(d.file.span(), format!("design.file: {}: {e}", p.display()))
            })?;
            Some((p, model))
        }
        None => None,
    };
    // Sweep.
    let bound = match &file.sweep.rotary_step_bound_mm {
        Some(v) => {
            let b = ctx.positive(v, "rotary_step_bound_mm")?;
            if b > 1.0 {
                return Err(ctx.err(v.span(), "rotary_step_bound_mm must be at most 1 mm"));
            }
            b
        }
        None => tol::ROTARY_STEP_BOUND,
    };
    Ok(Cut {
        tool,
        holder,
        stock_box,
        stock_shape,
        pitch_mm,
        fixtures,
        design,
        sweep: SweepOptions {
            rotary_step_bound_mm: bound,
        },
    })
}
