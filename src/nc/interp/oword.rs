//! O-word control flow: subroutine definitions, calls (found earlier, later in the file or
//! in `NAME.ngc` files of the subroutine path) and returns with their values; if/elseif/
//! else, while, do/while, repeat, break and continue; the skipping of lines up to an O-word
//! target; and Fanuc-style subprograms (`O1000 … M99` called by `M98 P1000 L2`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::math::Real;
use crate::nc::lex::{Block, NoParams, OKeyword, OWord};
use crate::nc::source::{Pos, Source};

use super::Interpreter;
use super::errors::{LR, lerr};

/// A call frame.
pub(super) struct Frame {
    ret: Pos,
    saved: [Real; 30],
    locals: HashMap<String, Real>,
    fanuc: bool,
    repeat_left: u32,
    start: Pos,
    label: String,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum LoopKind {
    While,
    Do,
    Repeat,
}

pub(super) struct LoopState {
    kind: LoopKind,
    pos: Pos,
    left: i64,
}

/// What to do when a skip reaches its target line.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum SkipThen {
    /// Execute the target line normally.
    Exec,
    /// Resume after the target line.
    Consume,
    /// A forward search for a sub: call it when found.
    CallFound,
}

pub(super) struct Skip {
    label: String,
    until: &'static [OKeyword],
    then: SkipThen,
    /// Skipping a Fanuc subprogram body: ends at an M99 line.
    fanuc_body: bool,
    /// For CallFound: the pending call.
    call: Option<PendingCall>,
}

#[derive(Clone)]
struct PendingCall {
    label: String,
    args: Vec<Real>,
    fanuc: bool,
    repeat: u32,
    ret: Pos,
    err_line: usize,
    err_path: Arc<Path>,
    searched_external: bool,
}

impl Interpreter {
    /// The end of the file (or a closing `%`) at line `last`.
    pub(super) fn at_eof_line(&mut self, last: usize, percent: bool) {
        self.line_no = last;
        if let Some(skip) = &self.skip {
            if let Some(call) = skip.call.clone()
                && !call.searched_external
                && !percent
                && !call.fanuc
            {
                self.skip = None;
                if let Err(e) = self.call_external(call) {
                    self.fail(e);
                }
                return;
            }
            let msg = match &skip.call {
                Some(c) if c.fanuc || percent => {
                    format!("Failed to find sub 'O{}' before EOF", c.label)
                }
                Some(c) => format!("Unable to find subroutine o{}", c.label),
                None => format!("Reached end of file while skipping to O{}", skip.label),
            };
            let e = lerr(1, "", msg);
            self.fail(e);
            return;
        }
        if self.cur != 0 || !self.frames.is_empty() {
            let e = lerr(1, "", "File ended inside a subroutine");
            self.fail(e);
            return;
        }
        if self.percent_started {
            let e = lerr(1, "", "File ended with no percent sign");
            self.fail(e);
            return;
        }
        let e = lerr(1, "", "File ended with no percent sign or program end");
        self.fail(e);
    }

