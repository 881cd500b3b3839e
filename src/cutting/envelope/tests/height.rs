//! Unit tests of the swept cull's height-aware test (`cull::AxisSweep`): near misses it
//! clears that the swept halves cannot, and grazing rays it never culls where a pose of the
//! move reaches their material, against the move's poses sampled densely.
//!
//! **Invariant:** expected values come from independent derivations, never from the
//! program's output.

use super::*;

/// Whether any of `poses` (the move of `env`) meets the open stretch `lo`–`hi` of the ray
/// `o + t·e`: the tool's own interval at each pose, no growth.
fn poses_reach(
    env: &RotaryEnvelope,
    poses: &[Sample],
    (o, e): (&Point3, &Vector3),
    (lo, hi): (Real, Real),
) -> bool {
    poses.iter().any(|s| {
        let p = s.rot.tr_mul(&(o - s.tip));
        let w = s.rot.tr_mul(e);
        tool_interval(env.shape, env.r, env.l, &p, &w, 0.0)
            .is_some_and(|(t0, _, t1, _)| t0 < hi && t1 > lo)
    })
}

/// The height-aware swept cull clears near misses and never a ray the tool reaches. On a
/// one-cell move of a long tool (Ø6 × 25 mm, flat and ball) turning A by 0.5° (the tool's
/// ends sweep 0.1 mm more than its middle), for every x and y ray of a 0.05 mm grid that the
/// move's exact envelope meets (one in seven), the material is put just inside and just
/// beyond each end of the envelope's interval:
///
/// - reached by 1 nm, 1 µm or 0.1 mm (the interval's end is a pose's own, so that pose
///   meets the material): the cull must keep the ray, and the swept poses alone keep it too;
/// - missed by 5 µm or 20 µm: the swept poses alone, whose growth holds the tool turning
///   about its middle (`(l/2)·θ` ≈ 27 µm for a half-cell), skip few of these rays, and the
///   cull with the height-aware test skips most of them.
///
/// Every skipped ray is then checked against the move's poses sampled every 1/1024 of it
/// (the tool's own interval at each pose, no growth): none reaches its material.
#[test]
fn the_height_aware_cull_clears_near_misses_and_only_those() {
    use crate::cutting::stock::{Crossing, Segment};
    let c = deviated();
    let end = |t: Real| Crossing {
        t,
        normal: [0.0, 0.0, 1.0],
        line: 0,
    };
    for kind in [ToolKind::Flat, ToolKind::Ball] {
        let tool = Tool::try_new(kind, 6.0, 25.0).expect("valid");
        let env = RotaryEnvelope::new(
            &c,
            &tool,
            &q(-1.0, 0.5, 3.0, 20.0),
            &q(-0.9, 0.5, 3.0, 20.5),
        )
        .expect("supported");
        assert_eq!(env.cells(), 1);
        let swept = env.swept.as_ref().expect("constant rates: the swept cull");
        let rl = (env.shape, env.r, env.l);
        let poses: Vec<Sample> = (0..=1024)
            .map(|k| env.path.sample(k as Real / 1024.0))
            .collect();
        let (mut misses, mut skipped, mut skipped_by_halves) = (0, 0, 0);
        let mut seen = 0usize;
        grid_rays(&env.bounds(), |o, axis, e| {
            seen += 1;
            if axis == 2 || !seen.is_multiple_of(7) {
                return;
            }
            let mut cuts = Vec::new();
            env.intervals(&o, &e, &mut cuts);
            let (Some(first), Some(last)) = (cuts.first(), cuts.last()) else {
                return;
            };
            let (t_in, t_out) = (first.t_in, last.t_out);
            for depth in [1e-6, 1e-3, 0.1] {
                for material in [
                    [Segment {
                        lo: end(t_out - depth),
                        hi: end(t_out + 50.0),
                    }],
                    [Segment {
                        lo: end(t_in - 50.0),
                        hi: end(t_in + depth),
                    }],
                ] {
                    assert!(
                        env.may_cut(&o, axis, &material),
                        "{kind:?}: the ray through {o:?} along axis {axis} is reached                          {depth} mm deep but culled"
                    );
                    assert!(swept.may_cut_by_halves(rl, &o, axis, &material));
                }
            }
            for gap in [5e-3, 2e-2] {
                for material in [
                    [Segment {
                        lo: end(t_out + gap),
                        hi: end(t_out + 50.0),
                    }],
                    [Segment {
                        lo: end(t_in - 50.0),
                        hi: end(t_in - gap),
                    }],
                ] {
                    misses += 1;
                    if !swept.may_cut_by_halves(rl, &o, axis, &material) {
                        skipped_by_halves += 1;
                    }
                    if !env.may_cut(&o, axis, &material) {
                        skipped += 1;
                        assert!(
                            !poses_reach(
                                &env,
                                &poses,
                                (&o, &e),
                                (material[0].lo.t, material[0].hi.t)
                            ),
                            "{kind:?}: the ray through {o:?} along axis {axis} was                              skipped but a pose reaches its material"
                        );
                    }
                }
            }
        });
        assert!(misses > 2000, "{kind:?}: {misses} near misses");
        assert!(
            4 * skipped > 3 * misses && 4 * skipped_by_halves < misses,
            "{kind:?}: of {misses} near misses the cull skips {skipped}, the swept poses \
             alone {skipped_by_halves}"
        );
    }
}

