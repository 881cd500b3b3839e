//! Building the envelope of one move (cells, speed bounds, the tool's extent) and solving a
//! ray: poses probed at the cells' ends and middles, sign changes of rates and `φ` solved by
//! the Illinois regula falsi, touches between missing poses ruled out by bisection, the
//! interval ends merged.
//!
//! **Invariant:** every interval end is the exact interval of some pose, within the
//! envelope's tolerance ([`ENVELOPE_TOL`] unless loosened) of the true swept surface.

use super::*;

/// The heights bounding the pieces of the tool's axis whose capsules of radius `r` hold a
/// tool of `shape`, radius `r` and length `l`: the segment from the bottom (a flat end
/// mill) or the ball's centre up to the top, in [`PARTS`] equal pieces.
fn capsule_heights(shape: Shape, r: Real, l: Real) -> [Real; PARTS + 1] {
    let z0 = match shape {
        Shape::Flat => 0.0,
        Shape::Ball => r,
    };
    std::array::from_fn(|k| z0 + (l - z0) * k as Real / PARTS as Real)
}

impl RotaryEnvelope {
    /// The envelope of `tool` on the move `start → end` of `chain` (moving axes settled in
    /// their direction of motion, see [`MovePath::new`]).
    pub fn new(
        chain: &Chain,
        tool: &Tool,
        start: &AxisValues,
        end: &AxisValues,
    ) -> Result<Self, EnvelopeError> {
        let state = chain.reversal_state(&Directions::default().after_move(start, end));
        Self::with_state(chain, tool, start, end, &state)
    }

    /// The envelope of `tool` on the move `start → end` of `chain` from the reversal
    /// shares `state` (see [`MovePath::with_state`]).
    pub fn with_state(
        chain: &Chain,
        tool: &Tool,
        start: &AxisValues,
        end: &AxisValues,
        state: &[Real; 6],
    ) -> Result<Self, EnvelopeError> {
        let shape = match tool.kind() {
            ToolKind::Flat => Shape::Flat,
            ToolKind::Ball if tool.length() >= 2.0 * tool.radius() => Shape::Ball,
            _ => return Err(EnvelopeError::UnsupportedTool),
        };
        let (r, l) = (tool.radius(), tool.length());
        let path = MovePath::with_state(chain, start, end, state);
        let speed = speed_bound(chain, l / 2.0, tool.reach_from(l / 2.0), start, end, state);
        let part_z = capsule_heights(shape, r, l);
        let part_speed: [Real; PARTS] = std::array::from_fn(|k| {
            let half = (part_z[k + 1] - part_z[k]) / 2.0;
            speed_bound(chain, part_z[k] + half, half + r, start, end, state)
        });
        // The swept cull's rates: the total turn Ω and bounds on the acceleration of the
        // tool axis's middle point and of any point of the axis, 2·Ω·P with P their
        // per-axis speed bound (see `cull`).
        let rates = path.constant_rates().then(|| {
            let (omega, _) = rotation_and_travel(chain, start, end);
            let per_axis = |reach| axis_speed_bounds(chain, l / 2.0, reach, start, end).1;
            cull::SweptRates {
                omega,
                accel: 2.0 * omega * per_axis(0.0),
                axis_accel: 2.0 * omega * per_axis(l / 2.0),
            }
        });
        // A point accelerates by at most 2·Ω·P, P its per-axis speed bound (the swept cull's
        // bound, see `cull`).
        let touch = rates.map(|cull::SweptRates { omega, .. }| {
            let half = (l - part_z[0]) / 2.0;
            let per_axis = |reach: Real| {
                axis_speed_bounds(chain, part_z[0] + half, half + reach, start, end).1
            };
            TouchBounds {
                omega,
                capsule_accel: 2.0 * omega * per_axis(0.0),
                slab_speed: (shape == Shape::Flat).then(|| per_axis(r + SLAB_REACH)),
            }
        });
        let mut env = Self::of_path(shape, (r, l), path, speed, (part_z, part_speed), rates)?;
        env.touch = touch;
        Ok(env)
    }

    /// The envelope of `tool` on a move read pose by pose, through its pilot poses `pilot`
    /// (at least three, evenly spaced in λ from 0 to 1): the move's path is the curve
    /// through them, [`SampledPath`], with its speed bounds.
    pub fn sampled(tool: &Tool, pilot: &[Isometry3]) -> Result<Self, EnvelopeError> {
        let shape = match tool.kind() {
            ToolKind::Flat => Shape::Flat,
            ToolKind::Ball if tool.length() >= 2.0 * tool.radius() => Shape::Ball,
            _ => return Err(EnvelopeError::UnsupportedTool),
        };
        let (r, l) = (tool.radius(), tool.length());
        let curve = SampledPath::new(pilot);
        let speed = curve.speed_bound(l / 2.0, tool.reach_from(l / 2.0));
        let part_z = capsule_heights(shape, r, l);
        let part_speed: [Real; PARTS] = std::array::from_fn(|k| {
            let half = (part_z[k + 1] - part_z[k]) / 2.0;
            curve.speed_bound(part_z[k] + half, half + r)
        });
        Self::of_path(
            shape,
            (r, l),
            MovePath::sampled(curve),
            speed,
            (part_z, part_speed),
            None,
        )
    }