    /// A line read while skipping to an O-word target.
    pub(super) fn skip_line(&mut self) -> LR<()> {
        let r = self.lexer.read(&self.buf, &NoParams);
        if r.is_err() {
            return Ok(());
        }
        let Some(skip) = &self.skip else {
            return Ok(());
        };
        if skip.fanuc_body {
            if self.lexer.block.ms().iter().any(|(m, _)| *m == 99) {
                self.skip = None;
            }
            return Ok(());
        }
        let Some(o) = &self.lexer.block.o else {
            return Ok(());
        };
        // remember sub definitions passed over by a forward search
        if skip.then == SkipThen::CallFound {
            let target = skip.call.as_ref().map(|c| (c.label.clone(), c.fanuc));
            if let Some((label, fanuc)) = target {
                let is_def = if fanuc {
                    o.keyword == OKeyword::Fanuc
                } else {
                    o.keyword == OKeyword::Sub
                };
                let wrong_style = if fanuc {
                    o.keyword == OKeyword::Sub
                } else {
                    o.keyword == OKeyword::Fanuc
                };
                if wrong_style && o.label == label {
                    self.skip = None;
                    let msg = if fanuc {
                        "'O.... sub' subroutine must be called with 'O.... call'"
                    } else {
                        "Fanuc 'O....' subroutine must be called with 'M98'"
                    };
                    let at = self.lexer.block.o_pos;
                    return Err(self.err_at(at, msg));
                }
                if is_def && o.label == label {
                    let skip = self.skip.take();
                    let pos = self.tell();
                    if fanuc {
                        self.fanuc_subs.insert(label, pos);
                    } else {
                        self.subs.insert(label, pos);
                    }
                    if let Some(call) = skip.and_then(|s| s.call) {
                        return self.enter_sub(call, pos);
                    }
                    return Ok(());
                }
                if o.keyword == OKeyword::Sub && !self.subs.contains_key(&o.label) {
                    let pos = self.tell();
                    self.subs.insert(o.label.clone(), pos);
                }
            }
            return Ok(());
        }
        if o.keyword == OKeyword::Sub && skip.until == [OKeyword::EndSub] && o.label != skip.label {
            let at = self.lexer.block.o_pos;
            self.skip = None;
            return Err(self.err_at(at, "Nested subroutine definition"));
        }
        if o.label == skip.label && skip.until.contains(&o.keyword) {
            let then = skip.then;
            self.skip = None;
            if then == SkipThen::Exec {
                // re-read with real parameters and execute
                if let Err(e) = self.lexer.read(&self.buf, &self.params) {
                    return Err(self.lex_error(e));
                }
                return self.exec_lexed();
            }
            if let Some(o) = &self.lexer.block.o {
                let key = (self.frames.len(), o.label.clone());
                if matches!(
                    o.keyword,
                    OKeyword::EndWhile | OKeyword::EndRepeat | OKeyword::While
                ) {
                    self.loops.remove(&key);
                }
                if o.keyword == OKeyword::EndIf {
                    self.ifs.remove(&key);
                }
            }
        }
        Ok(())
    }

    fn skip_to(&mut self, label: &str, until: &'static [OKeyword], then: SkipThen) {
        self.skip = Some(Skip {
            label: label.to_string(),
            until,
            then,
            fanuc_body: false,
            call: None,
        });
    }

