//! Unit tests of the sweep: the closed form and the driver against brute-force
//! point-in-sweep sampling, thread-count independence, benchmark P1's exact areas.
//!
//! **Invariant:** expected values come from independent derivations, never from the
//! program's output.

use super::*;
use crate::cutting::stock::Crossing;
use crate::progress::NoProgress;
use proptest::prelude::*;

fn flat(d: Real, l: Real) -> Tool {
    Tool::try_new(ToolKind::Flat, d, l).expect("valid")
}

/// Brute force: is `x` inside the tool translated to any s ∈ [0,1]? (dense s sampling)
fn inside_brute(t: &TranslatedTool, x: &Point3, samples: usize) -> bool {
    (0..=samples).any(|i| {
        let s = i as Real / samples as Real;
        let w = x - (t.start + t.d * s);
        let h = t.v.dot(&w);
        let r = (w - t.v.into_inner() * h).norm();
        t.tool.contains(r, h)
    })
}

#[test]
fn side_cut_interval_is_the_tangent_plane() {
    // Tool axis z, moving along x from (-10, 0, 0) to (10, 0, 0), radius 3.
    let t = TranslatedTool::new(
        flat(6.0, 20.0),
        Point3::new(-10.0, 0.0, 0.0),
        Vector3::new(20.0, 0.0, 0.0),
        Vector3::z_axis(),
    );
    let c = t.ray_cut(&Point3::new(0.0, 0.0, 5.0), 1).expect("cuts");
    assert_eq!((c.t_in, c.t_out), (-3.0, 3.0));
    assert!((c.n_in - Vector3::y()).norm() < 1e-12);
    // Below the tip: nothing.
    assert!(t.ray_cut(&Point3::new(0.0, 0.0, -0.5), 1).is_none());
    // A z ray through the floor: from the tip up to the top.
    let c = t.ray_cut(&Point3::new(5.0, 1.0, 0.0), 2).expect("cuts");
    assert!((c.t_in - 0.0).abs() < 1e-12 && (c.t_out - 20.0).abs() < 1e-12);
    // The material below the floor faces up, into the cut.
    assert!(
        (c.n_in - Vector3::z()).norm() < 1e-12,
        "floor normal {:?}",
        c.n_in
    );
}

#[test]
fn ray_cut_agrees_with_brute_force_on_random_sweeps() {
    let rng = crate::math::CounterRng::new(11);
    let mut k = 0u64;
    let mut next = || {
        k += 1;
        rng.uniform(k, 0) * 2.0 - 1.0
    };
    for case in 0..30 {
        let kind = if case % 2 == 0 {
            ToolKind::Flat
        } else {
            ToolKind::Ball
        };
        let tool = Tool::try_new(kind, 4.0, 8.0).expect("valid");
        let v = UnitVector3::new_normalize(Vector3::new(next() * 0.6, next() * 0.6, 1.0));
        let start = Point3::new(next() * 3.0, next() * 3.0, next() * 3.0);
        let d = Vector3::new(next() * 8.0, next() * 8.0, next() * 4.0);
        let t = TranslatedTool::new(tool, start, d, v);
        for _ in 0..30 {
            let axis = (next().abs() * 3.0) as usize % 3;
            let o = Point3::new(next() * 8.0, next() * 8.0, next() * 8.0);
            let mut e = Vector3::zeros();
            e[axis] = 1.0;
            let cut = t.ray_cut(&o, axis);
            // Sample along the ray; points well inside/outside the interval must agree.
            for i in 0..200 {
                let tt = -20.0 + 40.0 * i as Real / 200.0;
                let x = o + e * tt;
                let inside = inside_brute(&t, &x, 4000);
                let margin = 0.02;
                match cut {
                    Some(c) if tt > c.t_in + margin && tt < c.t_out - margin => {
                        assert!(inside, "case {case}: t={tt} should be inside {c:?}")
                    }
                    Some(c) if tt < c.t_in - margin || tt > c.t_out + margin => {
                        assert!(!inside, "case {case}: t={tt} should be outside {c:?}")
                    }
                    None => assert!(!inside, "case {case}: t={tt} inside but no cut"),
                    _ => {}
                }
            }
        }
    }
}

/// The nominal 3-axis machine of benchmark P1 (Y table, X carriage, Z spindle).
fn xyz_chain() -> Chain {
    Chain::cartesian([AxisLetter::Y, AxisLetter::X, AxisLetter::Z]).expect("valid chain")
}