    /// The envelope of a tool of `shape` (radius and length `r`, `l`) on `path`, no tool
    /// point faster than `speed` per unit λ, the capsule pieces between heights `part_z`
    /// no faster than `part_speed`; `rates`, where every axis moves at a constant rate, the
    /// total turn and the acceleration bounds of the swept cull (`cull::SweptPoses`).
    fn of_path(
        shape: Shape,
        (r, l): (Real, Real),
        path: MovePath,
        speed: Real,
        (part_z, part_speed): ([Real; PARTS + 1], [Real; PARTS]),
        rates: Option<cull::SweptRates>,
    ) -> Result<Self, EnvelopeError> {
        let want = speed / (2.0 * CELL_GROWTH * r);
        if !(want.is_finite() && want <= MAX_CELLS as Real) {
            return Err(EnvelopeError::TooManyCells(want));
        }
        let cells = (want.ceil() as usize).max(1);
        let h = 1.0 / cells as Real;
        let delta = speed * h / 2.0 + tol::FEASIBILITY;
        let samples: Vec<Sample> = (0..=2 * cells)
            .map(|k| path.sample(k as Real / (2 * cells) as Real))
            .collect();
        // Every λ lies within h/4 of a sample, where the tool has moved by at most M·h/4.
        let margin = speed * h / 4.0 + tol::FEASIBILITY;
        let mut bounds = Aabb::empty();
        for s in &samples {
            let b = frame_box(s, shape, r, l, margin);
            bounds.grow(&b.min);
            bounds.grow(&b.max);
        }
        let cell_boxes = (0..cells)
            .map(|j| frame_box(&samples[2 * j + 1], shape, r, l, delta))
            .collect();
        let lambda_of = |k: usize| k as Real / (2 * cells) as Real;
        let quarters: Vec<(Real, Sample)> = (0..2 * cells)
            .map(|k| {
                let mid = 0.5 * (lambda_of(k) + lambda_of(k + 1));
                (mid, path.sample(mid))
            })
            .collect();
        let cull = cull::CullPoses::new(&path, cells, speed);
        let swept =
            rates.map(|rates| cull::SweptPoses::new((&samples, &quarters), (shape, r, l), rates));
        let sample_dirs = samples.iter().map(cull::axis_dirs).collect();
        let quarter_dirs = quarters.iter().map(|(_, s)| cull::axis_dirs(s)).collect();
        Ok(Self {
            cull,
            swept,
            shape,
            r,
            l,
            path,
            cells,
            delta,
            speed,
            part_z,
            part_speed,
            touch: None,
            samples,
            sample_dirs,
            quarters,
            quarter_dirs,
            cell_boxes,
            bounds,
            tol: ENVELOPE_TOL,
            edge: EdgeSign::new(r),
        })
    }

    /// This envelope with its interval ends within `tol` (mm) of the true swept surface
    /// instead of [`ENVELOPE_TOL`] (never finer than that): shallower touches are ignored
    /// and the solves stop sooner. The cells, the culls and the ends' poses are found the
    /// same way; only how far each solve and touch test goes changes.
    pub fn with_tolerance(mut self, tol: Real) -> Self {
        self.tol = if tol.is_finite() {
            tol.max(ENVELOPE_TOL)
        } else {
            ENVELOPE_TOL
        };
        self
    }

    /// The bound (mm) on the interval ends' distance from the true swept surface.
    pub fn tolerance(&self) -> Real {
        self.tol
    }

    /// The distance (mm) to which a solve brings an interval end to the true extreme.
    fn solve_tol(&self) -> Real {
        SOLVE_SHARE * self.tol
    }

    /// Number of cells the move is split into.
    pub fn cells(&self) -> usize {
        self.cells
    }

    /// The bound on any tool point's speed per unit of the move parameter (mm).
    pub fn speed_bound(&self) -> Real {
        self.speed
    }

    fn lambda_of(&self, k: usize) -> Real {
        k as Real / (2 * self.cells) as Real
    }

    /// Whether the ray meets the tool at a pose grown by `grow` (mm) within the ray's span;
    /// `u` the ray's direction in the pose's tool frame.
    #[inline(always)]
    fn meets_grown(&self, s: &Sample, ray: &Ray, u: &Vector3, grow: Real) -> bool {
        let p = s.rot.tr_mul(&(ray.o - s.tip));
        let meets = |(t0, _, t1, _): (Real, Face, Real, Face)| t1 >= ray.span.0 && t0 <= ray.span.1;
        // A ball's interval holds its sphere's: when that meets the span so does the tool's
        // (the shank's cylinder, with its divisions, is then not needed for the answer)
        if self.shape == Shape::Ball && ball_sphere(self.r, &p, u, grow).is_some_and(meets) {
            return true;
        }
        tool_interval(self.shape, self.r, self.l, &p, u, grow).is_some_and(meets)
    }

    /// The ray evaluated exactly at a pose; `u` its direction in the pose's tool frame.
    #[inline(always)]
    fn probe(&self, s: &Sample, lambda: Real, ray: &Ray, u: Vector3) -> Probe {
        let p = s.rot.tr_mul(&(ray.o - s.tip));
        // The end planes' crossings serve both the interval and the edges' radii.
        let slab = end_slab(self.shape, self.r, self.l, &p, &u, 0.0);
        let hit =
            tool_interval_in(self.shape, self.r, &p, &u, 0.0, || slab).map(|(t0, f0, t1, f1)| {
                Hit {
                    t_in: t0,
                    face_in: f0,
                    t_out: t1,
                    face_out: f1,
                }
            });
        // The squared radius where the ray crosses the plane at `t` along it (the plane's
        // crossing `(h − p_z)/u_z`, as the slab has it: a bottom plane at `−0` instead of
        // `0` changes only the sign of a zero `t`, so not the radius).
        let radius2 = |t: Real| {
            let q = p + u * t;
            q.x * q.x + q.y * q.y
        };
        let (bottom, top) = match slab {
            Some((s0, Face::Bottom, s1, Face::Top)) => (s0, s1),
            Some((s0, Face::Top, s1, Face::Bottom)) => (s1, s0),
            // parallel to the planes (or no slab)
            _ => (Real::NAN, Real::NAN),
        };
        let edge_r2 = if bottom.is_nan() {
            [Real::INFINITY; 2]
        } else {
            let below = match self.shape {
                Shape::Flat => radius2(bottom),
                Shape::Ball => Real::INFINITY,
            };
            [below, radius2(top)]
        };
        Probe {
            lambda,
            hit,
            edge_r2,
            p,
            u,
            rot: s.rot,
            w_t: s.w_t,
            v_t: s.v_t,
            rates: Cell::new([Real::NAN; 2]),
            known: Cell::new(0),
        }
    }

    #[inline(always)]
    pub(super) fn probe_at(&self, lambda: Real, ray: &Ray) -> Probe {
        let (s, u) = self.sample_at(lambda, ray);
        self.probe(&s, lambda, ray, u)
    }

    /// The pose at `lambda` and the ray's direction in its tool frame: the stored ones when
    /// `lambda` is exactly a quarter point (the midpoint of two consecutive samples as
    /// [`Self::refine`] computes it) and the ray an axis ray, else computed.
    #[inline(always)]
    fn sample_at(&self, lambda: Real, ray: &Ray) -> (Sample, Vector3) {
        let k = ((lambda * (4 * self.cells) as Real - 1.0) / 2.0).round();
        if k >= 0.0
            && let Some((at, s)) = self.quarters.get(k as usize)
            && *at == lambda
        {
            let u = match ray.axis {
                Some(a) => self.quarter_dirs[k as usize][a],
                None => s.rot.tr_mul(ray.e),
            };
            return (*s, u);
        }
        let s = self.path.sample(lambda);
        (s, s.rot.tr_mul(ray.e))
    }