    pub(super) fn oword(&mut self, o: &OWord, b: &Block) -> LR<()> {
        let depth = self.frames.len();
        let key = (depth, o.label.clone());
        let here = self.line_start;
        let opos = b.o_pos;
        match o.keyword {
            OKeyword::Sub => {
                let pos = self.tell();
                if let Some(f) = self.frames.last()
                    && !f.fanuc
                    && f.label == o.label
                {
                    return Err(self.err_at(opos, "Nested subroutine definition"));
                }
                if self.main_title && self.frames.is_empty() {
                    let msg = format!(
                        "File:{} line:{} sub: o|{}| found in illegal location",
                        self.files[self.cur].path.display(),
                        self.line_no,
                        o.label.trim_start_matches('<').trim_end_matches('>')
                    );
                    return Err(self.err_at(opos, msg));
                }
                self.subs.insert(o.label.clone(), pos);
                self.skip_to(&o.label, &[OKeyword::EndSub], SkipThen::Consume);
            }
            OKeyword::Fanuc => {
                // in the normal flow a bare O-number is a program title; subprogram bodies
                // are found by the search of an M98 call
                self.main_title = true;
            }
            OKeyword::EndSub | OKeyword::Return => {
                if self.frames.is_empty() {
                    if o.keyword == OKeyword::Return {
                        return Err(self.err_at(opos, "Return outside of a subroutine"));
                    }
                    return Err(self.err_at(opos, "Endsub outside of a subroutine"));
                }
                if self.frames.last().is_some_and(|f| f.fanuc) {
                    return Err(self.err_at(
                        opos,
                        "Fanuc 'O....' subroutine definition must end with 'M99'",
                    ));
                }
                if let Some(v) = o.value {
                    self.params.globals.insert("_value".into(), v);
                    self.params.globals.insert("_value_returned".into(), 1.0);
                } else {
                    self.params.globals.insert("_value".into(), 0.0);
                    self.params.globals.insert("_value_returned".into(), 0.0);
                }
                self.return_from_sub()?;
            }
            OKeyword::Call => {
                let call = PendingCall {
                    label: o.label.clone(),
                    args: o.args.clone(),
                    fanuc: false,
                    repeat: 1,
                    ret: self.tell(),
                    err_line: self.line_no,
                    err_path: self.path(),
                    searched_external: false,
                };
                if self.fanuc_subs.contains_key(&o.label) && !self.subs.contains_key(&o.label) {
                    return Err(
                        self.err_at(opos, "Fanuc 'O....' subroutine must be called with 'M98'")
                    );
                }
                self.call(call)?;
            }
            OKeyword::If => {
                let c = o.value.unwrap_or(0.0) != 0.0;
                self.ifs.insert(key, c);
                if !c {
                    self.skip_to(
                        &o.label,
                        &[OKeyword::ElseIf, OKeyword::Else, OKeyword::EndIf],
                        SkipThen::Exec,
                    );
                }
            }
            OKeyword::ElseIf => {
                let taken = self.ifs.get(&key).copied().unwrap_or(true);
                if taken {
                    self.skip_to(&o.label, &[OKeyword::EndIf], SkipThen::Consume);
                } else {
                    let c = o.value.unwrap_or(0.0) != 0.0;
                    if c {
                        self.ifs.insert(key, true);
                    } else {
                        self.skip_to(
                            &o.label,
                            &[OKeyword::ElseIf, OKeyword::Else, OKeyword::EndIf],
                            SkipThen::Exec,
                        );
                    }
                }
            }
            OKeyword::Else => {
                let taken = self.ifs.get(&key).copied().unwrap_or(true);
                if taken {
                    self.skip_to(&o.label, &[OKeyword::EndIf], SkipThen::Consume);
                } else {
                    self.ifs.insert(key, true);
                }
            }
            OKeyword::EndIf => {
                self.ifs.remove(&key);
            }
            OKeyword::Do => {
                let pos = self.tell();
                self.loops.insert(
                    key,
                    LoopState {
                        kind: LoopKind::Do,
                        pos,
                        left: 0,
                    },
                );
            }
            OKeyword::While => {
                let c = o.value.unwrap_or(0.0) != 0.0;
                if let Some(l) = self.loops.get(&key)
                    && l.kind == LoopKind::Do
                {
                    if c {
                        let p = l.pos;
                        self.seek(p)?;
                    } else {
                        self.loops.remove(&key);
                    }
                    return Ok(());
                }
                if c {
                    self.loops.insert(
                        key,
                        LoopState {
                            kind: LoopKind::While,
                            pos: here,
                            left: 0,
                        },
                    );
                } else {
                    self.loops.remove(&key);
                    self.skip_to(&o.label, &[OKeyword::EndWhile], SkipThen::Consume);
                }
            }
            OKeyword::EndWhile => {
                if let Some(l) = self.loops.get(&key) {
                    let p = l.pos;
                    self.seek(p)?;
                }
            }
            OKeyword::Repeat => {
                let n = o.value.unwrap_or(0.0).round() as i64;
                if n > 0 {
                    let pos = self.tell();
                    self.loops.insert(
                        key,
                        LoopState {
                            kind: LoopKind::Repeat,
                            pos,
                            left: n,
                        },
                    );
                } else {
                    self.skip_to(&o.label, &[OKeyword::EndRepeat], SkipThen::Consume);
                }
            }
            OKeyword::EndRepeat => {
                if let Some(l) = self.loops.get_mut(&key) {
                    l.left -= 1;
                    if l.left > 0 {
                        let p = l.pos;
                        self.seek(p)?;
                    } else {
                        self.loops.remove(&key);
                    }
                }
            }
            OKeyword::Break => {
                let kind = self.loops.get(&key).map(|l| l.kind);
                self.loops.remove(&key);
                match kind {
                    Some(LoopKind::Do) => {
                        self.skip_to(&o.label, &[OKeyword::While], SkipThen::Consume)
                    }
                    Some(LoopKind::Repeat) => {
                        self.skip_to(&o.label, &[OKeyword::EndRepeat], SkipThen::Consume)
                    }
                    _ => self.skip_to(&o.label, &[OKeyword::EndWhile], SkipThen::Consume),
                }
            }
            OKeyword::Continue => {
                let l = self.loops.get(&key).map(|l| (l.kind, l.pos));
                match l {
                    Some((LoopKind::While, p)) => self.seek(p)?,
                    Some((LoopKind::Do, _)) => {
                        self.skip_to(&o.label, &[OKeyword::While], SkipThen::Exec)
                    }
                    Some((LoopKind::Repeat, _)) => {
                        self.skip_to(&o.label, &[OKeyword::EndRepeat], SkipThen::Exec)
                    }
                    None => {}
                }
            }
        }
        Ok(())
    }

    fn call(&mut self, call: PendingCall) -> LR<()> {
        let known = if call.fanuc {
            self.fanuc_subs.get(&call.label).copied()
        } else {
            self.subs.get(&call.label).copied()
        };
        if let Some(pos) = known {
            return self.enter_sub(call, pos);
        }
        // search forward in the current file, then in external files
        self.skip = Some(Skip {
            label: call.label.clone(),
            until: &[],
            then: SkipThen::CallFound,
            fanuc_body: false,
            call: Some(call),
        });
        Ok(())
    }

