//! The small CSV dialect the evaluations read (ISO 230-2 readings, ISO 230-4 traces, ball
//! sensor readings): fields separated by commas, semicolons or tabs; blank lines and lines
//! starting with `#` skipped; a header cell may carry its column's unit in brackets
//! (`deviation[um]`); every number finite.
//!
//! **Invariant:** positions are 1-based lines and columns of the original text, so every
//! message can name `file:line:column`.

use crate::math::Real;
use std::path::{Path, PathBuf};

/// A field of a file that cannot be read, at its place: `file:line:column: message`.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{}:{line}:{column}: {message}", path.display())]
pub struct FieldError {
    /// The file.
    pub path: PathBuf,
    /// 1-based line.
    pub line: usize,
    /// 1-based column (in characters).
    pub column: usize,
    /// What is wrong.
    pub message: String,
}

impl FieldError {
    /// The error at `line`, `column` of `path`.
    pub fn at(path: &Path, line: usize, column: usize, message: String) -> Self {
        Self {
            path: path.to_path_buf(),
            line,
            column,
            message,
        }
    }
}

/// The lines that carry data or a header, with their 1-based numbers: blank lines and
/// `#` comments skipped, a trailing `\r` removed.
pub fn rows(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_end_matches('\r')))
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
}

/// Splits a line into trimmed fields with their 1-based starting columns.
pub fn fields(line: &str) -> Vec<(usize, &str)> {
    let mut out = Vec::new();
    let mut start = 0;
    let mut field_col = 1;
    for (col, (i, c)) in (1..).zip(line.char_indices()) {
        if c == ',' || c == ';' || c == '\t' {
            out.push((field_col, line[start..i].trim()));
            start = i + c.len_utf8();
            field_col = col + 1;
        }
    }
    out.push((field_col, line[start..].trim()));
    out
}

/// A header cell split into its name and its unit in brackets, if any
/// (`deviation[um]` → `("deviation", Some("um"))`); an unclosed bracket is an error.
pub fn name_and_unit(cell: &str) -> Result<(&str, Option<&str>), String> {
    let cell = cell.trim();
    match cell.find('[') {
        None => Ok((cell, None)),
        Some(i) => match cell[i + 1..].strip_suffix(']') {
            Some(u) => Ok((cell[..i].trim(), Some(u.trim()))),
            None => Err(format!("unclosed unit in '{cell}'")),
        },
    }
}

/// The factor to mm of a length unit: `mm`, `um`/`µm`, `in`/`inch`.
pub fn length_unit(unit: &str) -> Option<Real> {
    match unit {
        "mm" => Some(1.0),
        "um" | "µm" | "μm" => Some(1e-3),
        "in" | "inch" => Some(25.4),
        _ => None,
    }
}

/// A finite number, or the message naming `what` was wrong with it.
pub fn number(s: &str, what: &str) -> Result<Real, String> {
    match s.parse::<Real>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(v) => Err(format!("{what} must be finite, got {v}")),
        Err(_) => Err(format!("{what}: '{s}' is not a number")),
    }
}

/// The marker of a set-up record: a `#` line `# set-up: <instrument> key=value …` that a
/// twin's instrument writes above its readings, so an identification can model the test
/// from the file alone (the comment lines are skipped by every reader of the data).
pub const SETUP_MARKER: &str = "# set-up:";

/// The set-up record of `instrument` in `text`: its 1-based line and its `key=value`
/// pairs in order; `None` when the file has none (a real instrument's export).
pub fn setup_record(text: &str, instrument: &str) -> Option<(usize, Vec<(String, String)>)> {
    text.lines().enumerate().find_map(|(k, l)| {
        let rest = l.trim().strip_prefix(SETUP_MARKER)?.trim();
        let mut words = rest.split_whitespace();
        (words.next()? == instrument).then(|| {
            let pairs = words
                .map(|w| match w.split_once('=') {
                    Some((a, b)) => (a.to_string(), b.to_string()),
                    None => (w.to_string(), String::new()),
                })
                .collect();
            (k + 1, pairs)
        })
    })
}

/// Axis values as a record writes them: `X:0.0,Y:0.0,…` (every axis, exact).
pub fn axis_values_record(v: &crate::nc::AxisValues) -> String {
    crate::nc::AxisLetter::ALL
        .iter()
        .map(|a| format!("{}:{:?}", a.as_char(), v.get(*a)))
        .collect::<Vec<_>>()
        .join(",")
}

/// Reads [`axis_values_record`]'s form.
pub fn parse_axis_values_record(s: &str) -> Result<crate::nc::AxisValues, String> {
    let mut v = crate::nc::AxisValues::default();
    for part in s.split(',') {
        let (a, x) = part
            .split_once(':')
            .ok_or_else(|| format!("'{part}' is not AXIS:VALUE"))?;
        let mut c = a.chars();
        let letter = match (c.next(), c.next()) {
            (Some(c), None) => crate::nc::AxisLetter::from_char(c),
            _ => None,
        }
        .ok_or_else(|| format!("'{a}' is not an axis letter"))?;
        v.set(letter, number(x, a)?);
    }
    Ok(v)
}

/// Reads three comma-separated numbers (`0.0,0.0,30.0`).
pub fn parse_vector_record(s: &str, what: &str) -> Result<crate::math::Vector3, String> {
    let v: Vec<Real> = s
        .split(',')
        .map(|x| number(x, what))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [a, b, c] => Ok(crate::math::Vector3::new(a, b, c)),
        _ => Err(format!("{what}: three numbers expected, got '{s}'")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_keep_their_columns_and_units_split_off() {
        assert_eq!(
            fields("a, bb;c\td"),
            vec![(1, "a"), (3, "bb"), (7, "c"), (9, "d")]
        );
        assert_eq!(fields("µ,x"), vec![(1, "µ"), (3, "x")]);
        assert_eq!(name_and_unit(" dev [um] "), Ok(("dev", Some("um"))));
        assert!(name_and_unit("dev[um").is_err());
        assert_eq!(length_unit("in"), Some(25.4));
        assert!(number("nan", "x").unwrap_err().contains("finite"));
        assert!(number("1e", "x").unwrap_err().contains("not a number"));
        let r: Vec<_> = rows("# c\n\nh\r\n1\n").collect();
        assert_eq!(r, vec![(3, "h"), (4, "1")]);
    }
}