    /// The sorted, disjoint intervals of the ray `o + t·e` (`e` unit) inside the swept volume,
    /// with material normals, appended to `out`.
    pub fn intervals(&self, o: &Point3, e: &Vector3, out: &mut Vec<RayCut>) {
        self.intervals_in(o, e, (Real::NEG_INFINITY, Real::INFINITY), out);
    }

    /// Like [`RotaryEnvelope::intervals`] where only `span` along the ray matters (the
    /// material's extent): interval ends outside it are left unrefined (they stay outside
    /// it) and parts of the move whose grown tool meets the ray only outside it are skipped.
    pub fn intervals_in(&self, o: &Point3, e: &Vector3, span: (Real, Real), out: &mut Vec<RayCut>) {
        self.intervals_near(o, e, span, false, out);
    }

    /// [`RotaryEnvelope::intervals_in`] for a ray that passed this move's cull
    /// ([`RotaryEnvelope::may_cut`]) where `culled`: a move of one cell then has its cell
    /// probed without the cell's own grown-tool test. That test only skips cells whose tool
    /// grown by `δ` misses the ray within `span`; such a cell's poses miss it there too, so
    /// probing it adds no interval that reaches into `span` (at most some wholly outside,
    /// which the stock leaves out), and after the cull, whose swept tool is far tighter than
    /// the tool grown by `δ`, the test nearly always passes: it would cost as much as a
    /// probe and skip nothing.
    pub(super) fn intervals_near(
        &self,
        o: &Point3,
        e: &Vector3,
        span: (Real, Real),
        culled: bool,
        out: &mut Vec<RayCut>,
    ) {
        let probe_all = culled && self.cells == 1;
        // a dexel ray's box tests need no divisions (the same results)
        let axis = Aabb::unit_axis(e);
        let box_meets = |b: &Aabb| match axis {
            Some(a) => b.axis_ray_interval(o, a),
            None => b.ray_interval(o, e),
        };
        if box_meets(&self.bounds).is_none() {
            return;
        }
        let ray = Ray { o, e, span, axis };
        let n = self.cells;
        // The ray's direction in sample k's tool frame: kept for an axis ray.
        let along = |k: usize| match axis {
            Some(a) => self.sample_dirs[k][a],
            None => self.samples[k].rot.tr_mul(e),
        };
        if n == 1 && !general_path_forced() {
            // A move of one cell (most small moves): its three samples on the stack.
            if box_meets(&self.cell_boxes[0]).is_some_and(|(t0, t1)| t1 >= span.0 && t0 <= span.1)
                && (probe_all || self.meets_grown(&self.samples[1], &ray, &along(1), self.delta))
            {
                self.one_cell(&ray, along, out);
            }
            return;
        }
        SCRATCH.with_borrow_mut(|scratch| {
            let Scratch {
                grown,
                slot,
                probes,
                comp_of,
                comps,
                cuts,
            } = scratch;
            grown.clear();
            grown.extend((0..n).map(|j| {
                box_meets(&self.cell_boxes[j]).is_some_and(|(t0, t1)| t1 >= span.0 && t0 <= span.1)
                    && (probe_all
                        || self.meets_grown(
                            &self.samples[2 * j + 1],
                            &ray,
                            &along(2 * j + 1),
                            self.delta,
                        ))
            }));
            if !grown.iter().any(|&g| g) {
                return;
            }
            // The probes at the samples of the cells that may meet the ray, each once:
            // `slot[k]` indexes sample k's probe in `probes` (NO_PROBE: not evaluated).
            slot.clear();
            slot.resize(2 * n + 1, NO_PROBE);
            probes.clear();
            for j in (0..n).filter(|&j| grown[j]) {
                for (k, at) in slot.iter_mut().enumerate().skip(2 * j).take(3) {
                    if *at == NO_PROBE {
                        *at = probes.len() as u32;
                        probes.push(self.probe(
                            &self.samples[k],
                            self.lambda_of(k),
                            &ray,
                            along(k),
                        ));
                    }
                }
            }
            let at = |k: usize| probes.get(slot[k] as usize);
            // Connected sets of poses: runs of samples inside the tool joined by half-cells
            // of cells that may meet the ray; each starts from its samples' extremes.
            comp_of.clear();
            comp_of.resize(2 * n + 1, None);
            comps.clear();
            for k in 0..=2 * n {
                let Some(p) = at(k).filter(|p| p.hit.is_some()) else {
                    continue;
                };
                let id = match (k > 0 && grown[(k - 1) / 2])
                    .then(|| comp_of[k - 1])
                    .flatten()
                {
                    Some(id) => id,
                    None => {
                        comps.push(None);
                        comps.len() - 1
                    }
                };
                comp_of[k] = Some(id);
                offer(&mut comps[id], p);
            }
            // Extremes between the samples, half-cell by half-cell.
            for k in (0..2 * n).filter(|k| grown[k / 2]) {
                let (Some(a), Some(b)) = (at(k), at(k + 1)) else {
                    continue;
                };
                match comp_of[k].or(comp_of[k + 1]) {
                    Some(id) => self.refine(&ray, a, b, &mut comps[id], 0),
                    None => {
                        let mut touch = None;
                        self.refine(&ray, a, b, &mut touch, 0);
                        comps.push(touch);
                    }
                }
            }
            // One interval (the common case) is emitted as it is: nothing to sort or merge,
            // and no copy of its ends.
            let mut found = comps.iter().flatten();
            match (found.next(), found.next()) {
                (None, _) => {}
                (Some(only), None) => emit(only, self.rim(), out),
                _ => {
                    cuts.clear();
                    cuts.extend(comps.drain(..).flatten());
                    self.merge_and_emit(cuts, out);
                }
            }
        });
    }