    fn call_external(&mut self, mut call: PendingCall) -> LR<()> {
        call.searched_external = true;
        let name = call
            .label
            .trim_start_matches('<')
            .trim_end_matches('>')
            .to_string();
        let mut dirs: Vec<PathBuf> = self.opts.subroutine_path.clone();
        if let Some(d) = self.files[0].path.parent() {
            dirs.push(d.to_path_buf());
        }
        let restore_line = call.err_line;
        for d in dirs {
            let p = d.join(format!("{name}.ngc"));
            if call.fanuc || !p.is_file() {
                continue;
            }
            if let Ok(src) = Source::open(&p) {
                self.files.push(src);
                self.cur = self.files.len() - 1;
                self.skip = Some(Skip {
                    label: call.label.clone(),
                    until: &[],
                    then: SkipThen::CallFound,
                    fanuc_body: false,
                    call: Some(call),
                });
                return Ok(());
            }
        }
        // report at the calling line
        self.cur = call.ret.file;
        self.line_no = restore_line;
        let msg = if call.fanuc {
            format!("Failed to find sub 'O{}' before EOF", call.label)
        } else {
            format!("Unable to open file <{name}.ngc>")
        };
        let _ = call.err_path;
        Err(lerr(1, &format!("o{}", call.label), msg))
    }

    fn enter_sub(&mut self, call: PendingCall, pos: Pos) -> LR<()> {
        if self.frames.len() > 200 {
            return Err(lerr(1, "", "Too many nested subroutine calls"));
        }
        let mut saved = [0.0; 30];
        saved.copy_from_slice(&self.params.numbered[1..31]);
        if !call.fanuc {
            for i in 0..30 {
                self.params.numbered[1 + i] = call.args.get(i).copied().unwrap_or(0.0);
            }
        }
        self.frames.push(Frame {
            ret: call.ret,
            saved,
            locals: HashMap::new(),
            fanuc: call.fanuc,
            repeat_left: call.repeat,
            start: pos,
            label: call.label.clone(),
        });
        let locals = if call.fanuc {
            self.params.locals.last().cloned().unwrap_or_default()
        } else {
            HashMap::new()
        };
        self.params.locals.push(locals);
        self.seek(pos)
    }

    fn return_from_sub(&mut self) -> LR<()> {
        let Some(f) = self.frames.pop() else {
            return Ok(());
        };
        let depth = self.frames.len() + 1;
        self.loops.retain(|(d, _), _| *d < depth);
        self.ifs.retain(|(d, _), _| *d < depth);
        self.params.locals.pop();
        let _ = f.locals;
        if !f.fanuc {
            self.params.numbered[1..31].copy_from_slice(&f.saved);
        }
        self.seek(f.ret)
    }

    /// M98 P… L…: calls a Fanuc-style subprogram, L times.
    pub(super) fn m98(&mut self, b: &Block, pos: usize) -> LR<()> {
        let Some(p) = b.word(b'p') else {
            return Err(self.err_at(pos, "Found 'm98' code with no P-word"));
        };
        let label = (p.round() as i64).to_string();
        if self.subs.contains_key(&label) && !self.fanuc_subs.contains_key(&label) {
            return Err(self.err_at(
                pos,
                "'O.... sub' subroutine must be called with 'O.... call'",
            ));
        }
        // LinuxCNC: L0 does not call (nor look for) the subprogram
        let repeat = match self.l_count(b)? {
            Some(0) => return Ok(()),
            Some(l) => u32::try_from(l).unwrap_or(u32::MAX),
            None => 1,
        };
        let call = PendingCall {
            label,
            args: Vec::new(),
            fanuc: true,
            repeat,
            ret: self.tell(),
            err_line: self.line_no,
            err_path: self.path(),
            searched_external: false,
        };
        self.call(call)
    }

    /// M99: repeats or ends the Fanuc-style subprogram being executed.
    pub(super) fn m99(&mut self, pos: usize) -> LR<()> {
        match self.frames.last_mut() {
            Some(f) if f.fanuc => {
                if f.repeat_left > 1 {
                    f.repeat_left -= 1;
                    let p = f.start;
                    self.seek(p)?;
                } else {
                    self.return_from_sub()?;
                }
            }
            Some(_) => {
                return Err(self.err_at(pos, "'O.... endsub' or 'O.... return' must follow 'O.... sub' subroutine definition"));
            }
            None => {
                // M99 in the main program: rs274 ends the program here
                self.end_program();
            }
        }
        Ok(())
    }
}
