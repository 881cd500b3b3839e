//! What `twinmill simulate` reports: the stock's figures (also part of `run`'s report), the
//! surface mesh, the collisions found while cutting and the deviation map's summary.

use crate::cutting::sweep::SweepReport;
use serde::Serialize;
use std::collections::BTreeMap;

/// Stock figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StockReport {
    /// Requested dexel pitch (mm).
    pub pitch_mm: f64,
    /// Rays in the three grids.
    pub rays: usize,
    /// Material segments after cutting.
    pub segments: usize,
    /// Material volume after cutting (mm³).
    pub volume_mm3: f64,
    /// Volume removed (mm³).
    pub removed_mm3: f64,
    /// Memory held by the tri-dexel (MiB).
    pub memory_mib: f64,
}

impl StockReport {
    /// The figures of a cut `stock` whose volume before cutting was `volume0` (mm³).
    pub fn of(stock: &crate::cutting::stock::TriDexel, volume0: f64) -> Self {
        let volume = stock.volume();
        Self {
            pitch_mm: stock.pitch(),
            rays: stock.grids().iter().map(|g| g.dims().0 * g.dims().1).sum(),
            segments: stock.grids().iter().map(|g| g.segment_count()).sum(),
            volume_mm3: volume,
            removed_mm3: volume0 - volume,
            memory_mib: stock.memory_bytes() as f64 / 1048576.0,
        }
    }
}

/// Surface-mesh figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MeshSummary {
    /// Vertices.
    pub vertices: usize,
    /// Triangles.
    pub triangles: usize,
    /// Euler characteristic V − E + F (2 for a part with no through-holes).
    pub euler_characteristic: i64,
    /// Volume enclosed by the mesh (mm³).
    pub volume_mm3: f64,
    /// Surface area (mm²).
    pub area_mm2: f64,
    /// Vertices added where the part is meshed at dexel resolution, at the quadratic-error
    /// point of a cell's crossings (sharp features there).
    pub feature_vertices: usize,
    /// Every crossing of the tri-dexel lies within this distance of the mesh (mm): the
    /// adaptive mesher's stated bound, 2 × plane tolerance + polyline tolerance
    /// (docs/cutting.md#the-part-mesh).
    pub bound_mm: f64,
    /// Largest distance of a crossing from the plane its region was meshed with (mm).
    pub max_plane_residual_mm: f64,
    /// Regions meshed as one plane (few large triangles).
    pub planar_regions: usize,
    /// Regions meshed as two planes meeting at an exact sharp edge.
    pub edge_regions: usize,
    /// Lattice cells meshed at dexel resolution (curved or intricate surface).
    pub fine_cells: usize,
}

/// What `twinmill simulate` reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SimulationReport {
    /// Scene name.
    pub scene: String,
    /// Program file.
    pub program: String,
    /// Stock figures (removed volume).
    pub stock: StockReport,
    /// What the sweep did, with its approximation bounds.
    pub sweep: SweepReport,
    /// The surface mesh.
    pub mesh: MeshSummary,
    /// Collisions in program order (empty: none).
    pub collisions: Vec<CollisionEvent>,
    /// The deviation from the scene's design model, if it has one.
    pub deviation: Option<DeviationSummary>,
    /// Stage timings (s): `stock`, `sweep`, `mesh`, `reference`, `render` (the display part
    /// and its picture), `page` (its 3-D view) and `deviation` (from a design model). The
    /// picture, the view and the deviation are made side by side, each timed on its own, so
    /// those three may overlap.
    pub timings_s: BTreeMap<String, f64>,
}

/// A collision found while sweeping (see [`crate::cutting::collide`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CollisionEvent {
    /// `rapid_through_material`, `shank_in_stock`, `holder_in_stock` or `fixture_hit`.
    pub kind: &'static str,
    /// The part that collided: `tool`, `shank` or `holder`.
    pub part: &'static str,
    /// The fixture's name (`fixture_hit` only).
    pub fixture: Option<String>,
    /// NC line of the move.
    pub line: usize,
    /// First contact point (mm, workpiece frame W).
    pub point_mm: [f64; 3],
    /// Stock: penetration depth estimate; fixture: travel after first contact (mm).
    pub depth_mm: f64,
    /// Stock: estimated overlap volume (mm³); fixtures: `None`.
    pub volume_mm3: Option<f64>,
}

