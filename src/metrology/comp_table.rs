//! LinuxCNC's axis (joint) compensation table, `[JOINT_n] COMP_FILE` with
//! `COMP_FILE_TYPE = 1`: written from ISO 230-2 readings, read back, and applied as the
//! LinuxCNC motion controller applies it.
//!
//! # What LinuxCNC does with the file
//!
//! Read in the LinuxCNC sources (repository `LinuxCNC/linuxcnc`):
//!
//! - `src/emc/motion/usrmotintf.cc`, `usrmotLoadComp` (commit
//!   887b6ec8bc497f0fa3c45aae74f36bd57d0450d8): each line is read with
//!   `sscanf("%lf %lf %lf")` as `nominal forward reverse`; **the first line that is not three
//!   numbers ends the file** (a comment line above the table would leave the joint without
//!   compensation). With `COMP_FILE_TYPE = 1` the second and third numbers are the trims as
//!   they stand; with type 0 they are positions, and the trims are `nominal − forward`,
//!   `nominal − reverse`.
//! - `src/emc/motion/command.c`, `EMCMOT_SET_JOINT_COMP` (commit
//!   d307d33d7ed28c132965a833755650e53e513f72): at most `EMCMOT_COMP_SIZE` entries per joint
//!   (256, `src/emc/motion/motion.h`, commit e33e02710ad00a84e7a8f34d252a0ac154f0f818; a
//!   further entry is refused, "too many compensation entries"); each nominal must be greater
//!   than the one before ("compensation values must increase", the entry is refused); the
//!   slope from each entry to the next is stored with it; the table is bounded by sentinel
//!   entries at ∓`DBL_MAX`, the lower one taking the first entry's trims, both with slope 0.
//!   Trims and slopes are stored as `float` (f32).
//! - `src/emc/motion/control.c`, `compute_screw_comp` and `output_to_hal` (commit
//!   829008280317bcf1a5ae94188cc7c9fddefb8f29): the entry with `nominal ≤ pos_cmd` below the
//!   next one is found, the correction is `trim + slope·(pos_cmd − nominal)` — the forward
//!   trim while the joint's commanded velocity is positive, the reverse trim while it is
//!   negative, the last value kept while it stands still — and the motor is commanded to
//!   `pos_cmd + correction` (after a velocity- and acceleration-limited filter that has
//!   settled when the axis stands at a target).
//! - `docs/src/config/ini-config.adoc` (commit d51e915c94a73db3caec68844dff879005d3bd82),
//!   `[JOINT_<num>]`: values in machine units, smallest nominal first in ascending order,
//!   "the limit inside LinuxCNC is for 256 triplets per joint", points between nominals
//!   interpolated. Its wording of type 1 ("positive offset from nominal while traveling in
//!   the positive direction") does not fix the sign; the source does: the trim is *added* to
//!   the command, so it is `nominal − actual`, minus the measured deviation.
//!
//! Hence: below the first nominal the first entry's trims hold, above the last the last
//! entry's, and between entries the trims are interpolated linearly, each direction on its
//! own.
//!
//! # From ISO 230-2 readings
//!
//! A reading is `x = position reached − target` ([`super::positioning`]); the forward trim at
//! a target is `−x̄↑` and the reverse trim `−x̄↓`, so that the compensated axis reaches every
//! target with zero mean deviation in both directions (its bidirectional systematic error
//! vanishes at the targets; between them it is interpolated). The written file holds the
//! triplets first and the provenance after them as `#` lines, where LinuxCNC's reader has
//! already stopped.
//!
//! **Invariant:** a [`CompTable`] always satisfies LinuxCNC's constraints: 1 to
//! [`MAX_ENTRIES`] entries, nominals strictly increasing, every number finite — a table
//! LinuxCNC loads whole.

use super::positioning::{Direction, PositioningFigures};
use crate::math::Real;
use std::path::{Path, PathBuf};

/// Most entries LinuxCNC keeps per joint (`EMCMOT_COMP_SIZE`).
pub const MAX_ENTRIES: usize = 256;

/// One line of the table (mm, or degrees for an angular joint).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompEntry {
    /// Nominal (commanded) position.
    pub nominal: Real,
    /// Correction added to the command while the joint moves in `+`.
    pub forward_trim: Real,
    /// Correction added to the command while the joint moves in `−`.
    pub reverse_trim: Real,
}

