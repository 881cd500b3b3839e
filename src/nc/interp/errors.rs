//! Errors located on the line being executed (column and offending word), and the report of
//! an error that stops the program: the error itself plus every syntax error of the rest of
//! the file.

use crate::nc::lex::{Block, LexError, Lexer, NoParams};
use crate::nc::{Diagnostic, NcError};

use super::{Interpreter, RunState};

/// A located error for the current line.
pub(super) struct LineErr {
    col: usize,
    word: String,
    message: String,
}

pub(super) type LR<T> = Result<T, LineErr>;

pub(super) fn lerr(col: usize, word: &str, message: impl Into<String>) -> LineErr {
    LineErr {
        col,
        word: word.to_string(),
        message: message.into(),
    }
}

impl Interpreter {
    fn col(&self, byte: usize) -> usize {
        let b = byte.min(self.buf.len());
        String::from_utf8_lossy(&self.buf[..b]).chars().count() + 1
    }

    fn word_text(&self, byte: usize) -> String {
        let b = byte.min(self.buf.len());
        let rest = &self.buf[b..];
        let mut end = 1.min(rest.len());
        while end < rest.len()
            && !rest[end].is_ascii_alphabetic()
            && rest[end] != b'('
            && rest[end] != b';'
        {
            end += 1;
        }
        String::from_utf8_lossy(&rest[..end]).trim().to_string()
    }

    pub(super) fn err_at(&self, byte: usize, message: impl Into<String>) -> LineErr {
        LineErr {
            col: self.col(byte),
            word: self.word_text(byte),
            message: message.into(),
        }
    }

    pub(super) fn err_word(&self, b: &Block, letter: u8, message: impl Into<String>) -> LineErr {
        self.err_at(b.pos(letter), message)
    }

    pub(super) fn err_g(&self, b: &Block, g: i32, message: impl Into<String>) -> LineErr {
        let pos = b
            .gs()
            .iter()
            .find(|(c, _)| *c == g)
            .map_or(0, |(_, p)| *p as usize);
        self.err_at(pos, message)
    }

    pub(super) fn fail(&mut self, e: LineErr) {
        let d = Diagnostic {
            path: self.files[self.cur].path.to_path_buf(),
            line: self.line_no,
            column: e.col,
            word: e.word,
            message: e.message,
        };
        let mut diagnostics = vec![d];
        self.collect_syntax_errors(&mut diagnostics);
        self.error = Some(NcError { diagnostics });
        self.state = RunState::Failed;
    }

    /// After a stopping error: every syntax error of the rest of the current file.
    fn collect_syntax_errors(&mut self, diags: &mut Vec<Diagnostic>) {
        let mut lexer = Lexer::default();
        let mut buf = Vec::new();
        let path = self.files[self.cur].path.to_path_buf();
        loop {
            let (_, line) = self.files[self.cur].tell();
            match self.files[self.cur].read_line(&mut buf) {
                Ok(true) => {}
                _ => break,
            }
            if super::is_percent_line(&buf) {
                continue;
            }
            if let Err(e) = lexer.read(&buf, &NoParams) {
                if e.message.contains("not defined") {
                    continue;
                }
                let col = String::from_utf8_lossy(&buf[..e.start.min(buf.len())])
                    .chars()
                    .count()
                    + 1;
                let word =
                    String::from_utf8_lossy(&buf[e.start.min(buf.len())..e.end.min(buf.len())])
                        .into_owned();
                diags.push(Diagnostic {
                    path: path.clone(),
                    line,
                    column: col,
                    word,
                    message: e.message,
                });
            }
        }
    }

    pub(super) fn lex_error(&self, e: LexError) -> LineErr {
        let s = e.start.min(self.buf.len());
        let end = e.end.clamp(s, self.buf.len());
        LineErr {
            col: self.col(s),
            word: String::from_utf8_lossy(&self.buf[s..end]).into_owned(),
            message: e.message,
        }
    }
}