impl CollisionEvent {
    /// The report of a collision event.
    pub fn of(e: &crate::cutting::collide::Event) -> Self {
        use crate::cutting::collide::{EventKind, Part};
        let part_name = |p: &Part| match p {
            Part::Tool => "tool",
            Part::Shank => "shank",
            Part::Holder => "holder",
        };
        let (kind, part, fixture) = match &e.kind {
            EventKind::RapidThroughMaterial => ("rapid_through_material", "tool", None),
            EventKind::NonCuttingInStock(p) => (
                if *p == Part::Holder {
                    "holder_in_stock"
                } else {
                    "shank_in_stock"
                },
                part_name(p),
                None,
            ),
            EventKind::FixtureHit { part, fixture } => {
                ("fixture_hit", part_name(part), Some(fixture.clone()))
            }
        };
        Self {
            kind,
            part,
            fixture,
            line: e.line,
            point_mm: e.point,
            depth_mm: e.depth_mm,
            volume_mm3: e.volume_mm3,
        }
    }
}

/// The cut part's deviation from its reference (signed distances of the part's surface,
/// positive where material is left, negative at a gouge): the scene's design model, or —
/// without one — the part the same program cuts on the nominal machine, the deviation the
/// picture and the page colour the part by.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DeviationSummary {
    /// What the deviation is from: `"design"` (the `[design]` mesh, every dexel crossing of
    /// the part) or `"nominal part"` (the display surface's corner deviations, mean and RMS
    /// weighted by area).
    pub from: &'static str,
    /// The design mesh file (`from` = `"design"`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub design: Option<String>,
    /// Max, min, mean and RMS of the signed distances, and where the extremes are (with the
    /// NC line of the surface there: for the nominal part, of the crossing of the cut part
    /// nearest to the corner).
    #[serde(flatten)]
    pub map: crate::report::deviation_map::DeviationReport,
}

impl DeviationSummary {
    /// The reference in words.
    pub fn reference(&self) -> String {
        match &self.design {
            Some(d) => d.clone(),
            None => "the nominal part (the program on the nominal machine)".into(),
        }
    }
}

impl SimulationReport {
    /// A short text summary.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "scene         {}\nprogram       {}\nmoves         {} ({} cutting, {} rotary)\nremoved       {:.4} mm³ of {:.4} mm³\nsweep bound   {:.2e} mm (rotary envelope or sub-steps, and arc chords)\nmesh          {} triangles, {} vertices, Euler characteristic {}, resolved crossings within {:.1e} mm\n",
            self.scene,
            self.program,
            self.sweep.moves,
            self.sweep.cutting_moves,
            self.sweep.rotary_moves,
            self.stock.removed_mm3,
            self.stock.volume_mm3 + self.stock.removed_mm3,
            self.sweep.error_bound_mm,
            self.mesh.triangles,
            self.mesh.vertices,
            self.mesh.euler_characteristic,
            self.mesh.bound_mm,
        );
        if let (Some(tip), Some(bow)) = (self.sweep.tip_error_mm, self.sweep.path_bow_mm) {
            s.push_str(&format!(
                "hexapod       tip off its command by up to {tip:.4} mm, straight moves bowed by up to {bow:.2e} mm (sampled poses); collision checks not run\n"
            ));
        }
        s.push_str(&format!("collisions    {}\n", self.collisions.len()));
        for e in &self.collisions {
            s.push_str(&format!(
                "  line {:<6} {} ({}{}) at [{:.3}, {:.3}, {:.3}] mm, depth {:.3} mm\n",
                e.line,
                e.kind,
                e.part,
                e.fixture
                    .as_ref()
                    .map_or_else(String::new, |f| format!(", fixture '{f}'")),
                e.point_mm[0],
                e.point_mm[1],
                e.point_mm[2],
                e.depth_mm
            ));
        }
        if let Some(d) = &self.deviation {
            let at = |p: &[f64; 3], line: u32| {
                let by = if line == 0 {
                    "stock face".to_string()
                } else {
                    format!("line {line}")
                };
                format!("at [{:.3}, {:.3}, {:.3}], {by}", p[0], p[1], p[2])
            };
            s.push_str(&format!(
                "deviation     max {:+.4} mm ({}), min {:+.4} mm ({}), RMS {:.4} mm over {} points from {}\n",
                d.map.max_mm,
                at(&d.map.at_max, d.map.line_at_max),
                d.map.min_mm,
                at(&d.map.at_min, d.map.line_at_min),
                d.map.rms_mm,
                d.map.points,
                d.reference()
            ));
        }
        s
    }
}
