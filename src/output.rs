//! Writing outputs into a folder, all or nothing: `run` writes `report.json`, `cloud.ply`,
//! `faces.png` and `report.html` into `<out>/<scene-name>/`; `simulate` writes
//! `report.json`, `part.png`, `report.html`, `deviation.png` (with a design model) and the
//! part's mesh into `<out>/<scene-name>-simulate/`; `scan` writes `cloud.ply`, `scan.json`
//! and `report.html` into `<out>/<scene-name>-scan/`; `correct` writes
//! `<scene-name>-corrected.ngc`, `<scene-name>-correct.json` and `<scene-name>-correct.html`
//! into `<out>/` ([`write_streamed`], file by file).
//!
//! Files are written into a fresh staging folder beside the target, which replaces the
//! target only when every file is complete; a failure leaves the previous outputs (if any)
//! untouched and removes the staging folder.
//!
//! **Invariant:** with [`crate::scene`], the only module that touches files.

use crate::cutting::mesh::MeshError;
use crate::metrology::cloud::{PointCloud, write_ply};
use crate::pipeline::{Outcome, Simulation};
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

/// Writes named files into `dir`, created or replaced as a whole: all of them or none.
pub fn write_files(dir: &Path, files: &[(&str, Vec<u8>)]) -> Result<PathBuf, OutputError> {
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
        for (file, bytes) in files {
            let p = staging.join(file);
            io(
                &p,
                std::fs::File::create(&p)
                    .and_then(|mut f| f.write_all(bytes).and_then(|_| f.sync_all())),
            )?;
        }
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

/// Writes one file whole or not at all: into a temporary sibling first, then renamed over
/// `path`.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    let parent = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let staging = parent.join(format!(".{name}.partial-{}", std::process::id()));
    let result = io(
        &staging,
        std::fs::File::create(&staging)
            .and_then(|mut f| f.write_all(bytes).and_then(|_| f.sync_all())),
    )
    .and_then(|()| io(path, std::fs::rename(&staging, path)));
    if result.is_err() {
        let _ = std::fs::remove_file(&staging);
    }
    result
}

/// Serialises `value` as pretty JSON.
pub fn json_bytes(value: &impl serde::Serialize, path: &Path) -> Result<Vec<u8>, OutputError> {
    serde_json::to_vec_pretty(value).map_err(|e| OutputError {
        path: path.to_path_buf(),
        source: std::io::Error::other(e),
    })
}

/// Encodes a cloud as binary PLY.
pub fn ply_bytes(cloud: &PointCloud, path: &Path) -> Result<Vec<u8>, OutputError> {
    let mut buf = Vec::new();
    io(path, write_ply(cloud, &mut buf))?;
    Ok(buf)
}

/// Writes the outcome of `run` into `dir`: report.json, cloud.ply, faces.png, report.html.
pub fn write_outcome(outcome: &Outcome, html: &str, dir: &Path) -> Result<PathBuf, OutputError> {
    let files = [
        (
            "report.json",
            json_bytes(&outcome.report, &dir.join("report.json"))?,
        ),
        (
            "cloud.ply",
            ply_bytes(&outcome.cloud, &dir.join("cloud.ply"))?,
        ),
        ("faces.png", outcome.heat_map_png.clone()),
        ("report.html", html.as_bytes().to_vec()),
    ];
    write_files(dir, &files)
}

/// A surface-mesh file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    /// Binary STL (`part.stl`).
    Stl,
    /// Wavefront OBJ (`part.obj`).
    Obj,
    /// Binary PLY (`part.ply`).
    Ply,
}

impl MeshFormat {
    /// The file name the format is written to.
    pub fn file_name(self) -> &'static str {
        match self {
            MeshFormat::Stl => "part.stl",
            MeshFormat::Obj => "part.obj",
            MeshFormat::Ply => "part.ply",
        }
    }
}

/// Writes the outcome of `simulate` into `dir`: report.json, part.png, report.html,
/// deviation.png (when the scene has a design model) and the mesh in each of `formats`.
pub fn write_simulation(
    sim: &Simulation,
    formats: &[MeshFormat],
    dir: &Path,
) -> Result<PathBuf, OutputError> {
    let mut files = vec![
        (
            "report.json",
            json_bytes(&sim.report, &dir.join("report.json"))?,
        ),
        ("part.png", sim.part_png.clone()),
        ("report.html", sim.html.clone().into_bytes()),
    ];
    if let Some(png) = &sim.deviation_png {
        files.push(("deviation.png", png.clone()));
    }
    for &f in formats {
        let path = dir.join(f.file_name());
        let mut buf = Vec::new();
        let r = match f {
            MeshFormat::Stl => sim.mesh.write_stl(&mut buf),
            MeshFormat::Obj => sim.mesh.write_obj(&mut buf),
            MeshFormat::Ply => sim.mesh.write_ply(&mut buf),
        };
        r.map_err(|e| OutputError {
            path: path.clone(),
            source: match e {
                MeshError::Io(e) => e,
                other => std::io::Error::other(other),
            },
        })?;
        files.push((f.file_name(), buf));
    }
    write_files(dir, &files)
}

/// A file to write with [`write_streamed`]: its name and the function that writes its
/// bytes, piece by piece, into the writer it is given.
pub type StreamedFile<'a> = (
    String,
    Box<dyn FnOnce(&mut dyn Write) -> std::io::Result<()> + 'a>,
);

/// Writes files into `dir` (created if needed) beside whatever else is there, each streamed
/// through a buffer into a hidden staging file first; only when every file is complete are
/// they renamed into place. A failure removes the staging files and leaves any previous
/// files of those names untouched.
pub fn write_streamed(
    dir: &Path,
    files: Vec<StreamedFile<'_>>,
) -> Result<Vec<PathBuf>, OutputError> {
    io(dir, std::fs::create_dir_all(dir))?;
    let mut staged: Vec<(PathBuf, PathBuf)> = Vec::new();
    let result = (|| {
        for (name, write) in files {
            let target = dir.join(&name);
            let staging = dir.join(format!(".{name}.partial-{}", std::process::id()));
            staged.push((staging.clone(), target));
            let file = io(&staging, std::fs::File::create(&staging))?;
            let mut buf = std::io::BufWriter::new(file);
            io(&staging, write(&mut buf))?;
            let file = io(&staging, buf.into_inner().map_err(|e| e.into_error()))?;
            io(&staging, file.sync_all())?;
        }
        let mut done = Vec::new();
        for (staging, target) in &staged {
            io(target, std::fs::rename(staging, target))?;
            done.push(target.clone());
        }
        Ok(done)
    })();
    if result.is_err() {
        for (staging, _) in &staged {
            let _ = std::fs::remove_file(staging);
        }
    }
    result
}
