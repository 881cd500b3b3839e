//! Parameters: the numbered ones (`#1`–`#5601`), the local named parameters of each call
//! level and the global ones (`#<_name>`), and the predefined named parameters that read the
//! interpreter's state as of the start of the line (`#<_x>`, `#<_line>`, `#<_metric>` …).

use std::collections::HashMap;

use crate::math::Real;
use crate::nc::lex::ParamRead;

/// Parameters and the state predefined named parameters expose.
pub(crate) struct Params {
    pub numbered: Vec<Real>,
    pub globals: HashMap<String, Real>,
    pub locals: Vec<HashMap<String, Real>>,
    pub snap_pos: [Real; 6],
    pub snap_line: Real,
    pub metric: bool,
    pub incremental: bool,
}

impl ParamRead for Params {
    fn numbered(&self, n: usize) -> Real {
        self.numbered.get(n).copied().unwrap_or(0.0)
    }
    fn named(&self, name: &str) -> Result<Real, String> {
        if let Some(v) = self.lookup(name) {
            return Ok(v);
        }
        Err(format!("Named parameter #<{name}> not defined"))
    }
    fn exists(&self, name: &str) -> bool {
        self.lookup(name).is_some()
    }
}

impl Params {
    fn lookup(&self, name: &str) -> Option<Real> {
        if name.starts_with('_') {
            if let Some(v) = self.globals.get(name) {
                return Some(*v);
            }
            let axis = |i: usize| Some(self.snap_pos[i]);
            return match name {
                "_x" => axis(0),
                "_y" => axis(1),
                "_z" => axis(2),
                "_a" => axis(3),
                "_b" => axis(4),
                "_c" => axis(5),
                "_line" => Some(self.snap_line),
                "_metric" => Some(if self.metric { 1.0 } else { 0.0 }),
                "_imperial" => Some(if self.metric { 0.0 } else { 1.0 }),
                "_absolute" => Some(if self.incremental { 0.0 } else { 1.0 }),
                "_incremental" => Some(if self.incremental { 1.0 } else { 0.0 }),
                "_task" => Some(0.0),
                "_vmajor" => Some(2.0),
                "_vminor" => Some(9.0),
                _ => None,
            };
        }
        self.locals.last().and_then(|m| m.get(name).copied())
    }
}
