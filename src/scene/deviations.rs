//! An identified machine's **deviations file** (`--deviations FILE`, written by
//! `identify --measurement … --deviations-out FILE`): the scene's `[deviations]`,
//! `[error_motions]` and `[reversal]` sections as identified, and an `[identified]` section
//! saying what they were identified for and from — the machine and scene, the machine's
//! axes, the source files, whether a misfit was accepted, the parameters not determined —
//! with `[identified.sigma]`, each identified parameter's standard uncertainty.
//!
//! Read into a scene, the file replaces the serial machine's deviation model: the chain the
//! twin simulates is the nominal chain with the file's sections exactly as if they had been
//! written in the scene file (read by the same functions, in the same order), and the
//! identification model is the nominal chain with the file's error motions and the scene's
//! `[identify] known` deviations, as the scene reader builds it.
//!
//! Refused, at the file's line and column: an unknown key, a non-finite number, a file
//! without `[identified]` or without `[identified.sigma]`, a file identified on a machine
//! whose axes differ from the scene's, a deviation or error motion the machine does not
//! have. A hexapod scene takes no deviations file.

use super::Ctx;
use super::Scene;
use super::SceneError;
use super::file::MotionFile;
use super::machine::{Machine, deviation_map, error_motions};
use super::{read_text, toml_error};
use crate::machine::chain::Chain;
use crate::math::Real;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;
use toml::Spanned;

/// The file's format.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DeviationsFile {
    #[serde(default)]
    deviations: BTreeMap<String, Spanned<Real>>,
    #[serde(default)]
    error_motions: BTreeMap<String, Spanned<MotionFile>>,
    #[serde(default)]
    reversal: BTreeMap<String, Spanned<Real>>,
    #[serde(default)]
    identified: Option<Spanned<IdentifiedFile>>,
}

/// `[identified]`: what the sections were identified for and from.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
#[expect(
    dead_code,
    reason = "machine, scene, sources and misfit_accepted are records for the reader of the file, checked for type only"
)]
struct IdentifiedFile {
    machine: String,
    scene: String,
    axes: Spanned<Vec<String>>,
    sources: Vec<String>,
    misfit_accepted: bool,
    not_determined: Vec<String>,
    #[serde(default)]
    sigma: Option<BTreeMap<String, Spanned<Real>>>,
}

/// What a deviations file gives a scene.
struct Read {
    chain: Chain,
    injected: BTreeMap<String, Real>,
}

/// Reads `text` (the file at `path`) for a machine whose nominal chain is `nominal`.
fn read(text: &str, path: &Path, nominal: &Chain) -> Result<Read, SceneError> {
    let ctx = Ctx { path, text };
    let file: DeviationsFile = toml::from_str(text).map_err(|e| toml_error(text, path, &e))?;
    let Some(identified) = &file.identified else {
        return Err(ctx.err(
            0..0,
            "no [identified] section: a deviations file records what it was identified for \
             and from (as `twinmill identify --deviations-out` writes it)",
        ));
    };
    let id = identified.get_ref();
    let axes: Vec<String> = nominal
        .axes()
        .iter()
        .map(|a| a.letter.as_char().to_string())
        .collect();
    if *id.axes.get_ref() != axes {
        return Err(ctx.err(
            id.axes.span(),
            format!(
                "identified.axes: identified on a machine with axes [{}], but this scene's \
                 machine has [{}]",
                id.axes.get_ref().join(", "),
                axes.join(", ")
            ),
        ));
    }
    let Some(sigma) = &id.sigma else {
        return Err(ctx.err(
            identified.span(),
            "identified.sigma: missing, expected each identified parameter's standard \
             uncertainty ([identified.sigma])",
        ));
    };
    for (name, s) in sigma {
        let v = ctx.finite(s, &format!("identified.sigma.{name}"))?;
        if v < 0.0 {
            return Err(ctx.err(
                s.span(),
                format!("identified.sigma.{name}: got {v}, expected 0 or more"),
            ));
        }
        if id.not_determined.iter().any(|n| n == name) {
            return Err(ctx.err(
                s.span(),
                format!(
                    "identified.sigma.{name}: a σ for a parameter the file lists as not \
                     determined"
                ),
            ));
        }
    }
    let mut chain = nominal.clone();
    let injected = deviation_map(&ctx, &mut chain, &file.deviations)?;
    error_motions(&ctx, &mut chain, &file.error_motions, &file.reversal)?;
    Ok(Read { chain, injected })
}

/// Sets `known` on `model` as the scene reader does: joint deviations first, then the ISO
/// location and squareness terms composed onto them.
fn apply_known(model: &mut Chain, known: &BTreeMap<String, Real>) -> Result<(), String> {
    for iso in [false, true] {
        for (name, v) in known.iter().filter(|(n, _)| n.contains('_') != iso) {
            if iso {
                model
                    .apply_iso_term(name, *v)
                    .map_err(|e| format!("{name}: {e}"))?;
            } else {
                let id = model
                    .deviation_id(name)
                    .map_err(|e| format!("{name}: {e}"))?;
                model.set_deviation(id, *v);
            }
        }
    }
    Ok(())
}

