//! Fixtures shared by the cloud tests (sample clouds with awkward values, PLY bytes written
//! and read back, bitwise comparison, hand-made binary files, valid files of every kind),
//! and the tests that span the module: round trips through every writer and reader,
//! refusals of invalid clouds, and robustness against random, truncated and mutated input.

use super::*;
use crate::math::{CounterRng, Point3, Real, Vector3};
use proptest::prelude::*;
use std::path::{Path, PathBuf};

pub(super) fn sample_cloud(n: usize, frame: Frame) -> PointCloud {
    let rng = CounterRng::new(42);
    let points = (0..n as u64)
        .map(|i| {
            Point3::new(
                100.0 * rng.normal(3 * i),
                250.0 + rng.normal(3 * i + 1) / 3.0,
                -1e-7 * rng.normal(3 * i + 2),
            )
        })
        .collect();
    PointCloud::new(frame, points)
}

/// A cloud with normals and two scalar fields, including awkward values (−0, a
/// subnormal, huge and tiny magnitudes) in its first points.
pub(super) fn full_cloud(n: usize, frame: Frame) -> PointCloud {
    let mut c = sample_cloud(n, frame);
    let rng = CounterRng::new(7);
    let normals: Vec<Vector3> = (0..n as u64)
        .map(|i| {
            Vector3::new(
                rng.normal(3 * i),
                rng.normal(3 * i + 1),
                rng.normal(3 * i + 2),
            )
            .normalize()
        })
        .collect();
    let dist: Vec<Real> = (0..n as u64).map(|i| 1e-3 * rng.normal(i + 999)).collect();
    let index: Vec<Real> = (0..n).map(|i| i as Real).collect();
    let awkward = [
        -0.0,
        5e-324,
        1.7976931348623157e308,
        -1e-300,
        0.1,
        1.0 / 3.0,
    ];
    for (k, v) in awkward.iter().enumerate().take(n) {
        c.points[k].x = *v;
    }
    c = c
        .with_normals(normals)
        .with_scalar("scalar_distance", dist)
        .with_scalar("index", index);
    if n > 0 {
        c.normals.as_mut().expect("normals")[0] = Vector3::zeros();
        c.scalars[0].values[0] = -0.0;
    }
    c
}

pub(super) fn to_bytes(c: &PointCloud) -> Vec<u8> {
    let mut out = Vec::new();
    write_ply(c, &mut out).expect("write to Vec");
    out
}

pub(super) fn to_bytes_as(c: &PointCloud, f: PlyFormat) -> Vec<u8> {
    let mut out = Vec::new();
    write_ply_as(c, f, &mut out).expect("write to Vec");
    out
}

pub(super) fn read(bytes: &[u8]) -> Result<PointCloud, CloudError> {
    read_ply(bytes, Path::new("test.ply"))
}

pub(super) fn is_malformed(r: Result<PointCloud, CloudError>) -> bool {
    matches!(r, Err(CloudError::Malformed { .. } | CloudError::At { .. }))
}

/// The Malformed message, or a description of what came instead.
pub(super) fn malformed_message(r: Result<PointCloud, CloudError>) -> String {
    match r {
        Err(e @ (CloudError::Malformed { .. } | CloudError::At { .. })) => e.to_string(),
        other => panic!("expected Malformed, got {other:?}"),
    }
}

/// Bitwise equality of two clouds (NaN-safe, distinguishes −0).
pub(super) fn assert_bit_identical(a: &PointCloud, b: &PointCloud) {
    assert_eq!(a.frame, b.frame);
    assert_eq!(a.points.len(), b.points.len());
    for (p, q) in a.points.iter().zip(&b.points) {
        for k in 0..3 {
            assert_eq!(p[k].to_bits(), q[k].to_bits(), "{p} vs {q}");
        }
    }
    assert_eq!(a.normals.is_some(), b.normals.is_some());
    if let (Some(na), Some(nb)) = (&a.normals, &b.normals) {
        assert_eq!(na.len(), nb.len());
        for (p, q) in na.iter().zip(nb) {
            for k in 0..3 {
                assert_eq!(p[k].to_bits(), q[k].to_bits());
            }
        }
    }
    assert_eq!(a.scalars.len(), b.scalars.len());
    for (s, t) in a.scalars.iter().zip(&b.scalars) {
        assert_eq!(s.name, t.name);
        let bits = |v: &[Real]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&s.values), bits(&t.values), "field {}", s.name);
    }
}