fn linear(start: AxisValues, end: AxisValues, line: usize) -> Move {
    Move {
        kind: MoveKind::Linear,
        start,
        end,
        feed_mm_per_min: Some(600.0),
        line,
    }
}

fn opts() -> SweepOptions {
    SweepOptions {
        rotary_step_bound_mm: tol::ROTARY_STEP_BOUND,
    }
}

/// Every crossing of the stock with its point, in a fixed order.
fn crossings(s: &TriDexel) -> Vec<(Point3, Crossing)> {
    let mut all = Vec::new();
    for g in s.grids() {
        g.for_each_crossing(|p, c| all.push((p, *c)));
    }
    all
}

/// Brute-force membership in a flat or ball end mill of radius `r`, length `l` (tip at
/// the origin, axis +z), written out from the tool's definition and offset by `delta`
/// (> 0 grows the tool, < 0 shrinks it: the flat's dilation is a superset of the true
/// one, its erosion and both of the ball's are exact).
fn in_tool(ball: bool, r: Real, l: Real, p: &Point3, delta: Real) -> bool {
    let rad = (p.x * p.x + p.y * p.y).sqrt();
    if p.z < -delta || p.z > l + delta {
        return false;
    }
    if ball && p.z < r {
        (rad * rad + (r - p.z) * (r - p.z)).sqrt() <= r + delta
    } else {
        rad <= r + delta && (delta >= 0.0 || p.z >= -delta)
    }
}

/// A move's tool poses sampled every `step` mm of tip travel (at least the two ends).
fn sampled_poses(chain: &Chain, mv: &Move, step: Real) -> Vec<Isometry3> {
    let a = chain.w_from_t(&mv.start) * Point3::origin();
    let b = chain.w_from_t(&mv.end) * Point3::origin();
    let n = (((b - a).norm() / step).ceil() as usize).max(1);
    (0..=n)
        .map(|i| pose_at(chain, mv, i as Real / n as Real).inverse())
        .collect()
}

