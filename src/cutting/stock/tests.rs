//! The tri-dexel's unit tests: exact removals, memory budgets, bytes read back, and
//! cutters cut together.

use super::*;

/// An axis-aligned box cutter, exact by construction.
struct BoxCutter(Aabb);

impl Cutter for BoxCutter {
    fn bounds(&self) -> Aabb {
        self.0
    }
    fn ray_cut(&self, origin: &Point3, axis: usize) -> Option<RayCut> {
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        let (t0, t1) = self.0.ray_interval(origin, &e)?;
        (t1 > t0).then_some(RayCut {
            t_in: t0,
            t_out: t1,
            n_in: e,
            n_out: -e,
        })
    }
}

fn unit_box(size: Real) -> Aabb {
    Aabb {
        min: Point3::origin(),
        max: Point3::new(size, size, size),
    }
}

#[test]
fn box_volume_is_exact() {
    let s = TriDexel::new_box(unit_box(10.0), 0.5, 1e9).expect("fits");
    assert!((s.volume() - 1000.0).abs() < 1e-9);
}

#[test]
fn removing_a_box_pocket_is_exact() {
    let mut s = TriDexel::new_box(unit_box(10.0), 0.25, 1e9).expect("fits");
    let pocket = Aabb {
        min: Point3::new(2.0, 2.0, 5.0),
        max: Point3::new(8.0, 8.0, 11.0),
    };
    assert!(s.remove(&BoxCutter(pocket), 7));
    // Pocket faces fall on ray-cell boundaries here, so every grid measures exactly.
    assert!((s.volume() - (1000.0 - 36.0 * 5.0)).abs() < 1e-9);
    // A z ray in the pocket ends at z = 5 with the floor normal +z and line 7.
    let g = &s.grids()[2];
    let segs = g.ray(20, 20);
    assert_eq!(segs.len(), 1);
    assert_eq!(segs[0].hi.t, 5.0);
    assert_eq!(segs[0].hi.normal, [0.0, 0.0, 1.0]);
    assert_eq!(segs[0].hi.line, 7);
}

/// Cutters cut together are taken latest first, but where two cuts end exactly at the
/// same point the crossing is the earlier cutter's, as in program order: two pockets
/// with the same floor (z = 5) overlapping in x, y ∈ [4, 6], cut after a third that
/// made the floor of x, y ∈ [5, 7] before the batch. In the overlap of the two the
/// floor carries line 1 (the first pocket; the second then met the floor and changed
/// nothing), where the third pocket was first it keeps line 9, and elsewhere each
/// pocket's own line; the whole stock is that of the three removed one by one.
#[test]
fn cutters_cut_together_keep_the_earlier_cutters_crossing_where_cuts_end_alike() {
    let pocket = |lo: Real, hi: Real| {
        BoxCutter(Aabb {
            min: Point3::new(lo, lo, 5.0),
            max: Point3::new(hi, hi, 11.0),
        })
    };
    let (first, second, before) = (pocket(2.0, 6.0), pocket(4.0, 8.0), pocket(5.0, 7.0));
    let mut together = TriDexel::new_box(unit_box(10.0), 0.25, 1e9).expect("fits");
    assert!(together.remove(&before, 9));
    let mut in_turn = together.clone();
    let removed = together.remove_each(&[(&first, 1), (&second, 2)], &[]);
    assert_eq!(removed.by_cutter, [true, true]);
    assert!(in_turn.remove(&first, 1) && in_turn.remove(&second, 2));
    // A z ray at (x, y) = (0.25·iu, 0.25·iv) + 0.125: the floor's line.
    let floor = |s: &TriDexel, iu: usize, iv: usize| {
        let segs = s.grids()[2].ray(iu, iv);
        assert_eq!(segs.len(), 1, "ray ({iu}, {iv})");
        assert_eq!(segs[0].hi.t, 5.0);
        segs[0].hi.line
    };
    for s in [&together, &in_turn] {
        assert_eq!(floor(s, 18, 18), 1, "x, y = 4.6: both pockets, the first's");
        assert_eq!(
            floor(s, 22, 22),
            9,
            "x, y = 5.6: the pocket cut before the batch"
        );
        assert_eq!(floor(s, 12, 12), 1, "x, y = 3.1: the first pocket only");
        assert_eq!(floor(s, 30, 30), 2, "x, y = 7.6: the second pocket only");
    }
    for (a, b) in together.grids().iter().zip(in_turn.grids()) {
        let (nu, nv) = a.dims();
        for (iu, iv) in (0..nu).flat_map(|iu| (0..nv).map(move |iv| (iu, iv))) {
            assert_eq!(
                a.ray(iu, iv),
                b.ray(iu, iv),
                "axis {} ray ({iu}, {iv})",
                a.axis()
            );
        }
    }
}

#[test]
fn refuses_a_pitch_beyond_the_budget() {
    let err = TriDexel::new_box(unit_box(100.0), 1e-4, 24e9).expect_err("too big");
    match err {
        StockError::TooMuchMemory {
            suggested_pitch, ..
        } => {
            // The suggested pitch must itself fit.
            assert!(estimate_bytes(&unit_box(100.0), suggested_pitch) <= 24e9);
        }
        other => panic!("unexpected {other:?}"),
    }
}

