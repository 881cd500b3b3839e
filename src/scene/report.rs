//! `[report]`: how the pages and pictures show the part (`view`).

use super::Ctx;
use super::SceneError;
use crate::math::{Real, UnitVector3, Vector3};
use toml::Spanned;

/// `[report] view`: `"faces"` (the default: `None`), `"iso"` (from +x, −y, +z), an axis
/// direction `"+x"` … `"-z"`, or a vector `[dx, dy, dz]` — always from the part towards
/// the eye.
pub(super) fn report_view(
    ctx: &Ctx<'_>,
    v: &Spanned<toml::Value>,
) -> Result<Option<UnitVector3>, SceneError> {
    let bad = |got: String| {
        ctx.err(
            v.span(),
            format!(
                "report view must be \"faces\", \"iso\", \"+x\", \"-x\", \"+y\", \"-y\", \"+z\", \"-z\" or a direction [dx, dy, dz] (from the part towards the eye), got {got}"
            ),
        )
    };
    let d = match v.get_ref() {
        toml::Value::String(s) => match s.as_str() {
            "faces" => return Ok(None),
            "iso" => Vector3::new(1.0, -1.0, 1.0),
            "+x" => Vector3::x(),
            "-x" => -Vector3::x(),
            "+y" => Vector3::y(),
            "-y" => -Vector3::y(),
            "+z" => Vector3::z(),
            "-z" => -Vector3::z(),
            other => return Err(bad(format!("\"{other}\""))),
        },
        toml::Value::Array(a) => {
            let c: Vec<Real> = a
                .iter()
                .filter_map(|x| match x {
                    toml::Value::Float(f) => Some(*f),
                    toml::Value::Integer(i) => Some(*i as Real),
                    _ => None,
                })
                .collect();
            match c[..] {
                [x, y, z] if c.len() == a.len() && c.iter().all(|x| x.is_finite()) => {
                    Vector3::new(x, y, z)
                }
                _ => return Err(bad(format!("{}", v.get_ref()))),
            }
        }
        other => return Err(bad(format!("{other}"))),
    };
    if d.norm() < 1e-9 {
        return Err(ctx.err(v.span(), "report view [0, 0, 0] has no direction"));
    }
    Ok(Some(UnitVector3::new_normalize(d)))
}