    /// [`Self::intervals_near`] on a move of one cell whose cell may meet the ray: the
    /// general case's steps with its buffers on the stack (the same probes, components and
    /// refinements in the same order, so the same intervals). `along(k)`: the ray's
    /// direction in sample `k`'s tool frame.
    fn one_cell(&self, ray: &Ray, along: impl Fn(usize) -> Vector3, out: &mut Vec<RayCut>) {
        let probe = |k: usize| self.probe(&self.samples[k], self.lambda_of(k), ray, along(k));
        let probes = [probe(0), probe(1), probe(2)];
        // Runs of samples inside the tool, then a touch found between two missing samples:
        // at most two runs and two touches.
        let mut comps: [Option<RawEnd>; 4] = [None; 4];
        let mut len = 0;
        let mut comp_of = [None; 3];
        for (k, p) in probes.iter().enumerate() {
            if p.hit.is_none() {
                continue;
            }
            let id = match (k > 0).then(|| comp_of[k - 1]).flatten() {
                Some(id) => id,
                None => {
                    len += 1;
                    len - 1
                }
            };
            comp_of[k] = Some(id);
            offer(&mut comps[id], p);
        }
        for k in 0..2 {
            let id = match comp_of[k].or(comp_of[k + 1]) {
                Some(id) => id,
                None => {
                    len += 1;
                    len - 1
                }
            };
            self.refine(ray, &probes[k], &probes[k + 1], &mut comps[id], 0);
        }
        let mut found = comps[..len].iter().flatten();
        match (found.next(), found.next()) {
            (None, _) => {}
            (Some(only), None) => emit(only, self.rim(), out),
            (Some(&first), Some(_)) => {
                let mut cuts = [first; 4];
                let mut m = 0;
                for c in comps[..len].iter().flatten() {
                    cuts[m] = *c;
                    m += 1;
                }
                self.merge_and_emit(&mut cuts[..m], out);
            }
        }
    }

    /// Sorts the intervals, merges those that overlap and emits them with their normals.
    fn merge_and_emit(&self, cuts: &mut [RawEnd], out: &mut Vec<RayCut>) {
        cuts.sort_by(|a, b| a.lo.t.total_cmp(&b.lo.t));
        let mut merged: Option<RawEnd> = None;
        for &c in cuts.iter() {
            merged = Some(match merged {
                Some(mut m) if c.lo.t <= m.hi.t + tol::SLIVER => {
                    if c.hi.t > m.hi.t {
                        m.hi = c.hi;
                    }
                    m
                }
                Some(m) => {
                    emit(&m, self.rim(), out);
                    c
                }
                None => c,
            });
        }
        if let Some(m) = merged {
            emit(&m, self.rim(), out);
        }
    }

    /// The tool radius and the heights of its edge circles' planes in the tool frame
    /// (bottom and top; NaN for none: a ball's end is smooth).
    fn rim(&self) -> (Real, [Real; 2]) {
        let bottom = match self.shape {
            Shape::Flat => 0.0,
            Shape::Ball => Real::NAN,
        };
        (self.r, [bottom, self.l])
    }

    /// `dφ/dλ` of edge circle `edge` at the probe `p`: the ray's point `q = p + u·t_e` in
    /// the edge's plane `z = h` moves in the tool frame at `−(w × q + v) + u·ṫ_e`, a point
    /// fixed in W moving against the tool, with `ṫ_e = (w × q + v)_z/u_z` keeping it in the
    /// plane; `φ = |q_xy| − R` changes at `q_xy·q̇_xy/|q_xy|`. NaN where the ray runs along
    /// the plane or crosses it on the axis, or the edge is not there (a ball's bottom).
    pub(super) fn phi_rate(&self, p: &Probe, edge: usize) -> Real {
        let h = self.rim().1[edge];
        let q = p.p + p.u * ((h - p.p.z) / p.u.z);
        let m = p.w_t.cross(&q) + p.v_t;
        let dq = p.u * (m.z / p.u.z) - m;
        (q.x * dq.x + q.y * dq.y) / q.xy().norm()
    }

    /// A guided edge crossing's guess ([`Self::solve`]): Newton's step on `φ` from the
    /// bracket end where `|φ|` is least, `φ'` from [`Self::phi_rate`] (NaN, so no guess,
    /// where that is not finite).
    fn crossing_guess(&self, edge: usize) -> impl Fn((&Probe, &Probe), (Real, Real)) -> Real {
        move |(lo, hi), (flo, fhi)| {
            let (p, f) = if flo.abs() <= fhi.abs() {
                (lo, flo)
            } else {
                (hi, fhi)
            };
            p.lambda - f / self.phi_rate(p, edge)
        }
    }

    /// Whether the ray crosses edge circle `edge` between the probes `a` and `b`: `φ` has a
    /// sign at both and the signs differ.
    #[inline(always)]
    fn crosses_edge(&self, (a, b): (&Probe, &Probe), edge: usize) -> bool {
        let (fa, fb) = (a.edge_r2[edge], b.edge_r2[edge]);
        !fa.is_nan() && !fb.is_nan() && self.edge.inside(fa) != self.edge.inside(fb)
    }