#[test]
fn a_budget_no_pitch_fits_says_so_instead_of_suggesting_inf() {
    // Once ruled by 1/pitch², a zero budget suggested "a pitch of at least inf mm".
    let b = unit_box(10.0);
    for budget in [0.0, 1.0, BYTES_PER_RAY] {
        match check_memory(&b, 0.1, budget) {
            Err(e @ StockError::NoPitchFits { .. }) => {
                let text = e.to_string();
                assert!(text.contains("one ray per grid"), "{text}");
                assert!(!text.contains("inf"), "{text}");
            }
            other => panic!("budget {budget}: {other:?}"),
        }
    }
    // Three rays fit exactly: the suggestion is the pitch from which each grid of the
    // 10 mm cube holds one ray, round(10/p) = 1, i.e. p > 10/1.5 mm, to three digits.
    match check_memory(&b, 0.1, 3.0 * BYTES_PER_RAY) {
        Err(StockError::TooMuchMemory {
            suggested_pitch, ..
        }) => {
            assert!((suggested_pitch - 6.67).abs() < 1e-9, "{suggested_pitch}");
            assert!(check_memory(&b, suggested_pitch, 3.0 * BYTES_PER_RAY).is_ok());
        }
        other => panic!("{other:?}"),
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 2000, failure_persistence: None, rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed), ..Default::default() })]
    /// Over any box, pitch and budget: the stock fits, or the suggested pitch is finite,
    /// fits, and one unit less in its third significant digit does not; or no pitch fits
    /// and the coarsest grid is indeed over the budget.
    #[test]
    fn the_suggested_pitch_is_finite_and_the_finest_that_fits(
        ex in -3.0..4.0f64, ey in -3.0..4.0f64, ez in -3.0..4.0f64,
        lp in -4.0..1.0f64, lb in -1.0..12.0f64, zero in proptest::bool::weighted(0.05),
    ) {
        let b = Aabb {
            min: Point3::origin(),
            max: Point3::new(10f64.powf(ex), 10f64.powf(ey), 10f64.powf(ez)),
        };
        let pitch = 10f64.powf(lp);
        let budget = if zero { 0.0 } else { 10f64.powf(lb) };
        match check_memory(&b, pitch, budget) {
            Ok(()) => proptest::prop_assert!(estimate_bytes(&b, pitch) <= budget),
            Err(StockError::TooMuchMemory { suggested_pitch: s, needed_mib, budget_mib, .. }) => {
                proptest::prop_assert!(s.is_finite() && s > pitch, "{s}");
                proptest::prop_assert!(needed_mib > budget_mib);
                proptest::prop_assert!(check_memory(&b, s, budget).is_ok(), "{s} does not fit");
                let unit = 10f64.powi(s.log10().floor() as i32 - 2);
                proptest::prop_assert!(
                    estimate_bytes(&b, s - unit) > budget,
                    "{} fits too: {s} is not the finest", s - unit
                );
                // The message prints the suggestion as it is.
                let text = check_memory(&b, pitch, budget).expect_err("over").to_string();
                proptest::prop_assert!(text.ends_with(&format!("at least {} mm", sig3(s))), "{text}");
                proptest::prop_assert!(!text.contains("inf") && !text.contains("NaN"), "{text}");
            }
            Err(StockError::NoPitchFits { least_mib, budget_mib }) => {
                proptest::prop_assert!(least_mib > budget_mib);
                proptest::prop_assert!(estimate_bytes(&b, 1e12) > budget);
            }
            Err(other) => proptest::prop_assert!(false, "{other:?}"),
        }
    }
}

#[test]
fn result_is_independent_of_thread_count() {
    let run = |threads| {
        crate::math::in_pool(threads, || {
            let mut s = TriDexel::new_box(unit_box(10.0), 0.1, 1e9).expect("fits");
            let pocket = Aabb {
                min: Point3::new(2.05, 1.33, 5.01),
                max: Point3::new(8.7, 8.2, 11.0),
            };
            s.remove(&BoxCutter(pocket), 1);
            let mut all = Vec::new();
            for g in s.grids() {
                g.for_each_crossing(|p, c| all.push((p, *c)));
            }
            all
        })
    };
    assert_eq!(run(1), run(2));
}

/// Every crossing of `s` with its point, in grid order.
fn all_crossings(s: &TriDexel) -> Vec<(Point3, Crossing)> {
    let mut all = Vec::new();
    for g in s.grids() {
        g.for_each_crossing(|p, c| all.push((p, *c)));
    }
    all
}

#[test]
fn bytes_read_back_to_the_same_stock_and_damage_is_refused() {
    // A box with a pocket (blocks touched and untouched, rays with two segments).
    let mut s = TriDexel::new_box(unit_box(10.0), 0.3, 1e9).expect("fits");
    let pocket = Aabb {
        min: Point3::new(2.05, -1.0, 5.01),
        max: Point3::new(8.7, 8.2, 7.0),
    };
    s.remove(&BoxCutter(pocket), 7);
    let bytes = s.to_bytes();
    let back = TriDexel::from_bytes(&bytes).expect("reads back");
    assert_eq!(all_crossings(&back), all_crossings(&s));
    assert_eq!(back.bounds(), s.bounds());
    assert_eq!(back.volume().to_bits(), s.volume().to_bits());
    // The pocket's volume, independently: 6.65 × 8.2 (from y = 0) × 1.99 mm, within
    // the rays' coverage of its sides (half a 0.3 mm pitch each way: under 15 %).
    let removed = 1000.0 - back.volume();
    let exact = 6.65 * 8.2 * 1.99;
    assert!((removed - exact).abs() < 0.15 * exact, "{removed}");
    // Any flipped bit, a cut short or a longer file: refused.
    for at in [0, 9, bytes.len() / 3, bytes.len() / 2, bytes.len() - 1] {
        let mut bad = bytes.clone();
        bad[at] ^= 0x10;
        assert!(TriDexel::from_bytes(&bad).is_none(), "flip at {at}");
    }
    assert!(TriDexel::from_bytes(&bytes[..bytes.len() - 9]).is_none());
    assert!(TriDexel::from_bytes(&[]).is_none());
    let mut long = bytes.clone();
    long.push(0);
    assert!(TriDexel::from_bytes(&long).is_none());
}