/// The cull keeps every ray a pose of the move reaches, on rays that graze the tool: moves
/// of the trunnion A/C with a long tool (Ø6 × 25 mm, flat and ball) 19 mm from C's line,
/// turning C by 1.5° and A by 0.5° at A 20° and −30°, and A by 0.2° at C 30° (the tool's
/// axis tilts across the rays, and the rays cross it at a slant, so a stretch of material
/// spans a band of heights).
/// Each of 3,000 x and y rays, square to the tool's axis at a random pose and height,
/// passes within 20 µm of where such a ray grazes the move's envelope (found by bisection on
/// the envelope's intervals), and its material runs from 0–4 mm before the grazing point to
/// 0–4 mm after it. Wherever the move's poses, sampled every 1/2048 of it,
/// reach 0.1 nm into the material (the tool's own interval at each pose, no growth), the
/// cull keeps the ray; and it skips a good share of the rest.
#[test]
fn the_cull_keeps_every_ray_a_pose_reaches() {
    use crate::cutting::stock::{Crossing, Segment};
    let c = crate::machine::chain::trunnion_for_tests();
    let at = |z: Real, a: Real, cc: Real| q(0.0, -19.0, z, a).with(AxisLetter::C, cc);
    let end = |t: Real| Crossing {
        t,
        normal: [0.0, 0.0, 1.0],
        line: 0,
    };
    // A fixed stream of uniform numbers in [0, 1) (splitmix64).
    let mut state = 0x5eed_u64;
    let mut uniform = move || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        (z ^ (z >> 31)) as Real / 2f64.powi(64)
    };
    for kind in [ToolKind::Flat, ToolKind::Ball] {
        for (a0, c0, da, dc) in [
            (20.0, 0.0, 0.5, 1.5),
            (-30.0, 250.0, 0.5, 1.5),
            (20.0, 30.0, 0.2, 0.05),
        ] {
            let tool = Tool::try_new(kind, 6.0, 25.0).expect("valid");
            let env =
                RotaryEnvelope::new(&c, &tool, &at(10.0, a0, c0), &at(9.99, a0 + da, c0 + dc))
                    .expect("supported");
            assert!(env.swept.is_some(), "constant rates: the swept cull");
            let poses: Vec<Sample> = (0..=2048)
                .map(|k| env.path.sample(k as Real / 2048.0))
                .collect();
            let (mut reached, mut missed, mut skipped) = (0, 0, 0);
            for _ in 0..3000 {
                let axis = usize::from(uniform() < 0.5);
                let e = Vector3::ith(axis, 1.0);
                // A point of the tool's axis at a random pose and height (on the ball's
                // cylinder for a ball end mill), and the ray square to the axis there,
                // passing within 20 µm of the side.
                let s = env.path.sample(uniform());
                let base = if kind == ToolKind::Ball { env.r } else { 0.0 };
                let z = base + 0.2 + uniform() * (env.l - base - 0.4);
                let centre = s.tip + s.rot * Vector3::new(0.0, 0.0, z);
                let Some(n) = (s.rot * Vector3::z()).cross(&e).try_normalize(1e-6) else {
                    continue;
                };
                // Moved out along n to where it grazes the move's envelope (bisection on the
                // envelope's own intervals), then within 20 µm of that.
                let ray_at = |d: Real| {
                    let off = centre + n * d;
                    off - e * off[axis]
                };
                let meets = |d: Real| {
                    let mut cuts = Vec::new();
                    env.intervals(&ray_at(d), &e, &mut cuts);
                    cuts.first().map(|c| 0.5 * (c.t_in + c.t_out))
                };
                let (mut inside, mut outside) = (0.0, env.r + 2.0);
                if meets(outside).is_some() {
                    continue;
                }
                while outside - inside > 1e-7 {
                    let mid = 0.5 * (inside + outside);
                    if meets(mid).is_some() {
                        inside = mid;
                    } else {
                        outside = mid;
                    }
                }
                let Some(at) = meets(inside) else {
                    continue;
                };
                let o = ray_at(inside + (uniform() - 0.5) * 4e-2);
                let (lo, hi) = (at - 4.0 * uniform(), at + 4.0 * uniform());
                let material = [Segment {
                    lo: end(lo),
                    hi: end(hi),
                }];
                let reaches = poses_reach(&env, &poses, (&o, &e), (lo + 1e-7, hi - 1e-7));
                let may = env.may_cut(&o, axis, &material);
                if reaches {
                    reached += 1;
                    assert!(
                        may,
                        "{kind:?} at A {a0}°: the ray through {o:?} along axis {axis} \
                         with material {lo}–{hi} is reached but culled"
                    );
                } else {
                    missed += 1;
                    skipped += usize::from(!may);
                }
            }
            assert!(
                reached > 500 && missed > 500 && 4 * skipped > missed,
                "{kind:?} at A {a0}°: {reached} reached, {missed} missed, {skipped} skipped"
            );
        }
    }
}
