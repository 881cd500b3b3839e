//! Writing a run's outputs: `report.json`, `cloud.ply` and `faces.png` into
//! `<out>/<scene-name>/`, all or nothing.
//!
//! Files are written into a fresh staging folder beside the target, which replaces the
//! target only when every file is complete; a failure leaves the previous outputs (if any)
//! untouched and removes the staging folder.
//!
//! **Invariant:** with [`crate::scene`], the only module that touches files.

use crate::cloud::write_ply;
use crate::pipeline::Outcome;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A failure to write outputs.
#[derive(Debug, thiserror::Error)]
#[error("{path}: cannot write: {source}")]
pub struct OutputError {
    /// The file or folder.
    pub path: PathBuf,
    /// Why.
    pub source: std::io::Error,
}

fn io<T>(path: &Path, r: std::io::Result<T>) -> Result<T, OutputError> {
    r.map_err(|source| OutputError {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes the outcome into `dir` (created or replaced as a whole). Returns `dir`.
pub fn write_outcome(outcome: &Outcome, dir: &Path) -> Result<PathBuf, OutputError> {
    let parent = dir
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    io(parent, std::fs::create_dir_all(parent))?;
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let staging = parent.join(format!(".{name}.partial-{}", std::process::id()));
    let result = (|| {
        if staging.exists() {
            io(&staging, std::fs::remove_dir_all(&staging))?;
        }
        io(&staging, std::fs::create_dir(&staging))?;
        let json = serde_json::to_vec_pretty(&outcome.report).map_err(std::io::Error::other);
        let p = staging.join("report.json");
        io(&p, json.and_then(|j| std::fs::write(&p, j)))?;
        let p = staging.join("cloud.ply");
        let mut buf = Vec::new();
        io(&p, write_ply(&outcome.cloud, &mut buf))?;
        io(
            &p,
            std::fs::File::create(&p)
                .and_then(|mut f| f.write_all(&buf).and_then(|_| f.sync_all())),
        )?;
        let p = staging.join("faces.png");
        io(&p, std::fs::write(&p, &outcome.heat_map_png))?;
        if dir.exists() {
            io(dir, std::fs::remove_dir_all(dir))?;
        }
        io(dir, std::fs::rename(&staging, dir))?;
        Ok(dir.to_path_buf())
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&staging);
    }
    result
}
