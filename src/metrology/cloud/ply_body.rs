//! What the PLY data readers share: the decoded vertex data ([`Body`]) and the reader's own
//! error ([`ReadError`], given a path and worded for the user by `ply_read`).

use crate::math::{Point3, Real, Vector3};

/// Reader-internal error, given a path by `ply_read::read_ply`.
pub(super) enum ReadError {
    Malformed(String),
    /// A value of an ASCII data line, at its 1-based line and column.
    At {
        line: usize,
        column: usize,
        message: String,
    },
    NonFinite {
        index: usize,
        what: &'static str,
        line: Option<usize>,
    },
}

/// What the data section yields.
pub(super) struct Body {
    pub(super) points: Vec<Point3>,
    pub(super) normals: Option<Vec<Vector3>>,
    pub(super) scalars: Vec<Vec<Real>>,
}

pub(super) fn too_large(what: &str) -> ReadError {
    ReadError::Malformed(format!("{what}: element counts too large for the file"))
}

pub(super) fn non_finite(index: usize, what: &'static str, line: Option<usize>) -> ReadError {
    ReadError::NonFinite { index, what, line }
}
