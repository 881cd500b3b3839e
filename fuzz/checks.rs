//! What every fuzz target checks, one function per target: the input is read (and, where
//! the reader's result feeds an evaluation, evaluated) or refused with one error on one line
//! naming the file — never a panic, a hang or unbounded memory. Shared by the cargo-fuzz
//! targets (`fuzz_targets/*.rs`) and the stable driver that runs them in the test suite
//! (`tests/twinmill/fuzz.rs`).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use twinmill::metrology::cloud::{read_ply, read_pts, read_xyz};
use twinmill::metrology::{ball_sensor, circular, positioning};
use twinmill::nc::{InterpOptions, Interpreter, ToolTable};
use twinmill::pipeline::dbb::parse_plan;
use twinmill::scene::HexapodScene;
use twinmill::scene::{MemoryBudget, Scene, machine_kind};
use twinmill::study::{self, Manifest};

/// An error's message: it starts with the file's name and is one line.
fn one_line(e: &dyn std::fmt::Display, name: &str) {
    let m = e.to_string();
    assert!(
        m.starts_with(name) && !m.contains('\n'),
        "not one line naming {name}: {m}"
    );
}

/// Any bytes as an NC program through the interpreter, with a two-tool table.
pub fn nc_interp(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let tool_table = ToolTable::parse("T1 P1 Z1 D0.5\nT2 P2 Z2 D1\n", Path::new("t.tbl"))
        .expect("the tool table reads");
    let opts = InterpOptions {
        max_blocks: 5_000,
        max_idle_blocks: 2_000,
        tool_table,
        ..InterpOptions::default()
    };
    for rec in Interpreter::from_text(&text, Path::new("fuzz.ngc"), opts) {
        if let Err(e) = rec {
            one_line(&e, "fuzz.ngc");
            break;
        }
    }
}

/// Any bytes as a scene file: the serial-chain reader (with a 64 MiB stock budget: a
/// mutated pitch must be refused, not allocated), and the hexapod reader when the text says
/// `kind = "hexapod"`.
pub fn scene(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.toml");
    let budget = MemoryBudget {
        bytes: 64.0 * 1024.0 * 1024.0,
        source: "the fuzz budget".into(),
    };
    if machine_kind(text).as_deref() == Some("hexapod") {
        if let Err(e) = HexapodScene::parse(text, path) {
            one_line(&e, "fuzz.toml");
        }
    } else if let Err(e) = Scene::parse_with(text, path, &budget) {
        assert!(!e.to_string().contains('\n'), "a message on one line: {e}");
    }
}

/// Any bytes as a point-cloud file: PLY (ASCII or binary), and as text XYZ and PTS.
pub fn cloud(data: &[u8]) {
    if let Err(e) = read_ply(data, Path::new("fuzz.ply")) {
        one_line(&e, "fuzz.ply");
    }
    if let Ok(text) = std::str::from_utf8(data) {
        if let Err(e) = read_xyz(text, Path::new("fuzz.xyz")) {
            one_line(&e, "fuzz.xyz");
        }
        if let Err(e) = read_pts(text, Path::new("fuzz.pts")) {
            one_line(&e, "fuzz.pts");
        }
    }
}

/// Any text as a readings file: ISO 230-2 positioning readings (evaluated when read), an
/// ISO 230-4 / ball-bar trace (evaluated, with and without a pitch), the ball sensor's
/// readings, a DBB calibration plan.
pub fn readings(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.csv");
    match positioning::parse_readings(text, path) {
        Ok(r) => {
            if let Err(e) = positioning::evaluate(&r, path) {
                one_line(&e, "fuzz.csv");
            }
        }
        Err(e) => one_line(&e, "fuzz.csv"),
    }
    match circular::parse_trace(text, path) {
        Ok(samples) => {
            for pitch_mm in [None, Some(5.0)] {
                let opts = circular::CircularOptions {
                    radius_mm: 150.0,
                    pitch_mm,
                };
                if let Err(e) = circular::evaluate(&samples, &opts, path) {
                    one_line(&e, "fuzz.csv");
                }
            }
        }
        Err(e) => one_line(&e, "fuzz.csv"),
    }
    if let Err(e) = ball_sensor::parse_readings(text, path) {
        one_line(&e, "fuzz.csv");
    }
    if let Err(e) = parse_plan(text, Path::new("fuzz.toml")) {
        one_line(&e, "fuzz.toml");
    }
}

/// A folder holding the repository's studies and scenes (so that a study file's `scene` is
/// found), and the manifest of `studies/nine-deviations.toml` that shards are read against.
pub struct StudySetup {
    dir: PathBuf,
    manifest: Manifest,
}

impl StudySetup {
    /// Copies `top`'s `studies/` and `scenes/` into a fresh temporary folder and plans the
    /// nine-deviation study there in two shards.
    pub fn new(top: &Path) -> StudySetup {
        let dir = std::env::temp_dir().join(format!("twinmill-fuzz-study-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("a temporary folder");
        for folder in ["studies", "scenes"] {
            for e in std::fs::read_dir(top.join(folder))
                .expect("the repository's files")
                .flatten()
            {
                std::fs::copy(e.path(), dir.join(e.file_name())).expect("copied");
            }
        }
        let manifest = study::plan(&dir.join("nine-deviations.toml"), 2).expect("the study plans");
        StudySetup { dir, manifest }
    }

    /// The manifest shards are read against.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The folder the study's files are in.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Drop for StudySetup {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// The setup of the cargo-fuzz target, made once per process.
pub fn study_setup() -> &'static StudySetup {
    static SETUP: OnceLock<StudySetup> = OnceLock::new();
    SETUP.get_or_init(|| StudySetup::new(&Path::new(env!("CARGO_MANIFEST_DIR")).join("..")))
}

/// Any bytes as a study's file: a shard (Parquet, from `PAR1`), a manifest (JSON, from
/// `{`), else a study file (TOML) that is planned.
pub fn study(setup: &StudySetup, data: &[u8]) {
    let dir = &setup.dir;
    if data.starts_with(b"PAR1") {
        let p = dir.join("fuzz-shard.parquet");
        std::fs::write(&p, data).expect("written");
        if let Err(e) = study::read_shard(&setup.manifest, &p) {
            one_line(&e, &p.display().to_string());
        }
    } else if data.starts_with(b"{") {
        let p = dir.join("fuzz-manifest.json");
        std::fs::write(&p, data).expect("written");
        if let Err(e) = study::read_manifest(&p) {
            one_line(&e, &p.display().to_string());
        }
    } else {
        let p = dir.join("fuzz-study.toml");
        std::fs::write(&p, data).expect("written");
        if let Err(e) = study::plan(&p, 1) {
            assert!(!e.to_string().contains('\n'), "a message on one line: {e}");
        }
    }
}
