//! The memory the tri-dexel stock may use: half the installed memory, or `--memory`.

use crate::math::Real;

/// The memory the tri-dexel may use, and where that figure comes from (for messages).
///
/// By default half the machine's installed memory (`MemTotal` in `/proc/meminfo`; 16 GiB
/// assumed where it cannot be read): a stable figure, so that whether a scene loads does
/// not depend on what else the machine is doing at that moment. The stock is the
/// pipeline's largest structure; the other half is left to the scan, the mesh and the rest
/// of the machine. `--memory SIZE` sets it instead.
#[derive(Clone, Debug, PartialEq)]
pub struct MemoryBudget {
    /// Bytes.
    pub bytes: Real,
    /// Where the figure comes from, as messages say it: `the budget is half of the
    /// installed 23.4 GiB; …`, `the budget is --memory 2G`.
    pub source: String,
}

/// The fraction of the installed memory the tri-dexel may use by default.
pub const INSTALLED_MEMORY_FRACTION: Real = 0.5;

/// Installed memory assumed where `/proc/meminfo` cannot be read (bytes).
const ASSUMED_INSTALLED_BYTES: Real = 16.0 * GIB;

const GIB: Real = 1073741824.0;

impl MemoryBudget {
    /// [`INSTALLED_MEMORY_FRACTION`] of the installed memory.
    pub fn installed() -> Self {
        let total = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("MemTotal:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<Real>().ok())
                .map(|kb| kb * 1024.0)
        });
        let (bytes, what) = match total {
            Some(t) => (t, "installed"),
            None => (ASSUMED_INSTALLED_BYTES, "assumed installed"),
        };
        MemoryBudget {
            bytes: bytes * INSTALLED_MEMORY_FRACTION,
            source: format!(
                "the budget is half of the {what} {:.1} GiB; --memory sets another",
                bytes / GIB
            ),
        }
    }

    /// A budget given as a size: a number of bytes with an optional unit `K`, `M`, `G` or
    /// `T` (powers of 1024; `KiB`, `MB`, … accepted alike), e.g. `2G`, `1.5GiB`, `512M`.
    pub fn parse(text: &str) -> Result<Self, String> {
        let t = text.trim();
        let split = t.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(t.len());
        let (num, unit) = (t[..split].trim(), t[split..].trim());
        let scale = match unit.to_ascii_uppercase().as_str() {
            "" | "B" => 1.0,
            "K" | "KB" | "KIB" => 1024.0,
            "M" | "MB" | "MIB" => 1048576.0,
            "G" | "GB" | "GIB" => GIB,
            "T" | "TB" | "TIB" => 1024.0 * GIB,
            _ => {
                return Err(format!(
                    "--memory: '{}': expected a size such as 2G, 512M or 1.5GiB",
                    text.escape_debug()
                ));
            }
        };
        match num.parse::<Real>() {
            Ok(v) if v.is_finite() && v > 0.0 && (v * scale).is_finite() => Ok(MemoryBudget {
                bytes: v * scale,
                source: format!("the budget is --memory {t}"),
            }),
            _ => Err(format!(
                "--memory: '{}': expected a positive size such as 2G, 512M or 1.5GiB",
                text.escape_debug()
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_sizes_parse_in_powers_of_1024_and_bad_ones_are_refused() {
        for (text, bytes) in [
            ("2G", 2.0 * 1073741824.0),
            ("1.5GiB", 1.5 * 1073741824.0),
            ("512M", 512.0 * 1048576.0),
            ("64 kb", 64.0 * 1024.0),
            ("1T", 1099511627776.0),
            ("1000", 1000.0),
            ("1000B", 1000.0),
        ] {
            let b = MemoryBudget::parse(text).expect(text);
            assert_eq!(b.bytes, bytes, "{text}");
            assert!(b.source.contains(text.trim()), "{}", b.source);
        }
        for bad in [
            "", "G", "0", "-1G", "nan", "inf", "1e400", "1e300T", "2X", "1.5.2M", "½G",
        ] {
            let e = MemoryBudget::parse(bad).expect_err(bad);
            assert!(e.starts_with("--memory:") && !e.contains('\n'), "{e}");
        }
    }

    /// The default budget is a fixed fraction of the installed memory, read each time the
    /// same: it does not follow what is free at the moment.
    #[test]
    fn the_default_budget_is_half_the_installed_memory() {
        let a = MemoryBudget::installed();
        assert_eq!(INSTALLED_MEMORY_FRACTION, 0.5);
        assert!(a.bytes.is_finite() && a.bytes > 0.0);
        assert_eq!(MemoryBudget::installed(), a);
        assert!(a.source.contains("installed"), "{}", a.source);
    }
}