impl Scene {
    /// Replaces the serial machine's injected deviations (its `[deviations]` section) by
    /// `injected`, names as `[deviations]` takes them: the chain becomes the nominal chain
    /// with its error motions and reversals kept and the map applied as the scene reader
    /// applies the section (joint deviations first, then the ISO terms composed onto them).
    /// The identification model is unchanged. The scene is unchanged on an error (an
    /// unknown name, or a hexapod scene).
    pub fn replace_injected_deviations(
        &mut self,
        injected: BTreeMap<String, Real>,
    ) -> Result<(), String> {
        let Machine::Serial(m) = &mut self.machine else {
            return Err("a hexapod's deviations are not a serial chain's".into());
        };
        let mut chain = m.chain.nominal().with_error_motions_of(&m.chain);
        apply_known(&mut chain, &injected)?;
        m.chain = chain;
        m.injected = injected;
        Ok(())
    }

    /// Replaces the machine's deviation model by the deviations file at `path` (see the
    /// module documentation); the scene is unchanged on an error.
    pub fn apply_deviations_file(&mut self, path: &Path) -> Result<(), SceneError> {
        let text = read_text(path)?;
        self.apply_deviations_text(&text, path)
    }

    /// [`Scene::apply_deviations_file`] on the file's text; `path` locates messages.
    pub fn apply_deviations_text(&mut self, text: &str, path: &Path) -> Result<(), SceneError> {
        let scene_path = self.path.clone();
        let Machine::Serial(m) = &mut self.machine else {
            return Err(SceneError::Invalid {
                path: path.to_path_buf(),
                line: 1,
                column: 1,
                message: format!(
                    "a deviations file is for a serial machine; {} is a hexapod",
                    scene_path.display()
                ),
            });
        };
        let nominal = m.chain.nominal();
        let r = read(text, path, &nominal)?;
        let mut model = nominal.with_error_motions_of(&r.chain);
        apply_known(&mut model, &m.known).map_err(|message| SceneError::Invalid {
            path: scene_path.clone(),
            line: 1,
            column: 1,
            message: format!("identify.known: {message}"),
        })?;
        m.chain = r.chain;
        m.injected = r.injected;
        m.model = model;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> Scene {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/xyz-error-motions.toml");
        Scene::load(&path).expect("scene")
    }

    const IDENTIFIED: &str = "[identified]\nmachine = \"m\"\nscene = \"s\"\n\
        axes = [\"X\", \"Y\", \"Z\"]\nsources = [\"a.csv\"]\nmisfit_accepted = false\n\
        not_determined = []\n";

    #[test]
    fn the_file_replaces_the_chain_and_keeps_the_scene_on_a_refusal() {
        let mut s = scene();
        let text = format!(
            "[deviations]\n\"EC(0X)Y\" = 1e-5\n[reversal]\nX = 0.001\n{IDENTIFIED}\
             [identified.sigma]\n\"EC(0X)Y\" = 1e-7\n"
        );
        s.apply_deviations_text(&text, Path::new("f.toml"))
            .expect("reads");
        assert_eq!(s.injected().get("EC(0X)Y"), Some(&1e-5));
        let x = crate::nc::AxisLetter::X;
        assert_eq!(s.chain().error_motions(x).map(|e| e.reversal), Some(0.001));
        // No sigma: refused, the scene as it was.
        let before = s.injected().clone();
        let e = s
            .apply_deviations_text(
                &format!("[deviations]\n\"EC(0X)Y\" = 3e-5\n{IDENTIFIED}"),
                Path::new("f.toml"),
            )
            .expect_err("refused");
        assert!(e.to_string().starts_with("f.toml:3:1:"), "{e}");
        assert!(e.to_string().contains("identified.sigma"), "{e}");
        assert_eq!(s.injected(), &before);
    }

    #[test]
    fn other_axes_unknown_keys_and_non_finite_numbers_are_refused_at_their_place() {
        let mut s = scene();
        let other = IDENTIFIED.replace("[\"X\", \"Y\", \"Z\"]", "[\"X\", \"Y\", \"Z\", \"A\"]");
        let e = s
            .apply_deviations_text(&format!("{other}[identified.sigma]\n"), Path::new("f.toml"))
            .expect_err("refused");
        assert!(e.to_string().starts_with("f.toml:4:8:"), "{e}");
        let e = s
            .apply_deviations_text(
                &format!("[deviations]\nfoo_bar = 1.0\n{IDENTIFIED}[identified.sigma]\n"),
                Path::new("f.toml"),
            )
            .expect_err("refused");
        assert!(e.to_string().starts_with("f.toml:2:"), "{e}");
        let e = s
            .apply_deviations_text(
                &format!("[reversal]\nX = nan\n{IDENTIFIED}[identified.sigma]\n"),
                Path::new("f.toml"),
            )
            .expect_err("refused");
        assert!(e.to_string().starts_with("f.toml:2:5:"), "{e}");
        let e = s
            .apply_deviations_text(
                &format!("[wobble]\nX = 1.0\n{IDENTIFIED}[identified.sigma]\n"),
                Path::new("f.toml"),
            )
            .expect_err("refused");
        assert!(e.to_string().contains("wobble"), "{e}");
    }
}
