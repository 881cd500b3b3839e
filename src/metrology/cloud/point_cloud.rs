//! The point cloud itself: [`PointCloud`] (points in a [`Frame`], optional normals, named
//! [`ScalarField`]s) and its validation ([`PointCloud::validate`], [`InvalidCloud`]): what
//! every writer requires before it writes a byte.

use crate::math::{Aabb, Point3, Real, Vector3};
use rayon::prelude::*;
use std::collections::HashSet;

/// The frame a cloud's coordinates are expressed in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Frame {
    /// workpiece frame W
    Workpiece,
    /// scanner frame S
    Scanner,
}

impl Frame {
    /// The lower-case name used in the PLY `comment frame <name>` header line.
    pub fn name(self) -> &'static str {
        match self {
            Frame::Workpiece => "workpiece",
            Frame::Scanner => "scanner",
        }
    }

    /// The frame with the given lower-case name (`"workpiece"` or `"scanner"`).
    pub fn from_name(name: &str) -> Option<Frame> {
        match name {
            "workpiece" => Some(Frame::Workpiece),
            "scanner" => Some(Frame::Scanner),
            _ => None,
        }
    }
}

/// A named per-point value (a deviation, an intensity, a colour channel, …).
#[derive(Clone, Debug, PartialEq)]
pub struct ScalarField {
    /// The name, written as the PLY property name: no white space or control characters,
    /// not one of `x y z nx ny nz`, unique within the cloud.
    pub name: String,
    /// One value per point. Any `f64`, NaN included (CloudCompare's "no value").
    pub values: Vec<Real>,
}

impl ScalarField {
    /// A scalar field named `name` with `values`.
    pub fn new(name: impl Into<String>, values: Vec<Real>) -> Self {
        Self {
            name: name.into(),
            values,
        }
    }
}

/// A point cloud (mm).
#[derive(Clone, Debug, PartialEq)]
pub struct PointCloud {
    /// The frame the coordinates are expressed in.
    pub frame: Frame,
    /// The points (mm), in acquisition order.
    pub points: Vec<Point3>,
    /// Unit normals, one per point, when known. A zero vector is kept as given (some tools
    /// write it for "unknown").
    pub normals: Option<Vec<Vector3>>,
    /// Scalar fields, each with one value per point.
    pub scalars: Vec<ScalarField>,
}

impl PointCloud {
    /// A cloud of `points` in `frame`, without normals or scalar fields.
    pub fn new(frame: Frame, points: Vec<Point3>) -> Self {
        Self {
            frame,
            points,
            normals: None,
            scalars: Vec::new(),
        }
    }

    /// The cloud with `normals` (one per point; checked by [`PointCloud::validate`]).
    pub fn with_normals(mut self, normals: Vec<Vector3>) -> Self {
        self.normals = Some(normals);
        self
    }

    /// The cloud with one more scalar field (checked by [`PointCloud::validate`]).
    pub fn with_scalar(mut self, name: impl Into<String>, values: Vec<Real>) -> Self {
        self.scalars.push(ScalarField::new(name, values));
        self
    }

