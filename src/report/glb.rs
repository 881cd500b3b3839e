//! A small glTF 2.0 binary (GLB) writer for the report's 3-D view: named meshes of
//! triangles, lines or points with positions, vertex colours and named scalar attributes
//! (`_DEVIATION_UM`, `_RESIDUAL_UM`: glTF's application-specific attributes start with
//! `_`), and flat materials. One scene, one node per mesh, one buffer.
//!
//! Why a writer of its own: the page needs a handful of accessors per mesh, and the JSON is
//! a few dozen lines of `serde_json`; a typed glTF crate would add a derive-macro dependency
//! tree for that. What makes a GLB valid is checked structurally by this module's tests
//! (header, chunk alignment and padding, every buffer view inside the buffer, every accessor
//! inside its view and aligned, POSITION min/max, indices in range) and, in a real consumer,
//! by three.js's `GLTFLoader` in the browser test.
//!
//! **Invariant:** the output is a valid GLB or an error: non-finite positions or scalars,
//! indices out of range, empty meshes and attribute lengths that differ from the vertex
//! count are refused before a byte is written; the same input gives the same bytes.

use serde_json::{Value, json};

/// Why a GLB could not be built.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GlbError {
    /// A mesh has no vertices.
    #[error("mesh {0}: no vertices")]
    Empty(String),
    /// A position or scalar is NaN or infinite.
    #[error("mesh {mesh}: {what} {index} is not finite")]
    NotFinite {
        /// The mesh.
        mesh: String,
        /// `position` or the scalar's name.
        what: String,
        /// Index of the vertex.
        index: usize,
    },
    /// An index names a vertex that does not exist, or the index count does not fit the
    /// primitive.
    #[error("mesh {mesh}: {message}")]
    BadIndices {
        /// The mesh.
        mesh: String,
        /// What is wrong.
        message: String,
    },
    /// An attribute has a different length than the positions.
    #[error("mesh {mesh}: {what} has {got} values for {vertices} vertices")]
    Length {
        /// The mesh.
        mesh: String,
        /// The attribute.
        what: String,
        /// Its length.
        got: usize,
        /// The vertex count.
        vertices: usize,
    },
}

/// How a primitive's vertices are joined (glTF `mode`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Each vertex a point (0).
    Points,
    /// Each pair of indices a line segment (1).
    Lines,
    /// Each triple of indices a triangle, counter-clockwise seen from outside (4).
    Triangles,
}

impl Mode {
    fn code(self) -> u32 {
        match self {
            Mode::Points => 0,
            Mode::Lines => 1,
            Mode::Triangles => 4,
        }
    }
    fn arity(self) -> usize {
        match self {
            Mode::Points => 1,
            Mode::Lines => 2,
            Mode::Triangles => 3,
        }
    }
}

/// A flat material: base colour (linear RGBA, 0..1), blended when alpha < 1, not metallic,
/// fully rough.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name.
    pub name: String,
    /// Base colour, linear RGBA.
    pub rgba: [f32; 4],
    /// Shown from both sides.
    pub double_sided: bool,
}

/// One mesh: a single primitive.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshData {
    /// Name (shown in the page's layer list).
    pub name: String,
    /// How vertices are joined.
    pub mode: Mode,
    /// Positions (mm, workpiece frame).
    pub positions: Vec<[f32; 3]>,
    /// Vertex colours as sRGB bytes (written as glTF's linear `COLOR_0`), if any.
    pub colours: Option<Vec<[u8; 3]>>,
    /// Named scalar attributes, one value per vertex (the name without the leading `_`).
    pub scalars: Vec<(String, Vec<f32>)>,
    /// Indices; `None`: the vertices in order.
    pub indices: Option<Vec<u32>>,
    /// Index into the materials given to [`write_glb`].
    pub material: Option<usize>,
}

/// The linear value of an sRGB byte (IEC 61966-2-1), as a normalised byte.
pub fn srgb_to_linear_u8(c: u8) -> u8 {
    let s = f64::from(c) / 255.0;
    let l = if s <= 0.04045 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    };
    (l * 255.0).round().clamp(0.0, 255.0) as u8
}

/// glTF component types.
const FLOAT: u32 = 5126;
const UNSIGNED_BYTE: u32 = 5121;
const UNSIGNED_INT: u32 = 5125;
/// Buffer view targets.
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