    /// Offers to `acc` every extreme of the ray's interval strictly between the probes `a`
    /// and `b` (see the module docs).
    fn refine(&self, ray: &Ray, a: &Probe, b: &Probe, acc: &mut Option<RawEnd>, depth: u32) {
        let w = b.lambda - a.lambda;
        if depth > MAX_DEPTH || self.speed * w <= self.solve_tol() {
            return;
        }
        let bisect = |acc: &mut Option<RawEnd>| {
            let m = self.probe_at(0.5 * (a.lambda + b.lambda), ray);
            offer(acc, &m);
            self.refine(ray, a, &m, acc, depth + 1);
            self.refine(ray, &m, b, acc, depth + 1);
        };
        let (ha, hb) = (a.hit, b.hit);
        if ha.is_none() && hb.is_none() {
            // A touch between two missing poses needs the tool to travel to the ray from both.
            let z = &self.part_z;
            let sep =
                |p: &Probe, k: usize| line_segment_distance(&p.p, &p.u, z[k], z[k + 1]) - self.r;
            let apart =
                (0..PARTS).all(|k| sep(a, k) + sep(b, k) + 2.0 * self.tol > self.part_speed[k] * w);
            if apart {
                return;
            }
            // Between two misses the ray can only come to meet the tool where it passes
            // through an edge circle or touches the tool's smooth part (the capsule of radius
            // R about the axis from `z[0]` to the top, which holds the tool). An edge crossing
            // is solved for like one between hits: the ray meets the tool there, if at all.
            let mut crossing = false;
            for edge in 0..2 {
                if self.crosses_edge((a, b), edge) {
                    let phi = move |p: &Probe| Some(p.phi(edge, self.r));
                    let newton = self.crossing_guess(edge);
                    if let Some((lo, hi)) =
                        self.solve(ray, (a, b), phi, Some(&newton), Stop::Crossing, acc)
                    {
                        self.refine(ray, a, &lo, acc, depth + 1);
                        self.refine(ray, &hi, b, acc, depth + 1);
                        return;
                    }
                    crossing = true;
                }
            }
            // Without one, a ray that stays inside the capsule (its distance from the axis
            // segment below R at both ends, by more than the segment can move) touches no
            // smooth face in between: it misses throughout.
            let inside = |p: &Probe| self.r - line_segment_distance(&p.p, &p.u, z[0], self.l);
            if !crossing && inside(a) + inside(b) > self.speed * w {
                return;
            }
            // And the grown tool about the middle to meet it.
            let mid = 0.5 * (a.lambda + b.lambda);
            let (s, u) = self.sample_at(mid, ray);
            let grow = self.speed * w / 2.0 - self.tol;
            if grow > 0.0 && self.meets_grown(&s, ray, &u, grow) {
                if !crossing && self.touch_ruled_out(ray, (a, b)) {
                    return;
                }
                let m = self.probe(&s, mid, ray, u);
                offer(acc, &m);
                self.refine(ray, a, &m, acc, depth + 1);
                self.refine(ray, &m, b, acc, depth + 1);
            }
            return;
        }
        // Ends already beyond the span need no refinement.
        let (in_done, out_done) = acc.map_or((false, false), |c| {
            (c.lo.t < ray.span.0, c.hi.t > ray.span.1)
        });
        if in_done && out_done {
            return;
        }
        // The ray crosses an edge circle: a kink or the ray leaving through the edge.
        for edge in 0..2 {
            if self.crosses_edge((a, b), edge) {
                let phi = move |p: &Probe| Some(p.phi(edge, self.r));
                let newton = self.crossing_guess(edge);
                match self.solve(ray, (a, b), phi, Some(&newton), Stop::Crossing, acc) {
                    Some((lo, hi)) => {
                        self.refine(ray, a, &lo, acc, depth + 1);
                        self.refine(ray, &hi, b, acc, depth + 1);
                    }
                    None => bisect(acc),
                }
                return;
            }
        }
        let r = self.r;
        match (ha, hb) {
            (Some(x), Some(y)) => {
                if x.face_in.family() != y.face_in.family()
                    || x.face_out.family() != y.face_out.family()
                {
                    return bisect(acc);
                }
                if !in_done
                    && a.g_in(r) < 0.0
                    && b.g_in(r) > 0.0
                    && self.extreme(ray, (a, b), 0, acc).is_none()
                {
                    return bisect(acc);
                }
                if !out_done
                    && a.g_out(r) > 0.0
                    && b.g_out(r) < 0.0
                    && self.extreme(ray, (a, b), 1, acc).is_none()
                {
                    bisect(acc);
                }
            }
            // Into a touch t_in rises and t_out falls: an end moving the other way on the
            // inside has an extreme before the ray leaves.
            (Some(_), None) if (!in_done && a.g_in(r) < 0.0) || (!out_done && a.g_out(r) > 0.0) => {
                bisect(acc)
            }
            (None, Some(_)) if (!in_done && b.g_in(r) > 0.0) || (!out_done && b.g_out(r) < 0.0) => {
                bisect(acc)
            }
            _ => {}
        }
    }

    /// Whether the tool cannot meet the axis ray at all between the probes `a` and `b`
    /// (both missing), by second order. The tool lies in the capsule of radius `R` about its
    /// axis from `part_z[0]` to the top, and a flat end mill is the cylinder `r ≤ R` between
    /// its end planes (the slab); the tool misses the ray when either keeps farther than `R`
    /// from it over the half-cell. Then no pose between `a` and `b` meets the ray, and the
    /// bisection that would otherwise look for a touch would find none: skipping it leaves
    /// the intervals the same, bit for bit.
    ///
    /// Over `[a, (a+b)/2]` a distance vector `D(z, λ)` (from the ray to the axis point at
    /// height `z` for the capsule; from the axis point at height `z` to the ray's point at
    /// the same height in the tool frame for the slab, which lies across the axis) is within
    /// `K·(λ − a)²/2` of `D(z, a) + (λ − a)·Ḋ(z, a)`, `K` a bound on `|D̈|`, and likewise
    /// from `b` over the other half. Seen along the ray (the capsule) or along the tool's
    /// axis at `a` (the slab), those first-order vectors form a bilinear patch in `z` and
    /// `λ`, which lies in the convex hull of its four corners ([`hull_clear`]); when that
    /// hull stays farther than `R + K·(w/2)²/2` from the origin, the tool stays farther than
    /// `R`. For the capsule `K = 2·Ω·P` (the acceleration of the axis points, `P` their
    /// per-axis speed bound, as in `cull`). For the slab the ray's point at height `z` slides
    /// along the ray at `ṫ = n·V(X)/(n·e)` (`n` the axis, `V` the tool's velocity field), so
    /// with `c ≤ |n·e|` over the half-cell, `|ṅ| ≤ Ω`, the field's own rate at a point at
    /// most `Ω·P` and `|ẍ| ≤ 2·Ω·P` at the axis point: `|ẗ| ≤ 2·Ω·P/c + 2·Ω·P/c²` and
    /// `K = 2·Ω·P·(1 + 1/c + 1/c²)`, `P` the per-axis speed bound within `R +`
    /// [`SLAB_REACH`] of the axis. The slab is used only where `c ≥` [`SLAB_MIN_COS`] and the
    /// ray's point at a height cannot drift farther from the axis than that over the
    /// half-cell (`P·(1 + 1/c)·w/2 ≤` [`SLAB_REACH`]), so that `P` bounds its speed.
    ///
    /// `false` where no bound applies (an axis does not move at a constant rate, or the ray
    /// is not an axis ray). Where the tool passes along the ray at a nearly constant small
    /// distance, the speed bound alone needs the half-cell bisected until the tool moves
    /// less than that distance; this needs none once the distance exceeds `K·(w/2)²/2`.
    pub(super) fn touch_ruled_out(&self, ray: &Ray, (a, b): (&Probe, &Probe)) -> bool {
        let (Some(bounds), Some(axis)) = (&self.touch, ray.axis) else {
            return false;
        };
        let half = 0.5 * (b.lambda - a.lambda);
        // Farther than R (and the rounding's margin): the tool misses the ray.
        let clear = self.r + cull::CULL_MARGIN;
        let (z0, z1) = (self.part_z[0], self.l);
        let across = |v: Vector3| -> [Real; 2] {
            match axis {
                0 => [v.y, v.z],
                1 => [v.x, v.z],
                _ => [v.x, v.y],
            }
        };
        [(a, half), (b, -half)].into_iter().all(|(p, tau)| {
            // The capsule, seen along the ray from its origin: the axis point at height h
            // is `y0 + h·yz`, moving at `v0 + h·vz` per unit λ.
            let capsule = || {
                let y0 = across(-(p.rot * p.p));
                let yz = across(p.rot.column(2).into_owned());
                let v0 = across(p.rot * p.v_t);
                let vz = across(p.rot * Vector3::new(p.w_t.y, -p.w_t.x, 0.0));
                let at = |h: Real, t: Real| {
                    [
                        y0[0] + h * yz[0] + t * (v0[0] + h * vz[0]),
                        y0[1] + h * yz[1] + t * (v0[1] + h * vz[1]),
                    ]
                };
                let corners = [at(z0, 0.0), at(z1, 0.0), at(z1, tau), at(z0, tau)];
                hull_clear(&corners, clear + bounds.capsule_accel * tau * tau / 2.0)
            };
            // The slab, in the tool frame at the probe: the ray's point at height h is
            // `c0 + h·c1` across the axis, sliding along the ray at `t0 + h·t1`.
            let (u, q, w, v) = (&p.u, &p.p, &p.w_t, &p.v_t);
            let c = u.z.abs() - bounds.omega * tau.abs();
            let slab = |speed: Real| {
                if !(c >= SLAB_MIN_COS && speed * (1.0 + 1.0 / c) * tau.abs() <= SLAB_REACH) {
                    return false;
                }
                let c1 = [u.x / u.z, u.y / u.z];
                let c0 = [q.x - c1[0] * q.z, q.y - c1[1] * q.z];
                let t0 = (w.x * c0[1] - w.y * c0[0] + v.z) / u.z;
                let t1 = (w.x * c1[1] - w.y * c1[0]) / u.z;
                let at = |h: Real, t: Real| {
                    let slide = t0 + h * t1;
                    [
                        c0[0] + h * c1[0] + t * (u.x * slide - v.x - h * w.y),
                        c0[1] + h * c1[1] + t * (u.y * slide - v.y + h * w.x),
                    ]
                };
                let corners = [at(z0, 0.0), at(z1, 0.0), at(z1, tau), at(z0, tau)];
                let accel = 2.0 * bounds.omega * speed * (1.0 + 1.0 / c + 1.0 / (c * c));
                hull_clear(&corners, clear + accel * tau * tau / 2.0)
            };
            match bounds.slab_speed {
                // a ray near the axis's direction is better seen by the slab
                Some(speed) if c >= 0.5 => slab(speed) || capsule(),
                Some(speed) => capsule() || slab(speed),
                None => capsule(),
            }
        })
    }