/// A table that breaks LinuxCNC's rules, or a file that is not one.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CompError {
    /// A line of a file: not three numbers, a non-finite number, a nominal not above the one
    /// before, one entry too many, a comment above the last entry.
    #[error("{}:{line}: {message}", path.display())]
    Line {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A table as a whole (built from figures, or an empty file).
    #[error("{}: {message}", path.display())]
    Table {
        /// The file the table comes from or goes to.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// A compensation table LinuxCNC loads whole (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct CompTable {
    entries: Vec<CompEntry>,
}

/// What is wrong with the entry `k` (0-based) after `before`, if anything.
fn entry_problem(k: usize, e: &CompEntry, before: Option<&CompEntry>) -> Option<String> {
    if k >= MAX_ENTRIES {
        return Some(format!(
            "entry {} is one too many: LinuxCNC keeps at most {MAX_ENTRIES} per joint \
             (EMCMOT_COMP_SIZE)",
            k + 1
        ));
    }
    for (name, v) in [
        ("nominal", e.nominal),
        ("forward trim", e.forward_trim),
        ("reverse trim", e.reverse_trim),
    ] {
        if !v.is_finite() {
            return Some(format!("the {name} {v} is not finite"));
        }
    }
    match before {
        Some(b) if e.nominal <= b.nominal => Some(format!(
            "nominal {} is not above the one before ({}): LinuxCNC needs them strictly \
             increasing and drops the entry",
            e.nominal, b.nominal
        )),
        _ => None,
    }
}

impl CompTable {
    /// The table of `entries`, checked against LinuxCNC's rules (`path` names it in
    /// messages).
    pub fn try_new(entries: Vec<CompEntry>, path: &Path) -> Result<Self, CompError> {
        if entries.is_empty() {
            return Err(CompError::Table {
                path: path.to_path_buf(),
                message: "no entries".into(),
            });
        }
        for (k, e) in entries.iter().enumerate() {
            if let Some(m) = entry_problem(k, e, k.checked_sub(1).map(|j| &entries[j])) {
                return Err(CompError::Table {
                    path: path.to_path_buf(),
                    message: format!("entry {} (nominal {}): {m}", k + 1, e.nominal),
                });
            }
        }
        Ok(Self { entries })
    }

    /// The table that cancels the mean deviations of ISO 230-2 `figures` at their targets:
    /// forward trim `−x̄↑`, reverse trim `−x̄↓` (`path` names the output in messages).
    pub fn from_figures(figures: &PositioningFigures, path: &Path) -> Result<Self, CompError> {
        let entries = figures
            .targets
            .iter()
            .map(|t| CompEntry {
                nominal: t.target,
                forward_trim: -t.mean_fwd,
                reverse_trim: -t.mean_bwd,
            })
            .collect();
        Self::try_new(entries, path)
    }

    /// The entries, nominals ascending.
    pub fn entries(&self) -> &[CompEntry] {
        &self.entries
    }

    /// The correction LinuxCNC adds to the command `q` while the joint moves (or last moved)
    /// in `direction`: the trims and slopes as its `float`s, interpolated from the entry at or
    /// below `q`; the end entries' trims beyond the table.
    pub fn correction(&self, q: Real, direction: Direction) -> Real {
        let trim = |e: &CompEntry| match direction {
            Direction::Forward => e.forward_trim,
            Direction::Backward => e.reverse_trim,
        } as f32;
        let first = &self.entries[0];
        // The entry with nominal ≤ q (the −DBL_MAX sentinel below the first, holding its
        // trims with slope 0).
        let k = self.entries.partition_point(|e| e.nominal <= q);
        if k == 0 {
            return Real::from(trim(first));
        }
        let e = &self.entries[k - 1];
        let slope: f32 = match self.entries.get(k) {
            Some(next) => {
                ((Real::from(trim(next)) - Real::from(trim(e))) / (next.nominal - e.nominal)) as f32
            }
            None => 0.0,
        };
        Real::from(trim(e)) + Real::from(slope) * (q - e.nominal)
    }

    /// The file's text: one `nominal forward_trim reverse_trim` line per entry (every
    /// number as the shortest decimal that reads back exactly), then `comments` as `#`
    /// lines, after the table where LinuxCNC's reader has stopped.
    pub fn to_text(&self, comments: &[String]) -> String {
        let mut s = String::new();
        for e in &self.entries {
            // `+ 0.0` writes −0 as 0.
            s.push_str(&format!(
                "{} {} {}\n",
                e.nominal + 0.0,
                e.forward_trim + 0.0,
                e.reverse_trim + 0.0
            ));
        }
        for c in comments {
            for line in c.lines() {
                s.push_str("# ");
                s.push_str(line);
                s.push('\n');
            }
        }
        s
    }

    /// Reads a compensation file's text (`path` names it in messages): triplets separated by
    /// spaces or tabs, then optionally blank and `#` lines. Stricter than LinuxCNC, which
    /// silently stops at the first other line: any line of the table that LinuxCNC would not
    /// load whole is an error naming it.
    pub fn parse(text: &str, path: &Path) -> Result<Self, CompError> {
        let at = |line: usize, message: String| CompError::Line {
            path: path.to_path_buf(),
            line,
            message,
        };
        let mut entries: Vec<CompEntry> = Vec::new();
        let mut trailer: Option<usize> = None;
        for (i, raw) in text.lines().enumerate() {
            let line = i + 1;
            let l = raw.trim();
            if l.is_empty() || l.starts_with('#') {
                trailer.get_or_insert(line);
                continue;
            }
            if let Some(t) = trailer {
                return Err(at(
                    line,
                    format!(
                        "an entry after the comment or blank line {t}: LinuxCNC stops reading \
                         at the first line that is not three numbers and would not load it"
                    ),
                ));
            }
            let words: Vec<&str> = l.split_whitespace().collect();
            if words.len() != 3 {
                return Err(at(
                    line,
                    format!(
                        "expected three numbers 'nominal forward_trim reverse_trim', got {} \
                         words",
                        words.len()
                    ),
                ));
            }
            let mut v = [0.0; 3];
            for (k, w) in words.iter().enumerate() {
                v[k] = w
                    .parse::<Real>()
                    .map_err(|_| at(line, format!("'{w}' is not a number")))?;
            }
            let e = CompEntry {
                nominal: v[0],
                forward_trim: v[1],
                reverse_trim: v[2],
            };
            if let Some(m) = entry_problem(entries.len(), &e, entries.last()) {
                return Err(at(line, m));
            }
            entries.push(e);
        }
        if entries.is_empty() {
            return Err(CompError::Table {
                path: path.to_path_buf(),
                message: "no entries (expected lines 'nominal forward_trim reverse_trim')".into(),
            });
        }
        Ok(Self { entries })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(rows: &[[Real; 3]]) -> CompTable {
        CompTable::try_new(
            rows.iter()
                .map(|r| CompEntry {
                    nominal: r[0],
                    forward_trim: r[1],
                    reverse_trim: r[2],
                })
                .collect(),
            Path::new("t.comp"),
        )
        .expect("valid")
    }

    #[test]
    fn corrections_interpolate_per_direction_and_hold_beyond_the_ends() {
        let t = table(&[[0.0, 0.002, -0.001], [10.0, 0.004, 0.001]]);
        let near = |a: Real, b: Real| (a - b).abs() < 1e-9;
        assert!(near(t.correction(5.0, Direction::Forward), 0.003));
        assert!(near(t.correction(5.0, Direction::Backward), 0.0));
        assert!(near(t.correction(-3.0, Direction::Forward), 0.002));
        assert!(near(t.correction(12.0, Direction::Backward), 0.001));
        assert!(near(t.correction(10.0, Direction::Forward), 0.004));
    }

    #[test]
    fn text_round_trips_and_bad_lines_are_named() {
        let t = table(&[[-1.5, 1e-7, -0.0031], [2.0, 0.0, 3.25e-3]]);
        let text = t.to_text(&["made here".into()]);
        assert!(text.ends_with("# made here\n"));
        assert_eq!(CompTable::parse(&text, Path::new("t")).expect("reads"), t);
        let err = |s: &str| CompTable::parse(s, Path::new("x.comp")).expect_err("refused");
        assert!(
            err("0 0 0\n0 1 1\n")
                .to_string()
                .starts_with("x.comp:2: nominal 0")
        );
        assert!(
            err("0 0 nan\n")
                .to_string()
                .starts_with("x.comp:1: the reverse")
        );
        assert!(
            err("# c\n0 0 0\n")
                .to_string()
                .starts_with("x.comp:2: an entry after")
        );
        assert!(err("0 0\n").to_string().contains("three numbers"));
        let many: String = (0..=MAX_ENTRIES).map(|k| format!("{k} 0 0\n")).collect();
        assert!(err(&many).to_string().starts_with("x.comp:257: entry 257"));
    }
}