struct Writer {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Writer {
    /// Appends bytes as a buffer view (4-byte aligned) and returns its index.
    fn view(&mut self, bytes: &[u8], target: u32) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.views.push(json!({
            "buffer": 0, "byteOffset": offset, "byteLength": bytes.len(), "target": target
        }));
        self.views.len() - 1
    }

    fn accessor(&mut self, view: usize, component: u32, count: usize, ty: &str) -> usize {
        self.accessors.push(json!({
            "bufferView": view, "componentType": component, "count": count, "type": ty
        }));
        self.accessors.len() - 1
    }
}

fn check(m: &MeshData) -> Result<(), GlbError> {
    let n = m.positions.len();
    if n == 0 {
        return Err(GlbError::Empty(m.name.clone()));
    }
    if let Some(i) = m
        .positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(GlbError::NotFinite {
            mesh: m.name.clone(),
            what: "position".into(),
            index: i,
        });
    }
    let len_err = |what: &str, got: usize| GlbError::Length {
        mesh: m.name.clone(),
        what: what.into(),
        got,
        vertices: n,
    };
    if let Some(c) = &m.colours
        && c.len() != n
    {
        return Err(len_err("COLOR_0", c.len()));
    }
    for (name, v) in &m.scalars {
        if v.len() != n {
            return Err(len_err(name, v.len()));
        }
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(GlbError::NotFinite {
                mesh: m.name.clone(),
                what: name.clone(),
                index: i,
            });
        }
    }
    let count = m.indices.as_ref().map_or(n, Vec::len);
    let bad = |message: String| GlbError::BadIndices {
        mesh: m.name.clone(),
        message,
    };
    if count == 0 || !count.is_multiple_of(m.mode.arity()) {
        return Err(bad(format!(
            "{count} indices do not make whole {:?}",
            m.mode
        )));
    }
    if let Some(ix) = &m.indices
        && let Some(i) = ix.iter().find(|&&i| i as usize >= n)
    {
        return Err(bad(format!("index {i} but {n} vertices")));
    }
    Ok(())
}