    /// The scalar field called `name`, if any.
    pub fn scalar(&self, name: &str) -> Option<&ScalarField> {
        self.scalars.iter().find(|s| s.name == name)
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the cloud has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The bounding box of the points ([`Aabb::empty`] for an empty cloud).
    pub fn aabb(&self) -> Aabb {
        let mut b = Aabb::empty();
        for p in &self.points {
            b.grow(p);
        }
        b
    }

    /// Checks what every writer requires: as many normals and scalar values as points,
    /// finite coordinates and normals, and scalar field names that are valid, unique PLY
    /// property names other than `x y z nx ny nz`. Scalar values may be any `f64`.
    pub fn validate(&self) -> Result<(), InvalidCloud> {
        let n = self.points.len();
        if let Some(normals) = &self.normals
            && normals.len() != n
        {
            return Err(InvalidCloud::NormalCount {
                points: n,
                normals: normals.len(),
            });
        }
        let mut seen = HashSet::new();
        for s in &self.scalars {
            if s.values.len() != n {
                return Err(InvalidCloud::ScalarCount {
                    name: s.name.clone(),
                    points: n,
                    values: s.values.len(),
                });
            }
            let problem = scalar_name_problem(&s.name)
                .or_else(|| (!seen.insert(s.name.as_str())).then_some("appears twice"));
            if let Some(reason) = problem {
                return Err(InvalidCloud::ScalarName {
                    name: s.name.clone(),
                    reason,
                });
            }
        }
        if let Some(index) = first_non_finite(&self.points, |p| p.coords) {
            return Err(InvalidCloud::NonFinitePoint { index });
        }
        if let Some(index) = self
            .normals
            .as_ref()
            .and_then(|ns| first_non_finite(ns, |v| *v))
        {
            return Err(InvalidCloud::NonFiniteNormal { index });
        }
        Ok(())
    }
}

/// Index of the first item whose vector has a NaN or infinite component, searched in
/// parallel over fixed chunks (rayon's `position_first` is several times slower here).
pub(super) fn first_non_finite<T: Sync>(
    items: &[T],
    vector: impl Fn(&T) -> Vector3 + Sync,
) -> Option<usize> {
    items
        .par_chunks(CHECK_CHUNK)
        .enumerate()
        .filter_map(|(k, chunk)| {
            chunk
                .iter()
                .position(|t| {
                    let v = vector(t);
                    !(v.x.is_finite() && v.y.is_finite() && v.z.is_finite())
                })
                .map(|i| k * CHECK_CHUNK + i)
        })
        .min()
}

/// Items per task in [`first_non_finite`].
const CHECK_CHUNK: usize = 1 << 15;

/// Why [`PointCloud::validate`] refuses a cloud.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum InvalidCloud {
    /// The normals are not one per point.
    #[error("{normals} normals for {points} points")]
    NormalCount {
        /// Number of points.
        points: usize,
        /// Number of normals.
        normals: usize,
    },
    /// A scalar field does not have one value per point.
    #[error("scalar field {name:?} has {values} values for {points} points")]
    ScalarCount {
        /// The field's name.
        name: String,
        /// Number of points.
        points: usize,
        /// Number of values.
        values: usize,
    },
    /// A scalar field's name cannot be written as a PLY property name.
    #[error("scalar field name {name:?} {reason}")]
    ScalarName {
        /// The name.
        name: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A point has a NaN or infinite coordinate.
    #[error("point {index} has a non-finite coordinate")]
    NonFinitePoint {
        /// Zero-based index of the first such point.
        index: usize,
    },
    /// A normal has a NaN or infinite component.
    #[error("normal {index} has a non-finite component")]
    NonFiniteNormal {
        /// Zero-based index of the first such normal.
        index: usize,
    },
}

/// What is wrong with `name` as a scalar field (PLY property) name, if anything.
pub(super) fn scalar_name_problem(name: &str) -> Option<&'static str> {
    if name.is_empty() {
        Some("is empty")
    } else if name
        .chars()
        .any(|c| c.is_ascii_whitespace() || c.is_control())
    {
        Some("contains white space or a control character")
    } else if RESERVED.contains(&name) {
        Some("is reserved for coordinates and normals")
    } else {
        None
    }
}

/// Vertex property names that are not scalar fields.
pub(super) const RESERVED: [&str; 6] = ["x", "y", "z", "nx", "ny", "nz"];

#[cfg(test)]
mod tests {
    use super::super::tests::full_cloud;
    use super::*;

    #[test]
    fn validate_catches_every_problem() {
        let c = full_cloud(5, Frame::Workpiece);
        assert_eq!(c.validate(), Ok(()));
        let mut bad = c.clone();
        bad.normals.as_mut().expect("normals").pop();
        assert_eq!(
            bad.validate(),
            Err(InvalidCloud::NormalCount {
                points: 5,
                normals: 4
            })
        );
        let bad = c.clone().with_scalar("short", vec![1.0; 4]);
        assert!(matches!(
            bad.validate(),
            Err(InvalidCloud::ScalarCount { values: 4, .. })
        ));
        for name in ["", "a b", "tab\there", "nx", "x", "index", "ctl\u{1}"] {
            let bad = c.clone().with_scalar(name, vec![0.0; 5]);
            assert!(
                matches!(bad.validate(), Err(InvalidCloud::ScalarName { .. })),
                "{name:?}"
            );
        }
        let mut bad = c.clone();
        bad.points[3].z = Real::INFINITY;
        assert_eq!(
            bad.validate(),
            Err(InvalidCloud::NonFinitePoint { index: 3 })
        );
        let mut bad = c.clone();
        bad.normals.as_mut().expect("normals")[2].x = Real::NAN;
        assert_eq!(
            bad.validate(),
            Err(InvalidCloud::NonFiniteNormal { index: 2 })
        );
    }
}
