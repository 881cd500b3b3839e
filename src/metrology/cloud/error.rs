//! Why a cloud file could not be read or written ([`CloudError`]): I/O, a malformed file
//! (the message names the format and, for text, the line), a non-finite point, an invalid
//! cloud, an unsupported extension.

use super::point_cloud::InvalidCloud;
use std::path::PathBuf;

#[cfg(doc)]
use super::point_cloud::PointCloud;

/// Why a cloud file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum CloudError {
    /// The file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// The file is not one this reader understands: header problems, truncated data,
    /// counts that do not match the data, unsupported layout. The message names the
    /// format and, for text, the 1-based line.
    #[error("{}: {message}", path.display())]
    Malformed {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A PLY header line or ASCII value that is not what it should be, at its 1-based line
    /// and column: `file:line:col: what is wrong, what is expected`.
    #[error("{}:{line}:{column}: {message}", path.display())]
    At {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What is wrong, and what is expected.
        message: String,
    },
    /// A point has a NaN or infinite coordinate or normal.
    #[error("{}: {}point {index} has a non-finite {what}", path.display(), at_line(*line))]
    NonFinite {
        /// The file concerned.
        path: PathBuf,
        /// Zero-based index of the first offending point (vertex).
        index: usize,
        /// `"coordinate"` or `"normal"`.
        what: &'static str,
        /// Its 1-based line in a text file.
        line: Option<usize>,
    },
    /// The cloud cannot be written (see [`PointCloud::validate`]); nothing was written.
    #[error("{}: cloud not written: {source}", path.display())]
    Invalid {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong with the cloud.
        source: InvalidCloud,
    },
    /// The file extension does not name a supported format.
    #[error("{}: unsupported file extension (supported: {supported})", path.display())]
    UnsupportedExtension {
        /// The file concerned.
        path: PathBuf,
        /// The extensions that are supported for this operation.
        supported: &'static str,
    },
}

fn at_line(line: Option<usize>) -> String {
    line.map(|l| format!("line {l}: ")).unwrap_or_default()
}
