//! LinuxCNC's own regression programs (tests/ccomp, tests/interp), hand-translated: a
//! minimal block reader stands in for the interpreter and the outputs are compared with
//! the canonical calls LinuxCNC 2.9 recorded for them.

use super::super::*;

/// The recorded canon prints 4 decimals (program units, here inches).
const PRINT_EPS: Real = 1e-4;

#[derive(Debug, Clone, PartialEq)]
enum P {
    Move,
    Comment(&'static str),
    Feed(Real),
    /// A queued call without arguments (spindle start/stop).
    Call(&'static str),
    SpindleSpeed(Real),
}

#[derive(Debug, Clone, PartialEq)]
enum Canon {
    Traverse([Real; 3]),
    Feed([Real; 3]),
    /// end1, end2, center1, center2, rotation, normal end.
    Arc([Real; 6]),
    SetFeed(Real),
    Comment(String),
    Call(String),
    SpindleSpeed(Real),
}

fn canon(plane: Plane, o: CompOutput<P>) -> Canon {
    match o {
        CompOutput::Straight {
            rapid, end, along, ..
        } => {
            let p = plane.join(end, along);
            if rapid {
                Canon::Traverse(p)
            } else {
                Canon::Feed(p)
            }
        }
        CompOutput::Arc {
            center,
            ccw,
            turns,
            end,
            along,
            ..
        } => {
            let rot = Real::from(turns) * if ccw { 1.0 } else { -1.0 };
            Canon::Arc([end[0], end[1], center[0], center[1], rot, along])
        }
        CompOutput::Event(e) => event_canon(e),
    }
}

fn event_canon(e: P) -> Canon {
    match e {
        P::Comment(s) => Canon::Comment(s.to_string()),
        P::Feed(f) => Canon::SetFeed(f),
        P::Call(c) => Canon::Call(c.to_string()),
        P::SpindleSpeed(v) => Canon::SpindleSpeed(v),
        P::Move => unreachable!("moves are not events"),
    }
}

/// Centre of an R-format arc (minor arc for R > 0), as RS274/NGC defines it.
fn r_center(s: [Real; 2], e: [Real; 2], r: Real, ccw: bool) -> [Real; 2] {
    let mid = [(s[0] + e[0]) / 2.0, (s[1] + e[1]) / 2.0];
    let chord = dist(s, e);
    let u = [(e[0] - s[0]) / chord, (e[1] - s[1]) / chord];
    let left = [-u[1], u[0]];
    let off = (r * r - chord * chord / 4.0).max(0.0).sqrt();
    let sign = if ccw == (r > 0.0) { 1.0 } else { -1.0 };
    [mid[0] + sign * off * left[0], mid[1] + sign * off * left[1]]
}

/// Just enough of an RS274/NGC block reader for these programs.
struct Nc {
    plane: Plane,
    pos: [Real; 3],
    incremental: bool,
    motion: u32,
    /// Tool number → diameter (the tool table).
    table: &'static [(u32, Real)],
    selected: u32,
    loaded_diameter: Real,
    /// G21: the tool table (inches) is converted to mm.
    metric: bool,
    comp: Option<Compensator<P>>,
    exit_straight: bool,
    out: Vec<Canon>,
}

fn words(line: &str) -> Vec<(char, Real)> {
    let mut text = String::new();
    let mut depth = 0;
    for ch in line.to_lowercase().chars() {
        match ch {
            '(' => depth += 1,
            ')' => depth -= 1,
            ';' if depth == 0 => break,
            c if depth == 0 && !c.is_whitespace() => text.push(c),
            _ => {}
        }
    }
    let mut out = Vec::new();
    let mut chars = text.chars().peekable();
    while let Some(letter) = chars.next() {
        let mut num = String::new();
        while let Some(&c) = chars.peek() {
            if c.is_ascii_digit() || c == '.' || c == '-' || c == '+' {
                num.push(c);
                chars.next();
            } else {
                break;
            }
        }
        out.push((letter, num.parse().unwrap()));
    }
    out
}

impl Nc {
    fn new(table: &'static [(u32, Real)], loaded: u32, pos: [Real; 3]) -> Self {
        let mut nc = Nc {
            plane: Plane::Xy,
            pos,
            incremental: false,
            motion: 0,
            table,
            selected: loaded,
            loaded_diameter: 0.0,
            metric: false,
            comp: None,
            exit_straight: false,
            out: Vec::new(),
        };
        nc.loaded_diameter = nc.diameter(loaded);
        nc
    }

    fn diameter(&self, tool: u32) -> Real {
        let inches = self
            .table
            .iter()
            .find(|(t, _)| *t == tool)
            .map_or(0.0, |(_, d)| *d);
        if self.metric { inches * 25.4 } else { inches }
    }

    fn run(&mut self, program: &str) -> Result<(), CompError> {
        program.lines().try_for_each(|l| self.block(l))
    }

    fn current(&self) -> [Real; 3] {
        match &self.comp {
            Some(c) => self.plane.join(c.programmed(), c.along()),
            None => self.pos,
        }
    }

    fn collect(&mut self) {
        if let Some(c) = self.comp.as_mut() {
            let plane = self.plane;
            self.out.extend(c.drain().map(|o| canon(plane, o)));
        }
    }

    fn event(&mut self, e: P) {
        match self.comp.as_mut() {
            Some(c) => c.push_event(e),
            None => self.out.push(event_canon(e)),
        }
        self.collect();
    }

    fn block(&mut self, line: &str) -> Result<(), CompError> {
        self.block_body(line)?;
        // M0: the held move is released before the stop, which is not queued.
        if words(line).iter().any(|&(l, v)| l == 'm' && v == 0.0) {
            if let Some(c) = self.comp.as_mut() {
                c.release_held()?;
            }
            self.collect();
            self.out.push(Canon::Call("PROGRAM_STOP".to_string()));
        }
        Ok(())
    }

    fn block_body(&mut self, line: &str) -> Result<(), CompError> {
        let w = words(line);
        let get = |c: char| w.iter().find(|(l, _)| *l == c).map(|(_, v)| *v);
        let codes = |c: char| {
            w.iter()
                .filter(move |(l, _)| *l == c)
                .map(|(_, v)| (v * 10.0).round() as i64)
        };
        if let Some(f) = get('f') {
            self.event(P::Feed(f));
        }
        if let Some(v) = get('s') {
            self.event(P::SpindleSpeed(v));
        }
        if let Some(t) = get('t') {
            self.selected = t as u32;
        }
        let g: Vec<i64> = codes('g').collect();
        for &code in &g {
            match code {
                170 => self.plane = Plane::Xy,
                180 => self.plane = Plane::Zx,
                200 => self.metric = false,
                210 => self.metric = true,
                _ => {}
            }
        }
        if codes('m').any(|m| m == 60) {
            self.loaded_diameter = self.diameter(self.selected);
        }
        if codes('m').any(|m| m == 30) {
            self.event(P::Call("START_SPINDLE_CLOCKWISE"));
        }
        if codes('m').any(|m| m == 50) {
            self.event(P::Call("STOP_SPINDLE_TURNING"));
        }
        for &code in &g {
            match code {
                400 => self.g40()?,
                410 | 420 | 411 | 421 => {
                    let side = if code / 10 == 41 {
                        Side::Left
                    } else {
                        Side::Right
                    };
                    let diameter = match (code % 10, get('d')) {
                        (1, Some(d)) => d,
                        (_, Some(d)) => self.diameter(d as u32),
                        (_, None) => self.loaded_diameter,
                    };
                    self.g41(side, diameter)?;
                }
                _ => {}
            }
        }
        for &code in &g {
            match code {
                900 if self.incremental => {
                    self.event(P::Comment("interpreter: distance mode changed to absolute"));
                    self.incremental = false;
                }
                910 if !self.incremental => {
                    self.event(P::Comment(
                        "interpreter: distance mode changed to incremental",
                    ));
                    self.incremental = true;
                }
                _ => {}
            }
        }
        let axes = [get('x'), get('y'), get('z')];
        if g.contains(&920) {
            for (p, v) in self.pos.iter_mut().zip(axes) {
                if let Some(v) = v {
                    *p = v;
                }
            }
            return Ok(());
        }
        for &code in &g {
            if matches!(code, 0 | 10 | 20 | 30) {
                self.motion = (code / 10) as u32;
            }
        }
        let arc_words = ['i', 'j', 'k', 'r'].iter().any(|&c| get(c).is_some());
        if axes.iter().all(Option::is_none) && !(self.motion >= 2 && arc_words) {
            return Ok(());
        }
        let cur = self.current();
        let mut end = cur;
        for i in 0..3 {
            if let Some(v) = axes[i] {
                end[i] = if self.incremental { cur[i] + v } else { v };
            }
        }
        match self.motion {
            0 | 1 => self.straight(self.motion == 0, end),
            _ => {
                let ccw = self.motion == 3;
                let (s, _) = self.plane.split(cur);
                let (e, _) = self.plane.split(end);
                let center = match get('r') {
                    Some(r) => r_center(s, e, r, ccw),
                    None => {
                        let (off, _) = self.plane.split([
                            get('i').unwrap_or(0.0),
                            get('j').unwrap_or(0.0),
                            get('k').unwrap_or(0.0),
                        ]);
                        [s[0] + off[0], s[1] + off[1]]
                    }
                };
                self.arc(ccw, end, center)
            }
        }
    }

    fn g41(&mut self, side: Side, diameter: Real) -> Result<(), CompError> {
        let effective = if diameter < 0.0 {
            side.opposite()
        } else {
            side
        };
        self.event(P::Comment(match effective {
            Side::Left => "interpreter: cutter radius compensation on left",
            Side::Right => "interpreter: cutter radius compensation on right",
        }));
        let (q, a) = self.plane.split(self.pos);
        self.comp = Some(Compensator::new(side, diameter / 2.0, q, a)?);
        Ok(())
    }

    fn g40(&mut self) -> Result<(), CompError> {
        self.event(P::Comment("interpreter: cutter radius compensation off"));
        if let Some(mut c) = self.comp.take() {
            let end = c.finish();
            let plane = self.plane;
            self.out.extend(c.drain().map(|o| canon(plane, o)));
            self.exit_straight = end?.exit_must_be_straight;
            self.pos = plane.join(c.programmed(), c.along());
        }
        Ok(())
    }

    fn straight(&mut self, rapid: bool, end: [Real; 3]) -> Result<(), CompError> {
        self.exit_straight = false;
        let plane = self.plane;
        match self.comp.as_mut() {
            Some(c) => {
                let (q, a) = plane.split(end);
                let r = c.push_move(PlaneMove {
                    kind: PlaneMoveKind::Straight { rapid },
                    end: q,
                    along: a,
                    payload: P::Move,
                });
                self.collect();
                r
            }
            None => {
                self.out.push(if rapid {
                    Canon::Traverse(end)
                } else {
                    Canon::Feed(end)
                });
                self.pos = end;
                Ok(())
            }
        }
    }

    fn arc(&mut self, ccw: bool, end: [Real; 3], center: [Real; 2]) -> Result<(), CompError> {
        if self.exit_straight {
            return Err(CompError::ArcAfterCompOff);
        }
        let plane = self.plane;
        let (q, a) = plane.split(end);
        let mv = PlaneMove {
            kind: PlaneMoveKind::Arc {
                center,
                ccw,
                turns: 1,
            },
            end: q,
            along: a,
            payload: P::Move,
        };
        match self.comp.as_mut() {
            Some(c) => {
                let r = c.push_move(mv);
                self.collect();
                r
            }
            None => {
                self.out.push(canon(
                    plane,
                    CompOutput::Arc {
                        center,
                        ccw,
                        turns: 1,
                        end: q,
                        along: a,
                        payload: P::Move,
                    },
                ));
                self.pos = end;
                Ok(())
            }
        }
    }
}

/// Parses recorded canon lines; keeps motion, feed rates and the interpreter's comp
/// and distance-mode comments.
fn parse(text: &str) -> Vec<Canon> {
    text.lines()
        .filter_map(|l| {
            let l = l.trim();
            let (name, args) = l.split_once('(')?;
            let args = args.strip_suffix(')')?;
            let n: Vec<Real> = if name == "COMMENT" {
                Vec::new()
            } else {
                args.split(',')
                    .filter_map(|a| a.trim().parse().ok())
                    .collect()
            };
            match name {
                "STRAIGHT_FEED" => Some(Canon::Feed([n[0], n[1], n[2]])),
                "STRAIGHT_TRAVERSE" => Some(Canon::Traverse([n[0], n[1], n[2]])),
                "ARC_FEED" => Some(Canon::Arc([n[0], n[1], n[2], n[3], n[4], n[5]])),
                "SET_FEED_RATE" => Some(Canon::SetFeed(n[0])),
                "SET_SPINDLE_SPEED" => Some(Canon::SpindleSpeed(n[n.len() - 1])),
                "START_SPINDLE_CLOCKWISE" | "STOP_SPINDLE_TURNING" | "PROGRAM_STOP" => {
                    Some(Canon::Call(name.to_string()))
                }
                "COMMENT"
                    if args.starts_with("\"interpreter: cutter")
                        || args.starts_with("\"interpreter: distance") =>
                {
                    Some(Canon::Comment(args.trim_matches('"').to_string()))
                }
                _ => None,
            }
        })
        .collect()
}

fn close(a: &[Real], b: &[Real]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= PRINT_EPS)
}

fn assert_canon(got: &[Canon], recorded: &str) {
    let want = parse(recorded);
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        let ok = match (g, w) {
            (Canon::Feed(a), Canon::Feed(b)) | (Canon::Traverse(a), Canon::Traverse(b)) => {
                close(a, b)
            }
            (Canon::Arc(a), Canon::Arc(b)) => close(a, b),
            (Canon::SetFeed(a), Canon::SetFeed(b)) => close(&[*a], &[*b]),
            (Canon::Comment(a), Canon::Comment(b)) | (Canon::Call(a), Canon::Call(b)) => a == b,
            (Canon::SpindleSpeed(a), Canon::SpindleSpeed(b)) => close(&[*a], &[*b]),
            _ => false,
        };
        assert!(
            ok,
            "canon {i}: got {g:?}, LinuxCNC {w:?}\ngot: {:#?}",
            &got[i.saturating_sub(3)..(i + 3).min(got.len())]
        );
    }
    assert_eq!(got.len(), want.len(), "got {got:#?}");
}

