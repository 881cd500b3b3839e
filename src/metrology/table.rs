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
