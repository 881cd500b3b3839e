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
//! untouched and removes the staging folder. An output path that is a symbolic link is
//! written through to its target; one that is a FIFO, a device or a socket (or a file where
//! a folder goes, and the reverse) is refused, never replaced; messages name the path the
//! user gave, never a temporary one.
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

/// An error about `path` (the path the user gave) in our words.
fn refuse(path: &Path, message: String) -> OutputError {
    OutputError {
        path: path.to_path_buf(),
        source: std::io::Error::other(message),
    }
}

/// The folder `path` is in (`.` for a bare name).
fn parent_of(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// What a path that exists but is no regular file or folder is, in words.
fn kind_of(meta: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_char_device() || t.is_block_device() {
            return "a device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if meta.is_dir() {
        "a folder"
    } else if meta.is_file() {
        "a file"
    } else {
        "not a regular file"
    }
}

/// Where an output the user named as `path` is written: `path` itself, or the end of the
/// chain of symbolic links it starts (written through, as a shell's `>` does). `folder`
/// says whether a folder is wanted there (else a regular file). Anything else already there
/// — a FIFO, a device, a socket, a file where a folder is wanted and the reverse — is
/// refused: renaming over it would replace it. Errors name `path`.
fn target_of(path: &Path, folder: bool) -> Result<PathBuf, OutputError> {
    let mut at = path.to_path_buf();
    for _ in 0..40 {
        let meta = match std::fs::symlink_metadata(&at) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(at),
            Err(e) => return io(path, Err(e)),
        };
        if meta.file_type().is_symlink() {
            let link = io(path, std::fs::read_link(&at))?;
            at = parent_of(&at).join(link);
            continue;
        }
        let fits = if folder {
            meta.is_dir()
        } else {
            meta.is_file()
        };
        if fits {
            return Ok(at);
        }
        let leads = if at == path {
            String::new()
        } else {
            format!("it leads to {}, ", at.display())
        };
        let want = if folder { "a folder" } else { "a regular file" };
        return Err(refuse(
            path,
            format!(
                "{leads}{} that twinmill will not replace, expected {want} or nothing there",
                kind_of(&meta)
            ),
        ));
    }
    Err(refuse(
        path,
        "more than 40 symbolic links in a row, expected a file at the end".into(),
    ))
}

/// Checks that the folder a file is written into exists (errors name `path`, the file).
fn folder_exists(path: &Path, target: &Path) -> Result<(), OutputError> {
    let dir = parent_of(target);
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => Ok(()),
        Ok(_) => Err(refuse(
            path,
            format!(
                "{} is not a folder, expected an existing folder",
                dir.display()
            ),
        )),
        Err(_) => Err(refuse(
            path,
            format!(
                "the folder {} does not exist, expected an existing folder",
                dir.display()
            ),
        )),
    }
}

/// Writes named files into `dir`, created or replaced as a whole: all of them or none. A
/// symbolic link `dir` is written through (its target folder is replaced); a file or
/// anything else that is not a folder at `dir` is refused. Errors name `dir` or its files.
pub fn write_files(dir: &Path, files: &[(&str, Vec<u8>)]) -> Result<PathBuf, OutputError> {
    write_files_streamed(
        dir,
        files
            .iter()
            .map(|(name, bytes)| borrowed(name, bytes))
            .collect(),
    )
}

/// [`write_files`] with each file's bytes written piece by piece by its function into the
/// (buffered) file, so that no file need be held whole in memory.
pub fn write_files_streamed(
    dir: &Path,
    files: Vec<StreamedFile<'_>>,
) -> Result<PathBuf, OutputError> {
    let target = target_of(dir, true)?;
    let parent = parent_of(&target);
    io(dir, std::fs::create_dir_all(parent))?;
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let staging = parent.join(format!(".{name}.partial-{}", std::process::id()));
    let result = (|| {
        if staging.exists() {
            io(dir, std::fs::remove_dir_all(&staging))?;
        }
        io(dir, std::fs::create_dir(&staging))?;
        for (file, write) in files {
            stream_to(&staging.join(&file), &dir.join(&file), write)?;
        }
        if target.exists() {
            io(dir, std::fs::remove_dir_all(&target))?;
        }
        io(dir, std::fs::rename(&staging, &target))?;
        Ok(dir.to_path_buf())
    })();
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&staging);
    }
    result
}

/// Writes one file whole or not at all: into a temporary sibling first, then renamed over
/// `path` — over the end of its chain of symbolic links when `path` is one. A folder that
/// does not exist, and a FIFO, device, socket or folder at `path`, are refused. Errors name
/// `path`, never the temporary file.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    let target = target_of(path, false)?;
    folder_exists(path, &target)?;
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let staging = parent_of(&target).join(format!(".{name}.partial-{}", std::process::id()));
    let result = io(
        path,
        std::fs::File::create(&staging)
            .and_then(|mut f| f.write_all(bytes).and_then(|_| f.sync_all())),
    )
    .and_then(|()| io(path, std::fs::rename(&staging, &target)));
    if result.is_err() {
        let _ = std::fs::remove_file(&staging);
    }
    result
}

