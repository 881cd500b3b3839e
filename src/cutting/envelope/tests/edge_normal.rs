//! The normal at an interval end the tool's edge circle makes: where the ray's farthest
//! reach over the move is at a kink (the ray passing through the edge), the swept volume's
//! surface there is the one the edge sweeps, and its normal is neither face's.
//!
//! **Invariant:** expected values come from independent derivations, never from the
//! program's output: here the surface through the ends of neighbouring rays, each end found
//! by searching the poses of the chain (the standing tool's closed-form interval, see
//! `exact_at`), not by the envelope.

use super::*;

/// The end of the ray `o + t·e` over the move: the least entry (`out` false) or the
/// greatest exit over the poses, found on 500 poses and then by golden-section search
/// within a sample of the best (the end, a function of λ with one kink or a smooth extreme
/// there, is unimodal on that bracket). `None` where no pose meets the ray, or the best pose
/// is at the move's start or end (no extreme inside the move).
fn brute_end(
    (c, tool, a, b): (&Chain, &Tool, &AxisValues, &AxisValues),
    o: &Point3,
    e: &Vector3,
    out: bool,
) -> Option<(Real, Real)> {
    let n = 500;
    let end = |l: Real| exact_at(c, tool, a, b, l, o, e).map(|(t0, t1)| if out { -t1 } else { t0 });
    let (k, _) = (0..=n)
        .filter_map(|k| end(k as Real / n as Real).map(|t| (k, t)))
        .min_by(|x, y| x.1.total_cmp(&y.1))?;
    if k == 0 || k == n {
        return None;
    }
    let (mut lo, mut hi) = ((k - 1) as Real / n as Real, (k + 1) as Real / n as Real);
    let g = (5.0_f64.sqrt() - 1.0) / 2.0;
    let f = |l: Real| end(l).unwrap_or(Real::INFINITY);
    for _ in 0..80 {
        let (x1, x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
        if f(x1) <= f(x2) {
            hi = x2;
        } else {
            lo = x1;
        }
    }
    let l = 0.5 * (lo + hi);
    let t = f(l);
    t.is_finite().then(|| (l, if out { -t } else { t }))
}

/// On trunnion moves turning A and C together (a flat and a ball end mill), every interval
/// end of a 1.5 mm grid of x, y and z rays that lies on an edge circle at the pose of the
/// ray's farthest reach (within 1 µm of the circle, that pose found by searching the chain's
/// poses) has the normal of the surface through the neighbouring rays' ends (central
/// differences over ±1 µm across the ray, each end searched likewise): within 1e-3 rad,
/// where the one-sided differences agree (elsewhere the end is on a crease of the swept
/// volume, which few are). About a thousand such ends are checked, and at hundreds of them
/// the face's own normal (the side's radial or the end plane's axial one, at the farthest
/// pose) is more than 0.05 rad off: the normal is the swept edge's, not a face's.
#[test]
fn an_end_on_an_edge_circle_has_the_swept_edge_s_normal() {
    let c = trunnion();
    let moves = trunnion_moves();
    let (mut checked, mut off_face, mut creases) = (0, 0, 0);
    for (kind, (a, b)) in [
        (ToolKind::Flat, moves[2]),
        (ToolKind::Flat, moves[3]),
        (ToolKind::Ball, moves[2]),
    ] {
        let tool = Tool::try_new(kind, 6.0, 25.0).expect("valid");
        let env = RotaryEnvelope::new(&c, &tool, &a, &b).expect("supported");
        let (r, l) = (env.r, env.l);
        let edges: &[Real] = match kind {
            ToolKind::Flat => &[0.0, l],
            _ => &[l],
        };
        let mut rays = Vec::new();
        grid_rays_every(1.5, &env.bounds(), |o, axis, _| rays.push((o, axis)));
        let mv = (&c, &tool, &a, &b);
        for (o, axis) in rays {
            let e = Vector3::ith(axis, 1.0);
            let mut cuts = Vec::new();
            env.intervals(&o, &e, &mut cuts);
            // one interval: its ends are the ray's farthest reach either way
            let [cut] = cuts.as_slice() else {
                continue;
            };
            for out in [false, true] {
                let (t, n) = if out {
                    (cut.t_out, cut.n_out)
                } else {
                    (cut.t_in, cut.n_in)
                };
                let Some((lam, tb)) = brute_end(mv, &o, &e, out) else {
                    continue;
                };
                // No pose reaches beyond the envelope's end by more than its tolerance; where
                // the search falls short of the envelope's end (its bracket held another
                // extreme) its neighbours' ends are not trusted either.
                let beyond = if out { tb - t } else { t - tb };
                assert!(
                    beyond <= env.tolerance(),
                    "{kind:?}: a pose reaches {beyond:e} beyond the end {t}"
                );
                if beyond < -1e-9 {
                    continue;
                }
                let pose = chain_pose(&c, &a, &b, lam);
                let qt = pose.inverse_transform_point(&(o + e * tb)).coords;
                let rho = qt.xy().norm();
                let on_edge =
                    (rho - r).abs() < 1e-3 && edges.iter().any(|h| (qt.z - h).abs() < 1e-3);
                if !on_edge {
                    continue;
                }
                // The surface through the neighbouring rays' ends, by central differences.
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let d = 1e-3;
                let point = |du: Real, dv: Real| {
                    let mut oo = o;
                    oo[u] += du;
                    oo[v] += dv;
                    brute_end(mv, &oo, &e, out).map(|(_, t)| oo + e * t)
                };
                let (Some(p0), Some(pu0), Some(pu1), Some(pv0), Some(pv1)) = (
                    point(0.0, 0.0),
                    point(-d, 0.0),
                    point(d, 0.0),
                    point(0.0, -d),
                    point(0.0, d),
                ) else {
                    continue;
                };
                // Where the two one-sided surfaces disagree the end lies on a crease of the
                // swept volume (two of its sheets meeting), where no normal is defined.
                let ahead = (pu1 - p0).cross(&(pv1 - p0)).normalize();
                let behind = (p0 - pu0).cross(&(p0 - pv0)).normalize();
                if ahead.dot(&behind) < (1e-3 as Real).cos() {
                    creases += 1;
                    continue;
                }
                let mut fd = (pu1 - pu0).cross(&(pv1 - pv0)).normalize();
                // the material normal points along the ray at its entry, against it at exit
                if (fd.dot(&e) < 0.0) != out {
                    fd = -fd;
                }
                let got = Vector3::from(n);
                let angle = |x: &Vector3| x.normalize().dot(&fd).clamp(-1.0, 1.0).acos();
                assert!(
                    angle(&got) < 1e-3,
                    "{kind:?}: ray {o:?} axis {axis} {} end at λ {lam:.6}: normal {got:?}, surface {fd:?} ({} rad)",
                    if out { "exit" } else { "entry" },
                    angle(&got)
                );
                checked += 1;
                // the face's normal at the farthest pose, for comparison
                let radial = -(pose.rotation * Vector3::new(qt.x, qt.y, 0.0).normalize());
                let axial = -(pose.rotation * Vector3::z() * qt.z.signum());
                let face = if (qt.z - 0.0).abs() < 1e-3 {
                    // the bottom edge: the bottom's normal is −z outward
                    [radial, pose.rotation * Vector3::z()]
                } else {
                    [radial, axial]
                };
                if face.iter().all(|f| angle(f) > 0.05) {
                    off_face += 1;
                }
            }
        }
    }
    assert!(
        checked >= 500 && creases * 10 < checked,
        "{checked} ends on an edge circle checked ({creases} on creases)"
    );
    assert!(
        off_face >= 100,
        "{off_face} of {checked} ends off both faces' normals"
    );
}