    /// Solves for the extreme of the interval's end `end` (0 in, 1 out) between `a` and `b`,
    /// where its rate changes sign: [`Self::solve`] on the rate, guided by the Hermite cubic
    /// through the end's positions and rates ([`hermite_extreme`]).
    fn extreme(
        &self,
        ray: &Ray,
        (a, b): (&Probe, &Probe),
        end: usize,
        acc: &mut Option<RawEnd>,
    ) -> Option<(Probe, Probe)> {
        let r = self.r;
        let g = |p: &Probe| p.hit.map(|_| if end == 0 { p.g_in(r) } else { p.g_out(r) });
        let t = |p: &Probe| {
            p.hit
                .map_or(Real::NAN, |h| if end == 0 { h.t_in } else { h.t_out })
        };
        let cubic = |(lo, hi): (&Probe, &Probe), fs| {
            hermite_extreme((lo.lambda, hi.lambda), (t(lo), t(hi)), fs)
        };
        self.solve(ray, (a, b), g, Some(&cubic), Stop::Extreme, acc)
    }

    /// Brackets the sign change of `f` between `a` and `b` by the Illinois variant of regula
    /// falsi (a bisection every third step where the last three did not halve the bracket
    /// nor, for a rate's extreme, bring the least `|f|` at its ends down sixteenfold),
    /// offering every pose it evaluates. With a `guess` (a point for the bracket `(lo, hi)`
    /// with `f` there: the root of a Hermite cubic's slope for a rate's extreme, Newton's
    /// step for an edge crossing) the solve is guided: a guess
    /// inside the bracket is taken instead of the secant's point, a step near an end is
    /// moved past the root, and the bisection waits while `|f|` falls; without one it is the
    /// plain regula falsi. `None` where `f` is undefined (the ray missed a pose).
    fn solve(
        &self,
        ray: &Ray,
        (a, b): (&Probe, &Probe),
        f: impl Fn(&Probe) -> Option<Real>,
        guess: Option<Guess>,
        stop: Stop,
        acc: &mut Option<RawEnd>,
    ) -> Option<(Probe, Probe)> {
        let (mut lo, mut hi) = (a.clone(), b.clone());
        let (Some(f_lo), Some(f_hi)) = (f(&lo), f(&hi)) else {
            return None;
        };
        let neg_lo = f_lo < 0.0;
        // Secant weights (halved by Illinois) and the true values.
        let (mut wlo, mut whi) = (f_lo, f_hi);
        let (mut flo, mut fhi) = (f_lo, f_hi);
        let mut last_side = 0i8;
        let mut width = hi.lambda - lo.lambda;
        // The least |f| at the bracket's ends when `width` was taken.
        let mut least = f_lo.abs().min(f_hi.abs());
        let solve_tol = self.solve_tol();
        for step in 0..MAX_SOLVE_STEPS {
            let w = hi.lambda - lo.lambda;
            let slope = stop.slope(self, &lo, &hi, flo, fhi);
            if slope * w <= solve_tol || w <= 4.0 * Real::EPSILON {
                break;
            }
            let mut m = (lo.lambda * whi - hi.lambda * wlo) / (whi - wlo);
            // Every third step bisects where the last three did not halve the bracket, unless
            // (guided) they brought the least |f| down sixteenfold: the guesses closing in
            // from one side.
            let now = flo.abs().min(fhi.abs());
            let closing = guess.is_some() && now <= least / 16.0;
            let bisect = step % 3 == 2 && w > 0.5 * width && !closing;
            if step % 3 == 2 {
                (width, least) = (w, now);
            }
            if bisect {
                m = 0.5 * (lo.lambda + hi.lambda);
            } else if let Some(guess) = guess {
                let g = guess((&lo, &hi), (flo, fhi));
                if g > lo.lambda && g < hi.lambda {
                    m = g;
                }
            }
            // A step closer to an end than half the width the stop needs goes that far:
            // where the guess has the root that close, the point lands past it and the
            // bracket closes at once (regula falsi alone keeps the far end). Guided only
            // (an edge crossing is guided too: its two sides are different faces, but the
            // kept end's normal there is the swept edge's whichever side it comes from).
            if guess.is_some() {
                let need = solve_tol / slope;
                if m - lo.lambda < 0.5 * need {
                    m = lo.lambda + 0.5 * need;
                } else if hi.lambda - m < 0.5 * need {
                    m = hi.lambda - 0.5 * need;
                }
            }
            if !(m > lo.lambda && m < hi.lambda) {
                m = 0.5 * (lo.lambda + hi.lambda);
                if !(m > lo.lambda && m < hi.lambda) {
                    break;
                }
            }
            let p = self.probe_at(m, ray);
            offer(acc, &p);
            let fm = f(&p)?;
            if fm.is_nan() {
                return None;
            }
            if (fm < 0.0) == neg_lo {
                (lo, flo, wlo) = (p, fm, fm);
                if last_side < 0 {
                    whi *= 0.5;
                }
                last_side = -1;
            } else {
                (hi, fhi, whi) = (p, fm, fm);
                if last_side > 0 {
                    wlo *= 0.5;
                }
                last_side = 1;
            }
        }
        Some((lo, hi))
    }
}