/// The tool table of the ccomp tests (inches, diameters).
const TOOLS: &[(u32, Real)] = &[(1, 0.0625), (2, 0.125), (3, 0.25), (4, 1.0), (32, 0.0)];

#[test]
fn mill_line_arc_entry() {
    // tests/ccomp/mill-line-arc-entry, the compensated half (T4: diameter 1.0).
    let mut nc = Nc::new(TOOLS, 4, [2.0, 3.0, 0.0]);
    nc.run(
        "g0 x1 y5
        g41 g1 y4
        g3 x2 y3 i1
        g2 x3 y2 j-1
        g1 y-1
        g2 x2 y-2 i-1
        g1 x-2
        g2 x-2.6 y-0.2 j1
        g1 x1.4 y2.8
        g2 x2 y3 i.6 j-.8
        g40",
    )
    .unwrap();
    assert_canon(
        &nc.out,
        r#"STRAIGHT_TRAVERSE(1.0000, 5.0000, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        STRAIGHT_FEED(1.5000, 4.0000, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(2.0000, 3.5000, 2.0000, 4.0000, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(3.5000, 2.0000, 2.0000, 2.0000, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(3.5000, -1.0000, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(2.0000, -2.5000, 2.0000, -1.0000, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(-2.0000, -2.5000, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(-2.9000, 0.2000, -2.0000, -1.0000, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.1000, 3.2000, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(2.0000, 3.5000, 2.0000, 2.0000, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")"#,
    );
}

