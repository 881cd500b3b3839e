//! **Studies**: many identification trials of one scene, planned once, run in shards by
//! separate processes (a Slurm array job, a Kubernetes Indexed Job, or a loop), and merged.
//!
//! - [`plan`] reads a study file (TOML: the base scene, the number of trials, a seed, and
//!   what varies — deviations drawn from distributions, the scanner's range noise) and fixes
//!   every trial's inputs in a [`Manifest`] (JSON): the deviation values, the scanner's seed
//!   and noise, the shard each trial belongs to, and fingerprints of the scene and program
//!   files, so a shard run against changed inputs is refused.
//! - [`run_shard`] runs one shard's trials: the scene with the trial's deviations injected
//!   and its scanner set, cut, scanned and identified as `twinmill identify` does (no Monte
//!   Carlo inside a trial), one [`Row`] per trial; [`shard_parquet`] writes them as one
//!   Parquet file (one row per trial: inputs, identified values, σ, the injected truth,
//!   whether each parameter was determined, χ², the solver's rounds, timing).
//! - [`merge`] reads every shard's file, checks that each belongs to the manifest and holds
//!   exactly its trials, and summarises per parameter: bias, spread, coverage of ±3σ and the
//!   fraction of trials that determined it.
//!
//! May use [`crate::pipeline`], [`crate::scene`] and everything they use. **Invariants:** a
//! trial's outcome depends only on its inputs in the manifest, so the rows — and the summary —
//! are the same whatever the shard count (timings aside); a shard file is written whole or
//! not at all; merging never fills in a missing trial.

use crate::math::{CounterRng, Real};
use crate::pipeline::identify_scene;
use crate::progress::NoProgress;
use crate::scene::Scene;
use arrow_array::{
    Array, ArrayRef, BooleanArray, Float64Array, RecordBatch, StringArray, UInt64Array,
};
use arrow_schema::{DataType, Field, Schema};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;
use toml::Spanned;

/// Errors of a study.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// The study file or manifest is not valid.
    #[error("{path}: {message}")]
    Input {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// The study file or its scene is not valid, at a line and column (`file:line:col:
    /// key: what is wrong, what is expected`).
    #[error("{0}")]
    Located(#[from] crate::scene::SceneError),
    /// A shard file is missing, foreign or incomplete.
    #[error("{path}: {message}")]
    Shard {
        /// The shard file.
        path: String,
        /// What is wrong.
        message: String,
    },
}

fn input(path: &Path, message: impl Into<String>) -> StudyError {
    StudyError::Input {
        path: path.display().to_string(),
        message: message.into(),
    }
}

/// A distribution a study draws a value from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Distribution {
    /// Always this value.
    Fixed(Real),
    /// Uniform in `[lo, hi]`.
    Uniform([Real; 2]),
    /// Normal with mean and standard deviation.
    Normal([Real; 2]),
}

impl Distribution {
    fn check(&self) -> Result<(), String> {
        match *self {
            Distribution::Fixed(v) if !v.is_finite() => {
                Err(format!("got fixed = {v}, expected a finite value"))
            }
            Distribution::Uniform([a, b]) if !(a.is_finite() && b.is_finite() && a <= b) => Err(
                format!("got uniform = [{a}, {b}], expected finite [lo, hi] with lo ≤ hi"),
            ),
            Distribution::Normal([m, sd]) if !(m.is_finite() && sd.is_finite() && sd >= 0.0) => {
                Err(format!(
                    "got normal = [{m}, {sd}], expected a finite mean and σ ≥ 0"
                ))
            }
            _ => Ok(()),
        }
    }