/// A guided solve's guess of its next point from the bracket's ends and `f` there.
type Guess<'a> = &'a dyn Fn((&Probe, &Probe), (Real, Real)) -> Real;

/// Where the slope of the cubic through an interval end's two bracket ends changes sign:
/// the cubic (Hermite) takes the end's positions `t` and rates `g` (per unit λ) at `λ`
/// `l.0` and `l.1`; its slope is a quadratic in `x = (λ − l.0)/(l.1 − l.0)`, and the least
/// root strictly between 0 and 1 is taken (NaN for none). Exact for a cubic `t(λ)`.
pub(super) fn hermite_extreme(l: (Real, Real), t: (Real, Real), g: (Real, Real)) -> Real {
    let w = l.1 - l.0;
    let (g0, g1) = (g.0 * w, g.1 * w);
    let dt = t.0 - t.1;
    // T'(x) = a·x² + b·x + c, from the derivatives of the Hermite basis.
    let a = 6.0 * dt + 3.0 * (g0 + g1);
    let b = -6.0 * dt - 4.0 * g0 - 2.0 * g1;
    let c = g0;
    let x = if a.abs() <= 1e-12 * (b.abs() + c.abs()) {
        -c / b
    } else {
        let disc = b * b - 4.0 * a * c;
        // a NaN discriminant (no cubic) fails this too
        if disc.is_nan() || disc < 0.0 {
            return Real::NAN;
        }
        let q = -0.5 * (b + b.signum() * disc.sqrt());
        match [q / a, c / q]
            .into_iter()
            .filter(|x| *x > 0.0 && *x < 1.0)
            .reduce(Real::min)
        {
            Some(x) => x,
            None => return Real::NAN,
        }
    };
    l.0 + x * w
}

