//! LinuxCNC tool tables (`.tbl`), parameter files (`.var`) and the `[RS274NGC]` part of an
//! INI file.
//!
//! Lengths in tool tables and var files are in the *external* length unit
//! ([`super::LengthUnit`]); they are converted to mm by the interpreter.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::math::Real;

/// One tool table entry (values in the file's length unit).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ToolEntry {
    /// Pocket number (`P`).
    pub pocket: i32,
    /// Offsets X Y Z A B C (lengths in the external unit, angles in degrees).
    pub offset: [Real; 6],
    /// Diameter (`D`).
    pub diameter: Real,
}

/// A tool table: tool number → entry.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct ToolTable {
    /// Entries by tool number.
    pub tools: BTreeMap<i32, ToolEntry>,
}

/// A problem in a tool table, var or INI file: 1-based line and message.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{path}:{line}: {message}")]
pub struct TableError {
    /// File.
    pub path: String,
    /// 1-based line.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

fn table_error(path: &Path, line: usize, message: String) -> TableError {
    TableError {
        path: path.display().to_string(),
        line,
        message,
    }
}

impl ToolTable {
    /// Parses LinuxCNC's tool table format (`T1 P1 Z+1.0 D0.25 ;comment`).
    pub fn parse(text: &str, path: &Path) -> Result<ToolTable, TableError> {
        let mut tools = BTreeMap::new();
        for (index, raw) in text.lines().enumerate() {
            let line = raw.split(';').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let mut number = None;
            let mut entry = ToolEntry::default();
            for word in line.split_whitespace() {
                let mut chars = word.chars();
                let letter = chars.next().unwrap_or(' ').to_ascii_uppercase();
                let value: Real = chars
                    .as_str()
                    .parse()
                    .map_err(|_| table_error(path, index + 1, format!("bad word \"{word}\"")))?;
                if !value.is_finite() {
                    return Err(table_error(path, index + 1, format!("bad word \"{word}\"")));
                }
                match letter {
                    'T' => number = Some(value as i32),
                    'P' => entry.pocket = value as i32,
                    'X' => entry.offset[0] = value,
                    'Y' => entry.offset[1] = value,
                    'Z' => entry.offset[2] = value,
                    'A' => entry.offset[3] = value,
                    'B' => entry.offset[4] = value,
                    'C' => entry.offset[5] = value,
                    'D' => entry.diameter = value,
                    'U' | 'V' | 'W' | 'I' | 'J' | 'Q' => {}
                    _ => {
                        return Err(table_error(
                            path,
                            index + 1,
                            format!("unknown word \"{word}\""),
                        ));
                    }
                }
            }
            let Some(t) = number else {
                return Err(table_error(path, index + 1, "line without T word".into()));
            };
            tools.insert(t, entry);
        }
        Ok(ToolTable { tools })
    }
}

/// Parses a var file (`number value` per line) into (parameter, value) pairs.
pub fn parse_var_file(text: &str, path: &Path) -> Result<Vec<(usize, Real)>, TableError> {
    let mut out = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        let mut it = raw.split_whitespace();
        let (Some(a), Some(b)) = (it.next(), it.next()) else {
            continue;
        };
        let n: usize = a
            .parse()
            .map_err(|_| table_error(path, index + 1, format!("bad parameter \"{a}\"")))?;
        let v: Real = b
            .parse()
            .map_err(|_| table_error(path, index + 1, format!("bad value \"{b}\"")))?;
        if n == 0 || n >= super::lex::NUM_PARAMS || !v.is_finite() {
            return Err(table_error(path, index + 1, format!("bad entry \"{raw}\"")));
        }
        out.push((n, v));
    }
    Ok(out)
}

/// Interpreter settings read from an INI file's `[RS274NGC]` section.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IniSettings {
    /// `SUBROUTINE_PATH` directories (resolved against the INI's folder).
    pub subroutine_path: Vec<PathBuf>,
    /// `DISABLE_FANUC_STYLE_SUB` = 1.
    pub disable_fanuc_subs: bool,
}

/// Parses the `[RS274NGC]` settings of an INI file located at `path`.
pub fn parse_ini(text: &str, path: &Path) -> IniSettings {
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut section = String::new();
    let mut out = IniSettings::default();
    for raw in text.lines() {
        let line = raw.trim();
        if line.starts_with('#') || line.starts_with(';') || line.is_empty() {
            continue;
        }
        if let Some(s) = line.strip_prefix('[') {
            section = s.trim_end_matches(']').trim().to_string();
            continue;
        }
        if section != "RS274NGC" {
            continue;
        }
        let Some((k, v)) = line.split_once('=') else {
            continue;
        };
        match k.trim() {
            "SUBROUTINE_PATH" => {
                out.subroutine_path = v
                    .trim()
                    .split(':')
                    .filter(|s| !s.is_empty())
                    .map(|s| dir.join(s))
                    .collect();
            }
            "DISABLE_FANUC_STYLE_SUB" => {
                out.disable_fanuc_subs = v.trim().parse::<i32>().unwrap_or(0) != 0;
            }
            _ => {}
        }
    }
    out
}
