//! Ray/sweep throughput per tool kind (rays/s): one straight move of each tool, a fixed
//! grid of axis rays over its box. Flat and ball run through the sweep module's closed
//! form and through the piecewise cutter; the piecewise cutter also runs with every piece
//! forced onto the numeric path (Brent + regula falsi) to show the cost of non-closed forms.

use criterion::criterion_main;

mod bench {
    use criterion::{BenchmarkId, Criterion, Throughput};
    use std::hint::black_box;
    use twinmill::cutting::cutter::{PieceMethod, SweptTool};
    use twinmill::cutting::stock::{Cutter, RayCut};
    use twinmill::cutting::sweep::TranslatedTool;
    use twinmill::cutting::tool::{ProfileStep, Tool, ToolKind};
    use twinmill::math::{Point3, Real, UnitVector3, Vector3};

    fn form_cutter() -> Tool {
        Tool::try_profile(&[
            ProfileStep::Line { to: [1.0, 0.0] },
            ProfileStep::Arc {
                to: [2.0, 1.0],
                center: [1.0, 1.0],
                convex: true,
            },
            ProfileStep::Arc {
                to: [1.2, 1.8],
                center: [2.0, 1.8],
                convex: false,
            },
            ProfileStep::Line { to: [1.2, 3.0] },
            ProfileStep::Line { to: [2.5, 3.5] },
            ProfileStep::Line { to: [2.5, 12.0] },
            ProfileStep::Line { to: [0.0, 12.0] },
        ])
        .expect("valid")
    }

    /// Rays along x, y and z through a 24 × 24 grid over the cutter's box (1,728 rays).
    fn rays(c: &dyn Cutter) -> Vec<(Point3, usize)> {
        let b = c.bounds();
        let mut out = Vec::new();
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for i in 0..24 {
                for j in 0..24 {
                    let mut o = Point3::origin();
                    o[u] = b.min[u] + (b.max[u] - b.min[u]) * (i as Real + 0.5) / 24.0;
                    o[v] = b.min[v] + (b.max[v] - b.min[v]) * (j as Real + 0.5) / 24.0;
                    out.push((o, axis));
                }
            }
        }
        out
    }

    fn run(c: &dyn Cutter, rays: &[(Point3, usize)], out: &mut Vec<RayCut>) -> usize {
        let mut hits = 0;
        for (o, axis) in rays {
            out.clear();
            c.ray_cuts(o, *axis, out);
            hits += out.len();
        }
        hits
    }

    pub fn tools(c: &mut Criterion) {
        let start = Point3::new(0.0, 0.0, 0.0);
        let d = Vector3::new(6.0, 2.0, -1.0);
        let v = UnitVector3::new_normalize(Vector3::new(0.1, -0.2, 1.0));
        let flat = Tool::try_new(ToolKind::Flat, 6.0, 12.0).expect("valid");
        let ball = Tool::try_new(ToolKind::Ball, 6.0, 12.0).expect("valid");
        let cases: Vec<(&str, Box<dyn Cutter>)> = vec![
            (
                "flat/sweep-closed-form",
                Box::new(TranslatedTool::new(flat.clone(), start, d, v)),
            ),
            (
                "ball/sweep-closed-form",
                Box::new(TranslatedTool::new(ball.clone(), start, d, v)),
            ),
            (
                "flat/cutter-closed-form",
                Box::new(SweptTool::new(&flat, start, d, v)),
            ),
            (
                "ball/cutter-closed-form",
                Box::new(SweptTool::new(&ball, start, d, v)),
            ),
            (
                "flat/cutter-numeric",
                Box::new(SweptTool::with_method(
                    &flat,
                    start,
                    d,
                    v,
                    PieceMethod::Numeric,
                )),
            ),
            (
                "ball/cutter-numeric",
                Box::new(SweptTool::with_method(
                    &ball,
                    start,
                    d,
                    v,
                    PieceMethod::Numeric,
                )),
            ),
            (
                "bull-nose-r1/cutter",
                Box::new(SweptTool::new(
                    &Tool::try_bull_nose(6.0, 1.0, 12.0).expect("valid"),
                    start,
                    d,
                    v,
                )),
            ),
            (
                "tapered-flat/cutter",
                Box::new(SweptTool::new(
                    &Tool::try_tapered_flat(2.0, 10.0, 12.0).expect("valid"),
                    start,
                    d,
                    v,
                )),
            ),
            (
                "tapered-ball/cutter",
                Box::new(SweptTool::new(
                    &Tool::try_tapered_ball(2.0, 10.0, 12.0).expect("valid"),
                    start,
                    d,
                    v,
                )),
            ),
            (
                "form-profile/cutter",
                Box::new(SweptTool::new(&form_cutter(), start, d, v)),
            ),
        ];
        let mut g = c.benchmark_group("ray_sweep");
        let mut out = Vec::new();
        for (name, cutter) in &cases {
            let rs = rays(cutter.as_ref());
            g.throughput(Throughput::Elements(rs.len() as u64));
            g.bench_with_input(BenchmarkId::from_parameter(name), &rs, |b, rs| {
                b.iter(|| black_box(run(cutter.as_ref(), rs, &mut out)))
            });
        }
        g.finish();
    }
}

// criterion_group! generates an undocumented public function: keep it in a private module.
mod group {
    use criterion::criterion_group;
    criterion_group!(tools, super::bench::tools);
}
criterion_main!(group::tools);