/// Writes several files whole or none at all: each into a temporary sibling of its path
/// first (as [`write_file`]); only when every one is complete are they renamed into place.
/// A failure removes the temporary files and leaves any previous files of those names
/// untouched. Two of the paths naming the same file are refused before anything is written.
/// Errors name the path, never a temporary file.
pub fn write_paths(files: &[(&Path, &[u8])]) -> Result<(), OutputError> {
    let mut targets: Vec<PathBuf> = Vec::with_capacity(files.len());
    let mut seen: Vec<PathBuf> = Vec::with_capacity(files.len());
    for (path, _) in files {
        let target = target_of(path, false)?;
        folder_exists(path, &target)?;
        // The same file however the paths spell its folder (`a.toml`, `./a.toml`).
        let dir = parent_of(&target);
        let key = std::fs::canonicalize(dir)
            .unwrap_or_else(|_| dir.to_path_buf())
            .join(target.file_name().unwrap_or_default());
        if seen.contains(&key) {
            return Err(OutputError {
                path: path.to_path_buf(),
                source: std::io::Error::other("named twice among the files to write"),
            });
        }
        seen.push(key);
        targets.push(target);
    }
    let mut staged: Vec<PathBuf> = Vec::with_capacity(files.len());
    let result = (|| {
        for ((path, bytes), target) in files.iter().zip(&targets) {
            let name = target
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| "out".into());
            let staging = parent_of(target).join(format!(".{name}.partial-{}", std::process::id()));
            staged.push(staging.clone());
            io(
                path,
                std::fs::File::create(&staging)
                    .and_then(|mut f| f.write_all(bytes).and_then(|_| f.sync_all())),
            )?;
        }
        for (((path, _), target), staging) in files.iter().zip(&targets).zip(&staged) {
            io(path, std::fs::rename(staging, target))?;
        }
        Ok(())
    })();
    if result.is_err() {
        for staging in &staged {
            let _ = std::fs::remove_file(staging);
        }
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
/// The page and pictures are written from the simulation and the meshes streamed into their
/// files: nothing is copied whole (the side cut's part.stl alone is 33 MB).
pub fn write_simulation(
    sim: &Simulation,
    formats: &[MeshFormat],
    dir: &Path,
) -> Result<PathBuf, OutputError> {
    let json = json_bytes(&sim.report, &dir.join("report.json"))?;
    let mut files: Vec<StreamedFile<'_>> = vec![
        (
            "report.json".to_string(),
            Box::new(move |w: &mut dyn Write| w.write_all(&json)),
        ),
        borrowed("part.png", &sim.part_png),
        borrowed("report.html", sim.html.as_bytes()),
    ];
    if let Some(png) = &sim.deviation_png {
        files.push(borrowed("deviation.png", png));
    }
    for &f in formats {
        let mesh = &sim.mesh;
        files.push((
            f.file_name().to_string(),
            Box::new(move |w: &mut dyn Write| {
                match f {
                    MeshFormat::Stl => mesh.write_stl(w),
                    MeshFormat::Obj => mesh.write_obj(w),
                    MeshFormat::Ply => mesh.write_ply(w),
                }
                .map_err(|e| match e {
                    MeshError::Io(e) => e,
                    other => std::io::Error::other(other),
                })
            }),
        ));
    }
    write_files_streamed(dir, files)
}

/// Creates `file` and writes it through a buffer with `write`, synced to disk; errors name
/// `named` (where the file goes), never the staging file.
fn stream_to(
    file: &Path,
    named: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<(), OutputError> {
    let f = io(named, std::fs::File::create(file))?;
    let mut buf = std::io::BufWriter::new(f);
    io(named, write(&mut buf))?;
    let f = io(named, buf.into_inner().map_err(|e| e.into_error()))?;
    io(named, f.sync_all())
}

/// A file of [`write_files_streamed`] whose bytes are already in memory.
fn borrowed<'a>(name: &str, bytes: &'a [u8]) -> StreamedFile<'a> {
    (name.to_string(), Box::new(move |w| w.write_all(bytes)))
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
    // (staging file, where it goes, the path named in messages and returned)
    let mut staged: Vec<(PathBuf, PathBuf, PathBuf)> = Vec::new();
    let result = (|| {
        for (name, write) in files {
            let path = dir.join(&name);
            let target = target_of(&path, false)?;
            folder_exists(&path, &target)?;
            let staging = parent_of(&target).join(format!(
                ".{}.partial-{}",
                target
                    .file_name()
                    .map_or(name.clone(), |n| n.to_string_lossy().into_owned()),
                std::process::id()
            ));
            staged.push((staging.clone(), target, path.clone()));
            stream_to(&staging, &path, write)?;
        }
        let mut done = Vec::new();
        for (staging, target, path) in &staged {
            io(path, std::fs::rename(staging, target))?;
            done.push(path.clone());
        }
        Ok(done)
    })();
    if result.is_err() {
        for (staging, _, _) in &staged {
            let _ = std::fs::remove_file(staging);
        }
    }
    result
}