#[test]
fn mill_g90g91g92() {
    // tests/ccomp/mill-g90g91g92 (T3: diameter 0.25): R arcs, G91 increments taken
    // from the programmed point, distance-mode comments held behind the deferred
    // move, a Z-only rapid under compensation.
    let mut nc = Nc::new(TOOLS, 3, [0.0, 0.0, 0.0]);
    nc.run(
        "G0 X0 Y0
        F100
        G0 Z1
        X2Y0
        G3 X1Y0 R0.70710678118654752 Z.5
        G2 X0Y1 R1
        G3 X1Y2Z.9 R2
        G1 X2Y1Z.7
        X1Y0Z.5
        G0Z1
        G0 Z1
        G92 Z.5
        X2Y0
        G41
        G3 X1Y0 R0.70710678118654752 Z0
        G91 G2 X-1Y1 R1
        G90 G3 X1Y2Z.4 R2
        G91 G1 X1Y-1Z-.2
        G90 X1Y0Z0
        G0Z1
        G40",
    )
    .unwrap();
    assert_canon(
        &nc.out,
        r#"STRAIGHT_TRAVERSE(0.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(100.0000)
        STRAIGHT_TRAVERSE(0.0000, 0.0000, 1.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(2.0000, 0.0000, 1.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(1.0000, 0.0000, 1.5000, -0.5000, 1, 0.5000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.0000, 1.0000, 1.0000, 1.0000, -1, 0.5000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(1.0000, 2.0000, -0.8229, 2.8229, 1, 0.9000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.0000, 1.0000, 0.7000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.0000, 0.0000, 0.5000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(1.0000, 0.0000, 1.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(1.0000, 0.0000, 1.0000, 0.0000, 0.0000, 0.0000)
        SET_G92_OFFSET(0.0000, 0.0000, 0.5000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(2.0000, 0.0000, 0.5000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        ARC_FEED(1.0884, -0.0884, 1.5979, -0.5979, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: distance mode changed to incremental")
        ARC_FEED(1.0000, -0.1250, 1.0000, 0.0000, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(-0.1250, 1.0000, 1.0000, 1.0000, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: distance mode changed to absolute")
        ARC_FEED(-0.0514, 1.1139, 0.0000, 1.0000, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.8861, 2.0514, -0.8229, 2.8229, 1, 0.4000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: distance mode changed to incremental")
        ARC_FEED(1.0884, 2.0884, 1.0000, 2.0000, -1, 0.4000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.0884, 1.0884, 0.2000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: distance mode changed to absolute")
        ARC_FEED(2.0884, 0.9116, 2.0000, 1.0000, -1, 0.2000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.0884, -0.0884, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(1.0884, -0.0884, 1.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")"#,
    );
}

#[test]
fn bad_ccomp_gouging() {
    // tests/interp/bad/ccomp-gouging.ngc (G41.1 D.25).
    let mut nc = Nc::new(TOOLS, 0, [0.0, 0.0, 0.0]);
    let err = nc
        .run(
            "g0x0y0z0
            g41.1d.25
            g1x1f1
            g1x2
            g1y.1
            g1x1
            g40
            g1x2",
        )
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "Straight feed in concave corner cannot be reached by the tool without gouging"
    );
    assert_canon(
        &nc.out,
        r#"STRAIGHT_TRAVERSE(0.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        SET_FEED_RATE(1.0000)
        STRAIGHT_FEED(1.0000, 0.1250, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.8750, 0.1250, 0.0000, 0.0000, 0.0000, 0.0000)"#,
    );
}

#[test]
fn bad_ccomp_arcexit() {
    // tests/interp/bad/ccomp-arcexit.ngc.
    let mut nc = Nc::new(TOOLS, 0, [0.0, 0.0, 0.0]);
    let err = nc
        .run(
            "g0x0y0z0
            g41.1d.25
            g1x1f1
            g1x2
            g40
            g2i1",
        )
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "The move just after exiting cutter compensation mode must be straight, not an arc"
    );
    assert_canon(
        &nc.out,
        r#"STRAIGHT_TRAVERSE(0.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        SET_FEED_RATE(1.0000)
        STRAIGHT_FEED(1.0000, 0.1250, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.0000, 0.1250, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")"#,
    );
}

#[test]
fn mill_zchanges() {
    // tests/ccomp/mill-zchanges (after its first line, g20 f60): arc and line entries
    // with D0 (no compensation) and D2 (diameter 0.125), the Z change on the entry
    // move, the move after it, or the exit move.
    let mut nc = Nc::new(TOOLS, 0, [0.0, 0.0, 0.0]);
    nc.run(
        r#"
        (arc entry)
        (uncomp)
        g0x0y.5z.25
        g1x.25
        g41 g2 d0 x.5 y.75 i.25 
        g1 x.75 
        g40 x1 
        x1.25 z.25
        
        (comp)
        g0x0y.5z.25
        g1x.25 z0
        g41 g2 d2 x.5 y.75 i.25 
        g1 x.75 
        g40 x1 
        x1.25 z.25
        
        g0x0y.5z.25
        g1x.25
        g41 g2 d2 x.5 y.75 i.25 z0
        g1 x.75 
        g40 x1 
        x1.25 z.25
        
        g0x0y.5z.25
        g1x.25
        g41 g2 d2 x.5 y.75 i.25 
        g1 x.75 z0
        g40 x1 
        x1.25 z.25
        
        g0x0y.5z.25
        g1x.25
        g41 g2 d2 x.5 y.75 i.25
        g1 x.75 
        g40 x1 z0
        x1.25 z.25
        
        
        (line entry)
        (uncomp)
        g0x0y-.5z.25
        g1x.25
        g41 g1 d0 x.5 y-.25
        g1 x.75 
        g40 x1 
        x1.25 z.25
        
        (comp)
        g0x0y-.5z.25
        g1x.25 z0
        g41 g1 d2 x.5 y-.25
        g1 x.75 
        g40 x1 
        x1.25 z.25
        
        g0x0y-.5z.25
        g1x.25
        g41 g1 d2 x.5 y-.25 z0
        g1 x.75 
        g40 x1 
        x1.25 z.25
        
        g0x0y-.5z.25
        g1x.25
        g41 g1 d2 x.5 y-.25
        g1 x.75 z0
        g40 x1 
        x1.25 z.25
        
        g0x0y-.5z.25
        g1x.25
        g41 g1 d2 x.5 y-.25
        g1 x.75 
        g40 x1 z0
        x1.25 z.25
        
        
        m2"#,
    )
    .unwrap();
    assert_canon(
        &nc.out,
        r#"STRAIGHT_TRAVERSE(0.0000, 0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, 0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        ARC_FEED(0.5000, 0.7500, 0.5000, 0.5000, -1, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, 0.7500, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, 0.7500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, 0.7500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, 0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, 0.5000, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        ARC_FEED(0.5000, 0.8125, 0.5000, 0.5562, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, 0.8125, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, 0.7500, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, 0.7500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, 0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, 0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        ARC_FEED(0.5000, 0.8125, 0.5000, 0.5562, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, 0.8125, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, 0.7500, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, 0.7500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, 0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, 0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        ARC_FEED(0.5000, 0.8125, 0.5000, 0.5562, -1, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, 0.8125, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, 0.7500, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, 0.7500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, 0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, 0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        ARC_FEED(0.5000, 0.8125, 0.5000, 0.5562, -1, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, 0.8125, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, 0.7500, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, 0.7500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, -0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, -0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        STRAIGHT_FEED(0.5000, -0.2500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, -0.2500, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, -0.2500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, -0.2500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, -0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, -0.5000, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        STRAIGHT_FEED(0.4558, -0.2058, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.5000, -0.1875, 0.5000, -0.2500, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, -0.1875, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, -0.2500, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, -0.2500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, -0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, -0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        STRAIGHT_FEED(0.4558, -0.2058, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.5000, -0.1875, 0.5000, -0.2500, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, -0.1875, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, -0.2500, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, -0.2500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, -0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, -0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        STRAIGHT_FEED(0.4558, -0.2058, 0.2500, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.5000, -0.1875, 0.5000, -0.2500, -1, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, -0.1875, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, -0.2500, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, -0.2500, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, -0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2500, -0.5000, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        STRAIGHT_FEED(0.4558, -0.2058, 0.2500, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.5000, -0.1875, 0.5000, -0.2500, -1, 0.2500, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7500, -0.1875, 0.2500, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        STRAIGHT_FEED(1.0000, -0.2500, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2500, -0.2500, 0.2500, 0.0000, 0.0000, 0.0000)"#,
    );
}

/// tests/interp/inside-corners: the body of subroutine o100 (G17, called with
/// #100 = 0, -.15 and .15: a diameter for G41.1).
const INSIDE_CORNERS_O100: &str = r#"G00 Z0.0200
G00 X0.0000 Y0.0000
G01 Z-0.1000 F8.00
G41.1 D#100
G01 X0.6767 Y0.2334 F8.00
G01 X0.3359 Y0.4419 F8.00
G03 X1.2281 Y1.3456 I0.2921 J0.6039 F8.00
G02 X0.1253 Y0.9881 I-0.6093 J0.0000 F8.00
G03 X0.7669 Y1.4548 I0.2437 J0.3394 F8.00
G03 X0.6867 Y1.7527 I0.1687 J0.2052 F8.00
G02 X0.3459 Y1.7626 I-0.1687 J0.0629 F8.00
G01 X0.0652 Y1.5342 F8.00
G01 X0.0652 Y2.4577 F8.00
G02 X0.6065 Y2.4577 I0.2707 J0.0000 F8.00
G02 X1.4888 Y2.4577 I0.4411 J0.0000 F8.00
G02 X1.8597 Y2.4577 I0.1855 J0.0000 F8.00
G02 X1.3585 Y2.0307 I-0.4325 J0.0000 F8.00
G03 X2.3911 Y2.1499 I0.4303 J0.8046 F8.00
G01 X2.1404 Y1.3952 F8.00
G03 X1.7494 Y1.6236 I-0.2261 J0.0618 F8.00
G03 X2.5014 Y1.3456 I0.3111 J-0.3144 F8.00
G01 X2.7720 Y1.4846 F8.00
G01 X2.6618 Y2.8450 F8.00
G03 X2.2708 Y2.8450 I-0.1955 J-0.0158 F8.00
G03 X1.8296 Y2.8450 I-0.2206 J0.0000 F8.00
G01 X1.8296 Y3.5600 F8.00 ; XXX
G01 X1.2883 Y3.5600 F8.00
G03 X1.2883 Y3.2720 I0.0000 J-0.1440 F8.00
G01 X1.4587 Y3.2720 F8.00
G02 X1.4587 Y3.0138 I0.0000 J-0.1291 F8.00
G02 X0.7970 Y3.4408 I0.0000 J0.7262 F8.00
G02 X1.0376 Y3.8083 I0.2371 J0.1072 F8.00
G02 X3.2332 Y3.5004 I-0.1183 J-8.8277 F8.00
G02 X3.2132 Y2.9940 I-0.0681 J-0.2509 F8.00
G03 X3.0728 Y2.5968 I0.0450 J-0.2393 F8.00
G02 X3.4437 Y2.1003 I-3.7014 J-3.1521 F8.00
G02 X3.1530 Y0.9682 I-0.6638 J-0.4329 F8.00
G01 X3.2633 Y0.4518 F8.00
G01 X2.6317 Y0.8391 F8.00
G01 X2.3409 Y0.3227 F8.00
G01 X2.1805 Y0.4419 F8.00
G01 X1.7093 Y0.1440 F8.00
G01 X1.4086 Y0.4121 F8.00
G40
G01 X1.0000 Y0.0000 F8.00
G00 Z1.0000"#;

/// The same profile in G18 (Z first, X second), subroutine o101.
const INSIDE_CORNERS_O101: &str = r#"G18
G00 Z0.0000 X0.0000
G41.1 D#100
G01 Z0.6767 X0.2334 F8.00
G01 Z0.3359 X0.4419 F8.00
G03 Z1.2281 X1.3456 K0.2921 I0.6039 F8.00
G02 Z0.1253 X0.9881 K-0.6093 I0.0000 F8.00
G03 Z0.7669 X1.4548 K0.2437 I0.3394 F8.00
G03 Z0.6867 X1.7527 K0.1687 I0.2052 F8.00
G02 Z0.3459 X1.7626 K-0.1687 I0.0629 F8.00
G01 Z0.0652 X1.5342 F8.00
G01 Z0.0652 X2.4577 F8.00
G02 Z0.6065 X2.4577 K0.2707 I0.0000 F8.00
G02 Z1.4888 X2.4577 K0.4411 I0.0000 F8.00
G02 Z1.8597 X2.4577 K0.1855 I0.0000 F8.00
G02 Z1.3585 X2.0307 K-0.4325 I0.0000 F8.00
G03 Z2.3911 X2.1499 K0.4303 I0.8046 F8.00
G01 Z2.1404 X1.3952 F8.00
G03 Z1.7494 X1.6236 K-0.2261 I0.0618 F8.00
G03 Z2.5014 X1.3456 K0.3111 I-0.3144 F8.00
G01 Z2.7720 X1.4846 F8.00
G01 Z2.6618 X2.8450 F8.00
G03 Z2.2708 X2.8450 K-0.1955 I-0.0158 F8.00
G03 Z1.8296 X2.8450 K-0.2206 I0.0000 F8.00
G01 Z1.8296 X3.5600 F8.00 ; XXX
G01 Z1.2883 X3.5600 F8.00
G03 Z1.2883 X3.2720 K0.0000 I-0.1440 F8.00
G01 Z1.4587 X3.2720 F8.00
G02 Z1.4587 X3.0138 K0.0000 I-0.1291 F8.00
G02 Z0.7970 X3.4408 K0.0000 I0.7262 F8.00
G02 Z1.0376 X3.8083 K0.2371 I0.1072 F8.00
G02 Z3.2332 X3.5004 K-0.1183 I-8.8277 F8.00
G02 Z3.2132 X2.9940 K-0.0681 I-0.2509 F8.00
G03 Z3.0728 X2.5968 K0.0450 I-0.2393 F8.00
G02 Z3.4437 X2.1003 K-3.7014 I-3.1521 F8.00
G02 Z3.1530 X0.9682 K-0.6638 I-0.4329 F8.00
G01 Z3.2633 X0.4518 F8.00
G01 Z2.6317 X0.8391 F8.00
G01 Z2.3409 X0.3227 F8.00
G01 Z2.1805 X0.4419 F8.00
G01 Z1.7093 X0.1440 F8.00
G01 Z1.4086 X0.4121 F8.00
G40
G01 Z1.0000 X0.0000 F8.00"#;

#[test]
fn program_stop_under_compensation() {
    // As LinuxCNC does for M0 (seen in tests/interp/cam-nisley): the held move is
    // released before PROGRAM_STOP, compensation goes on (derived by hand: r = 0.125,
    // a right turn after the stop is a convex corner around (1, 0)).
    let mut nc = Nc::new(TOOLS, 0, [0.0, 0.0, 0.0]);
    nc.run(
        "g41.1 d.25
        g1 x1 f1
        m0
        m3 s1000
        g1 y-1
        g40",
    )
    .unwrap();
    assert_canon(
        &nc.out,
        r#"COMMENT("interpreter: cutter radius compensation on left")
        SET_FEED_RATE(1.0000)
        STRAIGHT_FEED(1.0000, 0.1250, 0.0000, 0.0000, 0.0000, 0.0000)
        PROGRAM_STOP()
        SET_SPINDLE_SPEED(0, 1000.0000)
        START_SPINDLE_CLOCKWISE(0)
        ARC_FEED(1.1250, 0.0000, 1.0000, 0.0000, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.1250, -1.0000, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")"#,
    );
}

#[test]
fn inside_corners_g17_left() {
    // Third call of o100 (#100 = .15): G41.1 with radius 0.075 along a CAM profile of
    // short lines and arcs meeting at concave and convex corners.
    let mut nc = Nc::new(TOOLS, 0, [1.0, 0.0, 1.0]);
    nc.run(&INSIDE_CORNERS_O100.replace("#100", ".15")).unwrap();
    assert_canon(
        &nc.out,
        r#"STRAIGHT_TRAVERSE(1.0000, 0.0000, 0.0200, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, 0.0000, 0.0200, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.0000, 0.0000, -0.1000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on left")
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.5019, 0.2524, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.2968, 0.3779, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.3686, 0.5094, 0.3359, 0.4419, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(1.2235, 1.0250, 0.6280, 1.0458, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.0646, 0.9441, 0.6188, 1.3456, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.1690, 1.0490, 0.1253, 0.9881, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.6955, 1.4319, 0.3690, 1.3275, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.8145, 1.5127, 0.7669, 1.4548, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.7570, 1.7265, 0.9356, 1.6600, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.3250, 1.6489, 0.5180, 1.8156, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.1125, 1.4760, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(-0.0098, 1.5342, 0.0652, 1.5342, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(-0.0098, 2.4577, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.5885, 2.6936, 0.3359, 2.4577, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.5194, 2.6670, 1.0476, 2.4577, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.9347, 2.4577, 1.6743, 2.4577, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.6616, 2.0076, 1.4272, 2.4577, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.3416, 2.2062, 1.7888, 2.8353, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.4623, 2.1263, 2.3911, 2.1499, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.2116, 1.3716, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.0681, 1.4150, 2.1404, 1.3952, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(1.8022, 1.5703, 1.9143, 1.4570, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.4267, 1.3394, 2.0605, 1.3092, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.4671, 1.4123, 2.5014, 1.3456, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.6932, 1.5284, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(2.5870, 2.8389, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.3456, 2.8390, 2.4663, 2.8292, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.1958, 2.8450, 2.2708, 2.8450, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(1.9046, 2.8450, 2.0502, 2.8450, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.7546, 2.8450, 1.8296, 2.8450, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.7546, 3.4850, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.2883, 3.4850, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.2883, 3.3470, 1.2883, 3.4160, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.4587, 3.3470, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.4587, 2.9388, 1.4587, 3.1429, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.7287, 3.4099, 1.4587, 3.7400, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.0386, 3.8833, 1.0341, 3.5480, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.2529, 3.5728, 0.9193, -5.0194, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.2271, 2.9203, 3.1651, 3.2495, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.1299, 2.6454, 3.2582, 2.7547, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.5065, 2.1413, -0.6286, -0.5553, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.2377, 0.9305, 2.7799, 1.6674, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(3.3366, 0.4675, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.2241, 0.3879, 3.2633, 0.4518, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.6589, 0.7345, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(2.4063, 0.2859, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.2962, 0.2625, 2.3409, 0.3227, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.1771, 0.3510, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.7494, 0.0806, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.6594, 0.0880, 1.7093, 0.1440, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.3587, 0.3561, -0.1000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.0000, 0.0000, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(1.0000, 0.0000, 1.0000, 0.0000, 0.0000, 0.0000)"#,
    );
}

#[test]
fn inside_corners_g17_right_from_negative_diameter() {
    // Second call of o100 (#100 = -.15): the same profile with the tool on the right.
    let mut nc = Nc::new(TOOLS, 0, [1.0, 0.0, 1.0]);
    nc.run(&INSIDE_CORNERS_O100.replace("#100", "-.15"))
        .unwrap();
    assert_canon(
        &nc.out,
        r#"STRAIGHT_TRAVERSE(1.0000, 0.0000, 0.0200, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(0.0000, 0.0000, 0.0200, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.0000, 0.0000, -0.1000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on right")
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.7012, 0.1625, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.7158, 0.2974, 0.6767, 0.2334, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.7051, 0.3040, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.2952, 1.3791, 0.6280, 1.0458, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.1531, 1.3456, 1.2281, 1.3456, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.4443, 0.8405, 0.6188, 1.3456, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.8618, 1.3275, 0.3690, 1.3275, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.6164, 1.7789, 0.9356, 1.6600, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.4176, 1.7847, 0.5180, 1.8156, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.2986, 1.8208, 0.3459, 1.7626, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.1402, 1.6919, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.1402, 2.4577, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.5315, 2.4577, 0.3359, 2.4577, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.6815, 2.4577, 0.6065, 2.4577, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(1.4138, 2.4577, 1.0476, 2.4577, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.5638, 2.4577, 1.4888, 2.4577, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(1.7847, 2.4577, 1.6743, 2.4577, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.3704, 2.1047, 1.4272, 2.4577, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.3231, 1.9646, 1.3585, 2.0307, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(2.2497, 1.9620, 1.7888, 2.8353, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(2.1489, 1.6587, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.6966, 1.6769, 1.9143, 1.4570, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.5778, 1.3005, 2.0605, 1.3092, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(2.8063, 1.4179, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.8468, 1.4907, 2.7720, 1.4846, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.7366, 2.8511, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.2822, 3.0282, 2.4663, 2.8292, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.9046, 3.1023, 2.0502, 2.8450, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.9046, 3.5600, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.8296, 3.6350, 1.8296, 3.5600, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.2883, 3.6350, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.2883, 3.1970, 1.2883, 3.4160, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.4587, 3.1970, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.4587, 3.0888, 1.4587, 3.1429, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.8653, 3.4717, 1.4587, 3.7400, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.0366, 3.7333, 1.0341, 3.5480, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.2135, 3.4280, 0.9193, -5.0194, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.1993, 3.0677, 3.1651, 3.2495, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.0157, 2.5482, 3.2582, 2.7547, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.3809, 2.0593, -0.6286, -0.5553, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.1177, 1.0344, 2.7799, 1.6674, -1, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.0797, 0.9525, 3.1530, 0.9682, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(3.1534, 0.6072, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(2.6709, 0.9030, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.5663, 0.8759, 2.6317, 0.8391, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.3173, 0.4337, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(2.2252, 0.5021, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.1404, 0.5053, 2.1805, 0.4419, 1, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.7170, 0.2376, -0.1000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.4585, 0.4681, -0.1000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.0000, 0.0000, -0.1000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_TRAVERSE(1.0000, 0.0000, 1.0000, 0.0000, 0.0000, 0.0000)"#,
    );
}

#[test]
fn inside_corners_g18_right_from_negative_diameter() {
    // Second call of o101 (#100 = -.15): G41.1 with a negative diameter compensates
    // on the right, in the ZX plane.
    let mut nc = Nc::new(TOOLS, 0, [0.0, 0.0, 1.0]);
    nc.run(&INSIDE_CORNERS_O101.replace("#100", "-.15"))
        .unwrap();
    assert_canon(
        &nc.out,
        r#"SELECT_PLANE(CANON_PLANE_XZ)
        STRAIGHT_TRAVERSE(0.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation on right")
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.1625, 0.0000, 0.7012, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.7158, 0.2974, 0.6767, 0.2334, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.3040, 0.0000, 0.7051, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.2952, 1.3791, 0.6280, 1.0458, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.1531, 1.3456, 1.2281, 1.3456, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(0.4443, 0.8405, 0.6188, 1.3456, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.8618, 1.3275, 0.3690, 1.3275, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.6164, 1.7789, 0.9356, 1.6600, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.4176, 1.7847, 0.5180, 1.8156, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.2986, 1.8208, 0.3459, 1.7626, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(1.6919, 0.0000, 0.1402, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(2.4577, 0.0000, 0.1402, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.5315, 2.4577, 0.3359, 2.4577, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.6815, 2.4577, 0.6065, 2.4577, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(1.4138, 2.4577, 1.0476, 2.4577, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.5638, 2.4577, 1.4888, 2.4577, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(1.7847, 2.4577, 1.6743, 2.4577, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.3704, 2.1047, 1.4272, 2.4577, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.3231, 1.9646, 1.3585, 2.0307, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        ARC_FEED(2.2497, 1.9620, 1.7888, 2.8353, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.6587, 0.0000, 2.1489, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.6966, 1.6769, 1.9143, 1.4570, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.5778, 1.3005, 2.0605, 1.3092, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(1.4179, 0.0000, 2.8063, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.8468, 1.4907, 2.7720, 1.4846, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(2.8511, 0.0000, 2.7366, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.2822, 3.0282, 2.4663, 2.8292, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.9046, 3.1023, 2.0502, 2.8450, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(3.5600, 0.0000, 1.9046, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.8296, 3.6350, 1.8296, 3.5600, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(3.6350, 0.0000, 1.2883, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.2883, 3.1970, 1.2883, 3.4160, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(3.1970, 0.0000, 1.4587, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.4587, 3.0888, 1.4587, 3.1429, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(0.8653, 3.4717, 1.4587, 3.7400, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(1.0366, 3.7333, 1.0341, 3.5480, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.2135, 3.4280, 0.9193, -5.0194, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.1993, 3.0677, 3.1651, 3.2495, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.0157, 2.5482, 3.2582, 2.7547, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.3809, 2.0593, -0.6286, -0.5553, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.1177, 1.0344, 2.7799, 1.6674, -1, 0.0000, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(3.0797, 0.9525, 3.1530, 0.9682, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.6072, 0.0000, 3.1534, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.9030, 0.0000, 2.6709, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.5663, 0.8759, 2.6317, 0.8391, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.4337, 0.0000, 2.3173, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.5021, 0.0000, 2.2252, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        ARC_FEED(2.1404, 0.5053, 2.1805, 0.4419, 1, 0.0000, 0.0000, 0.0000, 0.0000)
        STRAIGHT_FEED(0.2376, 0.0000, 1.7170, 0.0000, 0.0000, 0.0000)
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.4681, 0.0000, 1.4585, 0.0000, 0.0000, 0.0000)
        COMMENT("interpreter: cutter radius compensation off")
        SET_FEED_RATE(8.0000)
        STRAIGHT_FEED(0.0000, 0.0000, 1.0000, 0.0000, 0.0000, 0.0000)"#,
    );
}