/// A binary file with x y z float, nx ny nz float, red green blue uchar, plus a
/// leading fixed-size element and a trailing face element.
pub(super) fn binary_with_extras(big_endian: bool, pts: &[[f32; 3]]) -> Vec<u8> {
    let fmt = if big_endian {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let mut out = format!(
        "ply\nformat {fmt} 1.0\ncomment frame scanner\nobj_info whatever\n\
         element camera 1\nproperty short id\nproperty double scale\n\
         element vertex {}\nproperty float32 x\nproperty float32 y\nproperty float32 z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         element face 1\nproperty list uchar int vertex_indices\nend_header\n",
        pts.len()
    )
    .into_bytes();
    let f32b = |v: f32| {
        if big_endian {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    if big_endian {
        out.extend_from_slice(&7i16.to_be_bytes());
        out.extend_from_slice(&2.5f64.to_be_bytes());
    } else {
        out.extend_from_slice(&7i16.to_le_bytes());
        out.extend_from_slice(&2.5f64.to_le_bytes());
    }
    for p in pts {
        for v in p {
            out.extend_from_slice(&f32b(*v));
        }
        for v in [0.0f32, 0.6, 0.8] {
            out.extend_from_slice(&f32b(v));
        }
        out.extend_from_slice(&[200, 100, 50]);
    }
    out.push(3);
    for i in 0..3i32 {
        out.extend_from_slice(&if big_endian {
            i.to_be_bytes()
        } else {
            i.to_le_bytes()
        });
    }
    out
}

pub(super) fn xyz(text: &str) -> Result<PointCloud, CloudError> {
    read_xyz(text, Path::new("test.xyz"))
}

pub(super) fn xyz_round_trip(c: &PointCloud, sep: XyzSeparator) -> PointCloud {
    let mut out = Vec::new();
    write_xyz(c, &mut out, sep).expect("write xyz");
    let text = String::from_utf8(out).expect("utf-8");
    xyz(&text).expect("read back")
}

pub(super) fn pts(text: &str) -> Result<PointCloud, CloudError> {
    read_pts(text, Path::new("test.pts"))
}

pub(super) fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("twinmill_cloud_{tag}_{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn ascii_sample() -> Vec<u8> {
    b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
      property float z\nproperty uchar red\nelement face 1\n\
      property list uchar int vertex_indices\nend_header\n1 2 3 4\n5 6 7 8\n9 10 11 12\n\
      3 0 1 2\n"
        .to_vec()
}

fn xyz_sample() -> Vec<u8> {
    b"// frame scanner\nx,y,z,nx,ny,nz\n1,2,3,0,0,1\n4,5,6,0,1,0 # c\n\n7,8,9,1,0,0\n".to_vec()
}

/// Valid files of every kind to mutate.
pub(super) fn valid_files() -> Vec<Vec<u8>> {
    let c = full_cloud(4, Frame::Scanner);
    vec![
        to_bytes(&sample_cloud(4, Frame::Scanner)),
        to_bytes(&c),
        to_bytes_as(&c, PlyFormat::BinaryBigEndian),
        to_bytes_as(&c, PlyFormat::Ascii),
        binary_with_extras(true, &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]),
        binary_with_extras(false, &[[1.0, 2.0, 3.0]]),
        ascii_sample(),
        xyz_sample(),
        b"2\n1 2 3 4 5 6 7\n8 9 10 11 12 13 14\n".to_vec(),
    ]
}

/// Reads `bytes` with every reader (results ignored: they must only not panic).
fn read_all_ways(bytes: &[u8]) {
    let _ = read(bytes);
    let text = String::from_utf8_lossy(bytes);
    let _ = xyz(&text);
    let _ = pts(&text);
}

#[test]
fn round_trip_is_bit_exact() {
    for frame in [Frame::Workpiece, Frame::Scanner] {
        let c = sample_cloud(1000, frame);
        let back = read(&to_bytes(&c)).expect("read back");
        assert_bit_identical(&c, &back);
        assert_eq!(back, c);
    }
}

#[test]
fn empty_cloud_round_trips() {
    let c = PointCloud::new(Frame::Workpiece, Vec::new());
    for f in [
        PlyFormat::BinaryLittleEndian,
        PlyFormat::BinaryBigEndian,
        PlyFormat::Ascii,
    ] {
        assert_eq!(read(&to_bytes_as(&c, f)).expect("read"), c);
    }
    let e = full_cloud(0, Frame::Scanner);
    assert_eq!(read(&to_bytes(&e)).expect("read"), e);
}

#[test]
fn normals_and_scalars_round_trip_in_every_format() {
    for frame in [Frame::Workpiece, Frame::Scanner] {
        let c = full_cloud(500, frame);
        c.validate().expect("valid");
        for f in [
            PlyFormat::BinaryLittleEndian,
            PlyFormat::BinaryBigEndian,
            PlyFormat::Ascii,
        ] {
            let back = read(&to_bytes_as(&c, f)).expect("read back");
            assert_bit_identical(&c, &back);
            assert_eq!(back, c, "{f:?}");
        }
    }
}

#[test]
fn non_finite_scalars_round_trip() {
    let c = sample_cloud(4, Frame::Workpiece).with_scalar(
        "sf",
        vec![Real::NAN, Real::INFINITY, Real::NEG_INFINITY, -0.0],
    );
    for f in [
        PlyFormat::BinaryLittleEndian,
        PlyFormat::BinaryBigEndian,
        PlyFormat::Ascii,
    ] {
        let back = read(&to_bytes_as(&c, f)).expect("read back");
        assert_bit_identical(&c, &back);
    }
}

#[test]
fn invalid_clouds_write_nothing() {
    let c = full_cloud(5, Frame::Workpiece);
    let mut short = c.clone();
    short.scalars[1].values.pop();
    let mut long_normals = c.clone();
    long_normals
        .normals
        .as_mut()
        .expect("normals")
        .push(Vector3::x());
    let dup = c.clone().with_scalar("index", vec![0.0; 5]);
    for bad in [&short, &long_normals, &dup] {
        for f in [
            PlyFormat::BinaryLittleEndian,
            PlyFormat::BinaryBigEndian,
            PlyFormat::Ascii,
        ] {
            let mut out = Vec::new();
            let e = write_ply_as(bad, f, &mut out).expect_err("refused");
            assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput);
            assert!(
                e.get_ref()
                    .is_some_and(|inner| inner.downcast_ref::<InvalidCloud>().is_some())
            );
            assert!(out.is_empty());
        }
        let mut out = Vec::new();
        assert!(write_xyz(bad, &mut out, XyzSeparator::Space).is_err());
        assert!(out.is_empty());
    }
    let dir = temp_dir("invalid");
    let path = dir.join("bad.ply");
    assert!(matches!(
        write_ply_file(&short, &path),
        Err(CloudError::Invalid { .. })
    ));
    assert!(!path.exists(), "no file is created for an invalid cloud");
    assert!(matches!(
        write_cloud_file(&short, &dir.join("bad.csv")),
        Err(CloudError::Invalid { .. })
    ));
    assert!(!dir.join("bad.csv").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn valid_files_are_valid() {
    let files = valid_files();
    for f in &files[..7] {
        read(f).expect("valid PLY");
    }
    let c = xyz(&String::from_utf8_lossy(&files[7])).expect("valid XYZ");
    assert_eq!((c.len(), c.frame), (3, Frame::Scanner));
    assert_eq!(
        pts(&String::from_utf8_lossy(&files[8])).expect("PTS").len(),
        2
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        read_all_ways(&bytes);
        for prefix in [
            &b"ply\nformat ascii 1.0\n"[..],
            b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n\
              property float y\nproperty float z\nproperty list uchar int f\n",
            b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty uchar x\n\
              property char y\nproperty int z\nelement face 3\n\
              property list uint int vertex_indices\nend_header\n",
        ] {
            let mut with_magic = prefix.to_vec();
            with_magic.extend_from_slice(&bytes);
            let _ = read(&with_magic);
        }
    }

    #[test]
    fn random_text_never_panics(
        lines in proptest::collection::vec("[0-9eE.,+\\- \t#/naif]{0,30}", 0..20),
    ) {
        let text = lines.join("\n");
        let _ = xyz(&text);
        let _ = pts(&text);
    }

    #[test]
    fn truncations_never_panic(cut in 0usize..4000, which in 0usize..9) {
        let files = valid_files();
        let bytes = &files[which % files.len()];
        let cut = cut.min(bytes.len());
        read_all_ways(&bytes[..cut]);
        if cut < bytes.len() && bytes.starts_with(b"ply\nformat binary") {
            // Every truncated binary PLY is an error, never a shorter cloud.
            prop_assert!(read(&bytes[..cut]).is_err());
        }
    }

    #[test]
    fn mutations_never_panic(
        edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8),
        which in 0usize..9,
    ) {
        let files = valid_files();
        let mut bytes = files[which % files.len()].clone();
        let n = bytes.len();
        for (pos, val) in edits {
            if let Some(b) = bytes.get_mut(pos % n) {
                *b = val;
            }
        }
        read_all_ways(&bytes);
    }

    #[test]
    fn header_digit_mutations_never_panic(
        count in any::<u64>(),
        tail in proptest::collection::vec(any::<u8>(), 0..100),
    ) {
        for fmt in ["ascii", "binary_little_endian", "binary_big_endian"] {
            let mut bytes = format!(
                "ply\nformat {fmt} 1.0\nelement other {count}\nproperty uchar a\n\
                 element vertex {count}\nproperty float x\nproperty float y\n\
                 property float z\nelement face {count}\nproperty list uchar int v\n\
                 end_header\n"
            )
            .into_bytes();
            bytes.extend_from_slice(&tail);
            let _ = read(&bytes);
        }
    }

    #[test]
    fn random_clouds_round_trip(
        raw in proptest::collection::vec(any::<[u64; 7]>(), 0..40),
        normals in any::<bool>(),
        frame in any::<bool>(),
    ) {
        // Any finite coordinates/normals and any scalar bits survive every format.
        let finite = |b: u64| {
            let v = f64::from_bits(b);
            if v.is_finite() { v } else { 0.5 }
        };
        let frame = if frame { Frame::Scanner } else { Frame::Workpiece };
        let mut c = PointCloud::new(
            frame,
            raw.iter().map(|r| Point3::new(finite(r[0]), finite(r[1]), finite(r[2]))).collect(),
        )
        .with_scalar("s", raw.iter().map(|r| finite(r[6])).collect());
        if normals {
            c = c.with_normals(
                raw.iter().map(|r| Vector3::new(finite(r[3]), finite(r[4]), finite(r[5]))).collect(),
            );
        }
        for f in [PlyFormat::BinaryLittleEndian, PlyFormat::BinaryBigEndian, PlyFormat::Ascii] {
            let back = read(&to_bytes_as(&c, f)).expect("round trip");
            prop_assert_eq!(&back, &c);
        }
        let mut want = c.clone();
        want.scalars.clear();
        for sep in [XyzSeparator::Space, XyzSeparator::Comma] {
            prop_assert_eq!(&xyz_round_trip(&c, sep), &want);
        }
    }
}