/// Writes `meshes` (each checked first, see [`GlbError`]) with `materials` as one GLB.
pub fn write_glb(meshes: &[MeshData], materials: &[Material]) -> Result<Vec<u8>, GlbError> {
    for m in meshes {
        check(m)?;
        if let Some(k) = m.material
            && k >= materials.len()
        {
            return Err(GlbError::BadIndices {
                mesh: m.name.clone(),
                message: format!("material {k} but {} materials", materials.len()),
            });
        }
    }
    let mut w = Writer {
        bin: Vec::new(),
        views: Vec::new(),
        accessors: Vec::new(),
    };
    let mut json_meshes = Vec::new();
    for m in meshes {
        let n = m.positions.len();
        let mut attributes = serde_json::Map::new();
        let bytes: Vec<u8> = m
            .positions
            .iter()
            .flat_map(|p| p.iter().flat_map(|c| c.to_le_bytes()))
            .collect();
        let v = w.view(&bytes, ARRAY_BUFFER);
        let a = w.accessor(v, FLOAT, n, "VEC3");
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in &m.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        w.accessors[a]["min"] = json!(lo);
        w.accessors[a]["max"] = json!(hi);
        attributes.insert("POSITION".into(), json!(a));
        if let Some(c) = &m.colours {
            let bytes: Vec<u8> = c
                .iter()
                .flat_map(|rgb| {
                    let [r, g, b] = rgb.map(srgb_to_linear_u8);
                    [r, g, b, 255]
                })
                .collect();
            let v = w.view(&bytes, ARRAY_BUFFER);
            let a = w.accessor(v, UNSIGNED_BYTE, n, "VEC4");
            w.accessors[a]["normalized"] = json!(true);
            attributes.insert("COLOR_0".into(), json!(a));
        }
        for (name, values) in &m.scalars {
            let bytes: Vec<u8> = values.iter().flat_map(|x| x.to_le_bytes()).collect();
            let v = w.view(&bytes, ARRAY_BUFFER);
            let a = w.accessor(v, FLOAT, n, "SCALAR");
            attributes.insert(format!("_{}", name.to_uppercase()), json!(a));
        }
        let mut prim = json!({ "attributes": attributes, "mode": m.mode.code() });
        if let Some(ix) = &m.indices {
            let bytes: Vec<u8> = ix.iter().flat_map(|i| i.to_le_bytes()).collect();
            let v = w.view(&bytes, ELEMENT_ARRAY_BUFFER);
            let a = w.accessor(v, UNSIGNED_INT, ix.len(), "SCALAR");
            prim["indices"] = json!(a);
        }
        if let Some(k) = m.material {
            prim["material"] = json!(k);
        }
        json_meshes.push(json!({ "name": m.name, "primitives": [prim] }));
    }
    while !w.bin.len().is_multiple_of(4) {
        w.bin.push(0);
    }
    let nodes: Vec<Value> = meshes
        .iter()
        .enumerate()
        .map(|(i, m)| json!({ "mesh": i, "name": m.name }))
        .collect();
    let mats: Vec<Value> = materials
        .iter()
        .map(|m| {
            let mut v = json!({
                "name": m.name,
                "pbrMetallicRoughness": {
                    "baseColorFactor": m.rgba, "metallicFactor": 0.0, "roughnessFactor": 1.0
                },
                "doubleSided": m.double_sided,
            });
            if m.rgba[3] < 1.0 {
                v["alphaMode"] = json!("BLEND");
            }
            v
        })
        .collect();
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": "twinmill" },
        "scene": 0,
        "scenes": [{ "nodes": (0..meshes.len()).collect::<Vec<_>>() }],
        "nodes": nodes,
        "meshes": json_meshes,
        "accessors": w.accessors,
    });
    if !mats.is_empty() {
        doc["materials"] = json!(mats);
    }
    if !w.bin.is_empty() {
        doc["buffers"] = json!([{ "byteLength": w.bin.len() }]);
        doc["bufferViews"] = json!(w.views);
    }
    let mut text = doc.to_string().into_bytes();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len() + if w.bin.is_empty() { 0 } else { 8 + w.bin.len() };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    if !w.bin.is_empty() {
        out.extend_from_slice(&(w.bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&w.bin);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn u32_at(b: &[u8], i: usize) -> u32 {
        u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
    }

    /// Parses a GLB and checks its structure as the glTF 2.0 specification requires it;
    /// returns the JSON and the binary chunk.
    fn validate(glb: &[u8]) -> (Value, Vec<u8>) {
        assert_eq!(&glb[0..4], b"glTF");
        assert_eq!(u32_at(glb, 4), 2);
        assert_eq!(u32_at(glb, 8) as usize, glb.len());
        let jlen = u32_at(glb, 12) as usize;
        assert_eq!(&glb[16..20], b"JSON");
        assert!(jlen.is_multiple_of(4));
        let doc: Value = serde_json::from_slice(&glb[20..20 + jlen]).expect("JSON chunk");
        let mut bin = Vec::new();
        let rest = 20 + jlen;
        if rest < glb.len() {
            let blen = u32_at(glb, rest) as usize;
            assert_eq!(&glb[rest + 4..rest + 8], b"BIN\0");
            assert!(blen.is_multiple_of(4));
            assert_eq!(rest + 8 + blen, glb.len());
            bin = glb[rest + 8..].to_vec();
            assert_eq!(doc["buffers"][0]["byteLength"].as_u64(), Some(blen as u64));
        }
        assert_eq!(doc["asset"]["version"], "2.0");
        let views = doc["bufferViews"].as_array().cloned().unwrap_or_default();
        for v in &views {
            let (o, l) = (
                v["byteOffset"].as_u64().unwrap() as usize,
                v["byteLength"].as_u64().unwrap() as usize,
            );
            assert!(o + l <= bin.len() && o.is_multiple_of(4));
        }
        let size = |ty: &str| match ty {
            "SCALAR" => 1,
            "VEC3" => 3,
            "VEC4" => 4,
            other => panic!("type {other}"),
        };
        let accessors = doc["accessors"].as_array().unwrap();
        for a in accessors {
            let v = &views[a["bufferView"].as_u64().unwrap() as usize];
            let comp = match a["componentType"].as_u64().unwrap() as u32 {
                FLOAT | UNSIGNED_INT => 4,
                UNSIGNED_BYTE => 1,
                c => panic!("component {c}"),
            };
            let len =
                a["count"].as_u64().unwrap() as usize * comp * size(a["type"].as_str().unwrap());
            assert!(len <= v["byteLength"].as_u64().unwrap() as usize);
        }
        for m in doc["meshes"].as_array().unwrap() {
            let p = &m["primitives"][0];
            let pos = &accessors[p["attributes"]["POSITION"].as_u64().unwrap() as usize];
            let n = pos["count"].as_u64().unwrap() as usize;
            let o = views[pos["bufferView"].as_u64().unwrap() as usize]["byteOffset"]
                .as_u64()
                .unwrap() as usize;
            let f = |i: usize| f32::from_le_bytes([bin[i], bin[i + 1], bin[i + 2], bin[i + 3]]);
            for k in 0..3 {
                let vals: Vec<f32> = (0..n).map(|i| f(o + 12 * i + 4 * k)).collect();
                let lo = vals.iter().copied().fold(f32::INFINITY, f32::min);
                let hi = vals.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                assert_eq!(pos["min"][k].as_f64().unwrap() as f32, lo);
                assert_eq!(pos["max"][k].as_f64().unwrap() as f32, hi);
            }
            for (name, a) in p["attributes"].as_object().unwrap() {
                let a = &accessors[a.as_u64().unwrap() as usize];
                assert_eq!(a["count"].as_u64().unwrap() as usize, n, "{name}");
                assert!(["POSITION", "COLOR_0"].contains(&name.as_str()) || name.starts_with('_'));
            }
            if let Some(ix) = p["indices"].as_u64() {
                let a = &accessors[ix as usize];
                let o = views[a["bufferView"].as_u64().unwrap() as usize]["byteOffset"]
                    .as_u64()
                    .unwrap() as usize;
                for i in 0..a["count"].as_u64().unwrap() as usize {
                    assert!((u32_at(&bin, o + 4 * i) as usize) < n);
                }
            }
        }
        (doc, bin)
    }

    fn tetra() -> MeshData {
        MeshData {
            name: "part".into(),
            mode: Mode::Triangles,
            positions: vec![[0., 0., 0.], [1., 0., 0.], [0., 1., 0.], [0., 0., 1.]],
            colours: Some(vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [5, 48, 97]]),
            scalars: vec![("deviation_um".into(), vec![1.0, -2.0, 3.0, 0.5])],
            indices: Some(vec![0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3]),
            material: Some(0),
        }
    }

    #[test]
    fn a_glb_of_triangles_points_and_materials_is_structurally_valid() {
        let cloud = MeshData {
            name: "cloud".into(),
            mode: Mode::Points,
            positions: vec![[0.5, 0.5, 0.5]; 3],
            colours: None,
            scalars: vec![],
            indices: None,
            material: Some(1),
        };
        let mats = [
            Material {
                name: "part".into(),
                rgba: [1.0; 4],
                double_sided: false,
            },
            Material {
                name: "glass".into(),
                rgba: [0.2, 0.4, 0.8, 0.3],
                double_sided: true,
            },
        ];
        let glb = write_glb(&[tetra(), cloud.clone()], &mats).unwrap();
        let (doc, _) = validate(&glb);
        assert_eq!(doc["meshes"][0]["primitives"][0]["mode"], 4);
        assert_eq!(doc["meshes"][1]["primitives"][0]["mode"], 0);
        assert_eq!(doc["materials"][1]["alphaMode"], "BLEND");
        assert!(
            doc["meshes"][0]["primitives"][0]["attributes"]
                .get("_DEVIATION_UM")
                .is_some()
        );
        // Deterministic.
        assert_eq!(glb, write_glb(&[tetra(), cloud], &mats).unwrap());
    }

    #[test]
    fn bad_meshes_are_refused() {
        let mut m = tetra();
        m.positions[1][2] = f32::NAN;
        assert!(matches!(
            write_glb(&[m], &[]),
            Err(GlbError::NotFinite { .. })
        ));
        let mut m = tetra();
        m.indices = Some(vec![0, 1, 9]);
        assert!(matches!(
            write_glb(&[m], &[]),
            Err(GlbError::BadIndices { .. })
        ));
        let mut m = tetra();
        m.indices = Some(vec![0, 1]);
        assert!(matches!(
            write_glb(&[m], &[]),
            Err(GlbError::BadIndices { .. })
        ));
        let mut m = tetra();
        m.scalars[0].1.pop();
        assert!(matches!(write_glb(&[m], &[]), Err(GlbError::Length { .. })));
        let mut m = tetra();
        m.positions.clear();
        assert!(matches!(write_glb(&[m], &[]), Err(GlbError::Empty(_))));
        let m = tetra();
        assert!(matches!(
            write_glb(&[m], &[]),
            Err(GlbError::BadIndices { .. })
        ));
    }

    #[test]
    fn srgb_bytes_map_to_linear_ones() {
        assert_eq!(srgb_to_linear_u8(0), 0);
        assert_eq!(srgb_to_linear_u8(255), 255);
        assert_eq!(srgb_to_linear_u8(188), 128);
    }
}
