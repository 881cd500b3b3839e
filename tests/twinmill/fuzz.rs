//! The fuzz targets of `fuzz/` on stable Rust, for a fixed budget: each target's check
//! (`fuzz/checks.rs`, the function its cargo-fuzz target runs) on its seeds — the
//! repository's own files and files the binary writes from them — and on a fixed number of
//! inputs mutated from them by a seeded generator (bit flips, bytes and tokens put in, ranges
//! cut, doubled and spliced, numbers replaced by extreme ones). The same inputs on every run;
//! a panic fails the test, naming the target and showing the input. `.ci/fuzz` runs the
//! same checks coverage-guided under libFuzzer.

#[path = "../../fuzz/checks.rs"]
mod checks;

use crate::Sandbox;
use std::path::{Path, PathBuf};

/// splitmix64: a small seeded generator, the same sequence everywhere.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n` > 0).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// Bytes that change the meaning of text formats (TOML, CSV, PLY headers, G-code).
const BYTES: &[u8] = b"\0\xff\n\r \t\"'[]{}=,.-+e#;()%/0123456789NnXxGgOo";

/// Tokens put in anywhere, and numbers put in place of numbers.
const TOKENS: &[&str] = &[
    "1e308",
    "-1e308",
    "0",
    "-0",
    "nan",
    "inf",
    "-inf",
    "1e-320",
    "18446744073709551616",
    "-1",
    "4294967296",
    "1e9",
    "1e-9",
    "2147483647",
    "[]",
    "{}",
    "\"\"",
    "[[",
    "]]",
    " = ",
    "\n[machine]\n",
    "\n[tool]\n",
    "true",
    "\"x\"",
    "element vertex 4294967295\n",
    "property list uchar int x\n",
    "binary_big_endian",
    "end_header\n",
    "o100 while [1]\n",
    "o100 endwhile\n",
    "M98 P1 L99999\n",
    "G2 X1 I0\n",
    "#<_a>=",
    "[1/0]",
    "G91 G1 X1e30\n",
];

/// One input mutated from `seeds`: one to four edits of a seed (a splice takes another).
fn mutate(rng: &mut Rng, seeds: &[Vec<u8>]) -> Vec<u8> {
    let mut d = rng.pick(seeds).clone();
    for _ in 0..1 + rng.below(4) {
        let n = d.len();
        let at = if n == 0 { 0 } else { rng.below(n + 1) };
        match rng.below(8) {
            0 if n > 0 => {
                let i = rng.below(n);
                d[i] ^= 1 << rng.below(8);
            }
            1 if n > 0 => {
                let i = rng.below(n);
                d[i] = *rng.pick(BYTES);
            }
            2 => {
                let len = 1 + rng.below(16);
                d.drain(at..(at + len).min(n));
            }
            3 if n > 0 => {
                let from = rng.below(n);
                let len = (1 + rng.below(64)).min(n - from);
                let copy = d[from..from + len].to_vec();
                d.splice(at..at, copy);
            }
            4 => {
                let t = rng.pick(TOKENS).as_bytes().to_vec();
                d.splice(at..at, t);
            }
            5 => {
                // the number (or word) at or after `at`, replaced
                let start = (at..n).find(|&i| d[i].is_ascii_digit()).unwrap_or(n);
                let end = (start..n)
                    .find(|&i| !(d[i].is_ascii_alphanumeric() || b".-+".contains(&d[i])))
                    .unwrap_or(n);
                let t = rng.pick(&TOKENS[..14]).as_bytes().to_vec();
                d.splice(start..end, t);
            }
            6 => {
                let other = rng.pick(seeds);
                let from = rng.below(other.len() + 1);
                d.truncate(at);
                d.extend_from_slice(&other[from..]);
            }
            _ => d.truncate(at),
        }
    }
    d.truncate(1 << 16);
    d
}

/// Runs `check` on every seed and on `runs` mutated inputs; panics naming the first input
/// that made it panic (its bytes escaped, at most 4,000 of them) and how many did.
fn drive(target: &str, seeds: &[Vec<u8>], runs: usize, check: &dyn Fn(&[u8])) {
    assert!(!seeds.is_empty(), "{target}: no seeds");
    let mut rng = Rng(target.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
    }));
    let mut failed: Vec<(usize, Vec<u8>)> = Vec::new();
    let inputs = seeds
        .iter()
        .cloned()
        .map(Some)
        .chain((0..runs).map(|_| None));
    for (k, seed) in inputs.enumerate() {
        let data = seed.unwrap_or_else(|| mutate(&mut rng, seeds));
        if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| check(&data))).is_err() {
            failed.push((k, data));
        }
    }
    if let Some((k, data)) = failed.first() {
        let shown: String = data.escape_ascii().to_string().chars().take(4000).collect();
        panic!(
            "{target}: {} of {} inputs panicked; the first, input {k} ({} bytes):\n{shown}",
            failed.len(),
            seeds.len() + runs,
            data.len()
        );
    }
}

fn top() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The files under `dir` (recursively) whose names end with `suffix`, sorted.
fn files(dir: &Path, suffix: &str) -> Vec<Vec<u8>> {
    let mut paths = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d)
            .expect("a repository folder")
            .flatten()
        {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.to_string_lossy().ends_with(suffix) {
                paths.push(p);
            }
        }
    }
    paths.sort();
    paths
        .iter()
        .map(|p| std::fs::read(p).expect("readable"))
        .collect()
}

#[test]
fn fuzz_nc_interp() {
    let seeds = files(&top().join("tests/corpus/rs274-samples"), ".ngc");
    drive("nc_interp", &seeds, 10_000, &checks::nc_interp);
}

#[test]
fn fuzz_scene() {
    let seeds = files(&top().join("scenes"), ".toml");
    drive("scene", &seeds, 10_000, &checks::scene);
}

#[test]
fn fuzz_cloud() {
    let seeds = files(&top().join("tests/data"), ".ply");
    drive("cloud", &seeds, 10_000, &checks::cloud);
}

/// Seeds: the measured ISO 230-2 readings, and a ball-bar trace and a calibration plan the
/// binary writes for the built-in hexapod.
#[test]
fn fuzz_readings() {
    let sb = Sandbox::new("fuzz-readings");
    let scene = top().join("scenes/hexapod-machining-centre.toml");
    let scene = scene.to_string_lossy();
    for args in [
        &[
            "ballbar",
            &scene,
            "--points",
            "36",
            "--direction",
            "ccw",
            "--out",
            "trace.csv",
        ][..],
        &["calibrate-design", &scene, "--out", "plan.toml"][..],
    ] {
        let (code, _, stderr) = sb.run(args);
        assert_eq!(code, 0, "{stderr}");
    }
    let mut seeds = files(&top().join("tests/data"), ".csv");
    for f in ["trace.csv", "plan.toml"] {
        seeds.push(std::fs::read(sb.dir.join(f)).expect("written"));
    }
    drive("readings", &seeds, 10_000, &checks::readings);
}

/// Seeds: the repository's study files, the manifest of one of them and a shard of it.
#[test]
fn fuzz_study() {
    let setup = checks::StudySetup::new(&top());
    let m = setup.manifest();
    let mut seeds = files(&top().join("studies"), ".toml");
    seeds.push(serde_json::to_vec_pretty(m).expect("the manifest as JSON"));
    let rows = crate::robustness::rows_for(m);
    seeds.push(twinmill::study::shard_parquet(m, &rows).expect("a shard"));
    drive("study", &seeds, 2_000, &|d| checks::study(&setup, d));
}