    /// The value for trial `trial`, stream `k` of `rng`.
    fn draw(&self, rng: &CounterRng, trial: u64, k: u64) -> Real {
        let stream = trial.wrapping_mul(1 << 20).wrapping_add(k);
        match *self {
            Distribution::Fixed(v) => v,
            Distribution::Uniform([a, b]) => a + (b - a) * rng.uniform(stream, 7),
            Distribution::Normal([m, s]) => m + s * rng.normal(stream),
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StudyFile {
    /// The base scene, relative to the study file.
    scene: Spanned<String>,
    /// Number of trials.
    trials: Spanned<usize>,
    /// Seed of every draw.
    #[serde(default = "default_seed")]
    seed: u64,
    /// The scanner's seed of trial k is `scanner_seed_base + k` (as `identify --monte-carlo`
    /// seeds its trials from `[identify] monte_carlo.seed`); by default it is derived from
    /// the scene's scanner seed and `seed`.
    #[serde(default)]
    scanner_seed_base: Option<u64>,
    #[serde(default)]
    vary: VaryFile,
}

fn default_seed() -> u64 {
    1
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct VaryFile {
    /// Deviations by name (the base scene's `[deviations]` are replaced by the draws).
    #[serde(default)]
    deviations: BTreeMap<Spanned<String>, Spanned<Distribution>>,
    /// The scanner's Gaussian range noise σ (mm).
    #[serde(default)]
    scanner_noise_sigma_mm: Option<Spanned<Distribution>>,
}

/// One trial's inputs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrialInputs {
    /// Trial number, from 0.
    pub trial: u64,
    /// The shard that runs it, from 0.
    pub shard: usize,
    /// The scanner's seed.
    pub scanner_seed: u64,
    /// The scanner's range noise σ (mm).
    pub noise_sigma_mm: Real,
    /// Deviations injected, by name, in the order of the study file.
    pub deviations: Vec<(String, Real)>,
}

/// Every trial's inputs, fixed: what each shard runs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Format tag.
    pub format: String,
    /// Fingerprint of everything below (hex): shard files carry it.
    pub id: String,
    /// The base scene (absolute path).
    pub scene: PathBuf,
    /// Fingerprints of the scene and program texts when planned.
    pub inputs_fingerprint: String,
    /// The parameters identified (the scene's `[identify] parameters`).
    pub parameters: Vec<String>,
    /// The deviations varied, in order.
    pub varied: Vec<String>,
    /// Number of shards.
    pub shards: usize,
    /// The trials.
    pub trials: Vec<TrialInputs>,
}

const FORMAT: &str = "twinmill-study-1";

/// Most trials a study may plan: ten million (a manifest of some 2 GB).
pub const MAX_TRIALS: usize = 10_000_000;

/// FNV-1a over bytes: a fingerprint to notice changed inputs, not a security measure.
fn fnv(bytes: &[u8], mut h: u64) -> u64 {
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

const FNV_START: u64 = 0xcbf2_9ce4_8422_2325;

/// The key of a shard's row fingerprint in its Parquet (Arrow schema) metadata.
const ROWS_KEY: &str = "twinmill.rows";

/// A fingerprint of rows, every stored value bit for bit (FNV-1a over a canonical byte
/// string): a shard carries its rows', and reading checks it, so damage that still decodes —
/// a flipped bit in a value, or in the metadata that leads the reader elsewhere — is noticed.
fn rows_fingerprint(rows: &[Row]) -> String {
    let mut h = FNV_START;
    let mut put = |bytes: &[u8]| h = fnv(bytes, h);
    let opt_f = |v: Option<Real>| {
        v.map_or([0xff; 9], |x| {
            let mut b = [0u8; 9];
            b[1..].copy_from_slice(&x.to_bits().to_le_bytes());
            b
        })
    };
    let opt_u = |v: Option<u64>| {
        v.map_or([0xff; 9], |x| {
            let mut b = [0u8; 9];
            b[1..].copy_from_slice(&x.to_le_bytes());
            b
        })
    };
    for r in rows {
        put(&r.inputs.trial.to_le_bytes());
        put(&(r.inputs.shard as u64).to_le_bytes());
        put(&r.inputs.scanner_seed.to_le_bytes());
        put(&r.inputs.noise_sigma_mm.to_bits().to_le_bytes());
        for (_, v) in &r.inputs.deviations {
            put(&v.to_bits().to_le_bytes());
        }
        for (e, t) in r.estimates.iter().zip(&r.injected) {
            put(&opt_f(e.map(|e| e.0)));
            put(&opt_f(e.map(|e| e.1)));
            put(&t.to_bits().to_le_bytes());
        }
        put(&opt_f(r.chi2));
        put(&opt_u(r.dof));
        put(&opt_u(r.rounds));
        put(&[r.converged.map_or(2, u8::from)]);
        match &r.error {
            Some(e) => {
                put(&(e.len() as u64).to_le_bytes());
                put(e.as_bytes());
            }
            None => put(&[0xff; 8]),
        }
        put(&r.seconds.to_bits().to_le_bytes());
    }
    format!("{h:016x}")
}

fn scene_fingerprint(scene: &Path) -> Result<String, StudyError> {
    let s = Scene::load(scene).map_err(|e| input(scene, e.to_string()))?;
    let text = std::fs::read(scene).map_err(|e| input(scene, e.to_string()))?;
    let program =
        std::fs::read(&s.program_path).map_err(|e| input(&s.program_path, e.to_string()))?;
    Ok(format!("{:016x}", fnv(&program, fnv(&text, FNV_START))))
}

/// Plans the study in `study_file` into `shards` shards (see the module documentation).
pub fn plan(study_file: &Path, shards: usize) -> Result<Manifest, StudyError> {
    let text = crate::scene::read_text(study_file)?;
    let f: StudyFile =
        toml::from_str(&text).map_err(|e| crate::scene::toml_error(&text, study_file, &e))?;
    let at = |span: std::ops::Range<usize>, message: String| {
        let (line, column) = crate::scene::line_col(&text, span.start);
        StudyError::Located(crate::scene::SceneError::Invalid {
            path: study_file.to_path_buf(),
            line,
            column,
            message,
        })
    };
    let trials = *f.trials.get_ref();
    if !(1..=MAX_TRIALS).contains(&trials) {
        return Err(at(
            f.trials.span(),
            format!("trials: got {trials}, expected 1 to {MAX_TRIALS}"),
        ));
    }
    if shards == 0 || shards > trials {
        return Err(input(
            study_file,
            format!("--shards must be between 1 and the number of trials ({trials}), got {shards}"),
        ));
    }
    let base = study_file.parent().unwrap_or(Path::new("."));
    let scene_path = base.join(f.scene.get_ref());
    let scene_path = scene_path.canonicalize().map_err(|e| {
        at(
            f.scene.span(),
            format!("scene: {}: cannot read: {e}", scene_path.display()),
        )
    })?;
    let scene = Scene::load(&scene_path)?;
    if scene.parameters.is_empty() {
        return Err(input(
            &scene_path,
            "a study identifies the scene's [identify] parameters: the scene names none",
        ));
    }
    if scene.scanner.is_none() {
        return Err(input(
            &scene_path,
            "a study scans the cut part: the scene needs a [scanner]",
        ));
    }
    for (name, d) in &f.vary.deviations {
        let key = format!("vary.deviations.{}", name.get_ref());
        let chain = scene.chain();
        let n = name.get_ref();
        let named = if n.contains('_') {
            chain.deviation_id(n).map(|_| ())
        } else {
            chain.iso_term_id(n).map(|_| ())
        };
        named.map_err(|e| at(name.span(), format!("{key}: {e}")))?;
        d.get_ref()
            .check()
            .map_err(|e| at(d.span(), format!("{key}: {e}")))?;
    }
    if let Some(d) = &f.vary.scanner_noise_sigma_mm {
        d.get_ref()
            .check()
            .map_err(|e| at(d.span(), format!("vary.scanner_noise_sigma_mm: {e}")))?;
    }
    let scanner = scene.scanner.as_ref().map(|s| (s.seed, s.noise_sigma_mm));
    let (seed0, noise0) = scanner.unwrap_or((0, 0.0));
    let rng = CounterRng::new(f.seed);
    let n = trials;
    let trials = (0..n)
        .map(|k| {
            let t = k as u64;
            let noise = f
                .vary
                .scanner_noise_sigma_mm
                .as_ref()
                .map_or(noise0, |d| d.get_ref().draw(&rng, t, 0).max(0.0));
            TrialInputs {
                trial: t,
                shard: k * shards / n,
                scanner_seed: f
                    .scanner_seed_base
                    .unwrap_or(seed0.wrapping_add(f.seed.wrapping_mul(1_000_003)))
                    .wrapping_add(t),
                noise_sigma_mm: noise,
                deviations: f
                    .vary
                    .deviations
                    .iter()
                    .enumerate()
                    .map(|(j, (name, d))| {
                        (
                            name.get_ref().clone(),
                            d.get_ref().draw(&rng, t, 1 + j as u64),
                        )
                    })
                    .collect(),
            }
        })
        .collect();
    let mut m = Manifest {
        format: FORMAT.into(),
        id: String::new(),
        scene: scene_path.clone(),
        inputs_fingerprint: scene_fingerprint(&scene_path)?,
        parameters: scene.parameters.clone(),
        varied: f
            .vary
            .deviations
            .keys()
            .map(|k| k.get_ref().clone())
            .collect(),
        shards,
        trials,
    };
    let body = serde_json::to_vec(&m).map_err(|e| input(study_file, e.to_string()))?;
    m.id = format!("{:016x}", fnv(&body, FNV_START));
    Ok(m)
}

/// Reads a manifest and checks its fingerprint.
pub fn read_manifest(path: &Path) -> Result<Manifest, StudyError> {
    let text = std::fs::read_to_string(path).map_err(|e| input(path, e.to_string()))?;
    let m: Manifest = serde_json::from_str(&text)
        .map_err(|e| input(path, format!("{}:{}: {e}", e.line(), e.column())))?;
    if m.format != FORMAT {
        return Err(input(path, format!("not a {FORMAT} manifest")));
    }
    let mut body = m.clone();
    body.id = String::new();
    let bytes = serde_json::to_vec(&body).map_err(|e| input(path, e.to_string()))?;
    if format!("{:016x}", fnv(&bytes, FNV_START)) != m.id {
        return Err(input(
            path,
            "the manifest was changed after planning (its id does not match)",
        ));
    }
    Ok(m)
}

/// One trial's outcome.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// The inputs.
    pub inputs: TrialInputs,
    /// Per parameter of the manifest: value and σ when identified on its own.
    pub estimates: Vec<Option<(Real, Real)>>,
    /// Per parameter: the injected value.
    pub injected: Vec<Real>,
    /// χ² and degrees of freedom of the solve.
    pub chi2: Option<Real>,
    /// Degrees of freedom.
    pub dof: Option<u64>,
    /// Rounds of the model-correction loop, and whether it converged.
    pub rounds: Option<u64>,
    /// Converged.
    pub converged: Option<bool>,
    /// Why the trial failed, when it did.
    pub error: Option<String>,
    /// Seconds the trial took (not part of comparisons).
    pub seconds: Real,
}

/// A parameter's injected value in a trial's scene: a joint deviation (`dy_AY`) as the
/// chain holds it; an ISO term (`EY0A`, `EC(0X)Y`) as injected by that name, or zero when
/// the scene injects neither it nor any joint deviation (which would project onto it: the
/// value is then not one number, and `NaN` says so).
fn injected_value(s: &Scene, p: &str) -> Real {
    let chain = s.chain();
    if p.contains('_') {
        return chain
            .deviation_id(p)
            .map_or(Real::NAN, |id| chain.deviation(id));
    }
    let injected = s.injected();
    match injected.get(p) {
        Some(v) => *v,
        None if injected.keys().any(|k| k.contains('_')) => Real::NAN,
        None => 0.0,
    }
}

/// Which shard to run: the given index, else `SLURM_ARRAY_TASK_ID`, else
/// `JOB_COMPLETION_INDEX` (Kubernetes Indexed Jobs).
pub fn shard_index(given: Option<usize>) -> Result<usize, String> {
    if let Some(i) = given {
        return Ok(i);
    }
    for var in ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"] {
        if let Ok(v) = std::env::var(var) {
            return v
                .trim()
                .parse()
                .map_err(|_| format!("{var}='{v}' is not a shard index"));
        }
    }
    Err(
        "no shard: give --shard I, or run under a Slurm array (SLURM_ARRAY_TASK_ID) or a \
         Kubernetes Indexed Job (JOB_COMPLETION_INDEX)"
            .into(),
    )
}

/// Runs the trials of shard `shard` (see the module documentation).
pub fn run_shard(m: &Manifest, shard: usize) -> Result<Vec<Row>, StudyError> {
    if shard >= m.shards {
        return Err(input(
            &m.scene,
            format!(
                "shard {shard} does not exist: the study has shards 0 … {}",
                m.shards - 1
            ),
        ));
    }
    if scene_fingerprint(&m.scene)? != m.inputs_fingerprint {
        return Err(input(
            &m.scene,
            "the scene or its program changed since the study was planned: plan it again",
        ));
    }
    let base = Scene::load(&m.scene).map_err(|e| input(&m.scene, e.to_string()))?;
    let program = base
        .load_program()
        .map_err(|e| input(&m.scene, e.to_string()))?;
    let mut rows = Vec::new();
    for t in m.trials.iter().filter(|t| t.shard == shard) {
        let clock = Instant::now();
        let mut s = base.clone();
        // The draws replace the scene's values of the same names; joint deviations and ISO
        // terms are then applied as the scene reader applies `[deviations]`.
        let mut injected = s
            .serial_mut()
            .ok_or_else(|| input(&m.scene, "a study varies a serial machine's deviations"))?
            .injected
            .clone();
        for (name, v) in &t.deviations {
            injected.insert(name.clone(), *v);
        }
        s.replace_injected_deviations(injected)
            .map_err(|e| input(&m.scene, e))?;
        if let Some(sc) = s.scanner.as_mut() {
            sc.seed = t.scanner_seed;
            sc.noise_sigma_mm = t.noise_sigma_mm;
        }
        let injected: Vec<Real> = m.parameters.iter().map(|p| injected_value(&s, p)).collect();
        let row = match identify_scene(&s, &program, None, Some(0), &NoProgress) {
            Ok(out) => {
                let r = &out.report;
                Row {
                    inputs: t.clone(),
                    estimates: m
                        .parameters
                        .iter()
                        .map(|p| {
                            r.identified
                                .iter()
                                .find(|e| &e.name == p)
                                .map(|e| (e.value, e.sigma))
                        })
                        .collect(),
                    injected,
                    chi2: Some(r.solver.chi2),
                    dof: Some(r.solver.dof as u64),
                    rounds: Some(r.rounds.len() as u64),
                    converged: Some(r.converged),
                    error: None,
                    seconds: clock.elapsed().as_secs_f64(),
                }
            }
            Err(e) => Row {
                inputs: t.clone(),
                estimates: vec![None; m.parameters.len()],
                injected,
                chi2: None,
                dof: None,
                rounds: None,
                converged: None,
                error: Some(e.to_string()),
                seconds: clock.elapsed().as_secs_f64(),
            },
        };
        rows.push(row);
    }
    Ok(rows)
}

/// The file name of shard `i` of `k`.
pub fn shard_file_name(i: usize, k: usize) -> String {
    format!("shard-{i:05}-of-{k:05}.parquet")
}

/// The Parquet schema of a shard (see docs/studies.md): `trial`, `shard`, `scanner_seed`,
/// `noise_sigma_mm`, `in.<deviation>` per varied deviation, then per parameter
/// `<p>.value`, `<p>.sigma` (null when not determined on its own), `<p>.injected`,
/// `<p>.determined`; `chi2`, `dof`, `rounds`, `converged`, `error`, `seconds`.
pub fn schema(m: &Manifest) -> Schema {
    let mut fields = vec![
        Field::new("trial", DataType::UInt64, false),
        Field::new("shard", DataType::UInt64, false),
        Field::new("scanner_seed", DataType::UInt64, false),
        Field::new("noise_sigma_mm", DataType::Float64, false),
    ];
    for d in &m.varied {
        fields.push(Field::new(format!("in.{d}"), DataType::Float64, false));
    }
    for p in &m.parameters {
        fields.push(Field::new(format!("{p}.value"), DataType::Float64, true));
        fields.push(Field::new(format!("{p}.sigma"), DataType::Float64, true));
        fields.push(Field::new(
            format!("{p}.injected"),
            DataType::Float64,
            false,
        ));
        fields.push(Field::new(
            format!("{p}.determined"),
            DataType::Boolean,
            false,
        ));
    }
    fields.extend([
        Field::new("chi2", DataType::Float64, true),
        Field::new("dof", DataType::UInt64, true),
        Field::new("rounds", DataType::UInt64, true),
        Field::new("converged", DataType::Boolean, true),
        Field::new("error", DataType::Utf8, true),
        Field::new("seconds", DataType::Float64, false),
    ]);
    let meta = [
        ("twinmill.study".to_string(), m.id.clone()),
        ("twinmill.shards".to_string(), m.shards.to_string()),
    ];
    Schema::new(fields).with_metadata(meta.into_iter().collect())
}

/// One shard's rows as a Parquet file's bytes.
pub fn shard_parquet(m: &Manifest, rows: &[Row]) -> Result<Vec<u8>, StudyError> {
    let schema = schema(m);
    let mut meta = schema.metadata().clone();
    meta.insert(ROWS_KEY.into(), rows_fingerprint(rows));
    let schema = Arc::new(schema.with_metadata(meta));
    let f64s = |f: &dyn Fn(&Row) -> Option<Real>| -> ArrayRef {
        Arc::new(rows.iter().map(f).collect::<Float64Array>())
    };
    let u64s = |f: &dyn Fn(&Row) -> Option<u64>| -> ArrayRef {
        Arc::new(rows.iter().map(f).collect::<UInt64Array>())
    };
    let mut cols: Vec<ArrayRef> = vec![
        u64s(&|r| Some(r.inputs.trial)),
        u64s(&|r| Some(r.inputs.shard as u64)),
        u64s(&|r| Some(r.inputs.scanner_seed)),
        f64s(&|r| Some(r.inputs.noise_sigma_mm)),
    ];
    for j in 0..m.varied.len() {
        cols.push(f64s(&|r| r.inputs.deviations.get(j).map(|d| d.1)));
    }
    for k in 0..m.parameters.len() {
        cols.push(f64s(&|r| r.estimates[k].map(|e| e.0)));
        cols.push(f64s(&|r| r.estimates[k].map(|e| e.1)));
        cols.push(f64s(&|r| Some(r.injected[k])));
        cols.push(Arc::new(
            rows.iter()
                .map(|r| Some(r.estimates[k].is_some()))
                .collect::<BooleanArray>(),
        ));
    }
    cols.push(f64s(&|r| r.chi2));
    cols.push(u64s(&|r| r.dof));
    cols.push(u64s(&|r| r.rounds));
    cols.push(Arc::new(
        rows.iter().map(|r| r.converged).collect::<BooleanArray>(),
    ));
    cols.push(Arc::new(
        rows.iter()
            .map(|r| r.error.as_deref())
            .collect::<StringArray>(),
    ));
    cols.push(f64s(&|r| Some(r.seconds)));
    let shard_err = |e: String| StudyError::Shard {
        path: "(shard)".into(),
        message: e,
    };
    let batch = RecordBatch::try_new(schema.clone(), cols).map_err(|e| shard_err(e.to_string()))?;
    let mut out = Vec::new();
    let mut w = parquet::arrow::ArrowWriter::try_new(&mut out, schema, None)
        .map_err(|e| shard_err(e.to_string()))?;
    w.write(&batch).map_err(|e| shard_err(e.to_string()))?;
    w.close().map_err(|e| shard_err(e.to_string()))?;
    Ok(out)
}

/// Parquet's magic number, at both ends of a file.
const PARQUET_MAGIC: &[u8; 4] = b"PAR1";

/// Checks a Parquet file's frame before any decoding: the magic number at both ends and a
/// footer whose stated metadata length fits in the file. Returns the metadata's length.
fn check_frame(bytes: &[u8]) -> Result<usize, String> {
    let n = bytes.len();
    if n < 12 || &bytes[..4] != PARQUET_MAGIC || &bytes[n - 4..] != PARQUET_MAGIC {
        return Err(format!(
            "not a Parquet file ({n} bytes): expected one starting and ending with PAR1"
        ));
    }
    let mut len = [0u8; 4];
    len.copy_from_slice(&bytes[n - 8..n - 4]);
    let meta = u32::from_le_bytes(len) as usize;
    if meta == 0 || meta > n - 12 {
        return Err(format!(
            "damaged footer: it gives the metadata {meta} bytes, expected 1 to {} in a \
             file of {n} bytes",
            n - 12
        ));
    }
    Ok(meta)
}

/// Checks the decoded metadata against the file it came from before the reader trusts it:
/// row counts not negative and adding up, every column chunk inside the data part of the
/// file, uncompressed or Snappy (what twinmill writes), with as many columns as the schema.
fn check_metadata(
    meta: &parquet::file::metadata::ParquetMetaData,
    data_end: u64,
) -> Result<(), String> {
    use parquet::basic::Compression;
    let file = meta.file_metadata();
    let columns = file.schema_descr().num_columns();
    let mut rows: i64 = 0;
    for (g, rg) in meta.row_groups().iter().enumerate() {
        if rg.num_rows() < 0 || rg.num_columns() != columns {
            return Err(format!(
                "damaged metadata: row group {g} has {} rows in {} columns, expected \
                 0 or more rows in {columns}",
                rg.num_rows(),
                rg.num_columns()
            ));
        }
        rows = rows.saturating_add(rg.num_rows());
        for c in rg.columns() {
            // the chunk's first page (the reader's `byte_range`, which asserts instead)
            let start = c.dictionary_page_offset().unwrap_or(c.data_page_offset());
            let len = c.compressed_size();
            let inside = start >= PARQUET_MAGIC.len() as i64
                && len >= 0
                && start
                    .checked_add(len)
                    .is_some_and(|end| end as u64 <= data_end)
                && (c.data_page_offset() >= start && c.data_page_offset() < start + len);
            if !inside || c.num_values() < 0 {
                return Err(format!(
                    "damaged metadata: column {} of row group {g} lies at bytes {start}+{len}, \
                     expected within 4..{data_end}",
                    c.column_path()
                ));
            }
            if !matches!(
                c.compression(),
                Compression::UNCOMPRESSED | Compression::SNAPPY
            ) {
                return Err(format!(
                    "damaged metadata: column {} is compressed with {}, expected none or Snappy",
                    c.column_path(),
                    c.compression()
                ));
            }
        }
    }
    if file.num_rows() != rows {
        return Err(format!(
            "damaged metadata: the file has {} rows, its row groups {rows}",
            file.num_rows()
        ));
    }
    Ok(())
}

thread_local! {
    /// Set while [`contained`] runs: the panic hook stays silent on this thread.
    static SILENT: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f`; a panic inside it becomes `Err` with the panic's message, printed nowhere.
/// The Parquet and Arrow readers panic on some damaged files (`capacity overflow`, an
/// `unwrap` on `None`, an unsupported bit width) instead of returning an error.
fn contained<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !SILENT.with(std::cell::Cell::get) {
                previous(info);
            }
        }));
    });
    let was = SILENT.with(|s| s.replace(true));
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    SILENT.with(|s| s.set(was));
    r.map_err(|p| {
        one_line(
            &p.downcast_ref::<&str>()
                .map(|s| (*s).to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "a panic".into()),
        )
    })
}

/// A library's message on one line, at most 160 characters.
fn one_line(text: &str) -> String {
    let flat: String = text.split_whitespace().collect::<Vec<_>>().join(" ");
    if flat.chars().count() > 160 {
        format!("{}…", flat.chars().take(160).collect::<String>())
    } else {
        flat
    }
}

/// Reads a shard file back into rows, checking that it belongs to `m`. A damaged file is
/// one error naming it, whatever the damage: the frame and the metadata are checked before
/// the rows are decoded, and a panic of the Parquet reader is caught.
pub fn read_shard(m: &Manifest, path: &Path) -> Result<Vec<Row>, StudyError> {
    let err = |message: String| StudyError::Shard {
        path: path.display().to_string(),
        message,
    };
    let rerun = |what: String| {
        err(format!(
            "{what}; run the shard again (`twinmill study run MANIFEST --shard I`)"
        ))
    };
    let bytes = std::fs::read(path).map_err(|e| err(format!("cannot read: {e}")))?;
    let meta_len = check_frame(&bytes).map_err(rerun)?;
    let data_end = (bytes.len() - 8 - meta_len) as u64;
    let file = std::fs::File::open(path).map_err(|e| err(format!("cannot open: {e}")))?;
    let builder =
        contained(|| parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file))
            .map_err(|p| rerun(format!("damaged Parquet metadata (the reader failed: {p})")))?
            .map_err(|e| {
                rerun(format!(
                    "damaged Parquet metadata ({})",
                    one_line(&e.to_string())
                ))
            })?;
    check_metadata(builder.metadata(), data_end).map_err(rerun)?;
    let want = builder.schema().metadata().get(ROWS_KEY).cloned();
    let rows = match contained(|| decode_shard(m, builder, &err)) {
        Ok(r) => r?,
        Err(p) => {
            return Err(rerun(format!(
                "damaged Parquet data (the reader failed: {p})"
            )));
        }
    };
    let got = rows_fingerprint(&rows);
    match want {
        Some(w) if w == got => Ok(rows),
        Some(w) => Err(rerun(format!(
            "damaged: its rows read back with fingerprint {got}, the shard was written with {w}"
        ))),
        None => Err(rerun(format!(
            "holds no {ROWS_KEY} fingerprint of its rows"
        ))),
    }
}

/// The rows of a shard whose frame and metadata were checked ([`read_shard`]).
fn decode_shard(
    m: &Manifest,
    builder: parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder<std::fs::File>,
    err: &dyn Fn(String) -> StudyError,
) -> Result<Vec<Row>, StudyError> {
    let meta = builder.schema().metadata().get("twinmill.study").cloned();
    if meta.as_deref() != Some(m.id.as_str()) {
        return Err(err(format!(
            "belongs to study {} , not to this manifest's {}",
            meta.unwrap_or_else(|| "(none)".into()),
            m.id
        )));
    }
    let want = schema(m);
    if builder.schema().fields() != want.fields() {
        return Err(err("its columns are not this study's".into()));
    }
    let reader = builder.build().map_err(|e| {
        err(format!(
            "damaged Parquet data ({})",
            one_line(&e.to_string())
        ))
    })?;
    let mut rows = Vec::new();
    for batch in reader {
        let b = batch.map_err(|e| {
            err(format!(
                "damaged Parquet data ({})",
                one_line(&e.to_string())
            ))
        })?;
        let col = |name: &str| b.column_by_name(name).cloned();
        let f = |name: &str| -> Result<Float64Array, StudyError> {
            col(name)
                .and_then(|c| c.as_any().downcast_ref::<Float64Array>().cloned())
                .ok_or_else(|| err(format!("column {name} missing")))
        };
        let u = |name: &str| -> Result<UInt64Array, StudyError> {
            col(name)
                .and_then(|c| c.as_any().downcast_ref::<UInt64Array>().cloned())
                .ok_or_else(|| err(format!("column {name} missing")))
        };
        let bo = |name: &str| -> Result<BooleanArray, StudyError> {
            col(name)
                .and_then(|c| c.as_any().downcast_ref::<BooleanArray>().cloned())
                .ok_or_else(|| err(format!("column {name} missing")))
        };
        let opt_f = |a: &Float64Array, i: usize| a.is_valid(i).then(|| a.value(i));
        let opt_u = |a: &UInt64Array, i: usize| a.is_valid(i).then(|| a.value(i));
        let (trial, shard, seed, noise) = (
            u("trial")?,
            u("shard")?,
            u("scanner_seed")?,
            f("noise_sigma_mm")?,
        );
        let varied: Vec<Float64Array> = m
            .varied
            .iter()
            .map(|d| f(&format!("in.{d}")))
            .collect::<Result<_, _>>()?;
        let mut per = Vec::new();
        for p in &m.parameters {
            per.push((
                f(&format!("{p}.value"))?,
                f(&format!("{p}.sigma"))?,
                f(&format!("{p}.injected"))?,
            ));
        }
        let (chi2, dof, rounds, conv, secs) = (
            f("chi2")?,
            u("dof")?,
            u("rounds")?,
            bo("converged")?,
            f("seconds")?,
        );
        let error = col("error")
            .and_then(|c| c.as_any().downcast_ref::<StringArray>().cloned())
            .ok_or_else(|| err("column error missing".into()))?;
        for i in 0..b.num_rows() {
            rows.push(Row {
                inputs: TrialInputs {
                    trial: trial.value(i),
                    shard: shard.value(i) as usize,
                    scanner_seed: seed.value(i),
                    noise_sigma_mm: noise.value(i),
                    deviations: m
                        .varied
                        .iter()
                        .zip(&varied)
                        .map(|(d, a)| (d.clone(), a.value(i)))
                        .collect(),
                },
                estimates: per
                    .iter()
                    .map(|(v, s, _)| opt_f(v, i).zip(opt_f(s, i)))
                    .collect(),
                injected: per.iter().map(|(_, _, t)| t.value(i)).collect(),
                chi2: opt_f(&chi2, i),
                dof: opt_u(&dof, i),
                rounds: opt_u(&rounds, i),
                converged: conv.is_valid(i).then(|| conv.value(i)),
                error: error.is_valid(i).then(|| error.value(i).to_string()),
                seconds: secs.value(i),
            });
        }
    }
    Ok(rows)
}

/// The summary of one parameter over the trials.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParameterSummary {
    /// Parameter name.
    pub name: String,
    /// Trials that determined it on its own.
    pub determined: usize,
    /// Their fraction of all trials.
    pub determined_fraction: Real,
    /// Mean of (identified − injected) over those trials.
    pub bias: Real,
    /// Sample standard deviation of (identified − injected).
    pub spread: Real,
    /// Fraction of those trials with |identified − injected| ≤ 3σ.
    pub coverage_3sigma: Real,
    /// Mean reported σ.
    pub mean_sigma: Real,
}

/// The merged study.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// The manifest's id.
    pub study: String,
    /// Trials.
    pub trials: usize,
    /// Shards merged.
    pub shards: usize,
    /// Trials whose identification failed (with why, first few).
    pub failed: usize,
    /// The first failures' messages.
    pub failures: Vec<String>,
    /// Per parameter.
    pub parameters: Vec<ParameterSummary>,
    /// Seconds of trial work summed over all shards.
    pub trial_seconds: Real,
}

/// Summarises `rows` (every trial of `m`, in trial order).
pub fn summarize(m: &Manifest, rows: &[Row]) -> Summary {
    let n = rows.len();
    let parameters = m
        .parameters
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let errs: Vec<(Real, Real)> = rows
                .iter()
                .filter_map(|r| r.estimates[k].map(|(v, s)| (v - r.injected[k], s)))
                .collect();
            let d = errs.len();
            let mean = |f: &dyn Fn(&(Real, Real)) -> Real| {
                if d == 0 {
                    Real::NAN
                } else {
                    errs.iter().map(f).sum::<Real>() / d as Real
                }
            };
            let bias = mean(&|e| e.0);
            let spread = if d > 1 {
                (errs.iter().map(|e| (e.0 - bias).powi(2)).sum::<Real>() / (d - 1) as Real).sqrt()
            } else {
                Real::NAN
            };
            ParameterSummary {
                name: name.clone(),
                determined: d,
                determined_fraction: d as Real / n.max(1) as Real,
                bias,
                spread,
                coverage_3sigma: mean(&|e| Real::from(u8::from(e.0.abs() <= 3.0 * e.1))),
                mean_sigma: mean(&|e| e.1),
            }
        })
        .collect();
    let failures: Vec<String> = rows
        .iter()
        .filter_map(|r| {
            r.error
                .as_ref()
                .map(|e| format!("trial {}: {e}", r.inputs.trial))
        })
        .collect();
    Summary {
        study: m.id.clone(),
        trials: n,
        shards: m.shards,
        failed: failures.len(),
        failures: failures.into_iter().take(10).collect(),
        parameters,
        trial_seconds: rows.iter().map(|r| r.seconds).sum(),
    }
}

/// Reads every shard's file from `dir`, checks them against the manifest and summarises
/// (see the module documentation). Returns the rows in trial order too.
pub fn merge(m: &Manifest, dir: &Path) -> Result<(Summary, Vec<Row>), StudyError> {
    let mut rows = Vec::with_capacity(m.trials.len());
    for i in 0..m.shards {
        let path = dir.join(shard_file_name(i, m.shards));
        if !path.exists() {
            return Err(StudyError::Shard {
                path: path.display().to_string(),
                message: format!(
                    "shard {i} is missing: run `twinmill study run MANIFEST --shard {i}`"
                ),
            });
        }
        let got = read_shard(m, &path)?;
        let want: Vec<u64> = m
            .trials
            .iter()
            .filter(|t| t.shard == i)
            .map(|t| t.trial)
            .collect();
        let have: Vec<u64> = got.iter().map(|r| r.inputs.trial).collect();
        if have != want {
            return Err(StudyError::Shard {
                path: path.display().to_string(),
                message: format!(
                    "holds trials {:?}…, not shard {i}'s {} trials",
                    &have[..have.len().min(5)],
                    want.len()
                ),
            });
        }
        for (r, t) in got.iter().zip(m.trials.iter().filter(|t| t.shard == i)) {
            if r.inputs != *t {
                return Err(StudyError::Shard {
                    path: path.display().to_string(),
                    message: format!("trial {}: its inputs are not the manifest's", t.trial),
                });
            }
        }
        rows.extend(got);
    }
    Ok((summarize(m, &rows), rows))
}
