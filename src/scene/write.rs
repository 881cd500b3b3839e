//! A scene written back as TOML text: the scene of a designed test (`twinmill design`).

use super::Scene;
use super::SceneError;
use crate::machine::chain::AxisKind;
use crate::math::{Real, Vector3};

/// A scene file (TOML text) for a designed test: the machine, deviations, tool, sweep and
/// face options of `scene`, the design's part as stock, a scanner on a turntable (for the
/// bar: about the rotary axis, four views at the bar's corners, the camera 30° off the axis
/// so that faces across the bar's +x end are seen too; for the block: about its vertical
/// axis, four views at its corners from 35° above), the design's faces and the parameters.
pub fn design_scene_toml(
    scene: &Scene,
    design: &crate::calibration::design::Design,
    opts: &crate::calibration::design::DesignOptions,
    parameters: &[String],
    name: &str,
    program_file: &str,
) -> Result<String, SceneError> {
    use std::fmt::Write as _;
    let sc = scene.scanner_for("design")?;
    let mut s = String::new();
    let v = |p: &Vector3| format!("[{}, {}, {}]", p.x, p.y, p.z);
    let _ = writeln!(
        s,
        "# Test cuts designed by twinmill for: {}",
        parameters.join(", ")
    );
    let _ = writeln!(s, "name = \"{name}\"\nprogram = \"{program_file}\"\n");
    let _ = writeln!(
        s,
        "[machine]\nname = \"{}\"\naxes = [",
        scene.machine_name()
    );
    for a in scene.chain().axes() {
        let kind = match a.kind {
            AxisKind::Linear => "linear",
            AxisKind::Rotary => "rotary",
        };
        let _ = writeln!(
            s,
            "  {{ name = \"{}\", kind = \"{kind}\", direction = {}, origin = {} }},",
            a.letter.as_char(),
            v(&a.direction.into_inner()),
            v(&a.origin.coords)
        );
    }
    let spindle = scene.chain().joint_name(scene.chain().axes().len() - 1);
    let _ = writeln!(s, "]\nspindle = \"{}\"", &spindle[1..]);
    let rotaries: String = scene
        .chain()
        .axes()
        .iter()
        .filter(|a| a.kind == AxisKind::Rotary)
        .map(|a| format!(", {} = 0", a.letter.as_char()))
        .collect();
    let _ = writeln!(s, "home = {{ Z = {}{rotaries} }}\n", design.safe_z_mm);
    // The simulated machine carries only the requested deviations: one outside them is held
    // at zero by the identification, so its faces could not fit (the misfit refusal), and
    // the promise is made on a scan the requested model can produce.
    let _ = writeln!(s, "[deviations]");
    for (k, val) in scene.injected() {
        if parameters.iter().any(|p| p == k) {
            let _ = writeln!(s, "{k} = {val:e}");
        } else {
            let _ = writeln!(
                s,
                "# {k} = {val:e} (not simulated: not among the parameters)"
            );
        }
    }
    use crate::cutting::tool::ToolSizes;
    let tool_fields = match scene.tool.sizes() {
        ToolSizes::Plain { diameter } => format!(
            "kind = \"{}\"\ndiameter_mm = {diameter}",
            if scene.tool.kind() == crate::cutting::tool::ToolKind::Ball {
                "ball"
            } else {
                "flat"
            }
        ),
        ToolSizes::BullNose {
            diameter,
            corner_radius,
        } => format!(
            "kind = \"bull_nose\"\ndiameter_mm = {diameter}\ncorner_radius_mm = {corner_radius}"
        ),
        ToolSizes::TaperedFlat {
            tip_diameter,
            half_angle_deg,
        } => format!(
            "kind = \"tapered_flat\"\ndiameter_mm = {tip_diameter}\ntaper_half_angle_deg = {half_angle_deg}"
        ),
        ToolSizes::TaperedBall {
            ball_diameter,
            half_angle_deg,
        } => format!(
            "kind = \"tapered_ball\"\ndiameter_mm = {ball_diameter}\ntaper_half_angle_deg = {half_angle_deg}"
        ),
        ToolSizes::Profile => format!(
            "# a general profile cannot be written back; its enclosing flat tool:\nkind = \"flat\"\ndiameter_mm = {}",
            2.0 * scene.tool.radius()
        ),
    };
    let st = design.stock;
    let _ = writeln!(
        s,
        "\n[tool]\n{tool_fields}\nlength_mm = {}\n",
        scene.tool.length()
    );
    let _ = writeln!(
        s,
        "[stock]\nmin = {}\nmax = {}\npitch_mm = {}\n",
        v(&st.min.coords),
        v(&st.max.coords),
        scene.pitch_mm
    );
    let _ = writeln!(
        s,
        "[sweep]\nrotary_step_bound_mm = {}\n",
        scene.sweep.rotary_step_bound_mm
    );
    let dist = 0.5 * (sc.working_range_mm.0 + sc.working_range_mm.1);
    let block = design.family == crate::calibration::design::Family::Block;
    // The bar: the camera leans from the rotary axis's normal towards +x and turns about the
    // bar's axis (W x). The block: the camera looks down from the elevation and turns about
    // the block's vertical axis (W z), seeing its sides and top.
    let (tilt, fov, centre, axis, up) = if block {
        let c = 0.5 * (st.min.coords + st.max.coords);
        let e = 2.0 * (st.max - st.min).amax();
        (
            BLOCK_SCANNER_ELEVATION_DEG,
            [e, e],
            c,
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
        )
    } else {
        (
            SCANNER_TILT_DEG,
            [opts.length_mm * 1.5, opts.half_section_mm * 5.0],
            Vector3::zeros(),
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
        )
    };
    let (sn, cs) = tilt.to_radians().sin_cos();
    let position = if block {
        // Elevated over the block's centre towards −y.
        centre + Vector3::new(0.0, -dist * cs, dist * sn)
    } else {
        Vector3::new(dist * sn, 0.0, dist * cs)
    };
    let _ = writeln!(
        s,
        "[scanner]\nposition = {}\ntarget = {}\nup = [{}, {}, {}]",
        v(&position),
        v(&centre),
        up[0],
        up[1],
        up[2]
    );
    let _ = writeln!(
        s,
        "baseline_mm = {}\nfov_mm = [{}, {}]\npitch_mm = {}\nnoise_sigma_mm = {}",
        sc.baseline_mm, fov[0], fov[1], sc.pitch_mm, sc.noise_sigma_mm
    );
    let _ = writeln!(
        s,
        "working_range_mm = [{}, {}]\ngrazing_limit_deg = {}\nseed = {}",
        sc.working_range_mm.0, sc.working_range_mm.1, sc.grazing_limit_deg, sc.seed
    );
    let _ = writeln!(
        s,
        "turntable = {{ axis_point = {}, axis = [{}, {}, {}], angles_deg = [45.0, 135.0, 225.0, 315.0] }}\n",
        v(&centre),
        axis[0],
        axis[1],
        axis[2]
    );
    let _ = writeln!(s, "[identify]\nfaces = [");
    for f in &design.faces {
        let _ = writeln!(
            s,
            "  {{ name = \"{}\", line = {}, kind = \"{}\" }},",
            f.name,
            f.line,
            crate::calibration::design::kind_name(f.kind)
        );
    }
    let _ = writeln!(
        s,
        "]\nparameters = [{}]\nregistration = \"estimate\"\nmargin_mm = {}\nband_mm = {}",
        parameters
            .iter()
            .map(|p| format!("\"{p}\""))
            .collect::<Vec<_>>()
            .join(", "),
        scene.face_options.margin_mm,
        scene.face_options.band_mm
    );
    let _ = writeln!(s, "known = {{}}");
    Ok(s)
}

/// The block's camera elevation above the horizontal (degrees): the sides seen at 35°
/// incidence, the top at 55°.
const BLOCK_SCANNER_ELEVATION_DEG: Real = 35.0;

/// How far the designed scene's camera leans from the rotary axis's normal towards +x
/// (degrees): enough to see the faces across the bar's +x end at 60° incidence.
const SCANNER_TILT_DEG: Real = 30.0;