/// Is `x` in the sweep of a move (poses from [`sampled_poses`]), the tool offset by `delta`?
fn in_sweep(poses: &[Isometry3], ball: bool, r: Real, l: Real, x: &Point3, delta: Real) -> bool {
    poses
        .iter()
        .any(|t_from_w| in_tool(ball, r, l, &(t_from_w * x), delta))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Random programs of straight moves (some split into collinear pieces, which the
    /// sweep joins), flat or ball, tool axis tilted by a constant A: along every ray,
    /// points clear of the crossings agree with a brute-force point-in-sweep test, and
    /// every crossing names the earliest move whose tool reaches it.
    #[test]
    fn sweep_agrees_with_brute_force(
        ball in any::<bool>(),
        radius in 1.0..2.0f64,
        a_deg in prop_oneof![Just(0.0), -30.0..30.0f64],
        points in proptest::collection::vec((-4.0..4.0f64, -4.0..4.0f64, -2.0..3.0f64), 2..5),
        splits in proptest::collection::vec(1usize..4, 4),
    ) {
        let chain = crate::machine::chain::mdx50_for_tests();
        let kind = if ball { ToolKind::Ball } else { ToolKind::Flat };
        let (r, l) = (radius, 10.0);
        let tool = Tool::try_new(kind, 2.0 * r, l).expect("valid");
        let at = |p: &(Real, Real, Real)| {
            AxisValues::default()
                .with(AxisLetter::X, p.0)
                .with(AxisLetter::Y, p.1)
                .with(AxisLetter::Z, p.2)
                .with(AxisLetter::A, a_deg)
        };
        // Each leg between random points cut as 1 to 3 collinear pieces.
        let mut moves = Vec::new();
        for (w, &n) in points.windows(2).zip(&splits) {
            let (p, q) = (at(&w[0]), at(&w[1]));
            for k in 0..n {
                let lerp = |f: Real| {
                    let mut v = p;
                    for axis in [AxisLetter::X, AxisLetter::Y, AxisLetter::Z] {
                        v.set(axis, p.get(axis) + (q.get(axis) - p.get(axis)) * f);
                    }
                    v
                };
                let (s0, s1) = (k as Real / n as Real, (k + 1) as Real / n as Real);
                let start = if k == 0 { p } else { lerp(s0) };
                let end = if k + 1 == n { q } else { lerp(s1) };
                moves.push(linear(start, end, moves.len() + 1));
            }
        }
        let bounds = Aabb {
            min: Point3::new(-4.0, -4.0, -3.0),
            max: Point3::new(4.0, 4.0, 3.0),
        };
        let mut stock = TriDexel::new_box(bounds, 0.5, 1e9).expect("fits");
        let rep = sweep_program(&mut stock, &chain, &tool, &moves, &opts(), &NoProgress)
            .expect("sweeps");
        prop_assert_eq!(rep.moves, moves.len());
        prop_assert!(rep.sweeps < points.len());
        let delta = 0.02;
        let poses: Vec<_> = moves.iter().map(|m| sampled_poses(&chain, m, delta / 4.0)).collect();
        let near = |x: &Point3, k: usize| {
            let a = chain.w_from_t(&moves[k].start) * Point3::origin();
            let b = chain.w_from_t(&moves[k].end) * Point3::origin();
            let ab = b - a;
            let f = if ab.norm_squared() > 0.0 {
                ((x - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (x - (a + ab * f)).norm() <= l + r + 1.0
        };
        let deep = |x: &Point3, k: usize| near(x, k) && in_sweep(&poses[k], ball, r, l, x, -delta);
        let reached = |x: &Point3, k: usize| near(x, k) && in_sweep(&poses[k], ball, r, l, x, delta);
        for g in stock.grids() {
            let (nu, nv) = g.dims();
            let axis = g.axis();
            for iv in 0..nv {
                for iu in 0..nu {
                    let o = g.ray_origin(iu, iv);
                    let segs = g.ray(iu, iv);
                    let mut t = bounds.min[axis] + 0.01;
                    while t < bounds.max[axis] {
                        let clear = segs.iter().all(|s| {
                            (s.lo.t - t).abs() > delta && (s.hi.t - t).abs() > delta
                        });
                        if clear {
                            let mut x = o;
                            x[axis] = t;
                            let material = segs.iter().any(|s| s.lo.t < t && t < s.hi.t);
                            if material {
                                prop_assert!(
                                    !(0..moves.len()).any(|k| deep(&x, k)),
                                    "material at {x:?} lies inside the sweep"
                                );
                            } else {
                                prop_assert!(
                                    (0..moves.len()).any(|k| reached(&x, k)),
                                    "no material at {x:?} outside the sweep"
                                );
                            }
                        }
                        t += 0.25;
                    }
                }
            }
        }
        for (x, c) in crossings(&stock) {
            if c.line == 0 {
                continue;
            }
            let k = c.line as usize - 1;
            prop_assert!(reached(&x, k), "crossing {x:?} of line {} off its move", c.line);
            prop_assert!(
                !(0..k).any(|j| deep(&x, j)),
                "crossing {x:?} of line {} lies inside an earlier move", c.line
            );
        }
    }
}

/// Joined sweeps of a tilted tool in fixed chunks: one and two worker threads give
/// bit-identical stocks (every crossing's t, normal and line).
#[test]
fn sweep_is_bit_identical_for_one_and_two_threads() {
    let chain = crate::machine::chain::mdx50_for_tests();
    let tool = Tool::try_new(ToolKind::Ball, 3.0, 10.0).expect("valid");
    let at = |x: Real, y: Real, z: Real, a: Real| AxisValues::from_array([x, y, z, a, 0.0, 0.0]);
    let pts = [
        at(-6.0, -4.0, 4.0, 10.0),
        at(-6.0, -4.0, 1.0, 10.0),
        at(-3.0, -4.0, 1.0, 10.0),
        at(0.0, -4.0, 1.0, 10.0),
        at(6.0, -4.0, 1.0, 10.0),
        at(6.0, -2.5, 1.0, 10.0),
        at(-6.0, -2.5, 1.5, 10.0),
        at(2.0, 3.0, 0.0, 10.0),
    ];
    let moves: Vec<Move> = pts
        .windows(2)
        .enumerate()
        .map(|(k, w)| linear(w[0], w[1], k + 1))
        .collect();
    let run = |threads| {
        crate::math::in_pool(threads, || {
            let bounds = Aabb {
                min: Point3::new(-8.0, -8.0, -4.0),
                max: Point3::new(8.0, 8.0, 4.0),
            };
            let mut s = TriDexel::new_box(bounds, 0.05, 1e9).expect("fits");
            sweep_program(&mut s, &chain, &tool, &moves, &opts(), &NoProgress).expect("sweeps");
            crossings(&s)
        })
    };
    let one = run(1);
    assert!(one.iter().any(|(_, c)| c.line == 3), "the joined run cut");
    assert_eq!(one, run(2));
}

/// Benchmark P1-flat (docs/benchmarks.md) at 0.05 mm: the removed volume is 1.5 mm times
/// the exact area of the 3 mm offset of the path, within 0.01 %.
#[test]
fn p1_flat_removes_the_offset_area_times_the_depth() {
    let tool = Tool::try_new(ToolKind::Flat, p1::TOOL_DIAMETER, 30.0).expect("valid");
    let mut s = TriDexel::new_box(p1::stock_box(), 0.05, 1e9).expect("fits");
    let v0 = s.volume();
    let moves = p1::moves();
    let rep =
        sweep_program(&mut s, &xyz_chain(), &tool, &moves, &opts(), &NoProgress).expect("sweeps");
    assert_eq!(rep.moves, 3321);
    // The plunge and the 81 straight runs of the path.
    assert_eq!(rep.sweeps, 82);
    let truth = (20.0 - p1::Z_CUT) * p1::offset_area(p1::TOOL_DIAMETER / 2.0);
    let removed = v0 - s.volume();
    assert!(
        ((removed - truth) / truth).abs() < 1e-4,
        "removed {removed} mm³, truth {truth} mm³"
    );
}

/// Benchmark P1-ball at 0.05 mm: the z rays' top crossings lie on the analytic surface
/// h(x, y) = min over the straight runs of z_tip + R − sqrt(R² − d²) (≤ 1 µm RMS); the
/// scallop between rows 2 mm apart is R − sqrt(R² − 1) high (within 1 µm); and the
/// tri-dexel holds at most 300 MB.
#[test]
fn p1_ball_surface_is_exact_in_bounded_memory() {
    let tool = Tool::try_new(ToolKind::Ball, p1::TOOL_DIAMETER, 30.0).expect("valid");
    // The box grown by half a pitch puts z rays on multiples of 0.05 mm, so on the crest
    // lines y = 11, 13, … between the rows.
    let mut bx = p1::stock_box();
    bx.min.x -= 0.025;
    bx.min.y -= 0.025;
    bx.max.x += 0.025;
    bx.max.y += 0.025;
    let mut s = TriDexel::new_box(bx, 0.05, 1e9).expect("fits");
    sweep_program(
        &mut s,
        &xyz_chain(),
        &tool,
        &p1::moves(),
        &opts(),
        &NoProgress,
    )
    .expect("sweeps");
    let r = p1::TOOL_DIAMETER / 2.0;
    let runs = p1::runs();
    let height = |x: Real, y: Real| {
        runs.iter()
            .filter_map(|&((x0, y0), (x1, y1))| {
                let (dx, dy) = (x1 - x0, y1 - y0);
                let f = (((x - x0) * dx + (y - y0) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
                let d = (x - x0 - f * dx).hypot(y - y0 - f * dy);
                (d < r).then(|| p1::Z_CUT + r - (r * r - d * d).sqrt())
            })
            .fold(Real::INFINITY, Real::min)
    };
    let g = &s.grids()[2];
    let (nu, nv) = g.dims();
    let (mut sum2, mut n) = (0.0, 0usize);
    let mut crest: Real = 0.0;
    for iv in 0..nv {
        for iu in 0..nu {
            let o = g.ray_origin(iu, iv);
            let h = height(o.x, o.y);
            if h < 20.0 - tol::SLIVER {
                let top = g
                    .ray(iu, iv)
                    .last()
                    .expect("material below the pocket")
                    .hi
                    .t;
                sum2 += (top - h) * (top - h);
                n += 1;
                // Between rows, away from the step-overs.
                if (20.0..=80.0).contains(&o.x) && (11.0..=89.0).contains(&o.y) {
                    crest = crest.max(top - p1::Z_CUT);
                }
            }
        }
    }
    let rms = (sum2 / n as Real).sqrt();
    assert!(n > 2_000_000, "{n} rays in the pocket");
    assert!(rms <= 1e-3, "RMS {rms} mm");
    assert!(
        s.memory_bytes() <= 300_000_000,
        "{} bytes",
        s.memory_bytes()
    );
    let scallop = r - (r * r - 1.0).sqrt();
    assert!(
        (crest - scallop).abs() <= 1e-3,
        "scallop {crest} mm, formula {scallop} mm"
    );
}

/// An observer that looks (so the driver cuts every move on its own) and counts the moves
/// it is shown.
struct Counting(usize);

impl SweepObserver for Counting {
    fn after_move(
        &mut self,
        _: &TriDexel,
        _: usize,
        _: &Move,
        _: &Piece,
    ) -> Result<(), SweepError> {
        self.0 += 1;
        Ok(())
    }
}

/// The plain sweep cuts runs of envelope moves together; an observer that looks has them
/// cut one by one. A program of 40 small A turns (more than two batches), a straight move
/// in their middle and more turns after it leaves the same crossings bit for bit and the
/// same report either way, and the observer is shown every move.
#[test]
fn envelope_moves_cut_together_match_moves_cut_one_by_one() {
    let chain = crate::machine::chain::mdx50_for_tests();
    let tool = Tool::try_new(ToolKind::Flat, 3.0, 10.0).expect("valid");
    let at = |k: usize| {
        let k = k as Real;
        AxisValues::from_array([-4.0 + 0.2 * k, -1.0, 1.5 - 0.02 * k, -20.0 + k, 0.0, 0.0])
    };
    let mut moves: Vec<Move> = (0..40).map(|k| linear(at(k), at(k + 1), k + 1)).collect();
    let mut side = at(40);
    side.set(AxisLetter::Y, 1.0);
    moves.push(linear(at(40), side, 41));
    let mut back = side;
    back.set(AxisLetter::A, 10.0);
    moves.push(linear(side, back, 42));
    let bounds = Aabb {
        min: Point3::new(-8.0, -8.0, -4.0),
        max: Point3::new(8.0, 8.0, 4.0),
    };
    let stock = TriDexel::new_box(bounds, 0.1, 1e9).expect("fits");
    let mut together = stock.clone();
    let plain =
        sweep_program(&mut together, &chain, &tool, &moves, &opts(), &NoProgress).expect("sweeps");
    let mut one_by_one = stock;
    let mut seen = Counting(0);
    let watched = sweep_observed(
        &mut one_by_one,
        &chain,
        &tool,
        &moves,
        &opts(),
        &NoProgress,
        &mut seen,
    )
    .expect("sweeps");
    assert_eq!(seen.0, moves.len());
    assert_eq!(plain, watched);
    assert_eq!(plain.rotary_moves, 41);
    assert!(plain.cutting_moves > 20, "{plain:?}");
    assert_eq!(crossings(&together), crossings(&one_by_one));
}

/// Records the calls it gets in order — whether before a rapid, the move's index — and the
/// crossings of the stock each rapid meets; looks after moves or not as asked.
struct Recording {
    looks: bool,
    calls: Vec<(bool, usize)>,
    met: Vec<Vec<(Point3, Crossing)>>,
}

impl SweepObserver for Recording {
    fn before_rapid(
        &mut self,
        stock: &TriDexel,
        k: usize,
        _: &Move,
        _: &Piece,
    ) -> Result<(), SweepError> {
        self.calls.push((true, k));
        self.met.push(crossings(stock));
        Ok(())
    }

    fn after_move(
        &mut self,
        _: &TriDexel,
        k: usize,
        _: &Move,
        _: &Piece,
    ) -> Result<(), SweepError> {
        self.calls.push((false, k));
        Ok(())
    }

    fn looks(&self) -> bool {
        self.looks
    }
}

/// An observer that checks only rapids (the collision checks without a holder or fixtures)
/// has the envelope moves between rapids cut together, but each rapid still meets the stock
/// every move before it left: 20 small A turns, a rapid turning A back through the
/// material, 20 more turns and a second rapid. The calls come in the same order, each rapid
/// sees the same crossings as with an observer that looks after every move (and more
/// material gone than at the start: the turns before it cut), and the part is the same bit
/// for bit.
#[test]
fn rapids_meet_the_stock_every_earlier_move_left_when_moves_are_cut_together() {
    let chain = crate::machine::chain::mdx50_for_tests();
    let tool = Tool::try_new(ToolKind::Flat, 3.0, 10.0).expect("valid");
    let at = |k: usize, a: Real| {
        let k = k as Real;
        AxisValues::from_array([-4.0 + 0.2 * k, -1.0, 1.5 - 0.02 * k, a, 0.0, 0.0])
    };
    let mut moves = Vec::new();
    for k in 0..20 {
        moves.push(linear(at(k, k as Real), at(k + 1, k as Real + 1.0), k + 1));
    }
    let mut rapid = linear(at(20, 20.0), at(21, 5.0), 21);
    rapid.kind = MoveKind::Rapid;
    moves.push(rapid);
    for k in 21..41 {
        let a = 5.0 + (k - 21) as Real;
        moves.push(linear(at(k, a), at(k + 1, a + 1.0), k + 1));
    }
    let mut back = linear(at(41, 25.0), at(42, 0.0), 42);
    back.kind = MoveKind::Rapid;
    moves.push(back);
    let bounds = Aabb {
        min: Point3::new(-8.0, -8.0, -4.0),
        max: Point3::new(8.0, 8.0, 4.0),
    };
    let stock = TriDexel::new_box(bounds, 0.1, 1e9).expect("fits");
    let fresh = crossings(&stock);
    let run = |looks: bool| {
        let mut part = stock.clone();
        let mut seen = Recording {
            looks,
            calls: Vec::new(),
            met: Vec::new(),
        };
        let report = sweep_observed(
            &mut part,
            &chain,
            &tool,
            &moves,
            &opts(),
            &NoProgress,
            &mut seen,
        )
        .expect("sweeps");
        (report, crossings(&part), seen)
    };
    let (r_all, part_all, all) = run(true);
    let (r_rapids, part_rapids, rapids) = run(false);
    let expected: Vec<(bool, usize)> = (0..moves.len())
        .flat_map(|k| {
            let rapid = moves[k].kind == MoveKind::Rapid;
            [(true, k), (false, k)]
                .into_iter()
                .filter(move |c| rapid || !c.0)
        })
        .collect();
    assert_eq!(all.calls, expected);
    assert_eq!(rapids.calls, expected);
    assert_eq!(all.met.len(), 2);
    for (a, b) in all.met.iter().zip(&rapids.met) {
        assert_ne!(*a, fresh, "the turns before a rapid cut");
        assert!(a == b, "a rapid met another stock");
    }
    assert_eq!(r_all, r_rapids);
    assert_eq!(r_all.rotary_moves, 42);
    assert!(part_all == part_rapids, "another part");
}

use crate::machine::chain::ChainPoses;

/// Moves of a machine read pose by pose are cut by the envelope of the curve through
/// their pilot poses. The same chain cut as a chain (its own exact envelope, validated
/// against brute force) and read pose by pose: every crossing on the same ray, the normal
/// distance between them within the sampled run's stated bound plus the chain's envelope
/// tolerance; one move per envelope, none in sub-steps — a move that turns 1e-6° as well.
#[test]
fn a_pose_source_cut_by_its_curve_envelope_matches_the_chain() {
    let chain = crate::machine::chain::mdx50_for_tests();
    let tool = Tool::try_new(ToolKind::Flat, 3.0, 10.0).expect("valid");
    let ball = Tool::try_new(ToolKind::Ball, 3.0, 10.0).expect("valid");
    // A turning 1° a move while X, Z move (some moves large: 6° and 2 mm).
    let at = |k: usize| {
        let k = k as Real;
        AxisValues::from_array([-4.0 + 0.2 * k, -1.0, 1.5 - 0.03 * k, -20.0 + k, 0.0, 0.0])
    };
    let mut moves: Vec<Move> = (0..30).map(|k| linear(at(k), at(k + 1), k + 1)).collect();
    let mut far = at(30);
    far.set(AxisLetter::A, 16.0);
    far.set(AxisLetter::X, 4.0);
    moves.push(linear(at(30), far, 31));
    // Nearly a translation: A turns 1e-6° while X travels 8 mm (a corrected straight move).
    let mut back = far;
    back.set(AxisLetter::A, 16.000001);
    back.set(AxisLetter::X, -4.0);
    moves.push(linear(far, back, 32));
    let bounds = Aabb {
        min: Point3::new(-8.0, -8.0, -4.0),
        max: Point3::new(8.0, 8.0, 4.0),
    };
    let source = ChainPoses(chain.clone());
    for tool in [&tool, &ball] {
        let stock = TriDexel::new_box(bounds, 0.1, 1e9).expect("fits");
        let mut exact = stock.clone();
        let chained =
            sweep_program(&mut exact, &chain, tool, &moves, &opts(), &NoProgress).expect("sweeps");
        let mut read = stock;
        let report = sweep_program(
            &mut read,
            Kinematics::Poses(&source),
            tool,
            &moves,
            &opts(),
            &NoProgress,
        )
        .expect("sweeps");
        assert_eq!(report.sweeps, moves.len(), "{report:?}");
        assert!(report.rotary_error_bound_mm <= opts().rotary_step_bound_mm);
        // Each within its own bound of the true motion's surface.
        let tol = report.rotary_error_bound_mm + chained.rotary_error_bound_mm + 1e-9;
        let (a, b) = (crossings(&exact), crossings(&read));
        assert_eq!(a.len(), b.len());
        assert!(a.iter().filter(|(_, c)| c.line != 0).count() > 1000);
        let (mut worst, mut other_line): (Real, usize) = (0.0, 0);
        for ((p, c), (q, d)) in a.iter().zip(&b) {
            let along = q - p;
            let n = c.normal();
            // The same ray (the points differ only along it) and the same line.
            assert!(
                along.iter().filter(|x| x.abs() > 1e-12).count() <= 1,
                "{p} vs {q}"
            );
            // A surface two consecutive moves reach alike (to the tolerance) may be
            // named by either.
            if c.line != d.line {
                other_line += 1;
                assert!(
                    c.line.abs_diff(d.line) == 1,
                    "{p}: lines {} and {}",
                    c.line,
                    d.line
                );
            }
            worst = worst.max(along.dot(&n).abs());
        }
        assert!(worst <= tol, "normal distance {worst} mm > {tol} mm");
        assert!(other_line * 100 < a.len(), "{other_line} of {}", a.len());
    }
}

/// A chain read pose by pose that refuses every pose whose X axis lies beyond `limit`.
struct Reach {
    poses: ChainPoses,
    limit: Real,
}

impl crate::machine::PoseSource for Reach {
    fn has_axis(&self, axis: AxisLetter) -> bool {
        self.poses.has_axis(axis)
    }
    fn w_from_t(&self, q: &AxisValues) -> Result<Isometry3, crate::machine::PoseError> {
        if q.get(AxisLetter::X) > self.limit {
            return Err(crate::machine::PoseError("out of reach".into()));
        }
        self.poses.w_from_t(q)
    }
    fn commanded(&self, q: &AxisValues) -> Isometry3 {
        self.poses.commanded(q)
    }
    fn is_translation(&self, start: &AxisValues, end: &AxisValues) -> bool {
        self.poses.is_translation(start, end)
    }
}

/// A pose source's moves are prepared ahead of the cut, several at a time: a move the
/// machine cannot take, far past the first stretch prepared, still stops the sweep at its
/// own line, with exactly the moves before it cut and nothing after it; and a program the
/// machine can take comes out the same whether or not a refusal lies ahead of a move.
#[test]
fn a_pose_source_move_out_of_reach_stops_the_sweep_at_its_line() {
    let chain = crate::machine::chain::mdx50_for_tests();
    let tool = Tool::try_new(ToolKind::Flat, 3.0, 10.0).expect("valid");
    // A turning 1° a move while X creeps 0.1 mm: X passes 3.0 on move 71 (line 71).
    let at = |k: usize| {
        let k = k as Real;
        AxisValues::from_array([-4.0 + 0.1 * k, -1.0, 1.5 - 0.01 * k, -40.0 + k, 0.0, 0.0])
    };
    let moves: Vec<Move> = (0..90).map(|k| linear(at(k), at(k + 1), k + 1)).collect();
    let bounds = Aabb {
        min: Point3::new(-8.0, -8.0, -4.0),
        max: Point3::new(8.0, 8.0, 4.0),
    };
    let stock = TriDexel::new_box(bounds, 0.1, 1e9).expect("fits");
    let refusing = Reach {
        poses: ChainPoses(chain.clone()),
        limit: 3.0,
    };
    let first_out = moves
        .iter()
        .position(|m| m.end.get(AxisLetter::X) > 3.0)
        .expect("a move leaves the reach");
    assert!(first_out > 64, "past the first stretch prepared");
    let mut cut = stock.clone();
    let err = sweep_program(
        &mut cut,
        Kinematics::Poses(&refusing),
        &tool,
        &moves,
        &opts(),
        &NoProgress,
    )
    .expect_err("a move out of reach");
    assert!(
        matches!(err, SweepError::Pose { line, .. } if line == moves[first_out].line),
        "{err}"
    );
    // The moves before it, on a machine that refuses nothing.
    let open = Reach {
        poses: ChainPoses(chain),
        limit: Real::INFINITY,
    };
    let cut_before = |part: &mut TriDexel| {
        sweep_program(
            part,
            Kinematics::Poses(&open),
            &tool,
            &moves[..first_out],
            &opts(),
            &NoProgress,
        )
        .expect("sweeps")
    };
    let mut before = stock.clone();
    cut_before(&mut before);
    assert!(crossings(&cut) == crossings(&before), "another part");
    assert!(
        crossings(&cut).iter().filter(|(_, c)| c.line != 0).count() > 1000,
        "nothing was cut"
    );
    // On the one thread of a pool of one, the same part.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a pool");
    let mut alone = stock;
    pool.install(|| cut_before(&mut alone));
    assert!(
        crossings(&alone) == crossings(&before),
        "another part on one thread"
    );
}

/// A chain's envelopes are built ahead of the cut, 32 moves at a time, each from the
/// reversal shares its move starts from. On a 3-axis machine with error motions and lost
/// motion, a zigzag of 70 moves (X reversing every move, Y swinging back and forth: every
/// move curved by the error motions, its shares set by the ones before) cut by the driver
/// equals, bit
/// for bit, the test's own loop: the shares followed move by move, each move's envelope
/// built from them and cut in turn.
#[test]
fn envelopes_built_ahead_follow_the_reversal_shares_move_by_move() {
    // X, Y, Z with error motions and lost motion on X and Y (as `scenes/xyz-error-motions.toml`
    // has them: scale, a bow, the reversals).
    use crate::machine::error_motion::{AxisErrorMotions, Term};
    let mut chain = crate::machine::chain::xyz_for_tests();
    for (axis, scale, bow, reversal) in [
        (AxisLetter::X, 15e-6, 0.0, -0.003),
        (AxisLetter::Y, -30e-6, 2e-6, -0.002),
    ] {
        let mut e = AxisErrorMotions::for_axis(axis);
        let k = if axis == AxisLetter::X { 0 } else { 1 };
        e.functions[k].terms = vec![Term::polynomial(vec![0.0, scale]).expect("valid")];
        e.functions[2].terms = vec![Term::polynomial(vec![0.0, 0.0, bow]).expect("valid")];
        e.reversal = reversal;
        chain.set_error_motions(axis, e).expect("axis");
    }
    let chain = &chain;
    assert!(chain.has_error_motions());
    let tool = Tool::try_new(ToolKind::Flat, 6.0, 20.0).expect("valid");
    let at = |k: usize| {
        let x = if k.is_multiple_of(2) { 10.0 } else { 14.0 };
        let y = 20.0 + 2.0 * (0.9 * k as Real).sin();
        AxisValues::from_array([x, y, 19.0 - 0.02 * k as Real, 0.0, 0.0, 0.0])
    };
    let moves: Vec<Move> = (0..70).map(|k| linear(at(k), at(k + 1), k + 1)).collect();
    let stock = TriDexel::new_box(
        Aabb {
            min: Point3::new(5.0, 15.0, 15.0),
            max: Point3::new(19.0, 25.0, 20.0),
        },
        0.2,
        1e9,
    )
    .expect("fits");
    let mut driven = stock.clone();
    let report =
        sweep_program(&mut driven, chain, &tool, &moves, &opts(), &NoProgress).expect("sweeps");
    assert_eq!(report.curved_moves, moves.len(), "{report:?}");
    let mut own = stock;
    let mut state = chain.reversal_state(&crate::machine::error_motion::Directions::default());
    let mut shares = std::collections::BTreeSet::new();
    for mv in &moves {
        let before = state;
        state = chain.reversal_after_move(&state, &mv.start, &mv.end);
        shares.insert(before.map(Real::to_bits));
        let env = RotaryEnvelope::with_state(chain, &tool, &mv.start, &mv.end, &before)
            .expect("an envelope")
            .with_tolerance(opts().rotary_step_bound_mm);
        own.remove(&env, mv.line as u32);
    }
    assert_eq!(
        shares.len(),
        4,
        "X's and Y's directions in every combination"
    );
    assert!(crossings(&driven) == crossings(&own), "another part");
    assert!(
        crossings(&own).iter().filter(|(_, c)| c.line != 0).count() > 1000,
        "nothing was cut"
    );
}