/// Whether the convex hull of four points of the plane stays farther than `need` from the
/// origin: the origin lies in none of the triangles of three of them, and every segment
/// between two of them (the hull's edges are among them, and every other one lies in the
/// hull) is farther than `need`. The segment from the first point to the second is looked
/// at first: where the tool's side passes close to the ray it alone decides.
pub(super) fn hull_clear(pts: &[[Real; 2]; 4], need: Real) -> bool {
    let need2 = need * need;
    let far = |i: usize, j: usize| {
        let (a, b) = (pts[i], pts[j]);
        let d = [b[0] - a[0], b[1] - a[1]];
        let dd = d[0] * d[0] + d[1] * d[1];
        let t = if dd > 0.0 {
            (-(a[0] * d[0] + a[1] * d[1]) / dd).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (x, y) = (a[0] + t * d[0], a[1] + t * d[1]);
        x * x + y * y > need2
    };
    if !(need >= 0.0 && far(0, 1)) {
        return false;
    }
    let cross = |i: usize, j: usize| pts[i][0] * pts[j][1] - pts[i][1] * pts[j][0];
    let inside = |i: usize, j: usize, k: usize| {
        let (c0, c1, c2) = (cross(i, j), cross(j, k), cross(k, i));
        (c0 >= 0.0 && c1 >= 0.0 && c2 >= 0.0) || (c0 <= 0.0 && c1 <= 0.0 && c2 <= 0.0)
    };
    !(inside(0, 1, 2) || inside(0, 1, 3) || inside(0, 2, 3) || inside(1, 2, 3))
        && [(0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
            .into_iter()
            .all(|(i, j)| far(i, j))
}

/// When a solve's bracket is fine enough.
#[derive(Clone, Copy, Debug)]
enum Stop {
    /// A smooth extreme of an interval end: `f` is its rate; the end is within
    /// `min |rate| · w` of the extreme on a convex stretch.
    Extreme,
    /// An edge crossing: `t` moves by at most the larger rate at the bracket ends times `w`.
    Crossing,
}

impl Stop {
    /// The slope that bounds how far the solved end moves over the bracket `lo`–`hi` (`f`
    /// there `flo`, `fhi`) of `env`'s solve, per unit λ: the bracket is fine enough when
    /// its width times this is at most the envelope's solve tolerance.
    fn slope(self, env: &RotaryEnvelope, lo: &Probe, hi: &Probe, flo: Real, fhi: Real) -> Real {
        match self {
            Stop::Extreme => flo.abs().min(fhi.abs()),
            Stop::Crossing => {
                let rates = [lo, hi]
                    .into_iter()
                    .filter(|p| p.hit.is_some())
                    .flat_map(|p| [p.g_in(env.r).abs(), p.g_out(env.r).abs()])
                    .filter(|g| g.is_finite())
                    .fold(Real::NEG_INFINITY, Real::max);
                if rates.is_finite() { rates } else { env.speed }
            }
        }
    }
}

fn emit(c: &RawEnd, (r, edges): (Real, [Real; 2]), out: &mut Vec<RayCut>) {
    if c.hi.t - c.lo.t > tol::LENGTH_EPS {
        out.push(RayCut {
            t_in: c.lo.t,
            t_out: c.hi.t,
            n_in: c.lo.normal(r, edges),
            n_out: c.hi.normal(r, edges),
        });
    }
}

/// Whether [`RotaryEnvelope::intervals_near`] takes its general path on a move of one cell
/// too: never outside the tests.
#[cfg(not(test))]
#[inline(always)]
fn general_path_forced() -> bool {
    false
}

#[cfg(test)]
thread_local! {
    /// Set by a test to take a one-cell move through the general path.
    pub(super) static GENERAL_PATH: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

#[cfg(test)]
fn general_path_forced() -> bool {
    GENERAL_PATH.with(std::cell::Cell::get)
}

/// `Scratch::slot` of a sample not evaluated.
const NO_PROBE: u32 = u32::MAX;

/// Per-thread buffers of [`RotaryEnvelope::intervals_in`], reused from ray to ray.
#[derive(Default)]
struct Scratch {
    grown: Vec<bool>,
    /// Per sample, its probe's index in `probes` or [`NO_PROBE`].
    slot: Vec<u32>,
    probes: Vec<Probe>,
    comp_of: Vec<Option<usize>>,
    comps: Vec<Option<RawEnd>>,
    cuts: Vec<RawEnd>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// One end of an interval and where it was found: its normal is worked out only for the
/// ends that are kept.
#[derive(Clone, Copy, Debug)]
struct End {
    t: Real,
    face: Face,
    /// The end's point and the ray's direction in the tool frame, and the pose's rotation.
    q: Vector3,
    u: Vector3,
    rot: Matrix3,
    /// The pose's angular velocity and tip velocity (tool frame), for the normal of the
    /// surface an edge sweeps.
    w_t: Vector3,
    v_t: Vector3,
}

impl End {
    #[inline(always)]
    fn at(p: &Probe, t: Real, face: Face) -> Self {
        Self {
            t,
            face,
            q: p.p + p.u * t,
            u: p.u,
            rot: p.rot,
            w_t: p.w_t,
            v_t: p.v_t,
        }
    }

    /// The material normal (W): the inward normal of the swept volume at the end. On an
    /// edge circle (within [`EDGE_REACH`]) the normal of the surface the edge sweeps
    /// ([`edge_normal`]); elsewhere the tool's inward normal on the end's face, the ray where
    /// no face. `edges`: the edge circles' plane heights in the tool frame (NaN for none),
    /// `r` the tool radius.
    fn normal(&self, r: Real, edges: [Real; 2]) -> Vector3 {
        if let Some(n) = edge_normal(&self.q, (&self.w_t, &self.v_t), r, edges) {
            return -(self.rot * n);
        }
        match tool_normal(&self.q, self.face, r) {
            Some(n) => -(self.rot * n),
            None => self.rot * self.u,
        }
    }
}

/// How far from an edge circle (mm, in radius and in height) an end takes the swept edge's
/// normal ([`edge_normal`]). An end at a kink, where the ray passes through the edge, lies
/// on the edge to within the solve's bracket, far inside this; an end on a face this close
/// to the edge has the face's normal to within the edge point's velocity change over it.
const EDGE_REACH: Real = 1e-3;

/// Below this share of the edge point's speed across the edge (its velocity's part in the
/// plane of the edge's two face normals), the edge slides along itself and the swept
/// surface's normal is not read from it: the face's normal is taken.
const EDGE_MIN_ACROSS: Real = 1e-3;

/// The outward normal (tool frame) of the surface swept by the edge circle nearest the
/// tool-frame point `q` (radius `r`, planes at the heights `edges`, bottom and top; NaN for
/// none), at its point nearest `q`, the pose moving at `w × x + v` (`rates`). The edge's
/// outward normals span the quarter circle between the radial direction `ρ` and the
/// plane's axial normal `a` (`−z` at the bottom, `+z` at the top). Where the edge point's
/// velocity `V` has parts of opposite signs along them, one of those normals is across `V`,
/// `|a·V|·ρ + |ρ·V|·a`: the swept surface's normal (`τ × V`, `τ` the edge's tangent), which
/// at a kink of the interval end (the two faces' rates of opposite signs) is neither face's,
/// and which tends to the face's own where that face's rate vanishes. `None` where `q` is
/// not within [`EDGE_REACH`] of an edge, no normal of the edge is across `V`, or `V` runs
/// along the edge.
fn edge_normal(
    q: &Vector3,
    (w, v): (&Vector3, &Vector3),
    r: Real,
    edges: [Real; 2],
) -> Option<Vector3> {
    let rho = q.xy().norm();
    if rho.is_nan() || (rho - r).abs() > EDGE_REACH || rho == 0.0 {
        return None;
    }
    let top = (0..2).find(|&k| (q.z - edges[k]).abs() <= EDGE_REACH)? == 1;
    let h = edges[usize::from(top)];
    let radial = Vector3::new(q.x / rho, q.y / rho, 0.0);
    let point = Vector3::new(radial.x * r, radial.y * r, h);
    let axial = if top { Vector3::z() } else { -Vector3::z() };
    let vel = w.cross(&point) + v;
    let (av, rv) = (axial.dot(&vel), radial.dot(&vel));
    if av.hypot(rv) <= EDGE_MIN_ACROSS * vel.norm() {
        return None;
    }
    // along ρ and along a, both at least 0 for a normal of the edge
    let (x, y) = if av >= 0.0 && rv <= 0.0 {
        (av, -rv)
    } else if av <= 0.0 && rv >= 0.0 {
        (-av, rv)
    } else {
        return None;
    };
    (radial * x + axial * y).try_normalize(0.0)
}

/// An interval: its lower and upper ends.
#[derive(Clone, Copy, Debug)]
struct RawEnd {
    lo: End,
    hi: End,
}

/// Widens `best` by the interval of the probe, if the ray meets the tool there.
#[inline(always)]
fn offer(best: &mut Option<RawEnd>, p: &Probe) {
    let Some(h) = p.hit else {
        return;
    };
    match best {
        None => {
            *best = Some(RawEnd {
                lo: End::at(p, h.t_in, h.face_in),
                hi: End::at(p, h.t_out, h.face_out),
            })
        }
        Some(c) => {
            if h.t_in < c.lo.t {
                c.lo = End::at(p, h.t_in, h.face_in);
            }
            if h.t_out > c.hi.t {
                c.hi = End::at(p, h.t_out, h.face_out);
            }
        }
    }
}
